"""The robustness score of one parameter file: which runs make it up, and how they add up.

Runs: every case of a matrix case set (rodctl.sim.matrix.CASE_SETS) for every task it applies to,
plus M Monte Carlo plants (uncertainty.py) for every task, judged by the matrix's robust criterion
(no FAULT, every link within 3 deg at the end; swing-up caught within 10 s).

Score: the fraction of runs that pass, in [0, 1]. Refused designs and runs whose plant left the
model count as failed.

Margin (the documented tie-break, in [0, 1], higher is better): the mean over ALL runs of
    ( settle + error + torque ) / 3, with
    settle = 1 / (1 + settle_s / 1 s)          (0 when the run never settles to 1 deg)
    error  = 1 - min(max_dev_deg, 180) / 180   (the largest excursion after arming / the catch)
    torque = 1 - min(peak_torque_Nm / safety.torque_limit, 1)
Runs that fail count too, so a design that fails gracefully ranks above one that falls over.

Objective (what `rodctl tune` maximizes): score + margin / (2 n), n runs. The margin can move the
objective by at most half a run, so it only breaks ties between equal pass counts.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from rodgains.errors import InputError
from rodgains.params import Params

from rodctl.robust.execute import Unit
from rodctl.robust.uncertainty import draws

SETTLE_SCALE_S = 1.0
ERROR_SCALE_DEG = 180.0


def case_set(name: str, option: str = "--cases", also: tuple[str, ...] = ()) -> tuple[str, ...]:
    """The matrix cases of set `name`; `also`: further words the option accepts (they name no case)."""
    from rodctl.sim.matrix import CASE_SETS

    if name in also:
        return ()
    if name not in CASE_SETS:
        raise InputError(f"{option} {name}: unknown case set; one of {', '.join((*CASE_SETS, *also))}")
    return CASE_SETS[name]


def units(params: Params, cases: str = "matrix", samples: int | None = None, seed: int | None = None,
          seconds: float | None = None, info: tuple = (), plant: Params | None = None) -> list[Unit]:
    """The runs that make up the score of `params` (see the module docstring).
    plant: the true rod the design is judged on, when it is not params' own (`rodctl robustness --plant`):
    every case and Monte Carlo draw perturbs it instead."""
    from rodctl.sim.matrix import TASKS, Case, cases_for

    names = case_set(cases)
    pj = params.canonical_json()
    plj = plant.canonical_json() if plant is not None else None
    out = []
    for task in TASKS:
        for case in cases_for(task, names):
            out.append(Unit(pj, case, task, seconds, info + (("kind", "case"), ("draw", None)) + _plant(case),
                            plant_json=plj))
    for d in draws(params, samples, seed, plant=plant):
        case = Case(d.name, f"Monte Carlo plant {d.index} (seed {_seed(params, seed)})", plant_overrides=d.overrides,
                    delay_periods=d.delay_periods)
        for task in TASKS:
            if task in case.tasks:
                out.append(Unit(pj, case, task, seconds, info + (("kind", "draw"), ("draw", d.index)) + _plant(case),
                                plant_json=plj))
    return out


def unit_count(params: Params, cases: str = "matrix", samples: int | None = None) -> int:
    """len(units(params, cases, samples)), counted without making them (a sweep checks its size first)."""
    from rodctl.sim.matrix import TASKS, cases_for

    names = case_set(cases)
    draws_n = params["uncertainty"]["samples"] if samples is None else samples
    return sum(len(cases_for(task, names)) for task in TASKS) + draws_n * len(TASKS)


def _plant(case) -> tuple:
    """What the row needs to say which plant ran: its overrides and extra delay."""
    return (("plant_overrides", tuple(case.plant_overrides)), ("delay_periods", case.delay_periods))


def _seed(params: Params, seed: int | None) -> int:
    return params["uncertainty"]["seed"] if seed is None else seed


def run_margin(row: dict[str, Any], torque_limit: float) -> float:
    """The tie-break margin of one run, in [0, 1] (module docstring)."""
    if row.get("refused"):
        return 0.0
    settle = row.get("settle_s")
    s = 1.0 / (1.0 + settle / SETTLE_SCALE_S) if settle is not None and math.isfinite(settle) else 0.0
    dev = row.get("max_dev_deg")
    e = 1.0 - min(dev, ERROR_SCALE_DEG) / ERROR_SCALE_DEG if dev is not None else 0.0
    tq = row.get("peak_torque_Nm")
    t = 1.0 - min(tq / torque_limit, 1.0) if tq is not None and torque_limit > 0 else 0.0
    return (s + e + t) / 3.0


@dataclass(frozen=True)
class Score:
    passed: int
    runs: int
    margin: float  # [0, 1]

    @property
    def score(self) -> float:
        """Fraction of runs that pass [0, 1]."""
        return self.passed / self.runs if self.runs else 0.0

    @property
    def objective(self) -> float:
        return self.score + (self.margin / (2 * self.runs) if self.runs else 0.0)

    def text(self) -> str:
        return f"score {self.score:.4f} ({self.passed}/{self.runs} runs pass), margin {self.margin:.4f}"

    def to_json(self) -> dict:
        return {"score": self.score, "passed": self.passed, "runs": self.runs, "margin": self.margin,
                "objective": self.objective}


def score(rows: list[dict], params: Params) -> Score:
    limit = params["safety"]["torque_limit"]
    n = len(rows)
    passed = sum(1 for r in rows if r.get("passed"))
    margin = sum(run_margin(r, limit) for r in rows) / n if n else 0.0
    return Score(passed, n, margin)


def document(params: Params, rows: list[dict], sc: Score, *, cases: str, samples: int, seed: int,
             seconds: float | None, command: str, plant: Params | None = None) -> dict[str, Any]:
    """What `rodctl robustness --json` writes: the design, the plant it was judged on, the score, its
    definition and every run."""
    return {
        "command": command,
        "parameters": params.values,
        "params_source": params.source,
        "params_sha256": params.sha256(),
        "cases": cases,
        "samples": samples,
        "seed": seed,
        "seconds": seconds,
        "plant_source": None if plant is None else plant.source,
        "plant_sha256": None if plant is None else plant.sha256(),
        "plant_parameters": None if plant is None else plant.values,
        "score": sc.to_json(),
        "score_definition": __doc__.strip(),
        "runs": rows,
    }
