"""The friction compensation's window: a design against rigs whose dry friction is not its file's.

    python -m rodctl.sim.friction_study [--set lqr.friction_compensation=0.006] [--frictions 0.6,1,1.6]

The firmware adds `lqr.friction_compensation` in the direction of the estimated base rate. A real
gearbox's friction moves with temperature and wear, so the design meets rigs with more and with less
than its file says: too little compensation lets the motor stick, too much injects a limit cycle, and
either way the rod crosses the gearbox's play and swings out (docs/control.md "The friction
compensation's window").

For each plant friction (a multiple of the file's `motor.coulomb_friction`) it runs the nominal case,
balance and swing-up, on 12 nearby rigs: the boot zero -0.18 to +0.36 deg off and 0.75 to 1.5 deg of
play, both of which decide where the rod rests. Each run lasts --seconds; it reports, over the last 10 s,
how many runs peak past the matrix's 3 deg band, and the median of each run's mean deviation.
"""

from __future__ import annotations

import math
import sys
from concurrent.futures import ProcessPoolExecutor

import numpy as np

ZERO_ERRORS_DEG = (-0.18, 0.0, 0.18, 0.36)
BACKLASH_DEG = (0.75, 1.0, 1.5)
FRICTIONS = (0.6, 0.7, 0.8, 1.0, 1.25, 1.6)  # x the file's motor.coulomb_friction
WINDOW_S = 10.0  # judged over the end of each run [s]


def one_run(job: tuple) -> tuple[float, float]:
    """(mean, peak) of the largest link deviation from upright over the last WINDOW_S [deg]."""
    overrides, friction, zero_deg, backlash_deg, task, seconds = job
    from rodgains.params import load_params

    from rodctl.sim import matrix

    p = load_params(None, list(overrides))
    plant = (f"encoder.zero_error_deg={zero_deg}", f"gearbox.backlash_deg={backlash_deg}",
             f"motor.coulomb_friction*={friction}")
    r = matrix.run_case(p, matrix.CASES["nominal"], task, seconds=seconds, keep_log=True,
                        extra_plant_overrides=plant)
    return matrix.tail_deviation_deg(r["log"], WINDOW_S)


def window(overrides=(), frictions=FRICTIONS, seconds: float = 30.0, jobs: int = 2) -> dict[float, dict]:
    """Plant friction multiple -> {'past_band': runs peaking past 3 deg, 'runs', 'median_mean_deg',
    'max_peak_deg': the largest peak of any run}."""
    from rodctl.sim.matrix import ROBUST_BAND_DEG, TASKS

    grid = [(tuple(overrides), f, z, b, t, seconds)
            for f in frictions for z in ZERO_ERRORS_DEG for b in BACKLASH_DEG for t in TASKS]
    with ProcessPoolExecutor(jobs) as pool:
        results = list(pool.map(one_run, grid))
    out = {}
    for f in frictions:
        rows = [r for job, r in zip(grid, results) if job[1] == f]
        means, peaks = np.array([m for m, _ in rows]), np.array([pk for _, pk in rows])
        out[f] = {"past_band": int((peaks > ROBUST_BAND_DEG).sum()), "runs": len(rows),
                  "median_mean_deg": float(np.median(means)), "max_peak_deg": float(peaks.max())}
    return out


def main(argv=None) -> int:
    from rodctl.cli import OneLineParser
    from rodctl.sim.matrix import ROBUST_BAND_DEG, TASKS, scaled_overrides

    ap = OneLineParser(prog="python -m rodctl.sim.friction_study", description=__doc__.split("\n")[0])
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="override one parameter of the design (and the plant's file), e.g. "
                         "lqr.friction_compensation=0.006 (repeatable)")
    ap.add_argument("--frictions", default=",".join(f"{f:g}" for f in FRICTIONS), metavar="LIST",
                    help="plant dry friction, multiples of the file's motor.coulomb_friction [-]")
    ap.add_argument("--seconds", type=float, default=30.0, metavar="S", help="each run's length [s]")
    ap.add_argument("--jobs", type=int, default=2, metavar="N", help="runs at once (processes)")
    a = ap.parse_args(argv)
    from rodgains.errors import UserError
    from rodgains.params import load_params

    try:
        frictions = tuple(float(x) for x in a.frictions.split(","))
    except ValueError:
        frictions = ()
    problem = ""
    if not frictions or not all(math.isfinite(f) and f >= 0 for f in frictions) or len(set(frictions)) < len(frictions):
        problem = f"--frictions {a.frictions}: distinct finite multiples >= 0, comma-separated"
    elif not (WINDOW_S < a.seconds <= 600):
        problem = f"--seconds {a.seconds:g}: more than {WINDOW_S:g} and at most 600 s"
    elif a.jobs < 1:
        problem = f"--jobs {a.jobs}: at least 1"
    try:
        p = load_params(None, list(a.set))
        for f in frictions:  # every plant the runs would make, refused here rather than in a worker; the multiples
            p.with_overrides(*scaled_overrides(p, (f"motor.coulomb_friction*={f}",)))  # are typed: unit slips too
    except UserError as e:
        problem = problem or str(e)
    if problem:
        print(f"friction_study: {problem}", file=sys.stderr)
        return 2
    print(f"{len(ZERO_ERRORS_DEG) * len(BACKLASH_DEG) * len(TASKS)} runs per friction, {a.seconds:g} s each; "
          f"design: compensation {1e3 * p['lqr']['friction_compensation']:g} mN m for a file's "
          f"{1e3 * p['motor']['coulomb_friction']:g} mN m", file=sys.stderr)
    table = window(tuple(a.set), frictions, a.seconds, a.jobs)
    print(f"{'plant friction [x file]':>24}  {f'runs past {ROBUST_BAND_DEG:g} deg':>16}  {'median mean [deg]':>18}")
    for f, r in table.items():
        print(f"{f:>24g}  {r['past_band']:>9d} of {r['runs']:<3d}  {r['median_mean_deg']:>18.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
