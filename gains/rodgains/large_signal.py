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


def release(p: Params, dt: float, Ao, Bo, Co, K, L, start_deg: float | None = None,
            seconds: float = SECONDS, rod_params: Params | None = None, gain: float = 1.0, delay: int = 0) -> dict:
    """Release the design model from start_deg (default: the catch angle) under the sampled loop
    (Ao, Bo, Co, K, L as Design.estimator() returns them). Returns fell (theta_1 beyond
    safety.angle_limit_deg), fell_at_s, final_deg (largest |link - upright| over the last
    FINAL_WINDOW_S; None when it fell) and holds (did not fall, final_deg <= HOLD_DEG).
    rod_params: the rod simulated, if not p's; gain: torque reaching it per torque commanded [-];
    delay: extra control periods before a command reaches it."""
    rod = RodModel.from_params(p if rod_params is None else rod_params, design=True).kelvin_voigt()
    N = rod.N
    start = math.radians(p["swing_up"]["catch_angle_deg"] if start_deg is None else start_deg)
    limit = math.radians(p["safety"]["angle_limit_deg"])
    rad_per_count = p.rad_per_count
    tmax = p.torque_max
    A_fast = _stiffest_rate(rod)
    sub = max(1, math.ceil(A_fast * dt / RK4_STABILITY))
    h = dt / sub
    K, L, Co = np.asarray(K)[0], np.asarray(L)[:, 0], np.asarray(Co)[0]
    Bo = np.asarray(Bo)[:, 0]

    f = rod.f
    q = rod.upright.copy()
    q[:N] += start
    z = np.zeros(Ao.shape[0])
    z[:N] = round(start / rad_per_count) * rad_per_count
    u = 0.0
    line = [0.0] * delay  # commands on their way to the rod, oldest first
    steps = int(round(seconds / dt))
    window = max(1, int(round(FINAL_WINDOW_S / dt)))
    worst = np.zeros(steps)
    for k in range(steps):
        y = round((q[0] - math.pi) / rad_per_count) * rad_per_count
        if k:
            zp = Ao @ z + Bo * u
            z = zp + L * (y - Co @ zp)
        u = float(np.clip(-(K @ z), -tmax, tmax))
        line.append(u)
        tau = gain * line.pop(0)
        for _ in range(sub):
            k1 = f(q, tau)
            k2 = f(q + 0.5 * h * k1, tau)
            k3 = f(q + 0.5 * h * k2, tau)
            k4 = f(q + h * k3, tau)
            q = q + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        dev = q[:N] - math.pi
        if not np.all(np.isfinite(dev)) or abs(dev[0]) > limit:
            return {"fell": True, "fell_at_s": (k + 1) * dt, "final_deg": None, "holds": False}
        worst[k] = float(np.max(np.abs(dev)))
    final = math.degrees(float(worst[-window:].max()))
    return {"fell": False, "fell_at_s": None, "final_deg": final, "holds": final <= HOLD_DEG}


def guard(p: Params, dt: float, Ao, Bo, Co, K, L) -> dict:
    """The robust design's large-signal guard: release from the catch angle (release()) on the
    nominal design model, which must end within HOLD_DEG, and on the corners of the [uncertainty]
    table that pull hardest the other way, which must not fall: the torque low with one period of
    delay on a heavy rotor together, a light rotor, and the rod's damping at its low end.
    Returns holds and the release() of every case run, in order (it stops at the first failure)."""
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
    for name, kw, settle in cases:
        got = release(p, dt, Ao, Bo, Co, K, L, **kw)
        runs[name] = got
        if got["fell"] or (settle and not got["holds"]):
            return {"holds": False, "runs": runs}
    return {"holds": True, "runs": runs}


def _stiffest_rate(rod: RodModel) -> float:
    """Largest |eigenvalue| of the rod linearized upright [1/s]: sets the RK4 substep."""
    from .linearize import linearize_upright

    A, _ = linearize_upright(rod)
    return float(np.max(np.abs(np.linalg.eigvals(A))))
