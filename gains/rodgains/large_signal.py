"""Does a set of gains hold the design model released from the catch angle? (the robust design's guard)

Why: the robust refinement (robust_design.py) only looks at the loop's eigenvalues, which describe
small motions. From 30 deg the 0.2 N m limit saturates the command for a tenth of a second, and a
refined loop can then bang the rod over although every model of its family is linearly stable:
measured on a stiffer rod (E = 650 kPa, rotor 6e-7 kg m^2), the refined gains fall from 30 deg in
0.37 s (here and in the SIL on the faithful plant) while the LQG gains hold. The linear margins
cannot see this, so the refinement is checked here, on the same model family's nominal member.

What runs: the designer's own nonlinear N-link rod (RodModel, eq. 7, with the motor terms the gains
assume), released straight and at rest at `swing_up.catch_angle_deg` from upright, under the
firmware's loop: encoder quantization, the current-estimate observer with its disturbance state,
u = -K z - w clipped to the torque ceiling, held for one period. RK4 in float64; never the simulated
plant that judges the controller (host/rodctl/sim), so the guard is no inverse crime.
"""

from __future__ import annotations

import math

import numpy as np

from .params import Params
from .rod_model import RodModel

SECONDS = 2.0  # simulated time [s]: the nominal goal is 1 deg by 1.5 s on the faithful plant
FINAL_WINDOW_S = 0.25  # "at the end" = every sample of the last this many seconds [s]
HOLD_DEG = 3.0  # every link within this of upright at the end [deg]: the robustness matrix's band
RK4_STABILITY = 2.0  # RK4 is stable to |lambda h| = 2.78; substeps keep the stiffest mode below this [-]


def releases(p: Params, dt: float, Ao, Bo, Co, K, L, cases: list[dict], start_deg: float | None = None,
             seconds: float = SECONDS) -> list[dict]:
    """Release the design model from start_deg (default: the catch angle) under the sampled loop
    (Ao, Bo, Co, K, L as Design.estimator() returns them), once per case: a dict of rod_params (the rod
    simulated, if not p's), gain (torque reaching it per torque commanded [-]) and delay (extra control
    periods before a command reaches it). Returns, per case in order: fell (theta_1 beyond
    safety.angle_limit_deg), fell_at_s, final_deg (largest |link - upright| over the last FINAL_WINDOW_S;
    None when it fell) and holds (did not fall, final_deg <= HOLD_DEG).

    The cases are integrated side by side, one array operation for all of them, at the finest RK4
    substep any of their rods needs: the guard's four releases cost about what one alone does (a 30 %
    lighter rotor needs no finer step, a less damped rod a coarser one)."""
    rods = [RodModel.from_params(c.get("rod_params") or p, design=True).kelvin_voigt() for c in cases]
    sub = max(max(1, math.ceil(_stiffest_rate(rod) * dt / RK4_STABILITY)) for rod in rods)
    return _release_together(p, dt, Ao, Bo, Co, K, L, _Family(rods), sub, cases, start_deg, seconds)


class _Family:
    """Rods that differ only in their base inertia and joint damping (RodModel), stacked: f() of RodModel for
    a batch of states q (B, 2N) and torques (B,)."""

    def __init__(self, rods: list[RodModel]):
        r0 = rods[0]
        for r in rods[1:]:
            if (r.N, r.l, r.m, r.EI, r.g, r.b, r.extra_mass) != (r0.N, r0.l, r0.m, r0.EI, r0.g, r0.b, r0.extra_mass):
                raise ValueError("large_signal: the guard's rods differ in more than base inertia and damping")
        self.N = r0.N
        self.mass = r0.m * r0.l**2 * r0.staircase  # M(theta) at cos(theta_i - theta_j) = 1 [kg m^2]
        self.gravity = r0.m * r0.g * r0.l * r0.mass_below
        self.spring = 2.0 * r0.EI / r0.l
        # D of eq. (11) with the base's viscous friction, per rod
        self.damping = np.array([r.d * r0.laplacian for r in rods])
        self.damping[:, 0, 0] += r0.b
        self.J = np.array([r.J for r in rods])
        self.upright = r0.upright

    def take(self, keep: np.ndarray) -> "_Family":
        """The same family without the rods where keep is False."""
        other = object.__new__(_Family)
        other.__dict__.update(self.__dict__)
        other.J, other.damping = self.J[keep], self.damping[keep]
        return other

    def f(self, q: np.ndarray, torque: np.ndarray) -> np.ndarray:
        """Eq. (13) of each rod (RodModel.f): dq/dt, (B, 2N)."""
        N = self.N
        th, dth = q[:, :N], q[:, N:]
        diff = th[:, :, None] - th[:, None, :]
        M = np.cos(diff) * self.mass
        M[:, 0, 0] += self.J
        half = 0.5 * (th[:, 1:] - th[:, :-1])
        dEb = self.spring * np.tan(half) / np.cos(half) ** 2  # dE_b/dphi_k, RodModel.potential_gradient
        rhs = -self.gravity * np.sin(th)
        rhs[:, :-1] += dEb
        rhs[:, 1:] -= dEb
        rhs[:, 0] += torque
        rhs -= np.matmul(np.sin(diff) * self.mass, (dth * dth)[:, :, None])[:, :, 0]
        rhs -= np.matmul(self.damping, dth[:, :, None])[:, :, 0]
        out = np.empty_like(q)
        out[:, :N] = dth
        out[:, N:] = np.linalg.solve(M, rhs[:, :, None])[:, :, 0]
        return out


def _release_together(p: Params, dt: float, Ao, Bo, Co, K, L, family: _Family, sub: int, cases: list[dict],
                      start_deg: float | None, seconds: float) -> list[dict]:
    """releases() of cases whose rods form `family`, integrated with `sub` RK4 substeps per period."""
    N, B = family.N, len(cases)
    start = math.radians(p["swing_up"]["catch_angle_deg"] if start_deg is None else start_deg)
    limit = math.radians(p["safety"]["angle_limit_deg"])
    rad_per_count = p.rad_per_count
    tmax = p.torque_max
    h = dt / sub
    K, L, Co = np.asarray(K)[0], np.asarray(L)[:, 0], np.asarray(Co)[0]
    Ao, Bo = np.asarray(Ao), np.asarray(Bo)[:, 0]
    gain = np.array([float(c.get("gain", 1.0)) for c in cases])
    delay = [int(c.get("delay", 0)) for c in cases]

    live = np.arange(B)  # the cases still upright, in order
    q = np.tile(family.upright, (B, 1))
    q[:, :N] += start
    z = np.zeros((B, Ao.shape[0]))
    z[:, :N] = round(start / rad_per_count) * rad_per_count
    u = np.zeros(B)
    lines = [[0.0] * dl for dl in delay]  # commands on their way to each rod, oldest first
    steps = int(round(seconds / dt))
    window = max(1, int(round(FINAL_WINDOW_S / dt)))
    worst = np.zeros((B, steps))
    out: list[dict | None] = [None] * B
    for k in range(steps):
        y = np.round((q[:, 0] - math.pi) / rad_per_count) * rad_per_count
        if k:
            zp = z @ Ao.T + Bo * u[:, None]
            z = zp + L * (y - zp @ Co)[:, None]
        u = np.clip(-(z @ K), -tmax, tmax)
        tau = np.empty(len(live))
        for j, i in enumerate(live):
            lines[i].append(float(u[j]))
            tau[j] = gain[i] * lines[i].pop(0)
        for _ in range(sub):
            k1 = family.f(q, tau)
            k2 = family.f(q + 0.5 * h * k1, tau)
            k3 = family.f(q + 0.5 * h * k2, tau)
            k4 = family.f(q + h * k3, tau)
            q = q + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        dev = q[:, :N] - math.pi
        fell = ~np.all(np.isfinite(dev), axis=1) | (np.abs(dev[:, 0]) > limit)
        worst[live, k] = np.max(np.abs(dev), axis=1)
        if fell.any():
            for i in live[fell]:
                out[i] = {"fell": True, "fell_at_s": (k + 1) * dt, "final_deg": None, "holds": False}
            keep = ~fell
            live, q, z, u = live[keep], q[keep], z[keep], u[keep]
            family = family.take(keep)
            if not len(live):
                break
    for i in live:
        final = math.degrees(float(worst[i, -window:].max()))
        out[i] = {"fell": False, "fell_at_s": None, "final_deg": final, "holds": final <= HOLD_DEG}
    return out


def guard(p: Params, dt: float, Ao, Bo, Co, K, L) -> dict:
    """The robust design's large-signal guard: release from the catch angle (releases()) on the
    nominal design model, which must end within HOLD_DEG, and on the corners of the [uncertainty]
    table that pull hardest the other way, which must not fall: the torque low with one period of
    delay on a heavy rotor together, a light rotor, and the rod's damping at its low end.
    Returns holds and the release of every case up to the first that fails, in order (all four are
    integrated together)."""
    u, m, r = p["uncertainty"], p["motor"], p["rod"]
    J = m["rotor_inertia"]
    cases = [("nominal", {}, True),
             ("torque low, delayed, heavy rotor", {
                 "gain": 1.0 - u["torque_constant_rel"], "delay": int(u["delay_periods_max"]),
                 "rod_params": p.with_overrides(f"motor.rotor_inertia={J * (1 + u['rotor_inertia_rel'])!r}")}, False),
             ("light rotor", {"rod_params": p.with_overrides(
                 f"motor.rotor_inertia={J * (1 - u['rotor_inertia_rel'])!r}")}, False),
             ("rod damping low", {"rod_params": p.with_overrides(
                 f"rod.damping={r['damping'] / u['rod_damping_factor']!r}")}, False)]
    runs = {}
    for (name, _, settle), got in zip(cases, releases(p, dt, Ao, Bo, Co, K, L, [kw for _, kw, _ in cases])):
        runs[name] = got
        if got["fell"] or (settle and not got["holds"]):
            return {"holds": False, "runs": runs}
    return {"holds": True, "runs": runs}


def _stiffest_rate(rod: RodModel) -> float:
    """Largest |eigenvalue| of the rod linearized upright [1/s]: sets the RK4 substep."""
    from .linearize import linearize_upright

    A, _ = linearize_upright(rod)
    return float(np.max(np.abs(np.linalg.eigvals(A))))
