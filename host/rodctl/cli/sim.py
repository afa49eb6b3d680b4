"""rodctl sim: run a scenario on the simulated rod (the default main job, no hardware needed)."""

from __future__ import annotations

import re
import sys
import time
from pathlib import Path

import numpy as np

from rodgains.errors import InputError

from rodctl.cli.gains import add_param_args, params_from_args
from rodctl.cli.outputs import check_name, check_output, make_folder

TABLE_BEGIN = "<!-- BEGIN scenario table: regenerate with `rodctl sim --all --figures docs/img --table docs/scenarios.md` -->"
TABLE_END = "<!-- END scenario table -->"


class Progress:
    """One status line on stderr: rewritten in place on a terminal, a line per quarter otherwise."""

    def __init__(self, name: str):
        self.name = name
        self.tty = sys.stderr.isatty()
        self.last = -1
        self.t0 = time.monotonic()

    def __call__(self, label: str, fraction: float) -> None:
        pct = int(100 * fraction)
        if self.tty:
            bar = "#" * (pct // 5)
            sys.stderr.write(f"\r  {self.name} [{label}] [{bar:<20}] {pct:3d}%")
            sys.stderr.flush()
        elif pct // 25 != self.last // 25:
            sys.stderr.write(f"  {self.name} [{label}] {pct}%\n")
        self.last = pct

    def done(self) -> None:
        if self.tty:
            sys.stderr.write("\r" + " " * 70 + "\r")
            sys.stderr.flush()


def truth_name(log: Path) -> Path:
    """The simulator's true angles beside a log: LOG.truth.csv."""
    return log.with_name(log.stem + ".truth.csv")


def check_new_log(log: Path) -> None:
    """InputError when writing the log `log` would replace a file: the log's own files or its truth file."""
    from rodctl.logs.writer import check_new

    check_new(log, also=(truth_name(log),))


def write_log(o, trace, path: Path) -> tuple[Path, Path]:
    """The trace in the device log format (rodctl.logs.LogWriter), plus the true state beside it."""
    from rodctl import logs as logfile
    from rodctl.link import protocol as P

    p = o.params
    firmware = trace.est is not None
    n = trace.est.shape[1] // 2 if firmware else trace.theta.shape[1]
    meta = logfile.simulator_metadata(p, n=n, source=f"simulator: rodctl sim --scenario {o.name} ({trace.label}"
                                      + ("" if firmware else "; state feedback, theta_hat is the true state") + ")")
    period_us = int(round(p.dt * 1e6))
    w = logfile.LogWriter(path, meta, n=n, overwrite=True)  # run_one has checked --log against --force
    try:
        est = trace.est if firmware else np.hstack([trace.theta, np.zeros_like(trace.theta)])
        mode = trace.mode if trace.mode is not None else np.full(len(trace.t), 1)
        duty = trace.duty if trace.duty is not None else np.zeros(len(trace.t))
        count = trace.count if trace.count is not None else np.zeros(len(trace.t), int)
        for k in range(len(trace.t)):
            m = int(mode[k])
            reason = trace.reason if m == 3 else 0
            enabled = m in (1, 2)
            msg = P.Telemetry(m, reason, (1 if enabled else 0) | 4, n, int(count[k]), float(est[k, n]),
                              float(trace.torque[k]), float(duty[k]), 0, 0, 0, 0,
                              tuple(est[k, :n].tolist()), tuple(est[k, n:].tolist()))
            w.write_telemetry(msg, seq=k, time_us=(k * period_us) & 0xFFFFFFFF, host_time_s=float(trace.t[k]))
    finally:
        w.close()
    truth = truth_name(path)
    N = trace.theta.shape[1]
    header = "time_s," + ",".join(f"theta_{i + 1}_rad" for i in range(N))
    np.savetxt(truth, np.column_stack([trace.t, trace.theta]), delimiter=",", header=header, comments="",
               fmt="%.9g")
    return path, truth


def summary_lines(o) -> list[str]:
    from rodctl.sim.figures import fmt

    lines = [f"{o.name}: {o.title}", f"  {'PASS' if o.passed else 'FAIL'}: {o.criterion}"]
    head = f"  {'run':22s} {'settle<1deg [s]':>15s} {'overshoot [deg]':>15s} {'peak |u| [N m]':>14s} " \
           f"{'swing-up [s]':>12s} {'est. err [deg]':>14s} {'final [deg]':>11s}"
    lines.append(head)
    for label, m in o.metrics.items():
        lines.append(f"  {label:22s} {fmt(m['settle_s']):>15s} {fmt(m['overshoot_deg'], 1):>15s} "
                     f"{fmt(m['peak_torque_Nm'], 3):>14s} {fmt(m['swingup_s']):>12s} {fmt(m['est_rms_deg']):>14s} "
                     f"{fmt(m['final_dev_deg']):>11s}")
    return lines


def _outputs(args, name: str, all_mode: bool) -> tuple[Path | None, Path | None]:
    if all_mode:
        from rodctl.sim.scenarios import SCENARIOS

        if SCENARIOS[name].group == "robustness":  # 27 of them: the table carries their numbers
            return None, None
        folder = Path(args.figures)
        return folder / f"sim-{name}.png", None
    plot = None if args.no_plot else Path(args.plot or f"sim-{name}.png")
    log = None if args.no_log else Path(args.log or f"sim-{name}.csv")
    return plot, log


def run_one(args, name: str, params, all_mode: bool = False):
    from rodctl.sim.scenarios import Options, SCENARIOS

    scen = SCENARIOS[name]
    plot, log = _outputs(args, name, all_mode)
    for path, flag, figure in ((plot, "--figures" if all_mode else "--plot", True), (log, "--log", False)):
        if path is not None:  # before the run: the name, then the folder (made and checked writable)
            check_name(path, flag, figure=figure)
            if not figure:
                from rodctl.logs.writer import log_format

                try:
                    log_format(path)  # .csv, .parquet or .mcap
                except InputError as e:
                    raise InputError(f"{flag} {e}") from None
            make_folder(path.parent, f"{flag} {path}")
    if log is not None and args.log and not args.force:  # an explicit --log is never replaced silently
        check_new_log(log)
    if plot is not None and not all_mode and args.plot and not args.force and plot.exists():  # nor an explicit --plot
        raise InputError(f"--plot {plot} exists: choose another file name, or --force to replace it")
    prog = Progress(name)
    t0 = time.monotonic()
    try:
        o = scen.run(Options(params, progress=prog, duration=args.duration))
    finally:
        prog.done()
    wall = time.monotonic() - t0
    logs = []  # (trace, path): a run of several traces writes a log for each, named by its label
    if log is not None:
        traces = o.traces
        logs = [(traces[0], log)] if len(traces) == 1 else [
            (tr, log.with_name(f"{log.stem}-{re.sub(r'[^A-Za-z0-9.]+', '-', tr.label).strip('-')}{log.suffix}"))
            for tr in traces]
        if len(traces) > 1 and args.log and not args.force:  # known once run; checked before anything is written
            for _, path in logs:
                check_new_log(path)
    written = []
    if plot is not None:
        from rodctl.sim.figures import save

        save(o, plot)
        written.append(str(plot))
    for tr, path in logs:
        written += [str(f) for f in write_log(o, tr, path)]
    return o, wall, written


def table_markdown(outcomes) -> str:
    from rodctl.sim.figures import fmt
    from rodctl.sim.scenarios import SCENARIOS

    rows = ["| scenario | paper | run | plant | settle to 1 deg [s] | overshoot [deg] | peak torque [N m] | "
            "swing-up [s] | estimate error RMS [deg] | final [deg] | result |",
            "|---|---|---|---|---|---|---|---|---|---|---|"]
    for o in outcomes:
        s = SCENARIOS[o.name]
        if s.expect_pass is None:
            verdict = "pass" if o.passed else "fail (near the band: docs/control.md)"
        elif o.passed == s.expect_pass:
            verdict = "pass" if o.passed else "**fail** (documented below)"
        else:
            verdict = ("pass" if o.passed else "**fail**") + " (unexpected)"
        plants = {tr.label: (tr.plant or "paper's model") for tr in o.traces}
        for i, (label, m) in enumerate(o.metrics.items()):
            rows.append(f"| {o.name if i == 0 else ''} | {s.paper if i == 0 else ''} | {label} | {plants.get(label, '')} | "
                        f"{fmt(m['settle_s'])} | "
                        f"{fmt(m['overshoot_deg'], 1)} | {fmt(m['peak_torque_Nm'], 3)} | {fmt(m['swingup_s'])} | "
                        f"{fmt(m['est_rms_deg'])} | {fmt(m['final_dev_deg'])} | {verdict if i == 0 else ''} |")
    groups: dict[str, list[str]] = {}  # one line per distinct criterion (27 robust-* share one)
    for o in outcomes:
        groups.setdefault(o.criterion, []).append(f"`{o.name}`")
    crit = "\n".join(f"- {', '.join(names)}: {c}." for c, names in groups.items())
    return "\n".join(rows) + "\n\nPass criteria:\n\n" + crit + "\n"


def check_table_page(readme: Path) -> None:
    """InputError unless `readme` exists, holds the scenario-table markers, and can be rewritten."""
    check_output(readme, "--table")
    try:
        text = readme.read_text()
    except FileNotFoundError:
        raise InputError(f"--table {readme}: no such file (it needs the scenario-table markers)") from None
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"--table {readme}: cannot read it ({getattr(e, 'strerror', None) or e})") from None
    if TABLE_BEGIN not in text or TABLE_END not in text:
        raise InputError(f"{readme}: no scenario-table markers ({TABLE_BEGIN!r} ... {TABLE_END!r}) to replace")


def replace_table(readme: Path, table: str) -> None:
    text = readme.read_text() if readme.exists() else ""
    block = f"{TABLE_BEGIN}\n{table}{TABLE_END}"
    if TABLE_BEGIN in text and TABLE_END in text:
        start = text.index(TABLE_BEGIN)
        end = text.index(TABLE_END) + len(TABLE_END)
        text = text[:start] + block + text[end:]
    else:
        raise InputError(f"{readme}: no scenario-table markers ({TABLE_BEGIN!r} ... {TABLE_END!r}) to replace")
    readme.write_text(text)


def run_sim(args) -> int:
    from rodctl.sim.scenarios import DEFAULT, SCENARIOS

    if args.list:
        width = max(len(name) for name in SCENARIOS)
        for name, s in SCENARIOS.items():
            mark = " (default)" if name == DEFAULT else ""
            print(f"{name:{width}s} {s.paper:7s} {s.title}{mark}")
        return 0
    if args.duration is not None and not 0 < args.duration <= 600:
        raise InputError(f"--duration {args.duration}: must be in (0, 600] s")
    params = params_from_args(args)
    shorthand = ([f'plant.model="{args.plant}"'] if args.plant is not None else []) + \
        ([f"plant.edges={args.edges}"] if args.edges is not None else [])
    if shorthand:  # --plant / --edges: the [plant] table's model and edges, checked like --set
        params = params.with_overrides(*shorthand)
    names = list(SCENARIOS) if args.all else [args.scenario or DEFAULT]
    for name in names:
        if name not in SCENARIOS:
            raise InputError(f"unknown scenario {name!r}; one of: {', '.join(SCENARIOS)} (rodctl sim --list)")
    if args.all and args.readme:  # before every scenario has run, not after
        check_table_page(Path(args.readme))
    outcomes, unexpected = [], []
    for name in names:
        o, wall, written = run_one(args, name, params, all_mode=args.all)
        outcomes.append(o)
        sim_seconds = sum(tr.t[-1] + (tr.t[1] - tr.t[0]) for tr in o.traces)
        for line in summary_lines(o):
            print(line)
        print(f"  simulated {sim_seconds:.1f} s in {wall:.2f} s" + (f"; wrote {', '.join(written)}" if written else ""))
        expected = SCENARIOS[name].expect_pass
        if expected and not o.passed:
            unexpected.append(name)
        elif expected is False and o.passed:  # another rig's file, or a better design: good news, not an error
            print(f"  {name} passes, where the default rig's documented outcome is a fail (docs/scenarios.md)")
    if args.all and args.readme:
        replace_table(Path(args.readme), table_markdown(outcomes))
        print(f"updated the scenario table in {args.readme}")
    if unexpected:
        print(f"rodctl sim: {', '.join(unexpected)} failed where it must pass", file=sys.stderr)
        return 1
    return 0


def register(sub) -> None:
    s = sub.add_parser(
        "sim", help="simulate the rod with the firmware in the loop (default: swing-up and balance)",
        description="Run a scenario: the firmware's own C (SIL library built for the parameters) against the "
                    "simulated rod, motor, driver and encoder; or the paper's state-feedback figures. Writes a PNG "
                    "and a log in the device log format (rodctl plot reads it), and prints the metrics. Exit 1 "
                    "when a scenario that must pass fails; one whose documented outcome on the default rig is a fail "
                    "(docs/scenarios.md) exits 0 either way.")
    add_param_args(s)
    s.add_argument("--scenario", metavar="NAME", help="scenario to run (default: swingup); see --list")
    s.add_argument("--list", action="store_true", help="list the scenarios and exit")
    s.add_argument("--plot", metavar="PNG", help="figure to write (default: sim-NAME.png)")
    s.add_argument("--log", metavar="PATH", help="log to write, device log format (default: sim-NAME.csv)")
    s.add_argument("--no-plot", action="store_true", help="do not write the figure")
    s.add_argument("--no-log", action="store_true", help="do not write the log")
    s.add_argument("--force", action="store_true", help="replace an existing --log or --plot (the defaults "
                   "sim-NAME.csv and sim-NAME.png are always replaced)")
    s.add_argument("--plant", metavar="MODEL", help="the faithful plant's model: der or inextensible "
                   "(shorthand for --set plant.model=MODEL)")
    s.add_argument("--edges", type=int, metavar="N", help="the faithful plant's edges beyond the hub "
                   "(shorthand for --set plant.edges=N)")
    s.add_argument("--duration", type=float, metavar="S", help="simulated time [s] (default: the scenario's)")
    s.add_argument("--all", action="store_true", help="run every scenario (figures into --figures, no logs)")
    s.add_argument("--figures", metavar="DIR", default="docs/img", help="with --all: where figures go (docs/img)")
    s.add_argument("--table", "--readme", dest="readme", metavar="PATH",
                   help="with --all: replace the scenario table between its markers in this page (docs/scenarios.md)")
    s.set_defaults(func=run_sim)
