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
from dataclasses import dataclass
from decimal import Decimal, InvalidOperation

from rodgains.errors import InputError, ParamError
from rodgains.params import SCHEMA, Params, _coerce, _parse_override

MAX_AXIS_POINTS = 1_000_000  # one --grid range, --yes or not
MAX_RUNS_WITHOUT_YES = 100_000


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
