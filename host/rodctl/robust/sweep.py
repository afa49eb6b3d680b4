"""Design sweeps: a grid over any parameters, one task (or the whole score) per grid point.

    --grid 'rod.length=0.13:0.21:0.005'   start:stop:step, stop included when the steps land on it
    --grid 'rod.edges=5,10,20'             a list
    --grid 'plant.model=der,inextensible'  strings too

A grid key changes the parameter file, so it changes the design AND the plant (a longer rod is
designed for as a longer rod). Each value is checked against the parameter schema before anything
runs (bad input: one line, exit 2); a combination that the cross-checks reject, or a design the
generator refuses, becomes a row with refused = true and the reason.
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import dataclass, replace
from decimal import Decimal, InvalidOperation
from pathlib import Path
from typing import Callable

from rodgains.errors import InputError, ParamError
from rodgains.params import SCHEMA, Params, _coerce, _parse_override

MAX_AXIS_POINTS = 1_000_000  # one --grid range, --yes or not
MAX_RUNS_WITHOUT_YES = 100_000
SCENARIOS = ("balance", "swingup", "score")  # a task of the matrix at every point, or the whole score


@dataclass(frozen=True)
class Axis:
    name: str  # section.key
    values: tuple


def _number(text: str, what: str) -> Decimal:
    try:
        d = Decimal(text.strip())
    except InvalidOperation:
        raise InputError(f"--grid {what}: {text.strip()!r} is not a number") from None
    if not d.is_finite():
        raise InputError(f"--grid {what}: {text.strip()!r} is not a finite number")
    return d


def parse_axis(spec: str) -> Axis:
    """'section.key=start:stop:step' or 'section.key=v1,v2,...' -> the values, checked against the schema."""
    if "=" not in spec:
        raise InputError(f"--grid {spec!r}: expected section.key=start:stop:step or section.key=v1,v2,...")
    name, body = (x.strip() for x in spec.split("=", 1))
    section, _, key = name.partition(".")
    if section not in SCHEMA or key not in SCHEMA[section]:
        raise InputError(f"--grid {name}: unknown parameter (rodctl params lists them)")
    kind = SCHEMA[section][key]
    if not body:
        raise InputError(f"--grid {name}: empty list of values")
    if ":" in body:
        parts = body.split(":")
        if len(parts) != 3:
            raise InputError(f"--grid {name}={body}: a range is start:stop:step")
        start, stop, step = (_number(x, name) for x in parts)
        if step <= 0:
            raise InputError(f"--grid {name}={body}: the step must be > 0")
        if stop < start:
            raise InputError(f"--grid {name}={body}: inverted range (stop {stop} < start {start})")
        # Decimal steps: 0.13:0.21:0.005 has exactly 17 points, with no float drift at the end
        count = int((stop - start) / step) + 1
        if count > MAX_AXIS_POINTS:  # refused before the values are made: 1e8 of them take minutes and gigabytes
            raise InputError(f"--grid {name}={body}: {count:,} points on one axis (at most {MAX_AXIS_POINTS:,}); "
                             "use a larger step")
        raw = [start + i * step for i in range(count)]
        if kind.kind is int:
            if any(v != v.to_integral_value() for v in raw):
                raise InputError(f"--grid {name}={body}: {name} is an integer; use integer start and step")
            values = [int(v) for v in raw]
        else:
            values = [float(v) for v in raw]
    else:
        items = [x.strip() for x in body.split(",")]
        if any(not x for x in items):
            raise InputError(f"--grid {name}={body}: empty value in the list")
        values = [_parse_override(f"{name}={x}")[2] for x in items]
    if not values:
        raise InputError(f"--grid {name}={body}: empty range")
    checked = []
    for v in values:
        try:
            checked.append(_coerce(name, kind, v))
        except ParamError as e:
            raise InputError(f"--grid {e}") from None
    if len(set(checked)) != len(checked):
        raise InputError(f"--grid {name}={body}: a value appears twice")
    return Axis(name, tuple(checked))


def parse_grid(specs: list[str]) -> list[Axis]:
    if not specs:
        raise InputError("--grid: give at least one, e.g. --grid 'rod.length=0.13:0.21:0.005'")
    axes = [parse_axis(s) for s in specs]
    names = [a.name for a in axes]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise InputError(f"--grid {dup[0]}: given twice")
    return axes


def points(axes: list[Axis]) -> list[dict]:
    """Every combination, the first axis varying slowest."""
    return [dict(zip([a.name for a in axes], combo)) for combo in itertools.product(*(a.values for a in axes))]


def size(axes: list[Axis]) -> int:
    return math.prod(len(a.values) for a in axes)


def _text(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return f'"{v}"'
    return repr(v)


def apply(params: Params, point: dict) -> Params:
    """The parameters at one grid point; ParamError when the combination is not valid."""
    return params.with_overrides(*(f"{k}={_text(v)}" for k, v in point.items()))


def frontier(rows: list[dict], x: str, y: str, ok: str = "passed") -> dict:
    """For each value of y, the largest x whose row passed with every smaller x passing too
    (the longest rod balanced without a gap below it), or None."""
    out = {}
    for yv in sorted({r[y] for r in rows}):
        line = sorted((r for r in rows if r[y] == yv), key=lambda r: r[x])
        best = None
        for r in line:
            if not r.get(ok):
                break
            best = r[x]
        out[yv] = best
    return out


def run_count(params: Params, axes: list[Axis], scenario: str, cases: str, samples: int | None) -> int:
    """The runs of the whole grid: one per point, or every run of a score per point."""
    from rodctl.robust import score as S

    per_point = S.unit_count(params, cases, samples) if scenario == "score" else 1
    return size(axes) * per_point


def _point_info(point: dict, index: int) -> tuple:
    return (("point", index),) + tuple(point.items())


def grid_units(params: Params, axes: list[Axis], scenario: str, case: str, criterion: str, cases: str,
               samples: int | None, seed: int | None, seconds: float | None) -> tuple[list, list[dict]]:
    """The runs of every grid point, and a refused row for each point whose parameters are not valid.

    scenario: one of SCENARIOS; case: the matrix case of balance/swingup; criterion: "case" (its own
    pass rule) or "robust"; cases, samples, seed, seconds [s]: what a score is made of.
    """
    from rodctl.robust import score as S
    from rodctl.robust.execute import Unit
    from rodctl.sim.matrix import CASES

    the_case = CASES[case]
    if criterion == "robust":
        the_case = replace(the_case, strict=False)
    units, rows_refused = [], []
    for i, point in enumerate(points(axes)):
        info = _point_info(point, i)
        try:
            p = apply(params, point)
        except ParamError as e:
            rows_refused.append({**dict(info), "case": case if scenario != "score" else "score",
                                 "task": scenario, "passed": False, "refused": True,
                                 "reason": f"invalid parameters: {e}"})
            continue
        if scenario == "score":
            units += S.units(p, cases, samples, seed, seconds, info=info)
        else:
            units.append(Unit(p.canonical_json(), the_case, scenario, seconds, info))
    return units, rows_refused


def point_rows(rows: list[dict], names: list[str], scenario: str, params: Params) -> list[dict]:
    """One verdict per grid point: the run itself, or the score over the point's runs."""
    from rodctl.robust import score as S

    by_point: dict[int, list[dict]] = {}
    for r in rows:
        by_point.setdefault(r["point"], []).append(r)
    out = []
    for i in sorted(by_point):
        sub = by_point[i]
        head = {k: sub[0][k] for k in names}
        if scenario == "score":
            refused = all(r.get("refused") for r in sub)
            sc = S.score(sub, apply(params, head)) if not refused else None
            out.append({**head, "refused": refused, "reason": sub[0].get("reason", "") if refused else "",
                        "passed": bool(sc and sc.passed == sc.runs),
                        "score": sc.score if sc else 0.0, "passed_runs": sc.passed if sc else 0,
                        "runs": sc.runs if sc else len(sub), "margin": sc.margin if sc else 0.0, "settle_s": None})
        else:
            out.append(sub[0])
    return out


@dataclass
class Sweep:
    """A finished sweep: a row per run (refused points included), a verdict per grid point, and what ran."""

    params: Params
    axes: list[Axis]
    scenario: str
    case: str
    criterion: str
    cases: str
    rows: list[dict]  # sorted by grid point
    points: list[dict]
    wall_s: float
    critical_length_m: float | None  # continuum critical length when the first axis is rod.length

    @property
    def names(self) -> list[str]:
        return [a.name for a in self.axes]

    @property
    def passed(self) -> int:
        return sum(1 for r in self.points if r.get("passed"))

    @property
    def refused(self) -> int:
        return sum(1 for r in self.points if r.get("refused"))

    def frontier(self) -> dict | None:
        """frontier() over the two axes; None unless there are two and the first is numeric."""
        if len(self.axes) == 2 and not isinstance(self.axes[0].values[0], str):
            return frontier(self.points, self.names[0], self.names[1])
        return None

    def meta(self, command: str) -> dict:
        """The Parquet file's metadata; command: the command line that ran the sweep."""
        what = ({"cases": self.cases, "points": [{k: p[k] for k in (*self.names, "refused", "score", "passed_runs",
                                                                    "runs", "margin")} for p in self.points]}
                if self.scenario == "score" else {"case": self.case, "criterion": self.criterion})
        return {"command": command, "grid": {a.name: list(a.values) for a in self.axes},
                "scenario": self.scenario, **what, "params_sha256": self.params.sha256(),
                "params_source": self.params.source, "parameters": self.params.values,
                "wall_s": round(self.wall_s, 1)}


def run(params: Params, axes: list[Axis], scenario: str, case: str, criterion: str, cases: str,
        samples: int | None, seed: int | None, seconds: float | None, *, jobs: int | None = None,
        scheduler: str | None = None, say: Callable[[str], None] = lambda line: None) -> Sweep:
    """Every run of the grid (grid_units) on the local pool or the Dask cluster at `scheduler`;
    say() gets the line that tells how many runs go where."""
    from rodgains.buckling import greenhill_length

    from rodctl.robust.execute import Runner

    units, rows_refused = grid_units(params, axes, scenario, case, criterion, cases, samples, seed, seconds)
    t0 = time.monotonic()
    with Runner(jobs, scheduler) as runner:
        say(f"sweep: {size(axes)} grid points, {len(units)} runs on the {runner.where}")
        rows = runner.run(units, desc="sweep")
    wall = time.monotonic() - t0
    rows = sorted(rows + rows_refused, key=lambda r: r["point"])
    names = [a.name for a in axes]
    crit = greenhill_length(params) if names[0] == "rod.length" else None
    return Sweep(params, axes, scenario, case, criterion, cases, rows, point_rows(rows, names, scenario, params),
                 wall, crit)


def write_parquet(sweep: Sweep, path: str | Path, command: str) -> Path:
    """A row per run, with Sweep.meta(command) as the file's metadata."""
    from rodctl.robust.output import RUN_COLUMN_TYPES
    from rodctl.robust.output import write_parquet as write

    return write(path, sweep.rows, sweep.meta(command), RUN_COLUMN_TYPES)


def write_figure(sweep: Sweep, path: str | Path, params_shown: str) -> Path:
    """The frontier figure of a one- or two-axis sweep; params_shown: the parameter file as the title names it."""
    from rodctl.robust import figures

    names = sweep.names
    rule = ", robust criterion" if sweep.criterion == "robust" else ""
    what = f"{sweep.scenario} ({sweep.case}{rule})" if sweep.scenario != "score" else f"score ({sweep.cases})"
    key, label = ("score", "score") if sweep.scenario == "score" else ("settle_s", "settle to 1 deg [s]")
    title = f"rodctl sweep: {what} on the faithful plant; {params_shown}"
    return figures.frontier_figure(sweep.points, names[0], names[1] if len(sweep.axes) == 2 else None, Path(path),
                                   title, color_key=key, color_label=label,
                                   critical_length_m=sweep.critical_length_m)
