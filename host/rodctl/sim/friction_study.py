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

import argparse
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
    log = r["log"]
    dev = matrix._deviation_deg(log["theta"]).max(axis=1)[log["time"] >= seconds - WINDOW_S]
    return float(dev.mean()), float(dev.max())


def window(overrides=(), frictions=FRICTIONS, seconds: float = 30.0, jobs: int = 2) -> dict[float, dict]:
    """Plant friction multiple -> {'past_band': runs peaking past 3 deg, 'runs', 'median_mean_deg'}."""
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
                  "median_mean_deg": float(np.median(means))}
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m rodctl.sim.friction_study", description=__doc__.split("\n")[0])
    ap.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE",
                    help="override one parameter of the design (and the plant's file), e.g. "
                         "lqr.friction_compensation=0.006 (repeatable)")
    ap.add_argument("--frictions", default=",".join(f"{f:g}" for f in FRICTIONS), metavar="LIST",
                    help="plant dry friction, multiples of the file's motor.coulomb_friction [-]")
    ap.add_argument("--seconds", type=float, default=30.0, metavar="S", help="each run's length [s]")
    ap.add_argument("--jobs", type=int, default=2, metavar="N", help="runs at once (processes)")
    a = ap.parse_args(argv)
    from rodgains.errors import UserError

    try:
        frictions = tuple(float(x) for x in a.frictions.split(","))
        if not frictions or min(frictions) < 0 or not (a.seconds > WINDOW_S) or a.jobs < 1:
            raise ValueError
    except ValueError:
        print(f"friction_study: --frictions must be multiples >= 0, --seconds more than {WINDOW_S:g} and "
              "--jobs at least 1", file=sys.stderr)
        return 2
    try:
        from rodgains.params import load_params

        p = load_params(None, list(a.set))
    except UserError as e:
        print(f"friction_study: {e}", file=sys.stderr)
        return 2
    print(f"{len(ZERO_ERRORS_DEG) * len(BACKLASH_DEG) * 2} runs per friction, {a.seconds:g} s each; design: "
          f"compensation {1e3 * p['lqr']['friction_compensation']:g} mN m for a file's "
          f"{1e3 * p['motor']['coulomb_friction']:g} mN m", file=sys.stderr)
    table = window(tuple(a.set), frictions, a.seconds, a.jobs)
    print(f"{'plant friction [x file]':>24}  {'runs past 3 deg':>16}  {'median mean [deg]':>18}")
    for f, r in table.items():
        print(f"{f:>24g}  {r['past_band']:>9d} of {r['runs']:<3d}  {r['median_mean_deg']:>18.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
