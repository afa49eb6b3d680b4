"""rodctl tune: search weights, controller order and swing-up for the best robustness score."""

from __future__ import annotations

import shlex
import sys
import time

from rodgains.errors import DesignRefused, InputError

from rodctl.cli.gains import add_param_args, params_from_args
from rodctl.cli.outputs import check_output, check_output_folder
from rodctl.cli.robustness import add_exec_args, add_score_args, check_score_args


def reproduce_command(args) -> str:
    """The command that reruns this search, spelled from the arguments (not from how they were typed)."""
    from rodctl.link.design import design_flags

    parts = ["rodctl", "tune", *design_flags(args), "--cases", args.cases]
    for flag, v in (("--samples", args.samples), ("--seed", args.seed), ("--seconds", args.seconds),
                    ("--only", args.only)):
        if v is not None:
            parts += [flag, str(v)]
    for f in args.start_from:
        parts += ["--start-from", f]
    if not args.goals:
        parts += ["--no-goals"]
    parts += ["--budget", str(args.budget)]
    if args.study:
        parts += ["--study", args.study]
    parts += ["--out", args.out]
    return " ".join(shlex.quote(p) for p in parts)


def run_tune(args) -> int:
    from rodctl.robust import score as S
    from rodctl.robust import tune as T
    from rodctl.robust.execute import Runner
    from rodctl.robust.output import atomic_write

    params = params_from_args(args)
    check_score_args(args)
    if args.budget < 1:
        raise InputError(f"--budget {args.budget}: must be >= 1")
    check_output(args.out, "--out", force=args.force)
    if args.study is not None:  # an empty name is refused: it would put the study in the current folder
        check_output_folder(args.study, f"--study {args.study}".rstrip())
    dims = T.space(args.only, params)
    seed = params["uncertainty"]["seed"] if args.seed is None else args.seed
    samples = params["uncertainty"]["samples"] if args.samples is None else args.samples

    def make_units(p):
        return S.units(p, args.cases, samples, seed, args.seconds)

    from rodgains.params import load_params

    starts = [load_params(f) for f in args.start_from]
    for f, extra in zip(args.start_from, starts):
        for what in T.outside_the_search(extra, dims, params):
            print(f"rodctl: warning: --start-from {f}: {what}; that value is not tried", file=sys.stderr)
    meta = {"params_sha256": params.sha256(), "cases": args.cases, "samples": samples, "seed": seed,
            "seconds": args.seconds, "space": [d.text(params) for d in dims], "goals": args.goals}
    if args.study:
        T.check_study(args.study, meta)  # before the workers start: a study it cannot resume is one line
    runs = S.unit_count(params, args.cases, samples)
    from rodctl.build.sil_build import build_sil

    try:  # the search starts from this design: one it cannot make is the user's to fix, not a trial that scores 0
        build_sil(params)
    except DesignRefused as e:
        raise DesignRefused(f"the starting design is refused ({e.why}); a tune searches around a design that works: "
                            "see rodctl gains --report") from None
    t0 = time.monotonic()
    with Runner(args.jobs, args.scheduler) as runner:
        print(f"tune: {len(dims)} parameters, {runs} runs per trial (case set {args.cases!r} + Monte Carlo "
              f"plants: {samples}), budget {args.budget} trials, on the {runner.where}", file=sys.stderr)
        try:
            summary = T.tune(params, runner, dims=dims, budget=args.budget, make_units=make_units,
                             study_dir=args.study, meta=meta, sampler_seed=seed, goals=args.goals,
                             starts=tuple(starts))
        except KeyboardInterrupt:
            runner.close(abandon=True)  # the message below, not the workers' wind-down, ends the command
            if args.study:
                print(f"rodctl: interrupted; every finished trial is kept in {args.study}; resume with: "
                      f"{reproduce_command(args)}", file=sys.stderr)
            else:
                print("rodctl: interrupted (no --study folder: the trials are gone)", file=sys.stderr)
            return 130
    wall = time.monotonic() - t0
    check = " ".join(shlex.quote(x) for x in ["rodctl", "robustness", "--params", args.out, "--cases", args.cases,
                                              "--samples", str(samples), "--seed", str(seed)]
                     + (["--seconds", str(args.seconds)] if args.seconds else []))
    text = T.tuned_file(params, summary, dims, reproduce_command(args), check, goals=args.goals)
    atomic_write(args.out, text)
    b, s = summary["best"], summary["start"]
    if not summary.get("goals_met", True):
        print(T.unscored_text(summary))
        print(f"wrote {args.out} with the starting values unchanged  ({summary['trials']} trials, {wall:.0f} s in "
              f"this session); to score the trials without the nominal goals: --no-goals")
        return 1  # a file that holds the start unchanged is no tuned design: a script must not take it for one
    print(f"start  (trial #{summary['start_number']}): score {s.get('score', 0):.4f} ({s.get('passed', 0)}/"
          f"{s.get('runs', 0)}), margin {s.get('margin', 0):.4f}")
    print(f"tuned  (trial #{summary['best_number']}): score {b.get('score', 0):.4f} ({b.get('passed', 0)}/"
          f"{b.get('runs', 0)}), margin {b.get('margin', 0):.4f}")
    for k, v in summary["best_values"].items():
        print(f"  {k} = {T.fmt_value(v)}")
    print(f"wrote {args.out}  ({summary['trials']} trials, {wall:.0f} s in this session)")
    return 0


def register(sub) -> None:
    t = sub.add_parser("tune", help="search gains, model order and swing-up for the best robustness score",
                       description="Optuna (TPE) searches LQR and observer weights, the controller's model order, "
                                   "the swing-up amplitude and angles and the catch angle within safe ranges to "
                                   "maximize the robustness score (rodctl robustness). The first trial is the "
                                   "parameter file itself. --study DIR keeps every finished trial (Ctrl-C is safe) "
                                   "and resumes. Writes a complete parameter file whose comments say what was tuned, "
                                   "the score and the command that reproduces it. Exit 0: tuned; 1: NOT TUNED (no trial met "
                                   "the nominal goals: --out holds the starting values, unchanged); 2: bad input; "
                                   "3: the starting design is refused; 130: Ctrl-C.")
    add_param_args(t)
    add_score_args(t)
    add_exec_args(t)
    t.add_argument("--budget", type=int, default=100, metavar="N", help="finished trials in the study (default 100)")
    t.add_argument("--study", metavar="DIR", help="keep the trials in DIR/journal.log and resume from it")
    t.add_argument("--start-from", action="append", default=[], metavar="TOML",
                   help="also try this parameter file's values early (an earlier tune, a hand design); repeatable")
    t.add_argument("--no-goals", dest="goals", action="store_false",
                   help="score only; by default every trial must meet the nominal goals (balance settled by 1.5 s, "
                        "swing-up caught by 5 s and settled 2 s after the catch) and a miss ends it early")
    t.add_argument("--only", metavar="KEYS", help="search only these parameters (comma-separated section.key)")
    t.add_argument("--out", required=True, metavar="TOML", help="write the tuned parameter file here")
    t.add_argument("--force", action="store_true", help="overwrite --out")
    t.set_defaults(func=run_tune)
