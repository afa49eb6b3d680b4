"""rodctl sim: run a scenario on the simulated rod (the default main job, no hardware needed)."""

from __future__ import annotations

import sys
import time
from pathlib import Path

from rodgains.errors import InputError

from rodctl.cli.common import check_sim_seconds
from rodctl.cli.gains import add_param_args, params_from_args
from rodctl.cli.outputs import check_name, check_output, make_folder


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


def _fault_of(tr) -> tuple[str, float]:
    """(the reason's name, when [s]) of a run that ended in FAULT, else ("", 0): the pass rule's "no FAULT" is
    the criterion, and a run that broke it says so and why."""
    from rodctl.link import protocol as P
    from rodctl.link.session import name_of
    from rodctl.sim.scenarios import MODE_FAULT

    if not tr.fell:
        return "", 0.0
    return name_of(P.Reason, tr.reason), float(tr.t[int((tr.mode == MODE_FAULT).argmax())])


def summary_lines(o) -> list[str]:
    from rodctl.sim.figures import fmt

    lines = [f"{o.name}: {o.title}", f"  {'PASS' if o.passed else 'FAIL'}: {o.criterion}"]
    lines += [f"  {tr.label}: FAULT {fault} at {at:.3f} s" for tr in o.traces for fault, at in [_fault_of(tr)] if fault]
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
        folder = Path(args.figures or "docs/img")
        return folder / f"sim-{name}.png", None
    plot = None if args.no_plot else Path(args.plot or f"sim-{name}.png")
    log = None if args.no_log else Path(args.log or f"sim-{name}.csv")
    return plot, log


def run_one(args, name: str, params, all_mode: bool = False):
    from rodctl.sim.scenario_run import check_new_log, run_and_write

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
    keep_log = bool(args.log) and not args.force  # an explicit --log is never replaced silently
    if log is not None and keep_log:
        check_new_log(log)
    if plot is not None and not all_mode and args.plot and not args.force and plot.exists():  # nor an explicit --plot
        raise InputError(f"--plot {plot} exists: choose another file name, or --force to replace it")
    prog = Progress(name)
    return run_and_write(name, params, plot=plot, log=log, keep_log=keep_log, duration=args.duration,
                         progress=prog, finished=prog.done)


def check_table_page(readme: Path) -> None:
    """InputError unless `readme` exists, holds the scenario-table markers, and can be rewritten."""
    from rodctl.sim.scenario_table import check_markers

    check_output(readme, "--table")
    try:
        text = readme.read_text()
    except FileNotFoundError:
        raise InputError(f"--table {readme}: no such file (it needs the scenario-table markers)") from None
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"--table {readme}: cannot read it ({getattr(e, 'strerror', None) or e})") from None
    check_markers(readme, text)


def check_sim_options(args) -> None:
    """Options that contradict each other, or that the run would drop without a word: one line, exit 2."""
    given = {"--scenario": args.scenario is not None, "--plot": args.plot is not None, "--log": args.log is not None,
             "--figures": args.figures is not None, "--table": args.readme is not None, "--all": args.all,
             "--no-plot": args.no_plot, "--no-log": args.no_log}
    pairs = [("--list", "--scenario"), ("--list", "--all"), ("--all", "--scenario"), ("--all", "--plot"),
             ("--all", "--log"), ("--plot", "--no-plot"), ("--log", "--no-log")]
    given["--list"] = args.list
    for a, b in pairs:
        if given[a] and given[b]:
            why = {"--all": "--all runs every scenario, its figures into --figures and no logs"}.get(a, "pick one")
            raise InputError(f"{a} and {b} together: {why}")
    for flag in ("--figures", "--table"):
        if given[flag] and not args.all:
            raise InputError(f"{flag} is for --all (every scenario); one scenario's figure is --plot")


def run_sim(args) -> int:
    from rodctl.sim.scenario_table import replace_table, table_markdown
    from rodctl.sim.scenarios import DEFAULT, SCENARIOS

    check_sim_options(args)
    if args.list:
        width = max(len(name) for name in SCENARIOS)
        for name, s in SCENARIOS.items():
            mark = " (default)" if name == DEFAULT else ""
            print(f"{name:{width}s} {s.paper:7s} {s.title}{mark}")
        return 0
    check_sim_seconds(args.duration, "--duration")
    for flag, name in (("--plot", args.plot), ("--log", args.log)):
        if name is not None:
            check_name(name, flag)  # an empty name is refused, not taken for the default sim-NAME one
    params = params_from_args(args)
    shorthand = ({f'plant.model="{args.plant}"': f"--plant {args.plant}"} if args.plant is not None else {}) | \
        ({f"plant.edges={args.edges}": f"--edges {args.edges}"} if args.edges is not None else {})
    if shorthand:  # --plant / --edges: the [plant] table's model and edges, checked like --set
        params = params.with_overrides(*shorthand)
    typed = {o: f"--set {o}" for o in args.overrides} | shorthand  # each override as the user spelled it
    names = list(SCENARIOS) if args.all else [args.scenario or DEFAULT]
    for name in names:
        if name not in SCENARIOS:
            raise InputError(f"unknown scenario {name!r}; one of: {', '.join(SCENARIOS)} (rodctl sim --list)")
    for name in names:  # a --set the scenario sets itself would be recorded as applied, and is not
        ignored = SCENARIOS[name].ignored(list(typed))
        if ignored:
            print(f"rodctl: warning: {name} sets or leaves out {', '.join(o.split('=', 1)[0].strip() for o in ignored)} "
                  f"(docs/scenarios.md): {' '.join(typed[o] for o in ignored)} is not applied", file=sys.stderr)
    if any(SCENARIOS[n].group != "paper" for n in names):  # the faithful plant's: refused before a compile
        from rodctl.sim.plant import check_faithful

        check_faithful(params)
    if args.all and args.readme:  # before every scenario has run, not after
        check_table_page(Path(args.readme))
    from rodctl import paths

    typed_over = " ".join(typed[o] for o in typed)
    print(f"parameters: {paths.shown(params.source)}{' ' + typed_over if typed_over else ''} "
          f"(sha256 {params.sha256()[:16]}; a scenario may set some itself, docs/scenarios.md)")
    outcomes, unexpected = [], []
    for name in names:
        o, wall, written = run_one(args, name, params, all_mode=args.all)
        outcomes.append(o)
        sim_seconds = sum(tr.t[-1] + (tr.t[1] - tr.t[0]) for tr in o.traces)
        for line in summary_lines(o):
            print(line)
        print(f"  simulated {sim_seconds:.1f} s in {wall:.2f} s" + (f"; wrote {', '.join(written)}" if written else ""))
        expected = SCENARIOS[name].expect_pass
        fell = SCENARIOS[name].group == "testbed" and any(tr.fell for tr in o.traces)
        if (expected and not o.passed) or fell:  # the testbed's documented fail is a lean, never a fall
            unexpected.append(f"{name} (the rod fell)" if fell else name)
        elif expected is False and o.passed:  # another rig's file, or a better design: good news, not an error
            print(f"  {name} passes, where the default rig's documented outcome is a fail (docs/scenarios.md)")
        elif expected is False and not fell and SCENARIOS[name].group == "testbed":
            print(f"  {name}: a documented fail on a rig with play (the rod held, off the 1 deg goal: "
                  "docs/control.md), not a failed run")
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
                    "when a scenario that must pass fails, or a testbed run (balance, swingup) falls (FAULT); one "
                    "whose documented outcome on the default rig is a fail (docs/scenarios.md) exits 0 otherwise.")
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
    s.add_argument("--figures", metavar="DIR", help="with --all: where figures go (default docs/img)")
    s.add_argument("--table", "--readme", dest="readme", metavar="PATH",
                   help="with --all: replace the scenario table between its markers in this page (docs/scenarios.md)")
    s.set_defaults(func=run_sim)
