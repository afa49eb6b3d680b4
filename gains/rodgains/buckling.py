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


def _gravity_margin(above_hub_m: float, mass_per_m: float, EI: float, g: float,
                    imu: tuple[float, float] | None) -> float:
    """How many times its own weight (and the IMU's) a rod above_hub_m long [m] of mass_per_m [kg/m], clamped at
    the hub, bears before it buckles [-], on TIP_MASS_EDGES equal links: the upright potential's Hessian
    (EI / l) Lap - m g l diag(c) stops being positive definite at lambda_min(Lap, diag(c)) EI / (m g l^2).
    imu: (its distance from the tip [m], its mass [kg]), or None. Plain numbers, not Params: the margins below
    try rods the parameter checks would refuse (one so short that the IMU sits on the model's clamped edge)."""
    from .imu import ImuSite

    n = TIP_MASS_EDGES
    l = above_hub_m / n
    extra = ()
    if imu is not None and above_hub_m - imu[0] > 0.0:  # an IMU inside the hub is held by the shaft, not the rod
        s = above_hub_m - imu[0]
        j = min(int(s / l), n - 1)
        extra = tuple(ImuSite(edge=j, frac=float(s / l - j), position=float(s)).node_masses(n, imu[1]))
    rod = RodModel(N=n, l=l, m=mass_per_m * l, EI=EI, d=0.0, g=g, extra_mass=extra)
    # (Lap, diag(c)) as one symmetric tridiagonal matrix, diag(c)^-1/2 Lap diag(c)^-1/2: its lowest eigenvalue alone
    lap, w = rod.laplacian[1:, 1:], 1.0 / np.sqrt(rod.mass_below[1:])
    lam = sla.eigh_tridiagonal(np.diag(lap) * w * w, np.diag(lap, 1) * w[:-1] * w[1:], eigvals_only=True,
                               select="i", select_range=(0, 0))[0]
    return float(lam * EI / (rod.m * g * l**2))


def _ratio(p: Params, density_scale: float = 1.0, length_m: float | None = None, imu: bool | None = None) -> float:
    """clamped_ratio of p's rod with its density scaled and its whole length (hub included) length_m [m]; imu: with
    the tip IMU's mass (None: as p says)."""
    r = p["rod"]
    lc = greenhill_length(p)
    if not math.isfinite(lc):
        return 0.0
    above = (r["length"] if length_m is None else length_m) - p["plant"]["hub_length"]
    ratio = above / (lc * density_scale ** (-1.0 / 3.0))  # Greenhill's length goes as rho^(-1/3)
    if not (p["sensors"]["tip_imu"] if imu is None else imu):
        return ratio
    q = r["density"] * density_scale * r["width"] * r["thickness"]
    imu = (p["sensors"]["imu_from_tip"], p["sensors"]["imu_mass"])
    # a load the rod bears scales its critical length as load^(-1/3): the cube root of the margins' ratio, which
    # cancels the links' own discretization error
    factor = (_gravity_margin(above, q, p.EI, r["gravity"], None)
              / _gravity_margin(above, q, p.EI, r["gravity"], imu)) ** (1.0 / 3.0)
    return ratio * factor


def tip_mass_factor(p: Params) -> float:
    """The rod's clamped buckling length without the tip IMU over that with its mass on it [-]: 1 without the IMU
    (sensors.tip_imu false); Table I's rod with the default 2 g at its tip 1.020."""
    bare = _ratio(p, imu=False) if p["sensors"]["tip_imu"] else 0.0
    return _ratio(p) / bare if bare > 0.0 else 1.0


def clamped_ratio(p: Params) -> float:
    """The rod above the hub, with the tip IMU's mass when it carries one, over its clamped self-buckling
    length [-]: Greenhill's for the bare rod, shortened by tip_mass_factor.

    The plant's hub (plant.hub_length) sits rigid in the shaft, so what can buckle is the rod above
    it, clamped at the hub. Past 1 that rod buckles under its own weight whenever the shaft holds
    still, and the only way to keep it straight is to move the shaft under it, which the encoder
    sees only after the rod has bent (docs/identification.md: three stiff-shaft designs held
    no run from 1.007 on)."""
    return _ratio(p)


def buckling_margins(p: Params) -> dict[str, float]:
    """The relative change of rod.youngs_modulus, rod.density or rod.length (the whole rod, hub
    included) alone that brings clamped_ratio to 1 [-]: negative for a drop. Greenhill's length
    goes as (E / rho)^(1/3); the tip IMU's load scales with E's margin too, not with the density or the length,
    whose margins are then solved for. Without gravity nothing buckles: +-inf."""
    r = clamped_ratio(p)
    if r <= 0.0:
        return {"youngs_modulus": -math.inf, "density": math.inf, "length": math.inf}
    hub, length = p["plant"]["hub_length"], p["rod"]["length"]
    if not p["sensors"]["tip_imu"]:
        critical = (length - hub) / r  # Greenhill's length, from the ratio
        return {"youngs_modulus": r**3 - 1.0, "density": r**-3 - 1.0, "length": (critical + hub) / length - 1.0}
    bare = _ratio(p, imu=False)  # the IMU's mass can only add to the load

    def solved(f, lo: float, hi: float) -> float:
        return float(brentq(lambda x: f(x) - 1.0, lo, hi, xtol=1e-7)) if f(lo) < 1.0 <= f(hi) else math.nan

    return {"youngs_modulus": r**3 - 1.0,
            "density": solved(lambda x: _ratio(p, density_scale=1.0 + x), -0.999, bare**-3 - 1.0),
            "length": solved(lambda x: _ratio(p, length_m=length * (1.0 + x)), (hub + 1e-6) / length - 1.0,
                             ((length - hub) / bare + hub) / length - 1.0)}


def margins_text(p: Params) -> str:
    """buckling_margins in words: "E -4.9 %, rho +5.1 % or length +1.6 %"."""
    m = buckling_margins(p)
    return f"E {100 * m['youngs_modulus']:+.1f} %, rho {100 * m['density']:+.1f} % or length {100 * m['length']:+.1f} %"
