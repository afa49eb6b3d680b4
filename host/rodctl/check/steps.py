"""The check's steps. Each measures on the board and returns one Result with the fix.

Conventions: theta_1 grows counter-clockwise seen from the front (docs/wiring.md), so a hand
turning the rod counter-clockwise and a positive torque must both raise the count.
"""

from __future__ import annotations

import numpy as np

from rodctl.check.model import planned_pulse
from rodctl.check.record import Recording
from rodctl.check.results import FAIL, PASS, SKIP, Result
from rodctl.link import protocol as P
from rodctl.link.session import hello_counts_per_rev, hello_settings, name_of, reason_text, rig_source

LOOP_S = 2.0  # loop-health window [s]
REST_NOISE_COUNTS = 1  # a still rod's count may flicker this much (one edge) [counts]
ZERO_TOLERANCE_COUNTS = 3  # the hanging rod reads within this of zero (the boot zero) [counts]
HAND_WATCH_S = 8.0  # how long the hand step watches after Enter [s]
HAND_MIN_COUNTS = 3  # less than this: the encoder did not see the turn [counts]
HAND_RANGE_DEG = (40.0, 150.0)  # "about a quarter turn" as read through the counts per turn
MOTOR_MIN_COUNTS = 3  # less than this under the pulses: nothing moved [counts]
MOTOR_GAIN_RANGE = (0.5, 2.0)  # measured / model excursion that passes [-]
HEARTBEAT_SLACK_S = 0.02  # the trip may come this much after the timeout (a few periods) [s]

ENCODER_WIRING = "check the encoder's 5 V and GND, and A and B to pins 3 and 4 (docs/wiring.md)"
ENCODER_SIGN_FIX = ("the encoder counts backwards: flip the board's encoder sign (`rodctl check --fix` stores it), "
                    "or swap the encoder's A and B wires")
MOTOR_SIGN_FIX = ("the motor turns the wrong way: flip the board's motor sign (`rodctl check --fix` stores it), "
                  "or swap the motor leads M1 and M2")


class Context:
    """What every step shares: the session, the design it is checked against, who can lend a hand."""

    def __init__(self, session, params, label: str, user, say=print, flash_hint: str = "rodctl flash"):
        self.session = session
        self.params = params
        self.label = label
        self.user = user
        self.say = say
        self.flash_hint = flash_hint
        self.design_cpr = float(params.counts_per_rev)  # the design's encoder counts per output turn
        # the board's own (a run-time rig setting, stored with the signs); the design's when it does not say
        self.cpr = hello_counts_per_rev(session.hello) or self.design_cpr
        self.rest: dict | None = None  # the loop step's recording of the rod at rest (the encoder step reads it)
        self.encoder_reversed: bool | None = None  # from the hand step; None: not measured
        self.motor_reversed: bool | None = None  # from the pulses, once the encoder's sign is known

    def deg(self, counts: float) -> float:
        return float(counts) * 360.0 / self.cpr

    def telemetry(self):
        return self.session.wait_telemetry(timeout=2.0)

    def driver_faulted(self) -> bool:
        return _driver_fault(self.telemetry())

    def ensure_disarmed(self) -> None:
        """Leave FAULT (other than the driver's own) so IDENTIFY may start."""
        t = self.telemetry()
        if t.mode == P.Mode.FAULT:
            self.session.clear_fault()


# ---- identity ---------------------------------------------------------------------------------

def identity(ctx: Context) -> Result:
    h = ctx.session.hello
    fw = f"{h.fw_major}.{h.fw_minor}.{h.fw_patch}"
    board = bytes(h.header_sha256).hex()
    want = ctx.params.sha256()
    values = {"firmware_version": fw, "protocol_version": P.VERSION, "gains_schema": int(h.gains_schema),
              "header_sha256": board, "design_sha256": want, "n": int(h.n), "period_us": int(h.period_us)}
    signs = hello_settings(h)
    values.update(encoder_sign=int(signs["encoder_sign"]), motor_sign=int(signs["motor_sign"]), signs_from=rig_source(h),
                  counts_per_rev=ctx.cpr, design_counts_per_rev=ctx.design_cpr)
    own = abs(ctx.cpr - ctx.design_cpr) > 1e-4  # the board holds its fraction to 1e-4 count
    counts = f"{ctx.cpr:.6g} counts/turn" + (f" (the design's {ctx.design_cpr:.6g})" if own else "")
    seen = (f"firmware {fw}, protocol v{P.VERSION}, N={h.n} at {1e6 / h.period_us:g} Hz, "
            f"signs encoder {signs['encoder_sign']:+.0f} motor {signs['motor_sign']:+.0f}, {counts} ({rig_source(h)}), "
            f"header {board[:12]}")
    if board != want:
        return Result("identity", FAIL, f"{seen}, but the design of {ctx.label} is {want[:12]}",
                      f"the board runs another design: flash this one with `{ctx.flash_hint}`", values)
    return Result("identity", PASS, f"{seen} = the design of {ctx.label}", values=values)


# ---- loop health ------------------------------------------------------------------------------

def loop(ctx: Context) -> Result:
    s = ctx.session
    h = s.hello
    gaps0 = s.seq_gaps
    with Recording(s) as rec:
        rec.wait(LOOP_S)
    a = rec.arrays()
    ctx.rest = a
    period_us = int(h.period_us)
    n = len(a["count"])
    if n < 2:
        return Result("loop", FAIL, f"{n} telemetry frames in {LOOP_S:g} s",
                      "the board sends no telemetry: reset it, and run `rodctl status`")
    span = float(a["t_s"][-1])
    expected_hz = 1e6 / period_us / max(1, int(h.decimation))
    rate_hz = (n - 1) / span if span > 0 else 0.0
    overruns = int(a["overruns"][-1]) - int(a["overruns"][0])
    dropped = int(a["frames_dropped"][-1]) - int(a["frames_dropped"][0])
    rx_err = int(a["rx_errors"][-1]) - int(a["rx_errors"][0])
    gaps = s.seq_gaps - gaps0
    step_med, step_max = float(np.median(a["step_us"])), int(np.max(a["step_us"]))
    values = {"step_us_median": step_med, "step_us_max": step_max, "period_us": period_us, "overruns": overruns,
              "telemetry_hz": rate_hz, "telemetry_hz_expected": expected_hz, "frames_dropped": dropped,
              "sequence_gaps": gaps, "rx_errors": rx_err}
    seen = (f"step {step_med:.0f} us median, {step_max} us max of {period_us} us; {overruns} overruns; telemetry "
            f"{rate_hz:.0f} of {expected_hz:.0f} Hz, {dropped} frames dropped, {rx_err} receive errors over {span:.1f} s")
    if overruns or step_max > period_us:
        return Result("loop", FAIL, seen, "the control step misses its period: build the release firmware "
                      "(`rodctl flash`), and keep other interrupts below the control timer's priority", values)
    if rate_hz < 0.9 * expected_hz or dropped or gaps:
        return Result("loop", FAIL, seen, "telemetry is lost on the way: plug the board into the computer "
                      "directly (no hub), or send less (`rodctl set telemetry_decimation=2`)", values)
    if rx_err:
        return Result("loop", FAIL, seen, "the board received damaged frames: another program on the port, "
                      "or a poor USB cable", values)
    return Result("loop", PASS, seen, values=values)


# ---- driver -----------------------------------------------------------------------------------

def _driver_fault(t) -> bool:
    """nFAULT low now, or the board latched a driver fault."""
    return bool(int(t.flags) & int(P.TelemetryFlag.NFAULT_LOW)) or (
        t.mode == P.Mode.FAULT and t.reason == P.Reason.DRIVER_FAULT)


def driver(ctx: Context) -> Result:
    t = ctx.telemetry()
    values = {"nfault_low": bool(int(t.flags) & int(P.TelemetryFlag.NFAULT_LOW)), "mode": name_of(P.Mode, t.mode),
              "reason": name_of(P.Reason, t.reason)}
    if _driver_fault(t):
        return Result("driver", FAIL, "nFAULT is low: the MAX14870 reports a fault and the board keeps the motor off",
                      "check the motor supply (VM, 4.5 to 36 V) and that the motor leads do not short, "
                      "and nFAULT's wire to pin 8 (docs/wiring.md)", values)
    return Result("driver", PASS, f"nFAULT high; mode {values['mode']}", values=values)


# ---- encoder ----------------------------------------------------------------------------------

def encoder(ctx: Context) -> Result:
    """At rest (from the loop step's recording): still, and hanging at its zero. Then a hand's quarter
    turn counter-clockwise: counts change, rise, and by about a quarter turn."""
    counts = ctx.rest["count"].astype(int)
    spread = int(counts.max() - counts.min()) if counts.size else 0
    hang = int(np.median(counts)) if counts.size else 0
    # a rod that went over the top hangs whole turns from its zero, which the firmware's angle counts: still its zero
    turns = int(round(hang / ctx.cpr))
    off = hang - turns * ctx.cpr  # [counts], not whole: a turn is 979.2 counts on the default gearmotor
    values = {"rest_spread_counts": spread, "hanging_count": hang, "hanging_deg": ctx.deg(hang), "hanging_turns": turns}
    if spread > REST_NOISE_COUNTS:
        return Result("encoder", FAIL, f"the count changes by {spread} with the rod at rest",
                      "electrical noise on A/B (a shielded cable away from the motor leads) or a loose coupling; "
                      "let the rod hang still and run the check again", values)
    round_text = f" after {abs(turns)} whole turn{'s' if abs(turns) != 1 else ''}" if turns else ""
    if abs(off) > ZERO_TOLERANCE_COUNTS:
        return Result("encoder", FAIL, f"the hanging rod reads {int(round(off))} counts ({ctx.deg(off):+.1f} deg) from zero"
                      f"{round_text}", "the board takes its zero at power-on: let the rod hang still, then reset "
                      "the board (its button, or unplug and replug USB)", values)
    rest_text = f"still at rest, hanging {int(round(off))} counts from zero{round_text}"
    instruction = "Turn the rod by hand about a quarter turn counter-clockwise (seen from the front) and back"
    ctx.say(f"encoder: {instruction}")
    if not ctx.user.do(instruction, ctx.session):
        return Result("encoder", SKIP, rest_text + "; the direction was not checked",
                      f"turning the rod needs a hand: {ctx.user.no_hand}",
                      values)
    with Recording(ctx.session) as rec:
        rec.wait(HAND_WATCH_S, until=lambda rows: _turn_done(rows, hang, ctx.cpr))
    a = rec.arrays()
    dev = a["count"].astype(int) - hang if a["count"].size else np.zeros(1, int)
    peak = int(dev[np.argmax(np.abs(dev))])
    values.update(turn_peak_counts=peak, turn_peak_deg=ctx.deg(peak))
    seen = f"{rest_text}; the turn read {peak:+d} counts ({ctx.deg(peak):+.0f} deg)"
    if abs(peak) < HAND_MIN_COUNTS:
        ctx.encoder_reversed = None
        return Result("encoder", FAIL, f"{rest_text}; the count did not change while the rod turned",
                      f"the encoder is not connected: {ENCODER_WIRING}", values)
    ctx.encoder_reversed = peak < 0
    lo, hi = HAND_RANGE_DEG
    if peak < 0:
        return Result("encoder", FAIL, seen, ENCODER_SIGN_FIX, values)
    if not lo <= ctx.deg(peak) <= hi:
        factor = ctx.deg(peak) / 90.0
        return Result("encoder", FAIL, seen + f", {factor:.1f} x a quarter turn",
                      f"the counts per output turn are not {ctx.cpr:.6g}: check encoder.counts_per_motor_rev and "
                      f"motor.gear_ratio in {ctx.label} (a gearmotor of another ratio?); for another encoder on "
                      "this gearbox, `rodctl set counts_per_rev=N --save` keeps the rig's own on the board", values)
    return Result("encoder", PASS, seen, values=values)


def _turn_done(rows, hang: int, cpr: float) -> bool:
    """The turn went out at least 20 deg and came back within 5 deg of where it started."""
    if not rows:
        return False
    dev = np.asarray([r[4] for r in rows]) - hang
    out = np.max(np.abs(dev)) * 360.0 / cpr
    return out >= 20.0 and abs(dev[-1]) * 360.0 / cpr <= 5.0


# ---- motor ------------------------------------------------------------------------------------

def motor(ctx: Context) -> Result:
    """Torque pulses +A, 0, -A, 0 through IDENTIFY; the count's response against the model's."""
    if ctx.driver_faulted():
        return Result("motor", SKIP, "no pulse", "the driver reports a fault (see driver)")
    exp, model = planned_pulse(ctx.params)
    model = model * (ctx.cpr / ctx.design_cpr)  # the model's counts are the design's; the board counts its own
    ctx.say(f"motor: {exp.describe().split(': ', 1)[1]} (the rod hanging, nothing in its way)")
    ctx.ensure_disarmed()
    _wait_still(ctx)
    a = _play(ctx, exp)
    ident = a["mode"] == P.Mode.IDENTIFY
    counts = a["count"][ident].astype(float)
    enabled = bool(np.any(a["flags"][ident].astype(int) & int(P.TelemetryFlag.DRIVER_ENABLED))) if ident.any() else False
    ended = _end_of(a)
    values = {"amplitude_Nm": exp.amplitude, "driver_enabled": enabled, "ended": ended}
    if counts.size < 2:
        return Result("motor", FAIL, f"the board did not play the pulses ({ended})",
                      "run `rodctl status` and clear any fault", values)
    meas = counts - counts[0]
    n = min(meas.size, model.size)
    m, p = meas[:n], model[:n]
    moved = float(np.max(np.abs(m)))
    values["peak_counts"] = moved
    values["model_peak_counts"] = float(np.max(np.abs(p)))
    amp = f"+-{exp.amplitude * 1e3:.0f} mN m"
    if moved < MOTOR_MIN_COUNTS:
        return Result("motor", FAIL, f"{amp} pulses moved the encoder {moved:.0f} counts "
                      f"(the model: {np.max(np.abs(p)):.0f})",
                      "the motor gets no power: the motor supply (VM) is off or the motor leads M1/M2 are loose; "
                      "or the encoder is not connected (the encoder step tells which)", values)
    gain = float(np.dot(m, p) / np.dot(p, p))
    values["gain"] = gain
    seen = (f"{amp} pulses: the rod moved {gain:+.2f} x the model of {ctx.label} "
            f"(peak {ctx.deg(moved):.1f} deg); driver enabled: {'yes' if enabled else 'no'}")
    if a["mode"].size and int(a["mode"][-1]) == P.Mode.FAULT:
        seen += f"; the board stopped them ({ended})"
    if ctx.encoder_reversed is not None:
        ctx.motor_reversed = (gain > 0) if ctx.encoder_reversed else (gain < 0)
    if ctx.encoder_reversed and gain < 0:
        # the count runs backwards, and so does the rate the drive's back-EMF compensation reads: only
        # the direction means something until the encoder is fixed
        return Result("motor", PASS, seen + ", against the torque as the reversed encoder counts: the motor "
                      "turns the right way (its size is judged once the encoder is fixed)", values=values)
    if gain < 0:
        if ctx.encoder_reversed is None:
            return Result("motor", FAIL, seen + ", against the commanded torque",
                          "the encoder or the motor is reversed: the encoder step with a hand (without --yes) "
                          "tells which", values)
        if not ctx.encoder_reversed:
            return Result("motor", FAIL, seen + ", against the commanded torque", MOTOR_SIGN_FIX, values)
    elif ctx.encoder_reversed:
        return Result("motor", FAIL, seen + " as the encoder counts, which is reversed: the motor turns "
                      "against the torque too", MOTOR_SIGN_FIX, values)
    lo, hi = MOTOR_GAIN_RANGE
    if not lo <= abs(gain) <= hi:
        return Result("motor", FAIL, seen, f"{'more' if abs(gain) > hi else 'less'} motion than the model: check "
                      f"motor.torque_constant, motor.gear_ratio and driver.supply_voltage in {ctx.label} "
                      "(and encoder.counts_per_motor_rev if the encoder step disagreed too); "
                      "`rodctl identify` measures them", values)
    return Result("motor", PASS, seen, values=values)


def _wait_still(ctx: Context, still_s: float = 0.5, limit_s: float = 10.0) -> None:
    """Until the count has held still for `still_s` (the model starts at rest), at most `limit_s`."""
    def still(rows) -> bool:
        if not rows:
            return False
        t_end, c_end = rows[-1][0], rows[-1][4]
        for r in reversed(rows):
            if r[4] != c_end:
                return False
            if (t_end - r[0]) % (1 << 32) >= still_s * 1e6:
                return True
        return False

    with Recording(ctx.session) as rec:
        rec.wait(limit_s, until=still)


def _play(ctx: Context, exp) -> dict:
    s = ctx.session
    with Recording(s) as rec:
        s.command(exp.command(), what="identify (check pulses)")
        rec.wait(exp.duration + 2.0, until=lambda rows: _left_identify(rows))
    return rec.arrays()


def _left_identify(rows) -> bool:
    modes = [r[1] for r in rows]
    return P.Mode.IDENTIFY in modes and modes[-1] != P.Mode.IDENTIFY


def _end_of(a: dict) -> str:
    if not a["mode"].size:
        return "no telemetry"
    mode, reason = int(a["mode"][-1]), int(a["reason"][-1])
    if mode == P.Mode.FAULT:
        return f"FAULT: {reason_text(reason)}"
    return name_of(P.Mode, mode)


# ---- heartbeat --------------------------------------------------------------------------------

def heartbeat(ctx: Context) -> Result:
    """Zero torque with the driver enabled (IDENTIFY RELEASE of a negligible push), then silence: the
    board must trip HEARTBEAT after its timeout."""
    if ctx.driver_faulted():
        return Result("heartbeat", SKIP, "not armed", "the driver reports a fault (see driver)")
    from rodctl.ident.experiments import Experiment

    s = ctx.session
    timeout = float(s.hello.heartbeat_timeout)
    period = s.hello.period_us * 1e-6
    hold = Experiment("check-heartbeat", int(P.Excitation.RELEASE), 1e-4, max(4 * timeout, 1.0), period)
    ctx.ensure_disarmed()
    _wait_still(ctx)
    ctx.say(f"heartbeat: the host falls silent for up to {2 * timeout + 1:g} s (zero torque, driver enabled)")
    with s.heartbeat_paused(), Recording(s) as rec:
        s.command(hold.command(), what="identify (heartbeat hold)")
        rec.wait(2 * timeout + 1.0, until=lambda rows: rows and rows[-1][1] == P.Mode.FAULT)
    a = rec.arrays()
    values = {"heartbeat_timeout_s": timeout}
    fault = np.flatnonzero(a["mode"] == P.Mode.FAULT) if a["mode"].size else np.zeros(0, int)
    armed = np.flatnonzero(a["mode"] == P.Mode.IDENTIFY) if a["mode"].size else np.zeros(0, int)
    if not fault.size or not armed.size:
        end = _end_of(a)
        if a["mode"].size:
            s.disarm()
        return Result("heartbeat", FAIL, f"silent for {2 * timeout + 1:g} s, the board stayed {end}",
                      "the firmware does not watch the host: reflash it (`rodctl flash`)", values)
    k = int(fault[0])
    # the hold started (heartbeat counted) one period before its first IDENTIFY frame
    t_trip = float(a["t_s"][k] - a["t_s"][armed[0]]) + period
    reason = int(a["reason"][k])
    enabled = bool(np.any(a["flags"][armed].astype(int) & int(P.TelemetryFlag.DRIVER_ENABLED)))
    values.update(trip_s=t_trip, reason=name_of(P.Reason, reason), driver_enabled=enabled)
    s.clear_fault()
    seen = (f"silent host: the board tripped {name_of(P.Reason, reason)} after {t_trip:.3f} s "
            f"(timeout {timeout:g} s), driver {'enabled' if enabled else 'off'} before")
    if reason != P.Reason.HEARTBEAT:
        return Result("heartbeat", FAIL, seen, f"the hold ended on {reason_text(reason)} before the host's "
                      "silence could: fix the steps above first", values)
    if not (timeout - 2 * period <= t_trip <= timeout + HEARTBEAT_SLACK_S):
        return Result("heartbeat", FAIL, seen, "the heartbeat watch is broken: reflash the firmware "
                      "(`rodctl flash`) and run the check again", values)
    return Result("heartbeat", PASS, seen, values=values)


STEPS = (identity, loop, driver, encoder, motor, heartbeat)  # in order: encoder reads loop's recording
