"""The design against the faithful plant, linearized: model order vs convergence, and the sampled loop's
spectral radius and least damped slow mode at the robustness matrix's parameter corners (`rodctl gains --report`).

A linear check only: the plant is linearized about its upright equilibrium (the DER compressed by
its weight), without Coulomb friction, current limit or quantization, with its gearbox (the motor
side, the gear train's stiffness, the teeth in contact: backlash has no linearization) and the
winding's current lag, the encoder on the motor; the firmware's estimator (with its disturbance
state) and LQR close the loop at the loop rate. A radius above 1 at a case means that case cannot
be balanced even from a small offset once nothing dry holds the rod; below 1 says nothing about 30 deg
starts, swing-up or the gap (the matrix runs those).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from rodgains import sampled
from rodgains.buckling import clamped_ratio
from rodgains.design import Design
from rodgains.report import least_damped
from rodgains.trim import STATICS_EDGES, blind, trim_gains

from rodctl.sim import convergence, matrix
from rodctl.sim.imu import ImuConfig, linear_rows
from rodctl.sim.plant import Plant, faithful_plant

LINEAR_CASES = ("E+15", "E-15", "rho+15", "rho-15", "damping*0.1", "damping*10", "viscous*3", "J+30", "J-30",
                "kt+15", "kt-15", "L+3", "L-3", "delay+1", "inext10", "inext20", "inext40", "der10", "der20",
                "der40", "gear20", "gear200", "lag0.75")
# The DER's stretching modes carry no damping (the rod's damping acts on bending rates): they sit on
# the unit circle, so radii within this of 1 are marginal, not unstable.
MARGINAL = 1e-6
# The rod's slow modes, where the loop's bend and lean live: the tip IMU's near-buckling rods hunt with the
# gearbox's play at 0.4 to 0.6 Hz (docs/sensors.md); the encoder's ringing above it is report.least_damped_mode's.
SLOW_HZ = 5.0
# The design model's first hanging period this far off the rod's: its gains are made for a rod that moves otherwise.
# Table I's rod: N = 3 is -13 % and hunts (balance ends 7.5 deg off), N = 4 -8 % (3.2 deg), the default N = 8 within 4 %.
MODEL_PERIOD_WARN = 0.10
CORNERS = (("E+15", "rho-15"), ("E+15", "rho+15"), ("E-15", "rho-15"), ("E-15", "rho+15"))


def _radius(z: np.ndarray) -> float:
    """Largest |z| among a loop's eigenvalues z off the unit circle (the DER's undamped stretching modes sit on it)."""
    mag = np.abs(z)
    off = mag[np.abs(mag - 1.0) > MARGINAL]
    return float(off.max()) if off.size else 1.0


def linear_plant(plant_p, imu: bool = False):
    """(A, B, C) of the faithful plant of plant_p linearized upright: torque input through the winding's
    current lag (L / R), no dry friction, the gear teeth in contact, output the encoder's angle. imu: also
    (C_imu, D_imu), the tip IMU's rows (rodctl.sim.imu.linear_rows), appended to the return."""
    pl = faithful_plant(plant_p, input_mode="torque", coulomb=0.0, at_rest=False)
    if pl.config.backlash > 0:
        pl = pl.twin(backlash=0.0)
    A, B = convergence.linearization(pl, upright=True)
    n = A.shape[0]
    C = np.zeros((1, n))
    C[0, pl.encoder_index] = 1.0
    extra = ()
    if imu:
        y0 = convergence.hanging_equilibrium(pl, True)
        Ci, Di = linear_rows(pl, y0, A, B, pl.config.imu.position, pl.config.g)
        extra = (Ci, Di)
    L, R = plant_p["motor"]["inductance"], plant_p["motor"]["resistance"]
    if L > 0:  # the torque follows the command through the current's first-order lag
        tau = L / R
        if imu:  # the IMU's torque feedthrough now comes through the current state
            Ci, Di = extra
            extra = (np.hstack([Ci, Di]), np.zeros_like(Di))
        A = np.block([[A, B], [np.zeros((1, n)), np.full((1, 1), -1.0 / tau)]])
        B = np.vstack([np.zeros((n, 1)), [[1.0 / tau]]])
        C = np.hstack([C, [[0.0]]])
    return (A, B, C, *extra)


def loop_matrix(d: Design, plant_p, delay_periods: int = 0, actuator_gain: float = 1.0) -> np.ndarray:
    """The sampled loop's state matrix: faithful plant of plant_p (linear_plant) with d's estimator and LQR."""
    if d.imu is not None:
        A, B, C, Ci, Di = linear_plant(plant_p, imu=True)
        Ad, Bd = sampled.zoh(A, B, d.dt)
        return d.imu_loop(actuator_gain, Ad, Bd, delay_periods, C_imu=Ci, D_imu=Di, C_enc=C)
    A, B, C = linear_plant(plant_p)
    Ad, Bd = sampled.zoh(A, B, d.dt)
    Ao, Bo, Co, Ko, Lo = d.estimator()
    return sampled.closed_loop(Ad, Bd, C, Ko, Lo, Ad_obs=Ao, Bd_obs=Bo, actuator_gain=actuator_gain, C_obs=Co,
                               delay=delay_periods)


def loop_radius(d: Design, plant_p, delay_periods: int = 0, actuator_gain: float = 1.0) -> float:
    """Spectral radius of the sampled loop (loop_matrix), the DER's undamped stretching modes left out."""
    return _radius(np.linalg.eigvals(loop_matrix(d, plant_p, delay_periods, actuator_gain)))


def slow_mode(z: np.ndarray, dt: float) -> tuple[float, float]:
    """(frequency [Hz], damping ratio [-]) of the least damped oscillation below SLOW_HZ among a sampled loop's
    eigenvalues z (period dt [s]); (nan, nan) when none oscillates there. A divergence that does not oscillate
    (a real z > 1) shows in the spectral radius, not here."""
    return least_damped(z[np.abs(np.abs(z) - 1.0) > MARGINAL], dt, SLOW_HZ) or (math.nan, math.nan)


class Corner(NamedTuple):
    name: str
    radius: float  # spectral radius of the sampled loop [-]
    ratio: float  # the case's rod above the hub over its clamped buckling length [-]
    slow_hz: float  # the least damped oscillation below SLOW_HZ [Hz] (slow_mode)
    slow_zeta: float  # ... and its damping ratio [-]


def corner_radii(d: Design) -> list[Corner]:
    """The loop on the nominal faithful plant, each linear case of the matrix and the E x rho corners."""
    p = d.params

    def corner(name, plant_p, ratio_p, delay_periods=0, actuator_gain=1.0):
        z = np.linalg.eigvals(loop_matrix(d, plant_p, delay_periods, actuator_gain))
        return Corner(name, _radius(z), clamped_ratio(ratio_p), *slow_mode(z, d.dt))

    out = [corner("nominal", p, p)]
    for name in LINEAR_CASES:
        case = matrix.CASES[name]
        gain = 1.0
        overrides = list(case.plant_overrides)
        if name.startswith("kt"):  # the design's torque-to-current conversion is off by this factor
            gain = float(overrides[0].split("*=")[1])
            overrides = []
        out.append(corner(name, matrix.apply_overrides(p, overrides), matrix.apply_overrides(p, case.plant_overrides),
                          case.delay_periods, gain))
    for a, b in CORNERS:
        q = matrix.apply_overrides(p, matrix.CASES[a].plant_overrides + matrix.CASES[b].plant_overrides)
        out.append(corner(f"{a} & {b}", q, q))
    return out


def _curvature_lines(d: Design, g) -> list[str]:
    """How near upright a steady base torque can hold the rod if it is curved at rest, what the trim holds, and the
    matrix's curved case on this rig (rodctl.sim.statics)."""
    from rodctl.sim.matrix import CASES, ROBUST_BAND_DEG, apply_overrides
    from rodctl.sim.statics import hanging_tip_offset_m, upright_shapes

    p = d.params
    lines = ["Static shapes upright (rodctl.sim.statics): a rod curved at rest has no straight one; the zero-moment shape "
             "is where a trim seeking no torque rests, the straightest is the floor of any controller at the base:"]
    rigs = [("this rod", p)] if p["rod"]["rest_curvature"] != 0.0 else []
    rigs.append(("the matrix's curved case", apply_overrides(p, CASES["curved"].plant_overrides)))
    for name, q in rigs:
        if clamped_ratio(q) >= 1.0:
            lines.append(f"  {name} ({q['rod']['rest_curvature']:g} 1/m): past its clamped buckling length, no static "
                         "shape near upright")
            continue
        try:
            zero, best = upright_shapes(q)
        except ArithmeticError as e:
            lines.append(f"  {name} ({q['rod']['rest_curvature']:g} 1/m): {e}")
            continue
        flag = f"  (past the {ROBUST_BAND_DEG:g} deg band: the matrix labels it)" if best.largest_deviation_deg > ROBUST_BAND_DEG else ""
        lines.append(f"  {name} ({q['rod']['rest_curvature']:g} 1/m, hanging tip {1e3 * hanging_tip_offset_m(q):+.1f} mm with "
                     f"the hub vertical): zero-moment {zero.largest_deviation_deg:.2f} deg; straightest "
                     f"{best.largest_deviation_deg:.2f} deg, held by {1e3 * best.torque_Nm:+.2f} mN m{flag}")
    if g.target:
        lines.append(f"  the trim holds this rod's straightest shape: {1e3 * g.target:+.2f} mN m, starting at "
                     f"{math.degrees(g.start):+.2f} deg (gains/rodgains/trim.py, design statics at {STATICS_EDGES} edges)")
    elif g.start:
        lines.append(f"  the set-point is this rod's straightest shape's hub, {math.degrees(g.start):+.2f} deg (the trim is "
                     "off: it seeks no torque)")
    return lines


def report_lines(d: Design) -> list[str]:
    p = d.params
    model, edges = p["plant"]["model"], p["plant"]["edges"]
    per_plant = convergence.first_hanging_period(p, model, edges)
    per_lim, _ = convergence.richardson([convergence.first_hanging_period(p, model, n) for n in (10, 20, 40)],
                                        [10, 20, 40])
    # the paper's N-link model, held, with the tip IMU's mass as the design's model carries it
    design_rod = Plant(p, edges=d.N, J=convergence.CLAMP_INERTIA, b=0.0,
                       imu=ImuConfig.from_params(p) if p["sensors"]["tip_imu"] else None)
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
    ]
    if abs(per_design - per_lim) > MODEL_PERIOD_WARN * per_lim:
        lines.append(f"  WARNING: the design model's first hanging period is {100 * (per_design - per_lim) / per_lim:+.0f} % "
                     "off the rod's: its gains are made for a rod that moves otherwise (on Table I's rod N = 3 is -13 % "
                     "and hunts); try another rod.edges and judge it with rodctl sim")
    lines += [
        "Sampled loop on the faithful plant (linearized upright, no dry friction, the gearbox's teeth in contact,",
        "the winding's current lag) at the matrix's corners (largest |z| off the unit circle: the DER's",
        "stretching modes are undamped and sit on it); slow mode: the least damped oscillation below "
        f"{SLOW_HZ:g} Hz, where play",
        "and dry friction turn a lightly damped bend into hunting; L/Lc: the rod above the hub over its clamped "
        "buckling length:",
    ]
    unstable, in_range = [], []
    corners = corner_radii(d)
    for name, rho, ratio, hz, zeta in corners:
        past = ratio >= 1.0
        if rho > 1.0:
            flag = "  <- unstable: past its buckling length" if past else "  <- WARNING: unstable (> 1)"
            (unstable if past else in_range).append(name)
        else:
            flag = "  (past its buckling length)" if past else ""
        slow = f"slow mode {hz:5.2f} Hz, damping {zeta:5.2f}" if math.isfinite(hz) else f"{'no slow oscillation':33s}"
        lines.append(f"  {name:22s} spectral radius {rho:.6f}  {slow}  L/Lc {ratio:.3f}{flag}")
    nominal = next(c for c in corners if c.name == "nominal")
    if nominal.radius > 1.0:  # the rod itself, not a corner of the matrix: it falls
        sensed = ("this design with the tip IMU does not hold" if p["sensors"]["tip_imu"] else
                  "feedback from the motor's encoder alone does not hold here (docs/sensors.md: the tip IMU)")
        why = (f"the rod above the hub is {nominal.ratio:.2f} x its clamped buckling length, which {sensed}"
               if nominal.ratio >= 1.0
               else "rodctl sim shows it fall; see the margins above")
        lines.append(f"  WARNING: the design does not hold the nominal rod even linearly: {why}")
    if in_range:
        lines.append(f"  WARNING: the design does not hold {', '.join(in_range)} even linearly, and nothing dry may"
                     + (f"; past its clamped buckling length it does not hold {', '.join(unstable)} either"
                        if unstable else ""))
    elif unstable:
        lines.append(f"  every case the loop cannot hold linearly ({', '.join(unstable)}) is past its clamped buckling "
                     "length: the matrix labels those runs, it does not count them as passed")
    g = trim_gains(d)
    lines += _curvature_lines(d, g)
    if g.torque_per_offset and blind(p, g.torque_per_offset):
        lines.append(f"Set-point trim (firmware/src/core/rod_trim.h): off: its {1e3 * g.band:g} mN m band is "
                     f"{math.degrees(g.band / abs(g.torque_per_offset)):.1f} deg of zero error on this rod (G = "
                     f"{g.torque_per_offset:.4g} N m/rad), past its {p['trim']['limit_deg']:g} deg range: the encoder's "
                     "zero holds a rod this stiff (docs/control.md)")
    if g.rate:
        lines.append(f"Set-point trim (firmware/src/core/rod_trim.h): {p['trim']['time_constant']:g} s on the design model, "
                     f"G = {g.torque_per_offset:.4g} N m per rad of zero error; band {1e3 * g.band:g} mN m, the steady torque that "
                     "keeps the rod on one flank of the gearbox's play (docs/control.md)")
    return lines
