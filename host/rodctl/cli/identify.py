"""rodctl identify: run identification experiments on the board (or fit recorded logs) and write a
parameter file with the rig's identified motor and rod values. The workflow is rodctl.ident.run (the
board's experiments) and rodctl.ident.fit_logs (the fit of their logs)."""

from __future__ import annotations

import argparse
import datetime as _dt
import math
import shlex
import sys
from pathlib import Path

from rodgains.errors import InputError

from rodctl.cli.common import add_design_args, add_port_arg
from rodctl.cli.outputs import check_apart, check_name, check_output, make_folder
from rodctl.ident.run import MAX_TRIES, RETRY_SCALE, SETTLE_S, SOFT_LIMIT_FRACTION


def _nominal(args, meta: dict | None = None):
    """(Params, where from): --params/--set, else the log's own parameters, else the defaults."""
    from rodgains.params import load_params

    if args.params or args.overrides:
        return load_params(args.params, args.overrides), args.params or "defaults with --set"
    if meta:
        from rodctl.logs import params_of

        p = params_of(meta)
        if p is not None:
            return p, "the log's parameters"
    return load_params(), "defaults (gains/rodgains/default.toml): pass --params with your rod's measurements"


def _confirm(args, text: str) -> None:
    print(text, file=sys.stderr, flush=True)
    if args.yes:
        return
    if not sys.stdin.isatty():
        raise InputError("the motor is about to move and no one can confirm: pass --yes to run without asking")
    answer = input("The motor will move. Rod hanging at rest, nothing in its way? [y/N] ").strip().lower()
    if answer not in ("y", "yes"):
        raise InputError("stopped before moving the motor (not confirmed)")


def _say(text: str) -> None:
    print(text, file=sys.stderr, flush=True)


def run_port(args) -> int:
    from rodctl.ident import experiments as E
    from rodctl.ident.fit_logs import incomplete_run

    if not 0 < args.scale <= 4:
        raise InputError(f"--scale must be in (0, 4], got {args.scale:g}")
    if not 0 < args.soft_limit <= 1:
        raise InputError(f"--soft-limit must be in (0, 1], got {args.soft_limit:g}")
    exps = [e.scaled(torque=args.scale) for e in E.select(args.experiment)]
    log_dir = make_folder(args.log_dir, f"--log-dir {args.log_dir}")
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    try:
        return _run_and_fit(args, exps, log_dir, stamp)
    except KeyboardInterrupt:
        kept = [f for f in log_dir.glob(f"identify-{stamp}-*.csv") if not f.name.endswith(".events.csv")]
        if not kept:
            raise
        complete = [f for f in kept if incomplete_run(f) is None]
        if not complete:
            print(f"rodctl: interrupted; the motor is off; no experiment played to its end (log{'s' * (len(kept) > 1)} "
                  f"kept: {', '.join(str(f) for f in kept)})", file=sys.stderr)
            return 130
        pattern = shlex.quote(str(log_dir / f"identify-{stamp}-")) + "*.csv"
        # the file the user asked for, not the default my_rod.toml
        pattern += "".join(f" {o} {shlex.quote(str(v))}" for o, v in (("--out", args.out), ("--plot", args.plot)) if v)
        played = "" if len(complete) == len(kept) else f" ({len(complete)} played to the end; the fit skips the others)"
        print(f"rodctl: interrupted; the motor is off; {len(kept)} experiment log{'s' * (len(kept) > 1)} kept{played}: "
              f"fit {'them' if len(complete) > 1 else 'it'} with: rodctl identify {pattern}", file=sys.stderr)
        return 130


def _run_and_fit(args, exps, log_dir: Path, stamp: str) -> int:
    from rodctl.cli.common import session_for, stop_signals
    from rodctl.ident import run as RUN
    from rodctl.link.design import design_params

    # a sim:// board is built from --params / --set, as a board would be flashed with them
    with stop_signals(), session_for(args) as session:
        # the rod the user measured (--params) is the fit's nominal rig, whatever gains the board was
        # flashed with (the records are the duty it played); without it, the board's own file. The
        # soft limits are the board's own, when its file is known.
        board, board_source = design_params(session, args)
        explicit = bool(args.params or args.overrides)
        params, source = (board, board_source) if board is not None and not explicit else _nominal(args)
        limits = board if board is not None else params
        h = session.hello
        params = RUN.prepare(session, params)
        print(f"identify: {session.port}, firmware N={h.n} at {1e6 / h.period_us:g} Hz; nominal parameters: {source}",
              file=sys.stderr)
        logs = RUN.run_experiments(session, exps, log_dir, stamp, params, source, limits, scale=args.scale,
                                   soft_limit=args.soft_limit, settle_s=args.settle,
                                   confirm=lambda text: _confirm(args, text), say=_say)
    return _fit(args, logs, params, source)


def _fit(args, logs: list[Path], params=None, source: str = "") -> int:
    from rodctl.ident.fit_logs import fit_logs

    ok = fit_logs(logs, params, source, nominal=lambda meta: _nominal(args, meta), out=Path(args.out),
                  plot=plot_path(args), starts=args.starts, exact=args.exact_plant, cases=args.compensation_cases,
                  jobs=args.jobs, say=_say, show=print)
    return 0 if ok else 1


def _check_compensation_cases(args) -> None:
    """Before the motor moves: the choice after the fit must not fail on its options."""
    from rodctl.robust.execute import check_jobs
    from rodctl.robust.score import case_set

    case_set(args.compensation_cases, option="--compensation-cases", also=("none",))
    check_jobs(args.jobs)


def run_imu(args) -> int:
    """--imu: the tip IMU's calibration on the hanging rod (rodctl.ident.imu_cal); nothing moves the motor."""
    from rodctl.check.user import user_for
    from rodctl.cli.common import session_for
    from rodctl.ident.imu_cal import calibrate, measure

    if args.logs:
        raise InputError("--imu measures on the board: give --port, not LOG files")

    from rodctl.link.design import design_params

    with session_for(args) as s:
        params, _ = design_params(s, args)  # the tilt its firmware already turns back
        still, turn = measure(s, user_for(s, args.yes), _say)
    try:
        cal = calibrate(still, turn, params["sensors"]["imu_tilt_deg"] if params is not None else None)
    except ValueError as e:
        raise InputError(str(e)) from None
    for line in cal.lines():
        print(line)
    print("IMU: PASS" if cal.ok else "IMU: FAIL")
    return 0 if cal.ok else 1


def plot_path(args) -> Path:
    """--plot, else --out with .png."""
    return Path(args.plot) if args.plot else Path(args.out).with_suffix(".png")


def check_outputs(args) -> None:
    check_output(args.out, "--out", force=args.force)
    if args.plot is not None:
        check_name(args.plot, "--plot")  # an empty name is refused, not taken for the default
    plot = plot_path(args)
    # the figure is this run's too: an existing one (often from another rig's run) is kept unless --force
    check_output(plot, "--plot", force=args.force, figure=True)
    check_apart(plot, "--plot", args.out, "--out")


def run_identify(args) -> int:
    if args.imu:
        return run_imu(args)
    if args.logs and args.port:
        raise InputError("give recorded LOG files or --port, not both")
    if args.starts < 1:
        raise InputError("--starts must be >= 1")
    if not (math.isfinite(args.settle) and 0 <= args.settle <= 600):
        raise InputError(f"--settle {args.settle:g}: must be in [0, 600] s")
    _check_compensation_cases(args)
    check_outputs(args)  # before the fit or the first experiment: the motor never moves for a bad path
    if args.logs:
        # A shell glob such as logs/*.csv also matches the CSV logs' event sidecars: not logs of their own.
        logs = [Path(p) for p in args.logs if not str(p).endswith((".events.csv", ".csv.json"))]
        return _fit(args, logs)
    return run_port(args)


def register(sub) -> None:
    from rodctl.ident.experiments import DEFAULT_SEQUENCE

    names = ", ".join(e.name for e in DEFAULT_SEQUENCE)
    p = sub.add_parser(
        "identify", help="measure the rig: excitation experiments + output-error fit -> parameter file",
        description="With --port: run the identification experiments (default: " + names + ") with the rod "
                    "hanging, asking before each one moves the motor, log each, then fit. With LOG files: fit "
                    "recorded logs. The fit identifies rotor inertia, viscous and Coulomb friction, a "
                    "torque-constant scale, the rod's Young's modulus and damping, the gearbox's backlash and the "
                    "encoder's zero error against the project's C plant, chooses the dry-friction compensation for the identified rig by the robustness "
                    "matrix, writes a complete parameter file with 95 % intervals, and ends with a verdict: the written "
                    "design judged by the matrix on the identified rig (gearbox included), whether the nominal goals "
                    "are met, and what to try next. Exit 0: READY; exit 1: file written but NOT READY, or a value "
                    "outside its physical range (kept nominal), or an experiment stopped (a FAULT, a rod that did not "
                    "come to rest: nothing written, the logs so far kept); exit 2: bad input or data that cannot identify the rig.",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("logs", nargs="*", metavar="LOG", help="recorded logs to fit instead of running experiments")
    add_port_arg(p)
    p.add_argument("--experiment", action="append", metavar="NAME", help=f"run only these ({names}; repeatable)")
    p.add_argument("--out", default="my_rod.toml", metavar="PATH", help="parameter file to write (default my_rod.toml)")
    p.add_argument("--force", action="store_true", help="overwrite --out and --plot")
    p.add_argument("--plot", metavar="PNG", help="figure of measured vs simulated theta_1 (default: --out with .png)")
    p.add_argument("--log-dir", default=".", metavar="DIR", help="where the experiments' logs go (default .)")
    p.add_argument("--yes", action="store_true", help="do not ask before moving the motor")
    p.add_argument("--imu", action="store_true",
                   help="calibrate the tip IMU instead (firmware with sensors.tip_imu): its gyro bias, its axes against "
                        "gravity and its mounting tilt with the rod hanging, then its sign under a hand's turn; the "
                        "motor stays off. Exit 0 PASS, 1 FAIL (each failure names its fix)")
    p.add_argument("--settle", type=float, default=SETTLE_S, metavar="S",
                   help=f"wait S seconds after the settle move between experiments (default {SETTLE_S:g})")
    p.add_argument("--scale", type=float, default=1.0, metavar="X",
                   help="multiply every experiment's torque amplitude (default 1: sized for the Table I rod)")
    p.add_argument("--soft-limit", type=float, default=SOFT_LIMIT_FRACTION, metavar="F",
                   help=f"stop an experiment once the swing passes F x the firmware's angle or speed limit and play "
                        f"it again {RETRY_SCALE:g} x smaller, up to {MAX_TRIES} tries (default {SOFT_LIMIT_FRACTION:g}: "
                        f"48 deg and 32 rad/s with the default limits; 1: only the firmware's own limits, which FAULT)")
    p.add_argument("--starts", type=int, default=3, metavar="N", help="optimizer starts (default 3)")
    p.add_argument("--exact-plant", action="store_true",
                   help="run every start on the parameter file's [plant] as is (a DER plant: ~5x slower); "
                        "default: the starts on the inextensible rod with at most 20 flexible edges, then the best "
                        "one polished on the file's plant")
    p.add_argument("--compensation-cases", default="matrix", metavar="SET",
                   help="after the fit, choose lqr.friction_compensation for the identified rig by this case set "
                        "of the robustness matrix (matrix, quick, nominal, plants; about 4 min for matrix on 2 cores, as "
                        "long again when none passes every run and the stiffer lqr.q_shaft_angle 400 is tried "
                        "too), or none to keep the nominal file's (default matrix); the closing verdict runs the same set on the "
                        "identified rig with its gearbox (with none: the nominal runs only)")
    p.add_argument("--jobs", type=int, metavar="N", help="worker processes for that choice (default: every core)")
    add_design_args(p, "your rig's parameter file, with the rod you measured (length, width, thickness, density): "
                       "the fit's nominal rig, whatever file the board was built from; with --port sim:// it also "
                       "builds the virtual board's firmware and plant")
    p.set_defaults(func=run_identify)
