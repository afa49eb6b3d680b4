"""rodctl robustness: the robustness matrix plus Monte Carlo plants, one score, a JSON and a heatmap."""

from __future__ import annotations

import shlex
import sys
import time
from pathlib import Path

from rodctl.cli.common import check_sim_seconds
from rodctl.cli.gains import add_param_args, params_from_args, set_line
from rodctl.cli.outputs import check_apart, check_output
from rodctl.paths import shown


def add_exec_args(p) -> None:
    """--jobs / --scheduler: where the runs go (shared by robustness, tune and sweep)."""
    p.add_argument("--jobs", type=int, metavar="N", help="local worker processes (default: every core)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="run on an existing Dask cluster instead, e.g. tcp://10.0.0.5:8786 (start workers with "
                        "`dask worker ADDRESS --nthreads 1` from a clone with rodctl installed)")


def add_score_args(p) -> None:
    """What a score is made of (shared by robustness, tune and sweep --scenario score)."""
    p.add_argument("--cases", default="matrix", metavar="NAME",
                   help="case set of the matrix: matrix (default), quick, nominal, plants")
    p.add_argument("--samples", type=int, metavar="M", help="Monte Carlo plants (default: uncertainty.samples)")
    p.add_argument("--seed", type=int, metavar="S", help="seed of the draws (default: uncertainty.seed)")
    p.add_argument("--seconds", type=float, metavar="S",
                   help="simulated length of every run [s] (default: the matrix's for each task)")


def check_score_args(args) -> None:
    from rodgains.errors import InputError
    from rodgains.params import MAX_SAMPLES

    from rodctl.robust.score import case_set

    case_set(args.cases)
    if args.samples is not None and not 0 <= args.samples <= MAX_SAMPLES:
        raise InputError(f"--samples {args.samples}: must be between 0 and {MAX_SAMPLES:,}")
    if args.seed is not None and not 0 <= args.seed < 2**32:
        raise InputError(f"--seed {args.seed}: must be in 0 .. 2^32 - 1")
    check_sim_seconds(args.seconds, "--seconds")


def command_line(argv_tail: list[str]) -> str:
    return " ".join(shlex.quote(a) for a in ["rodctl", *argv_tail])


def _fmt(v, nd=2) -> str:
    return "-" if v is None else f"{v:.{nd}f}"


def table_lines(rows: list[dict]) -> list[str]:
    """A line per case (both tasks side by side); Monte Carlo plants summed up at the end."""
    from rodctl.sim.matrix import CASES, ROBUST_BAND_DEG, TASKS, buckled, criterion, marks, past_band

    def cell(r):
        if r is None:
            return f"{'':>9s} {'':>9s} {'':>8s}"
        word = "refused" if r.get("refused") else "pass" if r.get("passed") else "FAIL"
        return f"{_fmt(r.get('settle_s')):>9s} {_fmt(r.get('final_dev_deg')):>9s} {word:>8s}"

    by: dict[str, dict] = {}
    for r in rows:
        if r.get("kind") != "draw":
            by.setdefault(r["case"], {})[r["task"]] = r
    past = {name: r["buckling_ratio"] for name, d in by.items() for r in d.values() if buckled(r)}
    bent = {name: r["straightest_deg"] for name, d in by.items() for r in d.values() if past_band(r)}
    strict = [name for name in by if name in CASES and CASES[name].strict]
    names = {name: name + (" *" if name in strict else "") + marks(next(iter(d.values()))) for name, d in by.items()}
    w = max([14, *map(len, names.values())])  # the case column as wide as its longest name
    lines = [f"  {'':{w}s}" + "".join(f" | {t:^28s}" for t in TASKS),
             f"  {'case':{w}s}" + "".join(f" | {'settle s':>9s} {'end deg':>9s} {'result':>8s}" for _ in TASKS)]
    for name, d in by.items():
        lines.append(f"  {names[name]:{w}s}" + "".join(f" | {cell(d.get(t))}" for t in TASKS))
    draws = [r for r in rows if r.get("kind") == "draw"]
    buckled_draws = len({r["draw"] for r in draws if buckled(r)})
    if draws:
        parts = []
        for t in TASKS:
            sub = [r for r in draws if r["task"] == t]
            parts.append(f"{t} {sum(1 for r in sub if r.get('passed'))}/{len(sub)} pass")
        n = len({r["draw"] for r in draws})
        lines.append(f"  Monte Carlo plants ({n}): " + ", ".join(parts)
                     + (f"; {buckled_draws} past the buckling length" if buckled_draws else ""))
    if strict:
        lines.append(f"  * held to the nominal goals, not the {ROBUST_BAND_DEG:g} deg band the other runs are: balance: "
                     f"{criterion('balance', strict=True)}; swing-up: {criterion('swingup', strict=True)}")
    if past or buckled_draws:
        which = f" ({', '.join(f'{name} {v:.3f} x' for name, v in past.items())})" if past else ""
        lines.append("  ^ past the buckling length: the rod above the hub (and a tip IMU's mass on it) is longer than its "
                     "clamped buckling length" + which + ", so it bends over whenever the shaft holds still "
                     "(rodctl gains --report; docs/identification.md, with the IMU docs/sensors.md)")
    if bent:
        which = ", ".join(f"{name} {v:.2f} deg" for name, v in bent.items())
        lines.append(f"  ~ no shape within {ROBUST_BAND_DEG:g} deg of upright: a rod curved at rest whose straightest static "
                     f"shape ({which}) is past the band, whatever the controller (docs/control.md)")
    return lines


def plant_from_args(args):
    """The true rod of --plant FILE (None: the design's own parameter file describes it)."""
    from rodgains.errors import ParamError
    from rodgains.params import load_params

    if args.plant is None:
        return None
    try:
        return load_params(args.plant)
    except ParamError as e:
        raise ParamError(f"--plant: {e}") from None


def run_robustness(args) -> int:
    from rodctl.build.sil_build import build_sil
    from rodctl.robust import figures, score as S
    from rodctl.robust.execute import Runner
    from rodctl.robust.output import write_json

    params = params_from_args(args)
    plant = plant_from_args(args)
    check_score_args(args)
    if args.json:  # before the runs, not after them
        check_output(args.json, "--json", force=args.force)
    if args.plot:
        check_output(args.plot, "--plot", force=args.force, figure=True)
    check_apart(args.plot, "--plot", args.json, "--json")
    units = S.units(params, args.cases, args.samples, args.seed, args.seconds, plant=plant)
    t0 = time.monotonic()
    with Runner(args.jobs, args.scheduler) as runner:
        build_sil(params)  # design and compile once here: a refused design stops before any run (exit 3)
        drawn = sum(1 for u in units if dict(u.info).get("kind") == "draw")
        print(f"{len(units)} runs (case set {args.cases!r}" + (f", {drawn} of them on Monte Carlo plants" if drawn else "")
              + f") on the {runner.where}", file=sys.stderr)
        if plant is not None:
            print(f"the design of {shown(params.source)} judged on the rod of {shown(plant.source)}",
                  file=sys.stderr)
        rows = runner.run(units, desc="robustness")
        where = runner.where
    wall = time.monotonic() - t0
    sc = S.score(rows, params)
    print("\n".join(table_lines(rows)))
    print(f"{sc.text()}  [{wall:.1f} s on the {where}]")
    seed = params["uncertainty"]["seed"] if args.seed is None else args.seed
    samples = params["uncertainty"]["samples"] if args.samples is None else args.samples
    written = []
    if args.json:
        doc = S.document(params, rows, sc, cases=args.cases, samples=samples, seed=seed, seconds=args.seconds,
                         command=command_line(sys.argv[1:]), plant=plant)
        written.append(write_json(args.json, doc))
    if args.plot:
        on = "faithful plant" if plant is None else f"rod of {shown(plant.source)}"
        draws = f" + {samples} Monte Carlo plants (seed {seed})" if samples else ""
        title = f"{shown(params.source)}: {sc.text()}\ncase set {args.cases!r}{draws} on the {on}" + set_line(args)
        written.append(figures.heatmap(rows, Path(args.plot), title))
    for w in written:
        print(f"wrote {w}")
    return 0


def register(sub) -> None:
    r = sub.add_parser("robustness", help="score a design: the robustness matrix plus Monte Carlo plants",
                       description="Run every case of the robustness matrix (balance and swing-up) and Monte Carlo "
                                   "plants drawn from the [uncertainty] table on the faithful plant, print a table "
                                   "and one score in [0, 1] (the fraction of runs that pass; the margin breaks ties: "
                                   "host/rodctl/robust/score.py). Exit 2: bad input; exit 3: the design is refused.")
    add_param_args(r)
    r.add_argument("--plant", metavar="FILE",
                   help="judge the design on another rod: this parameter file (and its [plant] table) is the true "
                        "plant, e.g. the hidden rig behind sim://?plant=FILE; the matrix's relative cases scale its "
                        "values. --params/--set still make the design (default: the design's own file is the plant)")
    add_score_args(r)
    add_exec_args(r)
    r.add_argument("--json", default="robustness.json", metavar="PATH",
                   help="every run's metrics and parameters (default robustness.json; '' for none)")
    r.add_argument("--plot", default="robustness.png", metavar="PNG",
                   help="case x metric heatmap, pass/fail marked (default robustness.png; '' for none)")
    r.add_argument("--force", action="store_true", help="replace an existing --json or --plot")
    r.set_defaults(func=run_robustness)

