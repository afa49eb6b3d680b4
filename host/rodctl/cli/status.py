"""One-shot device commands: status, disarm, clear-fault, set."""

from __future__ import annotations

import json

from rodctl.cli.common import add_design_args, add_port_arg, session_for, stop_signals
from rodctl.link import protocol as P
from rodctl.link.design import apply_settings, design_params
from rodctl.link.session import (SETTINGS, Session, cleared_text, fault_text, hello_settings, mode_text, name_of,
                                 parse_assignment, rig_source)
from rodctl.logs.schema import from_upright_deg


def status_report(session: Session, args=None) -> dict:
    h = session.hello
    t = session.wait_telemetry(timeout=2.0)
    params, source = design_params(session, args)
    return {
        "port": session.port,
        "firmware_version": f"{h.fw_major}.{h.fw_minor}.{h.fw_patch}",
        "gains_schema": h.gains_schema,
        "protocol_version": P.VERSION,
        "header_sha256": bytes(h.header_sha256).hex(),
        "params_source": source if params is not None else "unknown",
        "n": h.n,
        "rate_hz": 1e6 / h.period_us,
        "decimation": h.decimation,
        # the board's f32 to its 7 digits: 180 deg, not the 180.00000500895632 its radians make
        "settings": {k: None if v != v else v if k == "counts_per_rev" else float(f"{v:.7g}")  # NaN: unknown; the
                     for k, v in hello_settings(h).items()},  # counts a fraction num / den, not an f32
        "settings_units": {k: SETTINGS[k].unit or "1" for k in SETTINGS},
        "signs_from": rig_source(h),
        "torque_max_Nm": float(f"{h.torque_max:.7g}"),
        "mode": name_of(P.Mode, t.mode),
        "reason": name_of(P.Reason, t.reason),
        "flags": [f.name for f in P.TelemetryFlag if int(t.flags) & int(f)],
        "encoder_count": t.encoder_count,
        "theta_hat_rad": list(t.theta_hat),
        "rate_hat_rad_s": list(t.rate_hat),
        "base_rate_rad_s": t.base_rate,
        "torque_Nm": t.torque,
        "duty": t.duty,
        "overruns": t.overruns,
        "frames_dropped": t.frames_dropped,
        "rx_errors": t.rx_errors,
    }


def run_status(args) -> int:
    with stop_signals(), session_for(args) as s:
        r = status_report(s, args)
    if args.json:
        print(json.dumps(r, indent=1))
        return 0
    st = r["settings"]
    mode = mode_text(P.Mode[r["mode"]], P.Reason[r["reason"]])
    print(f"port        {r['port']}")
    print(f"firmware    {r['firmware_version']} (gains schema {r['gains_schema']}), protocol v{r['protocol_version']}")
    print(f"gains       N={r['n']} at {r['rate_hz']:g} Hz, header sha256 {r['header_sha256'][:16]}..., "
          f"parameters {r['params_source']}")
    print(f"mode        {mode}; flags {', '.join(r['flags']) or 'none'}")
    print(f"settings    swing_amplitude {st['swing_amplitude']:.4g} N m, swing_angle_deg {st['swing_angle_deg']:.4g} deg, "
          f"catch_angle_deg {st['catch_angle_deg']:.4g} deg, telemetry_decimation {st['telemetry_decimation']:g}, "
          f"heartbeat_timeout {st['heartbeat_timeout']:.3g} s (torque max {r['torque_max_Nm']:.3g} N m)")
    print(f"wiring      {rig_text(st)} ({r['signs_from']})")
    th = ", ".join(f"{from_upright_deg(x):+.1f}" for x in r["theta_hat_rad"])
    print(f"telemetry   encoder {r['encoder_count']} counts, theta_hat [{th}] deg from upright, base rate "
          f"{r['base_rate_rad_s']:+.3f} rad/s, torque {r['torque_Nm']:.3g} N m, duty {r['duty']:.3g}")
    print(f"counters    since boot: overruns {r['overruns']}, frames dropped {r['frames_dropped']}, rx errors {r['rx_errors']}")
    return 0


def rig_text(settings: dict) -> str:
    """The rig settings of a HELLO (hello_settings) on one line."""
    return (f"encoder_sign {settings['encoder_sign']:+.0f}, motor_sign {settings['motor_sign']:+.0f}, "
            f"counts_per_rev {settings['counts_per_rev']:.6g} counts/turn")


def run_disarm(args) -> int:
    with stop_signals(), session_for(args, disarm_on_close=False) as s:
        ack = s.disarm()
        if ack.mode == P.Mode.FAULT:
            print(f"{fault_text(s.current_reason())}; the driver is off")
        else:
            print(f"disarmed: mode {name_of(P.Mode, ack.mode)}")
    return 0


def run_clear_fault(args) -> int:
    with stop_signals(), session_for(args) as s:
        before = s.wait_telemetry(timeout=2.0)
        print(cleared_text(before, s.clear_fault()))
    return 0


def run_set(args) -> int:
    for a in args.assignments:
        parse_assignment(a)
    with stop_signals(), session_for(args) as s:
        apply_settings(s, args.assignments, args, out=print, kept=args.save)
        if args.save:
            now = s.save_rig()
            print(f"stored on the board for every power-on: {rig_text(now)}")
    return 0


def register(sub) -> None:
    p = sub.add_parser("status", help="firmware identity, settings and one telemetry frame",
                       description="Connect, print the HELLO (firmware version, header hash, N, rate, settings) "
                                   "and one telemetry frame, then disarm and disconnect.")
    add_port_arg(p)
    add_design_args(p)
    p.add_argument("--json", action="store_true", help="print as JSON")
    p.set_defaults(func=run_status)

    p = sub.add_parser("disarm", help="turn the motor driver off (DISARMED, reason HOST)",
                       description="Send DISARM and wait for the board's acknowledgement: the driver off, the mode "
                                   "DISARMED with reason HOST. A board in FAULT stays there (its driver already off): "
                                   "rodctl clear-fault leaves it.")
    add_port_arg(p)
    p.set_defaults(func=run_disarm)

    p = sub.add_parser("clear-fault", help="leave FAULT for DISARMED",
                       description="Send CLEAR_FAULT: a board in FAULT goes to DISARMED (the driver stays off) and "
                                   "says which fault it cleared; one that is not in FAULT says so. Three are held until "
                                   "the board restarts: no control timer, an upload under way, and a restart by its "
                                   "watchdog (the encoder's zero is then wherever the rod was: power it off and on "
                                   "with the rod hanging).")
    add_port_arg(p)
    p.set_defaults(func=run_clear_fault)

    names = ", ".join(f"{s.name} [{s.unit or 'integer'}]" for s in SETTINGS.values())
    p = sub.add_parser("set", help="change run-time settings (swing amplitude/angle, catch angle, ...)",
                       description=f"Change run-time settings on the board until it resets. Names: {names}. "
                                   "The board checks the bounds; a refused value is reported with its range.")
    p.add_argument("assignments", nargs="+", metavar="NAME=VALUE")
    p.add_argument("--save", action="store_true",
                   help="then store the rig settings (encoder_sign, motor_sign, counts_per_rev) on the board, "
                        "read at every power-on (SAVE_RIG)")
    add_port_arg(p)
    add_design_args(p)
    p.set_defaults(func=run_set)
