"""rodctl bench: the project's performance goals, measured (instruction counts, real-time factors, rates)."""

from __future__ import annotations

import json
import math
import sys

from rodgains.errors import InputError

from rodctl.bench.suite import GOALS, GROUPS, measure, verdict


def run_bench(args) -> int:
    if args.only is not None:
        groups = {g.strip() for g in args.only.split(",")}
        if "" in groups:
            raise InputError(f"--only {args.only!r}: name groups, comma-separated: {', '.join(GROUPS)}")
    else:
        groups = set(GROUPS)
    unknown = groups - set(GROUPS)
    if unknown:
        raise InputError(f"--only {args.only}: unknown group(s) {', '.join(sorted(unknown))}; {', '.join(GROUPS)}")
    if args.json is not None:  # an empty name is refused, not taken for no JSON
        from rodctl.cli.outputs import check_output

        check_output(args.json, "--json", force=args.force)  # before the measurements, not after them
    results = {}
    for g in GROUPS:
        if g in groups:
            print(f"measuring {g} ...", file=sys.stderr, flush=True)
            results.update(measure({g}, quick=args.quick))
    missed = []
    width = max(len(k) for k in results) if results else 0
    for key, value in results.items():
        goal, op, unit, what = GOALS[key]
        v = verdict(key, value)
        target = f"(goal {op} {goal:g} {unit})" if goal is not None else ""
        print(f"{key:{width}s} {value:>12,.6g} {unit:9s} {target:24s} {v:6s} {what}")
        if v == "MISSED":
            missed.append(key)
    if args.json:
        from rodgains.atomic_file import atomic_write

        # strict JSON: a time that never came (inf) is null, which JSON.parse and jq read
        finite = {k: (v if not isinstance(v, float) or math.isfinite(v) else None) for k, v in results.items()}
        atomic_write(args.json, json.dumps(finite, indent=1, allow_nan=False) + "\n")
        print(f"wrote {args.json}")
    return 1 if missed else 0


def register(sub) -> None:
    b = sub.add_parser("bench", help="measure the performance goals (M4 instructions, SIL speed, decode rate)",
                       description="Measure every performance goal of the project and compare with it. Instruction "
                                   "counts come from QEMU (../shared/tools/m4-icount.sh); speeds are medians of "
                                   "repeated runs. Exit 1 when a goal is missed.")
    b.add_argument("--json", metavar="PATH", help="write the results as JSON")
    b.add_argument("--force", action="store_true", help="replace an existing --json")
    b.add_argument("--only", metavar="GROUPS", help="comma-separated subset of: " + ", ".join(GROUPS))
    b.add_argument("--quick", action="store_true", help="shorter runs (noisier)")
    b.set_defaults(func=run_bench)
