"""Throughput of the robustness runs: runs per second per core, and the speed-up from 1 to 2 local workers.

The work is the matrix (every case, both tasks, default lengths) on the faithful plant, with the SIL
library already built and the pool already started, so the numbers are the runs themselves.
"""

from __future__ import annotations

import statistics
import time


def _rate(units, jobs: int, repeats: int) -> float:
    from rodctl.robust.execute import Runner

    with Runner(jobs=jobs, progress=False) as runner:
        runner.run(units[: 2 * jobs])  # start the workers, let each load the library
        rates = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            runner.run(units)
            rates.append(len(units) / (time.perf_counter() - t0))
    return statistics.median(rates)


def measure(quick: bool = False) -> dict[str, float]:
    from rodgains.params import load_params

    from rodctl.build.sil_build import build_sil
    from rodctl.robust import score as S

    p = load_params()
    build_sil(p)
    units = S.units(p, "matrix", samples=0)
    repeats = 1 if quick else 3
    one = _rate(units, 1, repeats)
    two = _rate(units, 2, repeats)
    return {"robustness_runs_per_s_per_core": round(one, 2), "robustness_scaling_1_to_2_workers": round(two / one, 2)}
