"""Self-buckling lengths: the continuum (Greenhill) value and the N-link model's own.

Eq. (23) of the paper has its numeric factors swapped (physics-notes.md). The correct
Greenhill length of a clamped column under its own weight is

    L^3 = (9 B^2 / 4) E I / (rho g A),  B = 1.8663 (first zero of J_{-1/3}),

i.e. 7.837 E I / (rho g A) = 3 E h^2 B^2 / (16 rho g) for a rectangular section.
"""

from __future__ import annotations

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
