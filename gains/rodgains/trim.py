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


class TrimGains(NamedTuple):
    """What rod_gains.h carries for rod_trim.c (SI units, per control period)."""

    hold_k: float  # low-pass coefficient of the held torque per period [-]
    rate: float  # trim change per N m of steady torque beyond the band, per period [rad/(N m)]
    band: float  # steady torque the trim leaves alone [N m]
    gate: float  # trims only while every estimated angle is within this of upright [rad]
    limit: float  # |trim| ceiling [rad]
    torque_per_offset: float  # G: steady torque per rad of measurement offset on the design model [N m/rad]


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


def trim_gains(d) -> TrimGains:
    """rod_trim's gains for a Design (its params' [trim] table); rate 0 when the trim is off."""
    t = d.params["trim"]
    if d.imu is not None:  # the estimator finds upright from the IMU's gravity: nothing for the trim to seek
        return TrimGains(hold_k=1.0 - math.exp(-d.dt / t["hold_time_constant"]), rate=0.0, band=band_nm(d.params),
                         gate=math.radians(t["gate_deg"]), limit=math.radians(t["limit_deg"]), torque_per_offset=0.0)
    G = static_torque_per_offset(d)
    on = t["time_constant"] > 0 and abs(G) > 1e-9
    return TrimGains(hold_k=1.0 - math.exp(-d.dt / t["hold_time_constant"]),
                     rate=d.dt / (G * t["time_constant"]) if on else 0.0, band=band_nm(d.params),
                     gate=math.radians(t["gate_deg"]), limit=math.radians(t["limit_deg"]), torque_per_offset=G)
