"""The rod's static shapes upright: what a steady base torque can hold, whatever the controller.

Held still near upright, the faithful plant's rod (its edges, hub, rest curvature and any IMU mass) has
one static shape for each angle of its hub, each held by its own steady base torque. A straight rod's
family passes through the straight upright shape at zero torque. A rod curved at rest has no straight
member: its zero-moment shape (what the set-point trim finds, docs/control.md) leans the curvature's way,
amplified by gravity near the buckling length, and even its straightest member, the hub tilted against
the bend, may leave some edge past the robustness matrix's band. That is a floor of the physics, not of a
design: no base-torque controller holds such a rod closer to upright.

Newton's method on the plant's own generalized force (rodctl.sim.plant, the motor and gearbox left out:
the rod's shape depends only on the hub's angle), continued from the straight upright rod.
"""

from __future__ import annotations

import json
import math
from typing import NamedTuple

import numpy as np
from scipy.optimize import minimize_scalar

from rodgains.buckling import clamped_ratio
from rodgains.params import Params

# the straightest shape is searched within this of the zero-moment hub angle [deg]
SEARCH_HALF_WIDTH_DEG = 15.0
# a "shape near upright" has its hub within this of it [deg]
MAX_HUB_DEG = 45.0


class UprightShape(NamedTuple):
    """A static shape of the rod near upright (SI units, angles in degrees)."""

    hub_deg: float  # the hub's angle from upright [deg]
    torque_Nm: float  # the steady base torque that holds it [N m]
    largest_deviation_deg: float  # the largest edge's (hub included) angle from upright [deg]


class _Family:
    """Static shapes of one rod, each solved from the last one found (continuation)."""

    def __init__(self, params: Params, about: float = math.pi):
        from rodctl.sim.plant import faithful_plant

        self.plant = faithful_plant(params, input_mode="torque", gear=None, coulomb=0.0, at_rest=False)
        n = self.plant.n
        y = self.plant.rest_state(about)
        self.origin = float(y[0])  # the hub coordinate of the straight rod at `about`
        self.x = np.concatenate([y[1:n], [0.0]])  # the rod's coordinates past the hub, then the base torque

    def _residual(self, x: np.ndarray, hub: float) -> np.ndarray:
        n = self.plant.n
        return self.plant.force(np.concatenate([[hub], x[:-1], np.zeros(n)]), float(x[-1]))

    def shape(self, hub_deg: float) -> UprightShape:
        hub = self.origin + math.radians(hub_deg)
        x = self.x.copy()
        n = self.plant.n
        scale = np.full(n, 1e-9)
        scale[-1] = 1e-7  # the torque's step [N m]
        for _ in range(40):
            r = self._residual(x, hub)
            J = np.empty((n, n))
            for k in range(n):
                e = np.zeros(n)
                e[k] = scale[k] * max(1.0, abs(x[k]))
                J[:, k] = (self._residual(x + e, hub) - self._residual(x - e, hub)) / (2 * e[k])
            try:
                step = np.linalg.solve(J, r)
            except np.linalg.LinAlgError:
                raise ArithmeticError(f"no static shape found with the hub {hub_deg:g} deg from upright") from None
            x = x - step
            if np.max(np.abs(step)) < 1e-13:  # converged to rounding
                break
        if not np.max(np.abs(self._residual(x, hub))) < 1e-8:
            raise ArithmeticError(f"no static shape found with the hub {hub_deg:g} deg from upright")
        self.x = x
        pl = self.plant
        pl.set_raw_state(np.concatenate([[hub], x[:-1]]), np.zeros(n))
        theta, _ = pl.state()
        dev = np.degrees(np.abs(np.mod(theta, 2 * math.pi) - math.pi))
        return UprightShape(hub_deg=float(hub_deg), torque_Nm=float(x[-1]), largest_deviation_deg=float(dev.max()))


def hanging_nodes(params: Params, hub_deg: float = 0.0) -> np.ndarray:
    """Node positions (N+1, 2) [m] of the rod hanging at rest with its hub held hub_deg from vertical (positive toward
    increasing angles), node 0 on the axis, y up: the plant's own nodes (rodctl.sim.plant.Plant.nodes)."""
    fam = _Family(params, about=0.0)
    fam.shape(float(hub_deg))
    return fam.plant.nodes()


class HangingShape(NamedTuple):
    """A rod curved at rest, hanging: where its hub hangs free, and its bend for a hub held near there."""

    hub_rad: float  # the hub's angle from vertical where it hangs free, no torque at the hub [rad]
    bend_rad: np.ndarray  # each edge's angle from the hub's, in that shape (N,) [rad]
    bend_per_rad: np.ndarray  # how that bend changes per rad of the hub held away from hub_rad (N,) [rad/rad]

    def bend_at(self, hub_rad: float) -> np.ndarray:
        """Each edge's angle from the hub's with the hub held at hub_rad [rad] (within a few degrees of hub_rad:
        the bend is linear in the hub's angle there)."""
        return self.bend_rad + (hub_rad - self.hub_rad) * self.bend_per_rad


_HANGING: dict[str, HangingShape] = {}
STEP_DEG = 0.5  # the hub's step for bend_per_rad [deg]


def hanging_shape(params: Params) -> HangingShape | None:
    """The hanging rod's HangingShape on the parameter file's own plant: where a rod curved at rest comes to rest, and
    its shape with the hub held on a flank of the gearbox's play; None for a straight rod (hanging vertically). Solved
    once per rod: the statics read only [rod], [plant] and [sensors] (an IMU's mass), so the many files of a fit that
    differ in the motor or the gearbox share one."""
    if params["rod"]["rest_curvature"] == 0.0:
        return None
    key = json.dumps([params.values[s] for s in ("rod", "plant", "sensors")], sort_keys=True, default=str)
    if key not in _HANGING:
        fam = _Family(params, about=0.0)
        shape = _zero_torque(fam)  # leaves the plant in that shape
        theta, _ = fam.plant.state()
        fam.shape(shape.hub_deg + STEP_DEG)
        theta_up, _ = fam.plant.state()
        bend, bend_up = theta - theta[0], theta_up - theta_up[0]
        if len(_HANGING) > 64:  # one per rod a fit visits
            _HANGING.clear()
        _HANGING[key] = HangingShape(math.radians(shape.hub_deg), np.asarray(bend, float),
                                     np.asarray((bend_up - bend) / math.radians(STEP_DEG), float))
    return _HANGING[key]


def hanging_tip_offset_m(params: Params) -> float:
    """How far the tip of the rod hanging at rest, its hub held vertical (where the encoder's zero is taken), is
    from the vertical through the axis [m], positive toward increasing angles: what to measure on a rod to set
    rod.rest_curvature (the matrix's 0.82 1/m: 5.0 mm)."""
    return float(hanging_nodes(params)[-1][0])


def zero_moment_shape(params: Params) -> UprightShape:
    """The shape that needs no steady base torque: where a rod that is let find its own balance rests."""
    return _zero_torque(_Family(params))


def _zero_torque(fam: _Family) -> UprightShape:
    a, b = 0.0, 0.5
    sa, sb = fam.shape(a), fam.shape(b)
    for _ in range(30):  # the secant method: the torque is nearly linear in the hub's angle
        if abs(sb.torque_Nm) < 1e-9 or sb.torque_Nm == sa.torque_Nm:
            break
        a, sa, b = b, sb, b - sb.torque_Nm * (b - a) / (sb.torque_Nm - sa.torque_Nm)
        if abs(b) > MAX_HUB_DEG:
            raise ArithmeticError(f"no zero-moment shape within {MAX_HUB_DEG:g} deg of upright")
        sb = fam.shape(b)
    return sb


def straightest_shape(params: Params) -> UprightShape:
    """The static shape whose largest edge deviation from upright is smallest, over every steady base torque:
    the closest to upright any controller acting at the base can hold this rod. A straight rod: upright itself.
    A rod at or past its clamped buckling length has no static shape near upright to hold: ArithmeticError."""
    if params["rod"]["rest_curvature"] == 0.0:
        return UprightShape(0.0, 0.0, 0.0)
    return upright_shapes(params)[1]


def upright_shapes(params: Params) -> tuple[UprightShape, UprightShape]:
    """(the zero-moment shape, the straightest shape) of a rod curved at rest, from one family: the straightest is
    searched about the zero-moment hub. ArithmeticError at or past the clamped buckling length."""
    if clamped_ratio(params) >= 1.0:
        raise ArithmeticError("the rod is past its clamped buckling length: no static shape near upright")
    fam = _Family(params)
    zero = _zero_torque(fam)
    centre = zero.hub_deg
    res = minimize_scalar(lambda h: fam.shape(h).largest_deviation_deg, method="bounded",
                          bounds=(centre - SEARCH_HALF_WIDTH_DEG, centre + SEARCH_HALF_WIDTH_DEG),
                          options={"xatol": 1e-4})
    return zero, fam.shape(float(res.x))
