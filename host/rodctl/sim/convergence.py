"""How fast the faithful plant converges with its discretization (plant.edges), per model.

    python -m rodctl.sim.convergence [--figure docs/img/plant-convergence.png]

Two measures, both against the N -> infinity Richardson extrapolation of the two finest plants:
- the first hanging period: the rod hanging at rest with the shaft held (the first bending mode of
  a clamped rod under gravity), from the plant's Jacobian at its static equilibrium (for the DER the
  edges are stretched by the weight below them; an unstretched DER misses the tension's stiffness);
- the tip trajectory: the shaft free on the physical motor (reflected inertia, viscous and
  Coulomb friction), driven open loop by a square-wave torque at the pendulum frequency for
  TRAJECTORY_S; the error is the largest tip-position distance over the run, as a fraction of
  the rod length.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rodgains.params import Params, load_params

from rodctl.sim.plant import Plant, faithful_plant

CLAMP_INERTIA = 1e6  # [kg m^2]: a shaft no torque turns
TRAJECTORY_S = 1.0  # [s] (issue 8: "at N = 20 the tip is 17 mm off after 1 s")
TRAJECTORY_TORQUE = 0.05  # square-wave amplitude [N m]
TRAJECTORY_PERIOD_S = 0.73  # about the rod + motor pendulum period [s]
SAMPLE_S = 1e-3
TOLERANCE = 0.01  # 1 %


def _plant(p: Params, model: str, edges: int, **kw) -> Plant:
    """The rod of the faithful plant on a rigid shaft: these studies measure the rod's discretization."""
    q = p.with_overrides(f'plant.model="{model}"', f"plant.edges={edges}")
    kw.setdefault("gear", None)
    return faithful_plant(q, input_mode="torque", **kw)


def hanging_equilibrium(pl: Plant, upright: bool = False) -> np.ndarray:
    """Raw state y = [q, 0] of the rod at rest under gravity, hanging (DER: each edge stretched by the
    weight it carries) or upright (compressed by it)."""
    y = pl.rest_state(math.pi if upright else 0.0)
    if pl.kind != "der":
        return y
    c = pl.config
    n = pl.n
    # node masses beyond each flexible edge: nodes 2..N carry m, the tip m / 2
    N = pl.N
    masses = np.full(N + 1, c.m)
    masses[N] = 0.5 * c.m
    s = 1.0 if upright else -1.0
    y_pos = s * c.hub_length
    for k in range(2, N + 1):
        below = masses[k:].sum()
        y_pos += s * c.l * (1.0 - s * below * c.g / c.EA)
        i = 1 + 2 * (k - 2)
        y[i], y[i + 1] = 0.0, y_pos
    y[n:] = 0.0
    return y


def first_hanging_period(p: Params, model: str, edges: int) -> float:
    """First bending period of the rod hanging from a held shaft [s]."""
    pl = _plant(p, model, edges, J=CLAMP_INERTIA, b=0.0)  # Coulomb friction on a held shaft: irrelevant
    A, _ = linearization(pl, upright=False)
    ev = np.linalg.eigvals(A)
    osc = ev[ev.imag > 1e-9]
    periods = 2 * math.pi / osc.imag
    return float(periods[periods < 5.0].max())  # the held shaft's own mode is far slower


def linearization(pl: Plant, upright: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of the plant about its static equilibrium (central differences), y = [q, qd], input torque."""
    y0 = hanging_equilibrium(pl, upright)
    A = pl.linearization(0.0, y0=y0, rel_step=1e-7)
    B = ((pl.deriv(y0, 1e-4) - pl.deriv(y0, -1e-4)) / 2e-4)[:, None]
    return A, B


def tip_trajectory(p: Params, model: str, edges: int, seconds: float = TRAJECTORY_S) -> np.ndarray:
    """Tip position (T, 2) [m] every SAMPLE_S under the square-wave torque, shaft on the physical motor."""
    pl = _plant(p, model, edges)
    pl.set_state(np.zeros(pl.N))
    T = int(round(seconds / SAMPLE_S))
    out = np.empty((T + 1, 2))
    out[0] = pl.nodes()[-1]
    for k in range(T):
        t = k * SAMPLE_S
        u = TRAJECTORY_TORQUE if math.sin(2 * math.pi * t / TRAJECTORY_PERIOD_S) >= 0 else -TRAJECTORY_TORQUE
        pl.advance(u, SAMPLE_S)
        out[k + 1] = pl.nodes()[-1]
    return out


def richardson(values: list, edges: list[int]):
    """Extrapolate to N -> infinity from the three finest (observed order), or the two finest at order 1
    when the order cannot be read. Returns (limit, order)."""
    a, b, c = (np.asarray(v, float) for v in values[-3:])
    r = edges[-1] / edges[-2]
    num, den = np.linalg.norm(b - a), np.linalg.norm(c - b)
    order = math.log(num / den) / math.log(r) if den > 0 and num > den else 1.0
    order = min(max(order, 0.5), 4.0)
    return c + (c - b) / (r**order - 1.0), order


@dataclass
class Study:
    model: str
    edges: list[int]
    periods_s: list[float]
    period_limit_s: float
    period_order: float
    period_err: list[float]  # relative to the limit
    tip_err: list[float]  # max tip distance / rod length
    tip_order: float

    def converged_edges(self, tol: float = TOLERANCE) -> int | None:
        for n, pe, te in zip(self.edges, self.period_err, self.tip_err):
            if pe <= tol and te <= tol:
                return n
        return None


REFERENCE_EDGES = (20, 40, 80)  # the extrapolation's plants: a geometric sequence


def study(p: Params | None = None, model: str = "inextensible", edges=(5, 10, 20, 30, 40, 80), progress=None) -> Study:
    """Errors of every plant in `edges` against the Richardson limit of REFERENCE_EDGES."""
    p = p or load_params()
    edges = sorted(set(edges) | set(REFERENCE_EDGES))
    periods, tips = [], []
    for n in edges:
        if progress:
            progress(f"{model} N={n}")
        periods.append(first_hanging_period(p, model, n))
        tips.append(tip_trajectory(p, model, n))
    ref = [edges.index(n) for n in REFERENCE_EDGES]
    lim, order = richardson([periods[i] for i in ref], list(REFERENCE_EDGES))
    tip_lim, tip_order = richardson([tips[i] for i in ref], list(REFERENCE_EDGES))
    L = p["rod"]["length"]
    return Study(model, edges, periods, float(lim), order, [abs(x - lim) / lim for x in periods],
                 [float(np.max(np.linalg.norm(t - tip_lim, axis=1)) / L) for t in tips], tip_order)


def figure(studies: list[Study], path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    for s in studies:
        ax[0].loglog(s.edges, [100 * e for e in s.period_err], "o-", label=f"{s.model} (order {s.period_order:.1f})")
        ax[1].loglog(s.edges, [100 * e for e in s.tip_err], "o-", label=f"{s.model} (order {s.tip_order:.1f})")
    for a, title in zip(ax, ("first hanging period", f"tip trajectory ({TRAJECTORY_S:g} s, max distance / L)")):
        a.axhline(100 * TOLERANCE, color="k", ls="--", lw=0.8)
        a.set_xticks(studies[0].edges, [str(n) for n in studies[0].edges])
        a.xaxis.set_minor_locator(matplotlib.ticker.NullLocator())
        a.set_xlabel("plant.edges (flexible edges beyond the hub)")
        a.set_ylabel("error vs N -> inf extrapolation [%]")
        a.set_title(title)
        a.grid(True, which="both", alpha=0.3)
        a.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None) -> int:
    import argparse
    import sys

    ap = argparse.ArgumentParser(prog="python -m rodctl.sim.convergence", description=__doc__.splitlines()[0])
    ap.add_argument("--figure", help="write the convergence figure here (PNG)")
    ap.add_argument("--edges", default="5,10,20,30,40,80")
    ap.add_argument("--models", default="inextensible,der")
    a = ap.parse_args(argv)
    p = load_params()
    edges = [int(x) for x in a.edges.split(",")]
    out = []
    for model in a.models.split(","):
        s = study(p, model, edges, progress=lambda m: print(f"  {m}", file=sys.stderr))
        out.append(s)
        print(f"{model}: first hanging period -> {1e3 * s.period_limit_s:.2f} ms (order {s.period_order:.2f}); "
              f"tip order {s.tip_order:.2f}; within {100 * TOLERANCE:g} % from N = {s.converged_edges()}")
        for n, per, pe, te in zip(s.edges, s.periods_s, s.period_err, s.tip_err):
            print(f"  N = {n:3d}: period {1e3 * per:7.2f} ms ({100 * pe:5.2f} %), tip {100 * te:5.2f} % of L")
    if a.figure:
        figure(out, a.figure)
        print(f"wrote {a.figure}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
