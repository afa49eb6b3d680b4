"""The balance set-point trim (firmware/src/core/rod_trim.h): its gains from the design model.

The trim moves the encoder angle the estimator calls upright while the balance holds a steady torque
beyond a small band. Its rate is set so that, on the design model, the set-point error decays with
the parameter file's time constant: a measurement offset delta gives the loop a steady torque
G delta (static_torque_per_offset), so trim += dt / (G T) * torque per period.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from . import sampled
from .buckling import clamped_ratio
from .errors import ParamError


class TrimGains(NamedTuple):
    """What rod_gains.h carries for rod_trim.c (SI units, per control period)."""

    hold_k: float  # low-pass coefficient of the held torque per period [-]
    rate: float  # trim change per N m of steady torque beyond the band, per period [rad/(N m)]
    band: float  # steady torque the trim leaves alone [N m]
    gate: float  # trims only while every estimated angle is within this of upright [rad]
    limit: float  # how far the trim may walk from its start [rad]
    torque_per_offset: float  # G: steady torque per rad of measurement offset on the design model [N m/rad]
    target: float = 0.0  # the steady torque the trim holds: the straightest shape's (straightest_shape) [N m]
    start: float = 0.0  # the trim at power-on: the straightest shape's hub in the encoder's angle [rad]


# the rod's statics are taken on this many edges, whatever the design's order: a shape, not a controller
STATICS_EDGES = 40


class StraightestShape(NamedTuple):
    """Where the trim aims on a rod curved at rest (SI units)."""

    torque: float  # the steady base torque that holds the straightest static shape upright [N m]
    hub: float  # its hub's angle from upright [rad]


def straightest_shape(params) -> StraightestShape:
    """The file's rod's straightest static shape upright: the one whose largest edge deviation from upright is
    smallest. Zero for a rod straight at rest. A rod curved at rest (rod.rest_curvature) has no straight upright
    shape: its zero-moment shape leans the curvature's way, amplified by gravity, and tilting the hub against the
    bend with a steady torque about halves the worst edge's lean (docs/control.md, "A rod curved at rest").

    The curvature is the rod's shape hanging with its hub vertical (rodctl.sim.statics hanging_tip_offset_m), where
    the encoder's zero is taken, so the trim starts at the shape's hub angle; a hub left elsewhere at boot is an
    error of the zero like any other, which the trim takes up.

    Linear statics about upright of the rod at STATICS_EDGES edges: within 0.04 mN m of the faithful
    plant's nonlinear statics on the matrix's curved rod (rodctl.sim.statics)."""
    kappa = params["rod"]["rest_curvature"]
    if kappa == 0.0 or params["rod"]["gravity"] == 0.0 or clamped_ratio(params) >= 1.0:
        return StraightestShape(0.0, 0.0)  # straight, no upright to prefer, or no static shape near it
    from .rod_model import RodModel

    m = RodModel.from_params(params, edges=STATICS_EDGES)
    # about upright the bending springs give (EI / l) Lp and gravity -m g l c_i on each edge; each
    # joint's rest angle kappa l is a constant load: edge angles delta = a + b T for a base torque T
    bend = (m.EI / m.l) * m.laplacian
    weight = np.diag(m.m * m.g * m.l * m.mass_below)
    rest = np.zeros(m.N)
    rest[:-1] += m.EI * kappa
    rest[1:] -= m.EI * kappa
    a = np.linalg.solve(bend - weight, -rest)
    b = np.linalg.solve(bend - weight, np.eye(m.N)[0])
    # the largest |a_i + b_i T| is convex and piecewise linear in T: its least value sits where two edges' lines meet
    i, j = np.triu_indices(m.N, k=1)
    cands = [-a / b]
    for sign in (1.0, -1.0):
        den = b[i] - sign * b[j]
        ok = np.abs(den) > 1e-15
        cands.append(-(a[i] - sign * a[j])[ok] / den[ok])
    T = np.concatenate(cands)
    worst = np.abs(a[None, :] + np.outer(T, b)).max(axis=1)
    best = float(T[np.argmin(worst)])
    return StraightestShape(torque=best, hub=float(a[0] + b[0] * best))


def static_torque_per_offset(d) -> float:
    """Steady torque [N m] the design's sampled loop (its model, estimator and LQR) commands per rad by
    which the encoder reads the base angle too high: the slope the trim follows down to upright."""
    Ao, Bo, Co, Ko, Lo = d.estimator()
    M = sampled.closed_loop(d.Ad, d.Bd, d.C, Ko, Lo, Ad_obs=Ao, Bd_obs=Bo, C_obs=Co)
    n = d.Ad.shape[0]
    inject = np.vstack([np.zeros((n, 1)), Lo])  # the offset enters through the measurement update
    steady = np.linalg.solve(np.eye(M.shape[0]) - M, inject)
    return float(-(Ko @ steady[n:])[0, 0])


def band_nm(params) -> float:
    """The steady torque the trim leaves alone [N m]: what keeps the rod's foot on one flank of the gearbox's
    play once the trim has walked the torque down. The motor side's dry friction holds the foot there too, so
    the band is the rest of trim.flank_hold, within trim.band (its floor) and trim.band_max (its ceiling: each
    mN m leans the tip about 1.3 deg). Measured on the robustness matrix (docs/control.md, "The band follows
    the rig's dry friction"): with Table I's 5 mN m the 0.5 mN m floor; with none, a 0.5 mN m band lets the
    rod hunt across the gap (22 of 78 runs pass) and 1.5 mN m holds it (56)."""
    t, coulomb = params["trim"], params["motor"]["coulomb_friction"]
    return max(t["band"], min(t["flank_hold"] - coulomb, t["band_max"]))


def blind(params, G: float) -> bool:
    """Is the trim's band wider than its range on this rod: the zero error whose steady torque G delta fills the
    band (band / G) more than trim.limit_deg? Then the trim cannot tell upright from anywhere it may walk, and on a
    short stiff rod it walks to its limit on the friction's torque: a 4 cm rod (band / G 5.6 deg) ended 5.9 deg off
    with the trim and 0.7 without (docs/control.md, "Finding upright")."""
    return abs(G) > 1e-9 and band_nm(params) / abs(G) > math.radians(params["trim"]["limit_deg"])


def trim_gains(d) -> TrimGains:
    """rod_trim's gains for a Design (its params' [trim] table); rate 0 when the trim is off."""
    t = d.params["trim"]
    if d.imu is not None:  # the estimator finds upright from the IMU's gravity: nothing for the trim to seek
        return TrimGains(hold_k=1.0 - math.exp(-d.dt / t["hold_time_constant"]), rate=0.0, band=band_nm(d.params),
                         gate=math.radians(t["gate_deg"]), limit=math.radians(t["limit_deg"]), torque_per_offset=0.0)
    G = static_torque_per_offset(d)
    on = t["time_constant"] > 0 and abs(G) > 1e-9 and not blind(d.params, G)
    # a trim that does not walk still starts where the rod stands straightest: knowledge of the rod, not a search
    aim = straightest_shape(d.params)
    if abs(aim.hub) > math.radians(t["limit_deg"]):  # the linear statics are about upright; so is the trim
        raise ParamError(f"rod.rest_curvature: {d.params['rod']['rest_curvature']:g} 1/m puts the straightest upright "
                         f"shape's hub {math.degrees(aim.hub):+.1f} deg off upright, past trim.limit_deg "
                         f"{t['limit_deg']:g} (raise it to hold a rod this curved, which leans at least as far)")
    return TrimGains(hold_k=1.0 - math.exp(-d.dt / t["hold_time_constant"]),
                     rate=d.dt / (G * t["time_constant"]) if on else 0.0, band=band_nm(d.params),
                     gate=math.radians(t["gate_deg"]), limit=math.radians(t["limit_deg"]), torque_per_offset=G,
                     target=aim.torque if on else 0.0, start=aim.hub)
