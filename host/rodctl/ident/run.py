"""Driving the board through the identification experiments (`rodctl identify --port`): each one
logged to its own file, the rod at rest before it, a swing past the soft limit stopped and played
again smaller. The fit of the logs is rodctl.ident.fit_logs.

    from rodctl.ident import run
    params = run.prepare(session, params)    # the board's counts per turn; every period's telemetry
    logs = run.run_experiments(session, exps, log_dir, stamp, params, source, limits, scale=1.0,
                               soft_limit=0.8, settle_s=2.0, confirm=ask, say=say)
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Callable

from rodgains.errors import UserError

REST_RATE_RAD_S = 0.05  # the rod counts as at rest below this base rate ...
REST_HOLD_S = 0.5  # ... for this long, or while the count stays within rest_span_counts that long:
# a count that toggles at its edge is a rate spike of about 1 rad/s from the board's rate filter. An
# encoder on the rod's side of the play (encoder.location = "output", simulated) sees the rod sway inside
# the gap, where the motor's dry friction does not reach it: on the default rod with 2 to 3 deg of play,
# 1 to 3 counts after the settle move, for 16 s and more. A motor encoder never sees that sway.
REST_TIMEOUT_S = 20.0
# After the settle move (experiments.settle_move) the rod is near rest; this wait lets what is left
# of its sway die out before the next record starts (docs/identification.md).
SETTLE_S = 2.0
END_MARGIN_S = 3.0  # beyond the experiment's duration before the host gives up waiting
# The default amplitudes are sized for the nominal rig; a livelier one (softer rod, less back-EMF
# damping) can swing a chirp into the firmware's 60 deg limit and FAULT: 1 of 30 random rigs, whose
# steps also reached 56 deg, while the other 29 stayed within 46 deg in every experiment. The host
# stops an experiment (DISARM, no FAULT) once the swing passes this fraction of the firmware's angle
# or speed limit (48 deg, 32 rad/s), and plays it again RETRY_SCALE times smaller, at most MAX_TRIES
# times in all.
SOFT_LIMIT_FRACTION = 0.8
RETRY_SCALE = 0.7
MAX_TRIES = 3


def rest_span_counts(params) -> int:
    """How far the count may range and the base still be at rest [counts]: one count's toggle, and with
    an encoder on the output shaft the play's width (the rod's sway inside the gap, which the fit's start
    treats as rest as it does behind a motor encoder)."""
    span = 1
    if params["encoder"].get("location", "motor") == "output":
        span += int(math.ceil(math.radians(float(params["gearbox"]["backlash_deg"])) / params.rad_per_count))
    return span


def _wait_rest(session, say: Callable[[str], None], settle: float = 0.0, log_dir: Path | None = None,
               span_counts: int = 1) -> None:
    """`settle` seconds, then until the base holds still (the fit starts every record at rest); a
    FAULT is reported. log_dir: where the logs so far are, for the message when the rod does not rest;
    span_counts: rest_span_counts."""
    from rodctl.link import protocol as P
    from rodctl.link.session import fault_text

    if settle > 0:
        say(f"  letting the rod settle for {settle:g} s")
        end = time.monotonic() + settle
        while time.monotonic() < end:
            session.check()
            time.sleep(0.05)
    watch, deadline, t = RestWatch(span_counts), time.monotonic() + REST_TIMEOUT_S, None
    while time.monotonic() < deadline:
        session.check()
        t = session.wait_telemetry(timeout=1.0)
        if t.mode == P.Mode.FAULT:
            raise UserError(fault_text(t.reason))
        if watch.still(time.monotonic(), t.base_rate, t.encoder_count):
            return
        time.sleep(0.02)
    rate = (f"|base rate| {abs(t.base_rate):.2f} rad/s, the count over {watch.span()} steps at the end; "
            if t is not None else "")
    kept = (f"; the logs so far are in {log_dir} (rodctl identify LOG ... fits them)" if log_dir is not None
            and any(log_dir.glob("identify-*.csv")) else "")
    raise UserError(f"the rod did not come to rest within {REST_TIMEOUT_S:g} s ({rate}at rest: under "
                    f"{REST_RATE_RAD_S} rad/s or within {span_counts} count{'s' if span_counts > 1 else ''} for {REST_HOLD_S:g} s): "
                    f"is it free to hang still? The motor is off{kept}")


class RestWatch:
    """Whether the base has held still for REST_HOLD_S [s]: its rate under REST_RATE_RAD_S the whole
    time, or its count within span_counts [counts] the whole time."""

    def __init__(self, span_counts: int = 1):
        self.span_counts = int(span_counts)
        self._seen: list[tuple[float, int]] = []  # (time [s], count) over the last REST_HOLD_S
        self._slow_since: float | None = None

    def still(self, now: float, rate: float, count: int) -> bool:
        """now [s], rate [rad/s], count [counts]: True once the base has held still long enough."""
        if abs(rate) < REST_RATE_RAD_S:
            self._slow_since = now if self._slow_since is None else self._slow_since
        else:
            self._slow_since = None
        self._seen.append((now, int(count)))
        while len(self._seen) > 1 and now - self._seen[1][0] >= REST_HOLD_S:
            self._seen.pop(0)  # keep the oldest sample at least REST_HOLD_S back
        covered = now - self._seen[0][0] >= REST_HOLD_S
        slow = self._slow_since is not None and now - self._slow_since >= REST_HOLD_S
        return slow or (covered and self.span() <= self.span_counts)

    def span(self) -> int:
        """The count's range over the window [counts]."""
        counts = [c for _, c in self._seen]
        return max(counts) - min(counts) if counts else 0


class SwingWatch:
    """Session listener: the largest swing from hanging [rad] and base speed [rad/s] seen in
    IDENTIFY telemetry, and whether either passed its soft limit (every frame, not only the
    ones the polling loop happens to read)."""

    def __init__(self, params, fraction: float = SOFT_LIMIT_FRACTION):
        """fraction: of the firmware's limits [-]; 1 watches without ever stopping (the firmware trips first)."""
        from rodctl.link import protocol as P

        self._telemetry, self._identify = P.MsgType.TELEMETRY, P.Mode.IDENTIFY
        self.rad_per_count = params.rad_per_count
        self.fraction = fraction
        self.angle_soft_rad = fraction * math.radians(params["safety"]["angle_limit_deg"])
        self.speed_soft_rad_s = fraction * params["safety"]["speed_limit"]
        self.angle_rad = 0.0
        self.speed_rad_s = 0.0
        self.over = ""  # what passed its soft limit first ("" while nothing has)

    def __call__(self, frame, _host_time_s) -> None:
        if frame.type != self._telemetry or frame.msg.mode != self._identify:
            return
        # the firmware's angle from hanging: the count wrapped to one output turn
        a = abs(math.remainder(frame.msg.encoder_count * self.rad_per_count, 2.0 * math.pi))
        w = abs(frame.msg.base_rate)
        self.angle_rad, self.speed_rad_s = max(self.angle_rad, a), max(self.speed_rad_s, w)
        if self.fraction >= 1.0:
            return
        if not self.over and a > self.angle_soft_rad:
            self.over = f"swung {math.degrees(a):.0f} deg from hanging (soft limit {math.degrees(self.angle_soft_rad):.0f} deg)"
        elif not self.over and w > self.speed_soft_rad_s:
            self.over = f"reached {w:.1f} rad/s (soft limit {self.speed_soft_rad_s:.1f} rad/s)"


def run_experiment(session, exp, log_path: Path | None, params, params_source: str, watch: SwingWatch | None = None):
    """Play one experiment while logging every frame to log_path (None: not logged, the settle move);
    returns (log path, final telemetry). With a `watch`, the experiment is stopped (DISARM) as soon as
    watch.over says the swing passed its soft limit."""
    from rodctl.link import protocol as P
    from rodctl.logs.writer import attach_device_log

    writer = None
    if log_path is not None:
        writer = attach_device_log(session, log_path, params=params, params_source=params_source)
    if watch is not None:
        session.add_listener(watch, replay=False)
    ended = "error"
    try:
        session.command(exp.command(), what=f"identify {exp.name}")
        deadline = time.monotonic() + exp.duration + END_MARGIN_S
        last = session.wait_telemetry(timeout=1.0)
        started = time.monotonic()
        seen = False  # telemetry queued before the ACK still shows DISARMED: wait for IDENTIFY first
        while time.monotonic() < deadline:
            time.sleep(0.01)
            session.check()
            if watch is not None and watch.over:
                session.disarm()
                ended = "stopped: " + watch.over
                time.sleep(0.1)  # the frames already on their way
                return log_path, session.telemetry
            if writer is not None:
                writer.maybe_flush()  # rows reach the file while the rod moves: a crash keeps them
            last = session.telemetry
            if last is None:
                continue
            seen = seen or last.mode == P.Mode.IDENTIFY
            if last.mode != P.Mode.IDENTIFY and (seen or time.monotonic() - started > 1.0):
                break
        else:
            ended = "timeout"
            raise UserError(f"{exp.name}: still in IDENTIFY {END_MARGIN_S:g} s after its end; disarmed")
        time.sleep(0.1)  # the frames already on their way
        ended = "fault" if last.mode == P.Mode.FAULT else "done"
        return log_path, last
    except KeyboardInterrupt as e:
        from rodctl.link.attach import stopped_by

        ended = f"interrupted: {stopped_by(e)}"
        raise
    finally:
        if ended != "done" and not ended.startswith("stopped"):
            try:
                session.disarm()
            except UserError:
                pass
        if watch is not None:
            session.remove_listener(watch)
        if writer is not None:
            session.remove_listener(writer)
            writer.close({"end": ended, "experiment": exp.describe()})


def _settle(session, settle, limits, source: str, log_dir: Path, *, soft_limit: float, settle_s: float,
            span_counts: int, say: Callable[[str], None]) -> None:
    """Play the settle move (not logged; `limits`: the parameters whose safety limits the watch uses), then
    wait settle_s seconds and for a still base."""
    from rodctl.link import protocol as P
    from rodctl.link.session import reason_text

    watch = SwingWatch(limits, soft_limit)
    _, last = run_experiment(session, settle, None, limits, source, watch)
    if last.mode == P.Mode.FAULT:
        raise UserError(f"settle move: safety limit tripped: {reason_text(last.reason)} ({P.Reason(last.reason).name}); "
                        f"the motor is stopped (FAULT); the logs so far are in {log_dir}")
    if watch.over:
        raise UserError(f"settle move: {watch.over}; motor stopped: is the rod free to swing, and hanging? "
                        f"The logs so far are in {log_dir}")
    _wait_rest(session, say, settle_s, log_dir, span_counts)


def prepare(session, params):
    """`params` with the board's counts per turn (the board reduces counts with its own, a rig setting;
    the fit reads them the same way), and the board set to send every period's telemetry (the fit
    replays every period's duty)."""
    from rodctl.link.session import hello_counts_per_rev

    h = session.hello
    board_counts = hello_counts_per_rev(h)
    if board_counts:
        params = params.with_counts_per_rev(board_counts)
    if h.decimation != 1:
        session.set("telemetry_decimation", 1)
    return params


def run_experiments(session, exps, log_dir: Path, stamp: str, params, source: str, limits, *, scale: float,
                    soft_limit: float, settle_s: float, confirm: Callable[[str], None],
                    say: Callable[[str], None]) -> list[Path]:
    """Play `exps` one after another, each logged to log_dir/identify-<stamp>-<name>.csv; returns the
    logs of the runs that played to their end. params: the fit's nominal rig (written into each log);
    limits: the parameters whose safety limits the soft limits are a `soft_limit` fraction of; scale:
    the --scale the experiments were played at [-] (for the hint after a trip); settle_s: the wait
    after each settle move [s]. confirm(text) is asked before each experiment moves the motor (it
    raises to stop); say(text) reports progress."""
    from rodctl.ident import experiments as E
    from rodctl.link import protocol as P
    from rodctl.link.session import reason_text

    logs = []
    settle = E.settle_move(params)
    span = rest_span_counts(params)
    for i, exp in enumerate(exps, 1):
        for attempt in range(1, MAX_TRIES + 1):
            # the first record starts from the rod the user hung still; every later one from where
            # the last experiment left the rig, which the settle move brings back to rest
            first = i == 1 and attempt == 1
            _wait_rest(session, say, log_dir=log_dir, span_counts=span)  # a stopped experiment leaves the rod swinging: the settle move starts from rest
            confirm(f"[{i}/{len(exps)}] {exp.describe()}" + ("" if first else f"\n  before it, {settle.describe()}"))
            if not first:
                _settle(session, settle, limits, source, log_dir, soft_limit=soft_limit, settle_s=settle_s,
                        span_counts=span, say=say)
            path = log_dir / f"identify-{stamp}-{exp.name}{'' if attempt == 1 else f'-{attempt}'}.csv"
            watch = SwingWatch(limits, soft_limit)
            path, last = run_experiment(session, exp, path, params, source, watch)
            if last.mode == P.Mode.FAULT:
                # a livelier rig than the amplitudes were sized for (softer rod, weaker back-EMF damping)
                hint = (f"; for smaller swings: --scale {RETRY_SCALE * scale:.2g}"
                        if last.reason in (P.Reason.ANGLE_LIMIT, P.Reason.SPEED_LIMIT) else "")
                raise UserError(f"{exp.name}: safety limit tripped: {reason_text(last.reason)} "
                                f"({P.Reason(last.reason).name}); the motor is stopped (FAULT); log kept: "
                                f"{path}{hint}")
            if not watch.over:
                break
            # the stopped run's log stays on disk (it is a clean record), but the fit takes the
            # complete run: the amplitudes were chosen to excite every parameter for its whole length
            smaller = exp.scaled(torque=RETRY_SCALE)
            if attempt == MAX_TRIES:
                raise UserError(f"{exp.name}: {watch.over} at {exp.amplitude * 1e3:.3g} mN m, after "
                                f"{MAX_TRIES} tries; motor stopped; logs kept in {log_dir}; "
                                f"for smaller swings: --scale {scale * RETRY_SCALE ** MAX_TRIES:.2g}")
            say(f"  stopped: {watch.over}; log kept: {path}; playing it again at "
                f"{smaller.amplitude * 1e3:.3g} mN m ({RETRY_SCALE:g} x)")
            exp = smaller
        logs.append(path)
        say(f"  done: {path} (largest swing {math.degrees(watch.angle_rad):.0f} deg from hanging, "
            f"{watch.speed_rad_s:.1f} rad/s)")
    return logs
