"""Self-buckling lengths: the continuum (Greenhill) value and the N-link model's own.

Eq. (23) of the paper has its numeric factors swapped (docs/physics-notes.md). The correct
Greenhill length of a clamped column under its own weight is

    L^3 = (9 B^2 / 4) E I / (rho g A),  B = 1.8663 (first zero of J_{-1/3}),

i.e. 7.837 E I / (rho g A) = 3 E h^2 B^2 / (16 rho g) for a rectangular section.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg as sla
from scipy.optimize import brentq
from scipy.special import jv

from .params import Params
from .rod_model import RodModel


def bessel_zero_minus_third() -> float:
    """B: first positive zero of J_{-1/3}."""
    return float(brentq(lambda x: jv(-1.0 / 3.0, x), 1.0, 2.5, xtol=1e-14))


def greenhill_length(p: Params) -> float:
    """Continuum self-buckling length of the clamped rod [m] (0.154 m for Table I)."""
    r = p["rod"]
    B = bessel_zero_minus_third()
    if r["gravity"] == 0:
        return float("inf")
    return float((9.0 * B**2 / 4.0 * p.EI / (r["density"] * r["gravity"] * r["width"] * r["thickness"])) ** (1 / 3))


def nlink_critical_length(p: Params, edges: int | None = None) -> float:
    """Length [m] at which the N-link model with theta_1 clamped upright loses stability.

    The upright potential Hessian of the free edges 2..N is (EI N / L) Lap - rho A g (L/N)^2 diag(c);
    it stops being positive definite at L^3 = lambda_min (EI N^3) / (rho A g), lambda_min the
    smallest generalized eigenvalue of (Lap, diag(c)) restricted to edges 2..N.
    """
    r = p["rod"]
    if r["gravity"] == 0:
        return float("inf")
    rod = RodModel.from_params(p, edges=edges)
    N = rod.N
    lam = sla.eigh(rod.laplacian[1:, 1:], np.diag(rod.mass_below[1:]), eigvals_only=True)[0]
    rhoAg = r["density"] * r["width"] * r["thickness"] * r["gravity"]
    return float((lam * p.EI * N**3 / rhoAg) ** (1 / 3))


def clamped_ratio(p: Params) -> float:
    """The rod above the hub over its clamped self-buckling (Greenhill) length [-].

    The plant's hub (plant.hub_length) sits rigid in the shaft, so what can buckle is the rod above
    it, clamped at the hub. Past 1 that rod buckles under its own weight whenever the shaft holds
    still, and the only way to keep it straight is to move the shaft under it, which the encoder
    sees only after the rod has bent (docs/identification.md: three stiff-shaft designs held
    no run from 1.007 on)."""
    lc = greenhill_length(p)
    return (p["rod"]["length"] - p["plant"]["hub_length"]) / lc if math.isfinite(lc) else 0.0


def buckling_margins(p: Params) -> dict[str, float]:
    """The relative change of rod.youngs_modulus, rod.density or rod.length (the whole rod, hub
    included) alone that brings clamped_ratio to 1 [-]: negative for a drop. Greenhill's length
    goes as (E / rho)^(1/3). Without gravity nothing buckles: +-inf."""
    r = clamped_ratio(p)
    if r <= 0.0:
        return {"youngs_modulus": -math.inf, "density": math.inf, "length": math.inf}
    hub, length = p["plant"]["hub_length"], p["rod"]["length"]
    critical = (length - hub) / r  # Greenhill's length, from the ratio
    return {"youngs_modulus": r**3 - 1.0, "density": r**-3 - 1.0, "length": (critical + hub) / length - 1.0}


def margins_text(p: Params) -> str:
    """buckling_margins in words: "E -4.9 %, rho +5.1 % or length +1.6 %"."""
    m = buckling_margins(p)
    return f"E {100 * m['youngs_modulus']:+.1f} %, rho {100 * m['density']:+.1f} % or length {100 * m['length']:+.1f} %"
