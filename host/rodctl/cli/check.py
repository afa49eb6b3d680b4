"""rodctl check: the first power-on's bring-up check (rodctl.check)."""

from __future__ import annotations

import json
import sys

from rodgains.atomic_file import atomic_write

from rodctl.cli.common import add_design_args, add_port_arg, session_for, stop_signals
from rodctl.cli.outputs import check_output


def _design(args, session=None):
    """(the design the board is checked against, its label, the flash command that gives a board that design): the
    given --params/--set, else a virtual board's own file (sim://?params=FILE), else the default file."""
    from rodgains.params import DEFAULT_PARAMS, load_params

    from rodctl.paths import shown

    path, overrides = args.params, list(args.overrides)
    dev = getattr(getattr(session, "ser", None), "device", None)
    if path is None and not overrides and getattr(dev, "params", None) is not None:
        path, overrides, params = getattr(dev, "params_path", None), list(getattr(dev, "overrides", ())), dev.params
        path = None if path is None else str(path)
    else:
        params = load_params(path, overrides)
    over = "".join(f" --set {o}" for o in overrides)
    flash = f"rodctl flash{f' --params {shown(path)}' if path else ''}{over}"
    return params, shown(path or DEFAULT_PARAMS) + over, flash


def _fix(session, report, yes: bool) -> None:
    """--fix: store the signs the check measured wrong on the board, after a yes."""
    from rodctl.check.runner import store_signs

    if not report.fixes:
        why = ("nothing to fix" if report.passed or not any(r.step in ("encoder", "motor") and r.status == "FAIL"
                                                             for r in report.results)
               else "no sign was measured unambiguously (the encoder step needs a hand)")
        print(f"fix: {why}; the board's signs are unchanged")
        return
    text = ", ".join(f"{k}={v:+d}" for k, v in report.fixes.items())
    if not yes:
        print(f"Store {text} on the board? [y/N] ", end="", file=sys.stderr, flush=True)
        answer = sys.stdin.readline()
        if answer.strip().lower() not in ("y", "yes"):
            closed = "" if answer else " (no answer: the input is closed; --fix --yes stores without asking)"
            print(f"fix: not stored{closed}", file=sys.stderr)
            return
    now = store_signs(session, report.fixes)
    report.stored = {k: int(now[k]) for k in report.fixes}
    print(f"fix: stored {text} on the board (its HELLO: encoder_sign {now['encoder_sign']:+.0f}, motor_sign "
          f"{now['motor_sign']:+.0f}, stored); run `rodctl check` again to prove them")


def run_check_command(args) -> int:
    from rodctl.check import run_check
    from rodctl.check.user import VirtualHand, user_for

    if args.json is not None:  # an empty name is refused, not taken for no record
        check_output(args.json, "--json", force=args.force)
    _design(args)  # a bad --params or --set is named before the board is opened
    say = lambda text: print(f"  {text}", file=sys.stderr, flush=True)  # noqa: E731
    show = lambda r: print(r.line(), flush=True)  # noqa: E731
    try:
        with stop_signals(), session_for(args) as s:
            params, label, flash = _design(args, s)
            user = user_for(s, args.yes)
            if isinstance(user, VirtualHand):
                say("sim://: the virtual board's hand turns the rod when a step asks for a hand")
            report = run_check(s, params, label, user, say=say, report=show, flash_hint=flash)
            if args.fix:
                _fix(s, report, args.yes)
    except KeyboardInterrupt:
        print("rodctl: interrupted; the board is disarmed (nothing was written)", file=sys.stderr)
        return 130
    print(report.summary())
    if args.json:
        atomic_write(args.json, json.dumps(report.to_json(), indent=1) + "\n")  # whole or not at all
    return 0 if report.passed else 1


def register(sub) -> None:
    p = sub.add_parser(
        "check", help="first power-on: prove the wiring, the signs and the loop before the first arm",
        description="A guided bring-up check of a powered rig: identity (firmware, protocol, the header's design "
                    "against --params), loop health over 2 s, the driver's nFAULT, the encoder (at rest, and a "
                    "quarter turn by hand), the motor's direction and gain (short torque pulses with the rod "
                    "hanging, through IDENTIFY and all its safety), and the heartbeat trip. Each step ends with "
                    "one line: PASS, FAIL or SKIP, what was measured, and the fix; --fix stores the wiring signs it measured "
                    "wrong on the board. Never arms balance or "
                    "swing-up; the board is left disarmed. Exit 0 when nothing failed, 1 when a step failed "
                    "or the board does not answer, 2 on bad input.")
    add_port_arg(p)
    add_design_args(p)
    p.add_argument("--yes", action="store_true",
                   help="ask nothing; a step that needs a hand at the rod says so and is skipped "
                        "(on sim:// the virtual board's hand does it)")
    p.add_argument("--fix", action="store_true",
                   help="afterwards, store the encoder and motor signs the check measured wrong on the board "
                        "(its EEPROM; asked first unless --yes), so no reflash is needed")
    p.add_argument("--json", metavar="PATH", help="also write every step's result and numbers as JSON")
    p.add_argument("--force", action="store_true", help="replace an existing --json (a check's record is never "
                                                        "replaced silently)")
    p.set_defaults(func=run_check_command)
