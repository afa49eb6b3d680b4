"""The design against the faithful plant, linearized: model order vs convergence, and the sampled loop's
spectral radius at the robustness matrix's parameter corners (`rodctl gains --report`).

A linear check only: the plant is linearized about its upright equilibrium (the DER compressed by
its weight), without Coulomb friction, current limit or quantization, and the firmware's
estimator (with its disturbance state) and LQR close the loop at the loop rate. A radius above 1
at a corner means that case cannot be balanced even from a small offset; below 1 says nothing about
30 deg starts or swing-up (the matrix runs those).
"""

from __future__ import annotations

import numpy as np

from rodgains import sampled
from rodgains.design import Design

from rodctl.sim import convergence, matrix
from rodctl.sim.plant import Plant, faithful_plant

LINEAR_CASES = ("E+15", "E-15", "rho+15", "rho-15", "damping*0.1", "damping*10", "viscous*3", "J+30", "J-30",
                "kt+15", "kt-15", "L+3", "L-3", "delay+1", "inext10", "inext20", "inext40", "der10", "der20",
                "der40")
# The DER's stretching modes carry no damping (the rod's damping acts on bending rates): they sit on
# the unit circle, so radii within this of 1 are marginal, not unstable.
MARGINAL = 1e-6
CORNERS = (("E+15", "rho-15"), ("E+15", "rho+15"), ("E-15", "rho-15"), ("E-15", "rho+15"))


def _radius(M: np.ndarray) -> float:
    """Largest |eigenvalue| off the unit circle (the DER's undamped stretching modes sit on it)."""
    mag = np.abs(np.linalg.eigvals(M))
    off = mag[np.abs(mag - 1.0) > MARGINAL]
    return float(off.max()) if off.size else 1.0


def loop_radius(d: Design, plant_p, delay_periods: int = 0, actuator_gain: float = 1.0) -> float:
    """Spectral radius of the sampled loop: faithful plant of plant_p (linearized upright, torque
    input, no dry friction) with d's estimator and LQR."""
    pl = faithful_plant(plant_p, input_mode="torque")
    pl = Plant(plant_p, kind=pl.kind, edges=pl.N - 1, input_mode="torque", hub_length=pl.hub, coulomb=0.0)
    A, B = convergence.linearization(pl, upright=True)
    n = A.shape[0] // 2
    Ad, Bd = sampled.zoh(A, B, d.dt)
    C = np.zeros((1, 2 * n))
    C[0, 0] = 1.0
    Ao, Bo, Co, Ko, Lo = d.estimator()
    return _radius(sampled.closed_loop(Ad, Bd, C, Ko, Lo, Ad_obs=Ao, Bd_obs=Bo, actuator_gain=actuator_gain, C_obs=Co,
                                       delay=delay_periods))


def corner_radii(d: Design) -> list[tuple[str, float]]:
    """(name, spectral radius) for the nominal faithful plant, each linear case of the matrix and the
    E x rho corners."""
    p = d.params
    out = [("nominal", loop_radius(d, p))]
    for name in LINEAR_CASES:
        case = matrix.CASES[name]
        gain = 1.0
        overrides = list(case.plant_overrides)
        if name.startswith("kt"):  # the design's torque-to-current conversion is off by this factor
            gain = float(overrides[0].split("*=")[1])
            overrides = []
        q = matrix.apply_overrides(p, overrides)
        out.append((name, loop_radius(d, q, delay_periods=case.delay_periods, actuator_gain=gain)))
    for a, b in CORNERS:
        q = matrix.apply_overrides(p, matrix.CASES[a].plant_overrides + matrix.CASES[b].plant_overrides)
        out.append((f"{a} & {b}", loop_radius(d, q)))
    return out


def report_lines(d: Design) -> list[str]:
    p = d.params
    model, edges = p["plant"]["model"], p["plant"]["edges"]
    per_plant = convergence.first_hanging_period(p, model, edges)
    per_lim, _ = convergence.richardson([convergence.first_hanging_period(p, model, n) for n in (10, 20, 40)],
                                        [10, 20, 40])
    design_rod = Plant(p, edges=d.N, J=convergence.CLAMP_INERTIA, b=0.0)  # the paper's N-link model, held
    A, _ = convergence.linearization(design_rod, upright=False)
    ev = np.linalg.eigvals(A)
    periods = 2 * np.pi / ev[ev.imag > 1e-9].imag
    per_design = float(periods[periods < 5.0].max())
    lines = [
        "",
        "Controller order against the faithful plant (docs/plant.md):",
        f"  plant: {model}, {edges} edges + {1e3 * p['plant']['hub_length']:g} mm hub; first hanging period "
        f"{1e3 * per_plant:.1f} ms ({100 * abs(per_plant - per_lim) / per_lim:.2f} % from N -> inf, {1e3 * per_lim:.1f} ms)",
        f"  design model: N = {d.N} equal edges, edge 1 ({1e3 * p['rod']['length'] / d.N:.1f} mm) clamped; first hanging "
        f"period {1e3 * per_design:.1f} ms ({100 * (per_design - per_lim) / per_lim:+.1f} % from the plant's limit)",
        "Sampled loop on the faithful plant (linearized upright, no dry friction) at the matrix's corners",
        "(largest |z| off the unit circle: the DER's stretching modes are undamped and sit on it):",
    ]
    worst = 0.0
    for name, rho in corner_radii(d):
        worst = max(worst, rho)
        flag = "  <- WARNING: unstable (> 1)" if rho > 1.0 else ""
        lines.append(f"  {name:22s} spectral radius {rho:.6f}{flag}")
    if worst > 1.0:
        lines.append("  WARNING: the design does not stabilize every corner of the matrix even linearly")
    return lines
