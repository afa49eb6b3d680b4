"""rodctl sweep: a task (or the robustness score) over a grid of any parameters; Parquet + frontier figure."""

from __future__ import annotations

import sys
from pathlib import Path

from rodctl.cli.gains import add_param_args, params_from_args, set_line
from rodctl.cli.outputs import check_output
from rodctl.cli.robustness import add_exec_args, add_score_args, check_score_args, command_line
from rodctl.paths import shown


def run_sweep(args) -> int:
    from rodgains.errors import InputError

    from rodctl.robust import score as S
    from rodctl.robust import sweep as W
    from rodctl.sim.matrix import CASES

    params = params_from_args(args)
    axes = W.parse_grid(args.grid)
    if args.scenario not in W.SCENARIOS:
        raise InputError(f"--scenario {args.scenario}: one of {', '.join(W.SCENARIOS)}")
    if args.scenario == "score" and (args.case is not None or args.criterion is not None):
        raise InputError(f"--{'case' if args.case is not None else 'criterion'} picks one task's run; --scenario score "
                         "scores the case set --cases with the matrix's own rules")
    args.case = args.case or "nominal"
    args.criterion = args.criterion or "case"
    if args.case not in CASES:
        raise InputError(f"--case {args.case}: unknown case; one of {', '.join(CASES)}")
    if args.scenario != "score" and args.scenario not in CASES[args.case].tasks:
        raise InputError(f"--case {args.case} does not apply to the {args.scenario} task")
    check_score_args(args)
    if not str(args.out).endswith(".parquet"):
        raise InputError(f"--out {args.out}: the sweep writes Parquet; name it *.parquet")
    plot = args.plot if args.plot is not None else str(Path(args.out).with_suffix(".png"))
    check_output(args.out, "--out", force=args.force)  # before the runs, not after them
    if plot:
        check_output(plot, "--plot", force=args.force, figure=True)

    total = W.run_count(params, axes, args.scenario, args.cases, args.samples)
    if total > W.MAX_RUNS_WITHOUT_YES and not args.yes:
        raise InputError(f"the grid is {total:,} runs (> {W.MAX_RUNS_WITHOUT_YES:,}); pass --yes to run it")

    sweep = W.run(params, axes, args.scenario, args.case, args.criterion, args.cases, args.samples, args.seed,
                  args.seconds, jobs=args.jobs, scheduler=args.scheduler, say=lambda line: print(line, file=sys.stderr))
    W.write_parquet(sweep, args.out, command_line(sys.argv[1:]))
    n_points, n_ok, n_ref = len(sweep.points), sweep.passed, sweep.refused
    if args.scenario == "score":  # a point's verdict is its score, not pass or fail
        print(f"{n_points} grid points scored, {n_ref} refused  [{sweep.wall_s:.1f} s]")
        for pt in sweep.points:
            where = ", ".join(f"{k} = {pt[k]}" for k in sweep.names)
            print(f"  {where}: " + (pt["reason"] if pt["refused"] else
                                    S.Score(pt["passed_runs"], pt["runs"], pt["margin"]).text()))
    else:
        print(f"{n_points} grid points: {n_ok} pass, {n_points - n_ok - n_ref} fail, "
              f"{n_ref} refused  [{sweep.wall_s:.1f} s]")
    names, crit = sweep.names, sweep.critical_length_m
    for yv, xv in (sweep.frontier() or {}).items():
        ratio = f" = {xv / crit:.3f} x the continuum critical length" if crit and xv is not None else ""
        print(f"  {names[1]} = {yv}: largest {names[0]} passing from the smallest up: "
              f"{'none' if xv is None else xv}{ratio}")
    print(f"wrote {args.out}")
    if plot:
        if len(axes) > 2:
            print("no figure: it shows one or two grid axes", file=sys.stderr)
        else:
            W.write_figure(sweep, plot, shown(params.source) + set_line(args))
            print(f"wrote {plot}")
    return 0


def register(sub) -> None:
    s = sub.add_parser("sweep", help="run a task or the robustness score over a grid of parameters",
                       description="Run one task of the robustness matrix (on --case, default the nominal faithful "
                                   "plant) or the whole score at every point of a grid of any parameters. Writes "
                                   "one Parquet row per run and a figure: the first grid axis across, the second "
                                   "up, colour = settle time (or score), crosses = fail, R = refused design, and "
                                   "the frontier line. Exit 2: unknown key, empty or inverted range, bad value.")
    add_param_args(s)
    s.add_argument("--grid", action="append", default=[], metavar="KEY=SPEC",
                   help="section.key=start:stop:step or section.key=v1,v2,... (repeatable; one axis each)")
    s.add_argument("--scenario", default="balance", metavar="NAME",
                   help="balance (default), swingup, or score (the robustness score at every point)")
    s.add_argument("--case", metavar="NAME", help="matrix case for balance/swingup (default nominal; not with score)")
    s.add_argument("--criterion", choices=("case", "robust"),
                   help="pass rule: the case's own (default; nominal holds the strict settle-time goals) or the "
                        "robust one (no FAULT, every link within 3 deg at the end); not with score")
    add_score_args(s)
    add_exec_args(s)
    s.add_argument("--out", required=True, metavar="PARQUET", help="one row per run")
    s.add_argument("--plot", metavar="PNG", help="figure (default: --out with .png; '' for none)")
    s.add_argument("--force", action="store_true", help="replace an existing --out or --plot")
    s.add_argument("--yes", action="store_true", help="run a grid of more than 100,000 runs")
    s.set_defaults(func=run_sweep)
