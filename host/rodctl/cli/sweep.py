"""rodctl sweep: a task (or the robustness score) over a grid of any parameters; Parquet + frontier figure."""

from __future__ import annotations

import sys
import time
from dataclasses import replace
from pathlib import Path

from rodgains.errors import ParamError

from rodctl.cli.gains import _shown_path, add_param_args, params_from_args
from rodctl.cli.outputs import check_output
from rodctl.cli.robustness import add_exec_args, add_score_args, check_score_args, command_line

SCENARIOS = ("balance", "swingup", "score")


def _point_info(point: dict, index: int) -> tuple:
    return (("point", index),) + tuple(point.items())


def run_sweep(args) -> int:
    from rodgains.errors import InputError

    from rodctl.robust import figures, score as S, sweep as W
    from rodctl.robust.execute import Runner, Unit
    from rodctl.robust.output import write_parquet
    from rodctl.sim.matrix import CASES

    params = params_from_args(args)
    axes = W.parse_grid(args.grid)
    if args.scenario not in SCENARIOS:
        raise InputError(f"--scenario {args.scenario}: one of {', '.join(SCENARIOS)}")
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

    per_point = S.unit_count(params, args.cases, args.samples) if args.scenario == "score" else 1
    total = W.size(axes) * per_point
    if total > W.MAX_RUNS_WITHOUT_YES and not args.yes:
        raise InputError(f"the grid is {total:,} runs (> {W.MAX_RUNS_WITHOUT_YES:,}); pass --yes to run it")

    case = CASES[args.case]
    if args.criterion == "robust":
        case = replace(case, strict=False)
    units, rows_refused = [], []
    for i, point in enumerate(W.points(axes)):
        info = _point_info(point, i)
        try:
            p = W.apply(params, point)
        except ParamError as e:
            rows_refused.append({**dict(info), "case": args.case if args.scenario != "score" else "score",
                                 "task": args.scenario, "passed": False, "refused": True,
                                 "reason": f"invalid parameters: {e}"})
            continue
        if args.scenario == "score":
            units += S.units(p, args.cases, args.samples, args.seed, args.seconds, info=info)
        else:
            units.append(Unit(p.canonical_json(), case, args.scenario, args.seconds, info))
    t0 = time.monotonic()
    with Runner(args.jobs, args.scheduler) as runner:
        print(f"sweep: {W.size(axes)} grid points, {len(units)} runs on the {runner.where}", file=sys.stderr)
        rows = runner.run(units, desc="sweep")
    wall = time.monotonic() - t0
    rows = sorted(rows + rows_refused, key=lambda r: r["point"])
    names = [a.name for a in axes]

    # one verdict per grid point: the run itself, or the score over the point's runs
    per_point_rows = []
    for i in sorted({r["point"] for r in rows}):
        sub = [r for r in rows if r["point"] == i]
        head = {k: sub[0][k] for k in names}
        if args.scenario == "score":
            refused = all(r.get("refused") for r in sub)
            sc = S.score(sub, W.apply(params, head)) if not refused else None
            per_point_rows.append({**head, "refused": refused, "reason": sub[0].get("reason", "") if refused else "",
                                   "passed": bool(sc and sc.passed == sc.runs),
                                   "score": sc.score if sc else 0.0, "settle_s": None})
        else:
            per_point_rows.append(sub[0])

    meta = {"command": command_line(sys.argv[1:]), "grid": {a.name: list(a.values) for a in axes},
            "scenario": args.scenario, "case": args.case, "params_sha256": params.sha256(),
            "params_source": params.source, "parameters": params.values, "wall_s": round(wall, 1)}
    write_parquet(args.out, rows, meta)
    n_ok = sum(1 for r in per_point_rows if r.get("passed"))
    n_ref = sum(1 for r in per_point_rows if r.get("refused"))
    print(f"{len(per_point_rows)} grid points: {n_ok} pass, {len(per_point_rows) - n_ok - n_ref} fail, "
          f"{n_ref} refused  [{wall:.1f} s]")
    if len(axes) == 2 and not isinstance(axes[0].values[0], str):
        from rodgains.buckling import greenhill_length

        crit = greenhill_length(params) if names[0] == "rod.length" else None
        for yv, xv in W.frontier(per_point_rows, names[0], names[1]).items():
            ratio = f" = {xv / crit:.3f} x the continuum critical length" if crit and xv is not None else ""
            print(f"  {names[1]} = {yv}: largest {names[0]} passing from the smallest up: "
                  f"{'none' if xv is None else xv}{ratio}")
    print(f"wrote {args.out}")
    if plot:
        if len(axes) > 2:
            print("no figure: it shows one or two grid axes", file=sys.stderr)
        else:
            from rodgains.buckling import greenhill_length

            crit = greenhill_length(params) if names[0] == "rod.length" else None
            rule = ", robust criterion" if args.criterion == "robust" else ""
            what = f"{args.scenario} ({args.case}{rule})" if args.scenario != "score" else f"score ({args.cases})"
            key, label = ("score", "score") if args.scenario == "score" else ("settle_s", "settle to 1 deg [s]")
            title = f"rodctl sweep: {what} on the faithful plant; {_shown_path(params.source)}"
            figures.frontier_figure(per_point_rows, names[0], names[1] if len(axes) == 2 else None, Path(plot), title,
                                    color_key=key, color_label=label, critical_length_m=crit)
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
    s.add_argument("--case", default="nominal", metavar="NAME", help="matrix case for balance/swingup (default nominal)")
    s.add_argument("--criterion", choices=("case", "robust"), default="case",
                   help="pass rule: the case's own (default; nominal holds the strict settle-time goals) or the "
                        "robust one (no FAULT, every link within 3 deg at the end)")
    add_score_args(s)
    add_exec_args(s)
    s.add_argument("--out", required=True, metavar="PARQUET", help="one row per run")
    s.add_argument("--plot", metavar="PNG", help="figure (default: --out with .png; '' for none)")
    s.add_argument("--force", action="store_true", help="replace an existing --out or --plot")
    s.add_argument("--yes", action="store_true", help="run a grid of more than 100,000 runs")
    s.set_defaults(func=run_sweep)
