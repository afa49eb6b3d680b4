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


TIP_MASS_EDGES = 400  # the clamped rod's discretization for the tip IMU's share: the factor within 1e-5 of 800's


def _gravity_margin(p: Params, imu: bool) -> float:
    """How many times its own weight (and the IMU's) the rod above the hub, clamped there, bears before it
    buckles [-], on TIP_MASS_EDGES equal links: the upright potential's Hessian (EI / l) Lap - m g l diag(c)
    stops being positive definite at lambda_min(Lap, diag(c)) EI / (m g l^2)."""
    from .imu import ImuSite

    r, n = p["rod"], TIP_MASS_EDGES
    length = r["length"] - p["plant"]["hub_length"]
    l = length / n
    extra = ()
    if imu:
        s = length - p["sensors"]["imu_from_tip"]
        j = min(max(int(s / l), 0), n - 1)
        extra = tuple(ImuSite(edge=j, frac=float(s / l - j), position=float(s)).node_masses(n, p["sensors"]["imu_mass"]))
    rod = RodModel(N=n, l=l, m=r["density"] * r["width"] * r["thickness"] * l, EI=p.EI, d=0.0, g=r["gravity"],
                   extra_mass=extra)
    # (Lap, diag(c)) as one symmetric tridiagonal matrix, diag(c)^-1/2 Lap diag(c)^-1/2: its lowest eigenvalue alone
    lap, w = rod.laplacian[1:, 1:], 1.0 / np.sqrt(rod.mass_below[1:])
    lam = sla.eigh_tridiagonal(np.diag(lap) * w * w, np.diag(lap, 1) * w[:-1] * w[1:], eigvals_only=True,
                               select="i", select_range=(0, 0))[0]
    return float(lam * rod.EI / (rod.m * rod.g * l**2))


def tip_mass_factor(p: Params) -> float:
    """The rod's clamped buckling length without the tip IMU over that with its mass on it [-]: 1 without the IMU
    (sensors.tip_imu false); Table I's rod with the default 2 g at its tip 1.020. A load the rod bears scales its
    critical length as load^(-1/3), so this is the cube root of the gravity margins' ratio, which cancels the
    links' own discretization error."""
    if not p["sensors"]["tip_imu"] or p["rod"]["gravity"] == 0:
        return 1.0
    return (_gravity_margin(p, imu=False) / _gravity_margin(p, imu=True)) ** (1 / 3)


def clamped_ratio(p: Params) -> float:
    """The rod above the hub, with the tip IMU's mass when it carries one, over its clamped self-buckling
    length [-]: Greenhill's for the bare rod, shortened by tip_mass_factor.

    The plant's hub (plant.hub_length) sits rigid in the shaft, so what can buckle is the rod above
    it, clamped at the hub. Past 1 that rod buckles under its own weight whenever the shaft holds
    still, and the only way to keep it straight is to move the shaft under it, which the encoder
    sees only after the rod has bent (docs/identification.md: three stiff-shaft designs held
    no run from 1.007 on)."""
    lc = greenhill_length(p)
    return (p["rod"]["length"] - p["plant"]["hub_length"]) / lc * tip_mass_factor(p) if math.isfinite(lc) else 0.0


def buckling_margins(p: Params) -> dict[str, float]:
    """The relative change of rod.youngs_modulus, rod.density or rod.length (the whole rod, hub
    included) alone that brings clamped_ratio to 1 [-]: negative for a drop. Greenhill's length
    goes as (E / rho)^(1/3). Without gravity nothing buckles: +-inf."""
    r = clamped_ratio(p)
    if r <= 0.0:
        return {"youngs_modulus": -math.inf, "density": math.inf, "length": math.inf}
    hub, length = p["plant"]["hub_length"], p["rod"]["length"]
    if tip_mass_factor(p) == 1.0:
        critical = (length - hub) / r  # Greenhill's length, from the ratio
        return {"youngs_modulus": r**3 - 1.0, "density": r**-3 - 1.0, "length": (critical + hub) / length - 1.0}
    # the IMU's mass does not scale with the rod's density or length: those two margins are solved for
    bare = clamped_ratio(p.with_overrides("sensors.tip_imu=false"))

    def ratio_at(key: str, x: float) -> float:
        return clamped_ratio(p.with_overrides(f"rod.{key}={p['rod'][key] * (1.0 + x)!r}", plausible=False)) - 1.0

    def solved(key: str, lo: float, hi: float) -> float:
        return float(brentq(lambda x: ratio_at(key, x), lo, hi, xtol=1e-7)) if ratio_at(key, lo) < 0.0 else math.nan

    near = p["sensors"]["imu_from_tip"] + hub  # the shortest rod that still carries the IMU above its hub
    return {"youngs_modulus": r**3 - 1.0,
            "density": solved("density", -0.999, bare**-3 - 1.0),  # bare: the IMU's mass can only add to the load
            "length": solved("length", near / length - 1.0 + 1e-6, ((length - hub) / bare + hub) / length - 1.0)}


def margins_text(p: Params) -> str:
    """buckling_margins in words: "E -4.9 %, rho +5.1 % or length +1.6 %"."""
    m = buckling_margins(p)
    return f"E {100 * m['youngs_modulus']:+.1f} %, rho {100 * m['density']:+.1f} % or length {100 * m['length']:+.1f} %"
