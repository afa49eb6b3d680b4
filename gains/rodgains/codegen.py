"""Generated C header for the firmware: macros and gain tables, float literals only.

The output depends only on the resolved parameters (and this generator), never on the time,
so identical inputs give byte-identical files and CI can diff the committed copy.
"""

from __future__ import annotations

import math
import struct
from pathlib import Path

import numpy as np

from .design import Design, lean_torque
from .trim import trim_gains

# Bump when the macro set or its meaning changes; firmware/src/core/rod_config.h checks it.
HEADER_SCHEMA_VERSION = 5
DEFAULT_HEADER = Path("firmware/include/rod_gains.h")


def f32(x: float) -> str:
    """C float literal that round-trips the nearest float32 of x."""
    v = struct.unpack("<f", struct.pack("<f", float(x)))[0]
    if not math.isfinite(v):
        raise ValueError(f"non-finite value {x!r} in generated header")
    if v == 0.0:
        return "0.0f"
    s = f"{v:.9g}"
    if "e" not in s and "." not in s:
        s += ".0"
    return s + "f"


def _vector(values) -> str:
    return "{" + ", ".join(f32(v) for v in np.ravel(values)) + "}"


def _matrix(M: np.ndarray, indent: str = "    ") -> str:
    rows = [indent + "  " + _vector(row) for row in M]
    return "{ \\\n" + ", \\\n".join(rows) + " \\\n" + indent + "}"


def rate_filter_gains(bandwidth_hz: float, dt: float) -> tuple[float, float]:
    """Critically damped angle-tracking loop: theta_e += dt w_e + k1 err, w_e += k2 err.

    Natural frequency w_n = 2 pi bandwidth, so k1 = 2 w_n dt and k2 = w_n^2 dt.
    """
    wn = 2.0 * math.pi * bandwidth_hz
    return 2.0 * wn * dt, wn * wn * dt


def pendulum_frequency(p) -> float:
    """Small-swing frequency of the rod hanging as a rigid body on the design's motor [rad/s]:
    omega0^2 = m g (L / 2) / (J + m L^2 / 3)."""
    r = p["rod"]
    m = r["density"] * r["width"] * r["thickness"] * r["length"]
    L = r["length"]
    w = math.sqrt(m * r["gravity"] * 0.5 * L / (p.design_base_inertia + m * L * L / 3.0))
    return max(w, 1e-3)  # no gravity: no pendulum; the firmware divides by it


FLANK_RAMP_S = 2.0  # the flank feed-forward comes in this slowly after the catch, so the catch itself is the plain LQR's [s]


def _imu_tables(d: Design) -> list[str]:
    """The tip IMU's estimator tables (rodgains.imu.ImuEstimator), none without it."""
    im = d.imu
    if im is None:
        return []
    return [
        "",
        f"/* The tip IMU (sensors.tip_imu): {im.delay} period(s) of read latency, {d.params['sensors']['imu_from_tip'] * 1e3:g} mm "
        "from the tip. Extra states a = [encoder offset, gyro bias, readings in flight]. */",
        f"#define ROD_IMU_NA {im.NA}",
        f"#define ROD_IMU_DELAY_PERIODS {im.delay}",
        f"#define ROD_IMU_L_INIT {_matrix(im.L)}",
        f"#define ROD_IMU_LW_INIT {_vector(im.Lw)}",
        f"#define ROD_IMU_LA_INIT {_matrix(im.La)}",
        f"#define ROD_IMU_AZ_INIT {_matrix(im.AZ)}",
        f"#define ROD_IMU_AA_INIT {_matrix(im.AA)}",
        f"#define ROD_IMU_BA_INIT {_vector(im.BA)}",
        f"#define ROD_IMU_CZ_INIT {_matrix(im.CZ)}",
        f"#define ROD_IMU_CA_INIT {_matrix(im.CA)}",
        f"#define ROD_IMU_DY_INIT {_vector(im.DY)}",
        f"#define ROD_IMU_FLANK_FF_NM {f32(d.flank_feedforward())}  /* added to the balance torque, ramped in over "
        f"ROD_IMU_FLANK_RAMP_STEPS: the rod held leaning so that gravity takes {lean_torque(d.params) * 1e3:g} "
        "mN m at the base (lqr.imu_flank_torque, where the play reaches lqr.imu_lean_from_play_deg) [N m] */",
        f"#define ROD_IMU_FLANK_RAMP_STEPS {round(FLANK_RAMP_S / d.dt)}  /* {FLANK_RAMP_S:g} s, slower than the balance */",
    ]


def header_text(d: Design, command: str) -> str:
    p = d.params
    N = d.N
    cpr = p.counts_per_rev
    k1, k2 = rate_filter_gains(p["encoder"]["rate_bandwidth_hz"], d.dt)
    sha = p.sha256()
    swing = p["swing_up"]
    trim = trim_gains(d)
    safety = p["safety"]
    drv = p["driver"]

    def deg(x):
        return math.radians(x)

    macros = [
        ("ROD_GAINS_SCHEMA_VERSION", str(HEADER_SCHEMA_VERSION), "layout of this header"),
        ("ROD_GAINS_INPUT_SHA256", f'"{sha}"', "SHA-256 of the resolved parameters"),
        ("ROD_GAINS_SHA256_BYTES_INIT", "{" + ", ".join(f"0x{sha[i:i + 2]}" for i in range(0, 64, 2)) + "}",
         "the same 32 bytes, for the hello frame"),
        ("ROD_N", str(N), "edges in the controller's model"),
        ("ROD_NX", str(2 * N), "state size: theta_1..N then rates"),
        ("ROD_LOOP_RATE_HZ", f32(1.0 / d.dt), "control loop rate [Hz]"),
        ("ROD_DT_S", f32(d.dt), "control period [s]"),
        ("ROD_LOOP_PERIOD_US", f"{round(d.dt * 1e6)}u", "control period [us]"),
        ("ROD_COUNTS_PER_REV_NUM", str(cpr.numerator), "encoder counts per output turn = NUM / DEN exactly"),
        ("ROD_COUNTS_PER_REV_DEN", str(cpr.denominator), ""),
        ("ROD_RAD_PER_COUNT", f32(2 * math.pi / float(cpr)), "[rad/count]"),
        ("ROD_RATE_FILTER_K1", f32(k1), f"base-rate tracking filter, {p['encoder']['rate_bandwidth_hz']:g} Hz [-]"),
        ("ROD_RATE_FILTER_K2", f32(k2), "[1/s]"),
        ("ROD_MOTOR_KT_NM_PER_A", f32(p.kt_out), "torque per ampere at the output shaft [N m/A]"),
        ("ROD_MOTOR_KE_V_S_PER_RAD", f32(p.ke_out), "back-EMF per output rad/s [V s/rad]"),
        ("ROD_MOTOR_R_OHM", f32(p["motor"]["resistance"]), "winding resistance [ohm]"),
        ("ROD_SUPPLY_V", f32(drv["supply_voltage"]), "motor supply [V]"),
        ("ROD_CURRENT_LIMIT_A", f32(drv["current_limit"]), "driver current limit [A]"),
        ("ROD_TORQUE_MAX_NM", f32(p.torque_max), "|torque| ceiling at the output [N m]"),
        ("ROD_DUTY_MAX", f32(drv["max_duty"]), "|duty| ceiling [-]"),
        ("ROD_PWM_FREQUENCY_HZ", str(int(drv["pwm_frequency_hz"])), "PWM carrier [Hz]"),
        ("ROD_COULOMB_COMP_NM", f32(p["lqr"]["friction_compensation"]),
         "balance adds this in the direction of the estimated base rate [N m]"),
        ("ROD_SWING_AMPLITUDE_NM", f32(swing["amplitude"]), "u_swing of eq. (22) [N m]"),
        ("ROD_SWING_ANGLE_RAD", f32(deg(swing["angle_deg"])), "pump only within this of hanging [rad]"),
        ("ROD_SWING_OMEGA0_RAD_S", f32(pendulum_frequency(p)), "rigid rod + motor pendulum frequency [rad/s]"),
        ("ROD_SWING_ENERGY_TARGET", f32(2.0 * swing["energy_target"]), "pump toward this energy (2 = upright) [-]"),
        ("ROD_SWING_RATE_LP_K", f32(1.0 - math.exp(-2 * math.pi * swing["rate_filter_hz"] * d.dt)),
         f"swing-up rate low-pass, {swing['rate_filter_hz']:g} Hz, per period [-]"),
        ("ROD_SWING_STALL_STEPS", str(swing['stall_steps']), "stalled half-swings that raise the pump, at most [-]"),
        ("ROD_CATCH_ANGLE_RAD", f32(deg(swing["catch_angle_deg"])), "switch to balance within this of upright [rad]"),
        ("ROD_ANGLE_LIMIT_RAD", f32(deg(safety["angle_limit_deg"])), "balance disarms beyond this from upright [rad]"),
        ("ROD_SPEED_LIMIT_RAD_S", f32(safety["speed_limit"]), "disarm beyond this base speed [rad/s]"),
        ("ROD_HEARTBEAT_TIMEOUT_S", f32(safety["heartbeat_timeout"]), "default host-silence limit [s]"),
        ("ROD_TRIM_HOLD_K", f32(trim.hold_k), f"held-torque low-pass, {p['trim']['hold_time_constant']:g} s, per period [-]"),
        ("ROD_TRIM_RATE", f32(trim.rate),
         f"set-point trim per N m beyond the band, per period [rad/(N m)]: {p['trim']['time_constant']:g} s on the "
         f"design model (G = {trim.torque_per_offset:.4g} N m/rad)"),
        ("ROD_TRIM_BAND_NM", f32(trim.band),
         "steady torque the trim leaves alone [N m]: trim.flank_hold - motor.coulomb_friction, within trim.band to band_max"),
        ("ROD_TRIM_TARGET_NM", f32(trim.target),
         "steady torque the trim holds [N m]: the straightest static shape of a rod curved at rest (rod.rest_curvature)"),
        ("ROD_TRIM_START_RAD", f32(trim.start), "the trim at power-on [rad]: that shape's hub angle"),
        ("ROD_TRIM_GATE_RAD", f32(trim.gate), "trims only with every estimated angle within this of upright [rad]"),
        ("ROD_TRIM_MAX_RAD", f32(trim.limit), "how far the trim may walk from its start [rad]"),
        ("ROD_NY", str(3 if d.imu is not None else 1),
         "measurements the estimator reads: theta_1, then the tip IMU's gyro and accelerometer y"),
        ("ROD_IMU_GYRO_RANGE_RAD_S", f32(p["sensors"]["gyro_range"]), "the IMU's gyro full scale [rad/s]"),
        ("ROD_IMU_ACCEL_RANGE_M_S2", f32(p["sensors"]["accel_range"]), "its accelerometer's [m/s^2]"),
        ("ROD_IMU_TILT_COS", f32(math.cos(math.radians(p["sensors"]["imu_tilt_deg"]))),
         f"the part's mounting tilt, {p['sensors']['imu_tilt_deg']:g} deg, turned back [-]"),
        ("ROD_IMU_TILT_SIN", f32(math.sin(math.radians(p["sensors"]["imu_tilt_deg"]))), ""),
    ]
    width = max(len(n) for n, _, _ in macros) + 1
    lines = [
        "/* rod_gains.h -- DO NOT EDIT: generated by rodctl from the parameter file.",
        " *",
        f" * Regenerate: {command}",
        f" * Inputs SHA-256: {sha}",
        f" * Design: {d.method} (ZOH at {1 / d.dt:g} Hz), observer form: {d.observer_form} estimate",
        f" * Sampled closed-loop spectral radius: {d.checks['closed_loop_spectral_radius']:.6f}",
        " *",
        " * Loop (deviation z = x - upright, x = [theta_1..N, rates], theta = pi upright):",
        " *   z_pred = Ad z + Bd (u_prev + w);  e = y - z_pred[0];  z = z_pred + L e;",
        " *   w = ROD_W_DECAY w + ROD_L_DISTURBANCE e;  u = -K z - w - ROD_K_TORQUE_PREV (u_prev + w)   [N m]",
        " */",
        "#ifndef ROD_GAINS_H",
        "#define ROD_GAINS_H",
        "",
    ]
    for name, value, comment in macros:
        text = f"#define {name.ljust(width)}{value}"
        lines.append(text + (f"  /* {comment} */" if comment else ""))
    lines += [
        "",
        "/* Gain tables: initializers for `const float x[..] = ROD_.._INIT;` in one translation unit. */",
        f"#define ROD_AD_INIT {_matrix(d.Ad)}",
        f"#define ROD_BD_INIT {_vector(d.Bd)}",
        f"#define ROD_K_INIT {_vector(d.K)}",
        f"#define ROD_L_INIT {_vector(d.L)}",
        f"#define ROD_L_DISTURBANCE {f32(d.Lw)}  /* gain of the base-torque disturbance estimate w [N m/rad]; u = -K z - w */",
        f"#define ROD_W_DECAY {f32(d.w_decay)}  /* w_pred = this * w per period: a passing torque (1: a random walk) [-] */",
        f"#define ROD_K_TORQUE_PREV {f32(d.Ku)}  /* gain on the last period's net torque (lqr.r_torque_rate); "
        "u = -K z - w - this (u_prev + w) [-] */",
        *_imu_tables(d),
        "",
        "#endif /* ROD_GAINS_H */",
        "",
    ]
    return "\n".join(lines)
