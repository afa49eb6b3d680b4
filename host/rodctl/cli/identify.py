"""rodctl identify: run identification experiments on the board (or fit recorded logs) and write a
parameter file with the rig's identified motor and rod values."""

from __future__ import annotations

import argparse
import datetime as _dt
import math
import shlex
import sys
import time
from pathlib import Path

from rodgains.errors import InputError, UserError

from rodctl.cli.common import add_design_args, add_port_arg
from rodctl.cli.outputs import check_output, make_folder

REST_RATE_RAD_S = 0.05  # the rod counts as at rest below this base rate ...
REST_HOLD_S = 0.5  # ... for this long
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


def _wait_rest(session, settle: float = 0.0) -> None:
    """`settle` seconds, then until the base holds still (the fit starts every record at rest); a
    FAULT is reported."""
    from rodctl.link import protocol as P
    from rodctl.link.session import reason_text

    if settle > 0:
        print(f"  letting the rod settle for {settle:g} s", file=sys.stderr, flush=True)
        end = time.monotonic() + settle
        while time.monotonic() < end:
            session.check()
            time.sleep(0.05)
    still_since, deadline = None, time.monotonic() + REST_TIMEOUT_S
    while time.monotonic() < deadline:
        session.check()
        t = session.wait_telemetry(timeout=1.0)
        if t.mode == P.Mode.FAULT:
            raise UserError(f"device is in FAULT ({reason_text(t.reason)}): run `rodctl clear-fault` first")
        if abs(t.base_rate) < REST_RATE_RAD_S:
            still_since = still_since or time.monotonic()
            if time.monotonic() - still_since >= REST_HOLD_S:
                return
        else:
            still_since = None
        time.sleep(0.02)
    raise UserError(f"the rod did not come to rest within {REST_TIMEOUT_S:g} s (|base rate| < {REST_RATE_RAD_S} rad/s)")


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
    from rodctl.logs import LogWriter, device_metadata

    writer = None
    if log_path is not None:
        meta = device_metadata(session.hello, port=session.port, params=params, params_source=params_source,
                               start_unix=session.open_unix)
        writer = LogWriter(log_path, meta, n=session.hello.n)
        session.add_listener(writer, replay=False)
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


def run_port(args) -> int:
    from rodctl.ident import experiments as E

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


def _settle(session, settle, limits, source: str, args, log_dir: Path) -> None:
    """Play the settle move (not logged; `limits`: the parameters whose safety limits the watch uses), then
    wait --settle seconds and for a still base."""
    from rodctl.link import protocol as P
    from rodctl.link.session import reason_text

    watch = SwingWatch(limits, args.soft_limit)
    _, last = run_experiment(session, settle, None, limits, source, watch)
    if last.mode == P.Mode.FAULT:
        raise UserError(f"settle move: safety limit tripped: {reason_text(last.reason)} ({P.Reason(last.reason).name}); "
                        f"the motor is stopped (FAULT); the logs so far are in {log_dir}")
    if watch.over:
        raise UserError(f"settle move: {watch.over}; motor stopped: is the rod free to swing, and hanging? "
                        f"The logs so far are in {log_dir}")
    _wait_rest(session, args.settle)


def _run_and_fit(args, exps, log_dir: Path, stamp: str) -> int:
    from rodctl.cli.common import stop_signals
    from rodctl.ident import experiments as E
    from rodctl.link import protocol as P
    from rodctl.link.design import design_params
    from rodctl.link.session import Session, hello_counts_per_rev, reason_text

    logs = []
    with stop_signals(), Session(args.port) as session:
        # the rod the user measured (--params) is the fit's nominal rig, whatever gains the board was
        # flashed with (the records are the duty it played); without it, the board's own file. The
        # soft limits are the board's own, when its file is known.
        board, board_source = design_params(session, args)
        explicit = bool(args.params or args.overrides)
        params, source = (board, board_source) if board is not None and not explicit else _nominal(args)
        limits = board if board is not None else params
        h = session.hello
        # the board reduces counts with its own counts per turn (a rig setting); the fit reads them the same way
        board_counts = hello_counts_per_rev(h)
        if board_counts:
            params = params.with_counts_per_rev(board_counts)
        if h.decimation != 1:
            session.set("telemetry_decimation", 1)  # the fit replays every period's duty
        print(f"identify: {session.port}, firmware N={h.n} at {1e6 / h.period_us:g} Hz; nominal parameters: {source}",
              file=sys.stderr)
        settle = E.settle_move(params)
        for i, exp in enumerate(exps, 1):
            for attempt in range(1, MAX_TRIES + 1):
                # the first record starts from the rod the user hung still; every later one from where
                # the last experiment left the rig, which the settle move brings back to rest
                first = i == 1 and attempt == 1
                _wait_rest(session)  # a stopped experiment leaves the rod swinging: the settle move starts from rest
                _confirm(args, f"[{i}/{len(exps)}] {exp.describe()}" + ("" if first else f"\n  before it, {settle.describe()}"))
                if not first:
                    _settle(session, settle, limits, source, args, log_dir)
                path = log_dir / f"identify-{stamp}-{exp.name}{'' if attempt == 1 else f'-{attempt}'}.csv"
                watch = SwingWatch(limits, args.soft_limit)
                path, last = run_experiment(session, exp, path, params, source, watch)
                if last.mode == P.Mode.FAULT:
                    # a livelier rig than the amplitudes were sized for (softer rod, weaker back-EMF damping)
                    hint = (f"; for smaller swings: --scale {RETRY_SCALE * args.scale:.2g}"
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
                                    f"for smaller swings: --scale {args.scale * RETRY_SCALE ** MAX_TRIES:.2g}")
                print(f"  stopped: {watch.over}; log kept: {path}; playing it again at "
                      f"{smaller.amplitude * 1e3:.3g} mN m ({RETRY_SCALE:g} x)", file=sys.stderr, flush=True)
                exp = smaller
            logs.append(path)
            print(f"  done: {path} (largest swing {math.degrees(watch.angle_rad):.0f} deg from hanging, "
                  f"{watch.speed_rad_s:.1f} rad/s)", file=sys.stderr, flush=True)
    return fit_logs(args, logs, params, source)


def fit_logs(args, logs: list[Path], params=None, source: str = "") -> int:
    from rodctl.ident import experiments as E
    from rodctl.ident import fit as F
    from rodctl.ident import report as R

    records, digests, meta0, skipped = [], [], None, 0
    for path in logs:
        meta, recs = E.records_from_log(path)
        why = _ended_early(meta)
        if why is not None:
            # the live run fits only the runs that played to their end (a stopped one is played again
            # smaller): fitting its logs afterwards, by the glob a Ctrl-C names, must fit the same records
            print(f"fit: skipping {path}: the experiment did not play to its end ({why})", file=sys.stderr, flush=True)
            skipped += 1
            continue
        meta0 = meta0 or meta
        records += recs
        digests.append((Path(path).name, E.file_sha256(path)))
    if skipped and not digests:
        raise InputError(f"no experiment log played to its end ({skipped} skipped): nothing to fit")
    if params is None:
        params, source = _nominal(args, meta0)
    print(f"fit: {len(records)} records, {sum(r.seconds for r in records):.1f} s of excitation; nominal: {source}",
          file=sys.stderr, flush=True)
    model = F.fit_model(params, exact=args.exact_plant)
    own = "the parameter file's [plant]"
    print(f"fit plant: {own if not model else ', '.join(model) + ', then a polish on ' + own}",
          file=sys.stderr, flush=True)
    res = F.fit(records, params, starts=args.starts, progress=F.progress_printer(), model=model)
    print(f"identified in {res.seconds:.1f} s ({res.evaluations} simulations); "
          f"theta_1 residual {res.rms_counts:.2f} counts RMS; validation (held-out {100 * F.VALIDATION_FRACTION:g} %): "
          f"{F.validation_text(res.validation_fit_pct)}")
    print("\n".join(F.report_lines(res)))
    print("identifiability:")
    print("\n".join("  " + s for s in F.identifiability_text(res)))
    identified = R.identified_params(params, res)
    print(buckling_line(identified))
    choice = _choose_compensation(args, identified)
    out = Path(args.out)
    verdict = _verdict(args, R.written_params(params, res, choice))
    lines = verdict.lines(str(out))
    out.write_text(R.parameter_file(params, res, digests, compensation=choice, verdict=lines))
    plot = plot_path(args)
    R.figure(res, plot)
    print(f"wrote {out} and {plot}")
    for name, why in res.out_of_range.items():
        print(f"rodctl: {name}: {why}; kept nominal in {out}", file=sys.stderr)
    print("\n".join(lines))  # last, where no one can miss it
    return 0 if verdict.ready and not res.out_of_range else 1


def _ended_early(meta: dict) -> str | None:
    """How an experiment log of `rodctl identify` ended when it did not play to its end ("stopped: swung
    ..." past the soft limit, "interrupted: ..." where the log says "error" (a Ctrl-C or a lost link), "fault",
    "timeout"); None for a complete run, or a log without that record (another tool's, or one a kill cut off)."""
    end = meta.get("end")
    if end in (None, "", "done"):
        return None
    return "interrupted: Ctrl-C or a lost link" if end == "error" else str(end)


def incomplete_run(path: Path) -> str | None:
    """_ended_early for a log on disk."""
    from rodctl.logs import read_log

    try:
        return _ended_early(read_log(path, columns=["mode_code"]).trailer)
    except Exception:  # noqa: BLE001 - an unreadable log is reported by the fit that reads it
        return None


def _verdict(args, written):
    """The matrix on the identified rig's faithful plant with the design about to be written."""
    from rodctl.ident.verdict import judge

    cases = "nominal" if args.compensation_cases == "none" else args.compensation_cases
    print(f"verdict: the written design on the identified rig, gearbox included (matrix case set {cases})",
          file=sys.stderr, flush=True)
    return judge(written, cases, jobs=args.jobs)


def buckling_line(identified) -> str:
    """How far the identified rod is from buckling, and which matrix cases take it past."""
    from rodgains.buckling import clamped_ratio, margins_text

    from rodctl.sim.matrix import buckled_cases

    ratio = clamped_ratio(identified)
    text = (f"buckling: the rod above the hub is {ratio:.3f} x its clamped buckling length (Greenhill)"
            + (f"; it reaches 1 at {margins_text(identified)}" if 0.0 < ratio < 1.0 else ""))
    past = buckled_cases(identified)
    if past:
        text += ("\n  past it in the robustness matrix: " + ", ".join(f"{n} {v:.3f} x" for n, v in past.items())
                 + "; measured, no design held a matrix run straight past 1.002 x (docs/identification.md)")
    return text


def _choose_compensation(args, identified):
    """The friction compensation for the identified rig, judged by the matrix (ident/compensation.py);
    None: keep the nominal file's."""
    from rodctl.ident import compensation as C

    if args.compensation_cases == "none":
        return None
    if identified["motor"]["coulomb_friction"] < C.MIN_COULOMB_NM:
        choice = C.without_friction(identified, args.compensation_cases)
        print(f"friction compensation: 0 mN m ({choice.note})")
        return choice
    print(f"friction compensation: {', '.join(f'{r:g}' for r in C.RATIOS)} x the identified Coulomb friction and "
          f"the nominal file's {1e3 * identified['lqr']['friction_compensation']:.2f} mN m, each judged by the "
          f"robustness matrix ({args.compensation_cases}) on the identified rig with an ideal gearbox (the play's "
          "lean would swamp the difference; the closing verdict keeps the play, so its counts differ)",
          file=sys.stderr, flush=True)
    choice = C.choose(identified, cases=args.compensation_cases, jobs=args.jobs,
                      say=lambda line: print(f"friction compensation: {line}", file=sys.stderr, flush=True))
    for c in choice.candidates:
        print(f"  {c.line()}", file=sys.stderr)
    print(f"friction compensation: {1e3 * choice.best.torque_nm:.2f} mN m ({choice.best.ratio:.3g} x)"
          f"{choice.best.with_weight(', ')}")
    return choice


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

    def say(text: str) -> None:
        print(text, file=sys.stderr, flush=True)

    with session_for(args) as s:
        still, turn = measure(s, user_for(s, args.yes), say)
    try:
        cal = calibrate(still, turn)
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
    # the figure is this run's too: an existing one (often from another rig's run) is kept unless --force
    check_output(plot_path(args), "--plot", force=args.force, figure=True)


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
        return fit_logs(args, logs)
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
                    "outside its physical range (kept nominal); exit 2: bad input or data that cannot identify the rig.",
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
