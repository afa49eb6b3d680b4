"""Parameter files: load, override, validate, and derive the quantities the rest uses.

A parameter file is TOML with every key of `SCHEMA` present (the default file is
`default.toml` beside this module). Values are SI unless the key ends in `_deg` or `_hz`.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any, Callable

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]

from .errors import ParamError

DEFAULT_PARAMS = Path(__file__).with_name("default.toml")


@dataclass(frozen=True)
class Key:
    kind: type  # int, float, bool or str
    unit: str
    check: Callable[[Any], str | None] | None = None  # returns a problem or None
    default: Any = None  # not None: the key may be left out of a file (added after files were written)


# Every check carries `text`, the allowed values in words, for the generated parameter reference.
def _positive(v):
    return None if v > 0 else "must be > 0"


_positive.text = "> 0"


def _nonneg(v):
    return None if v >= 0 else "must be >= 0"


_nonneg.text = ">= 0"


def _between(lo, hi):
    def check(v):
        return None if lo <= v <= hi else f"must be between {lo:g} and {hi:g}"

    check.text = f"{lo:g} to {hi:g}"
    return check


def _above_upto(lo, hi):
    def check(v):
        return None if lo < v <= hi else f"must be in ({lo:g}, {hi:g}]"

    check.text = f"({lo:g}, {hi:g}]"
    return check


def _choice(*options):
    def check(v):
        return None if v in options else "must be one of " + ", ".join(repr(o) for o in options)

    check.text = "one of " + ", ".join(f'"{o}"' for o in options)
    return check


def allowed_text(key: "Key") -> str:
    """The values a key accepts, in words ("" for any value of its kind)."""
    if key.kind is bool:
        return "true or false"
    return getattr(key.check, "text", "") if key.check is not None else ""


PLANT_MODELS = ("der", "inextensible")
GEARBOX_MODELS = ("compliant", "rigid")
ENCODER_LOCATIONS = ("motor", "output")
PLANT_MAX_EDGES = 200  # the simulated plant's discretization; beyond this a run costs minutes per second
MAX_SAMPLES = 100_000  # Monte Carlo plants per score (uncertainty.samples, --samples): each is a run per task

SCHEMA: dict[str, dict[str, Key]] = {
    "rod": {
        "edges": Key(int, "-", _between(2, 64)),
        "length": Key(float, "m", _positive),
        "width": Key(float, "m", _positive),
        "thickness": Key(float, "m", _positive),
        "density": Key(float, "kg/m^3", _positive),
        "youngs_modulus": Key(float, "Pa", _positive),
        "damping": Key(float, "N m s/rad", _nonneg),
        "gravity": Key(float, "m/s^2", _nonneg),
        # a rod that is not straight at rest (simulated plant only): uniform curvature of the free length
        "rest_curvature": Key(float, "1/m", _between(-20.0, 20.0), default=0.0),
    },
    "motor": {
        "gear_ratio": Key(float, "-", _positive),
        "torque_constant": Key(float, "N m/A", _positive),
        "back_emf_constant": Key(float, "V s/rad", _nonneg),
        "gearbox_efficiency": Key(float, "-", _above_upto(0, 1)),
        "resistance": Key(float, "ohm", _positive),
        "rotor_inertia": Key(float, "kg m^2", _nonneg),
        "viscous_friction": Key(float, "N m s/rad", _nonneg),
        "coulomb_friction": Key(float, "N m", _nonneg),
        "design_includes_motor": Key(bool, "-"),
        # the winding's inductance (simulated plant only): the current lags the voltage by L / R
        "inductance": Key(float, "H", _between(0.0, 0.05), default=7.0e-4),
    },
    # Between the motor (and its encoder) and the rod (simulated plant only; docs/plant.md)
    "gearbox": {
        "model": Key(str, "-", _choice(*GEARBOX_MODELS), default="compliant"),
        "backlash_deg": Key(float, "deg", _between(0.0, 10.0), default=1.0),
        "stiffness": Key(float, "N m/rad", _between(1.0, 1.0e5), default=60.0),
        "damping": Key(float, "N m s/rad", _between(0.0, 1.0), default=0.002),
        "output_inertia": Key(float, "kg m^2", _between(0.0, 1.0e-3), default=5.0e-7),
        "output_friction_share": Key(float, "-", _between(0.0, 1.0), default=0.1),
    },
    "plant": {
        "model": Key(str, "-", _choice(*PLANT_MODELS)),
        "edges": Key(int, "-", _between(2, PLANT_MAX_EDGES)),
        "hub_length": Key(float, "m", _nonneg),
        # the control interrupt's jitter: the encoder read and the new duty come up to this late [us]
        "isr_jitter_us": Key(float, "us", _between(0.0, 500.0), default=0.0),
    },
    "driver": {
        "supply_voltage": Key(float, "V", _between(4.5, 36.0)),
        "current_limit": Key(float, "A", _positive),
        "max_duty": Key(float, "-", _above_upto(0, 1)),
        "pwm_frequency_hz": Key(float, "Hz", _between(20000, 100000)),
    },
    "encoder": {
        "counts_per_motor_rev": Key(int, "-", _between(1, 100000)),
        "rate_bandwidth_hz": Key(float, "Hz", _positive),
        # where the boot zero really is (simulated plant only): the encoder reads the angle plus this
        "zero_error_deg": Key(float, "deg", _between(-5.0, 5.0), default=0.18),
        # where the encoder is (simulated plant only): on the motor, before the gearbox, or on the output shaft
        "location": Key(str, "-", _choice(*ENCODER_LOCATIONS), default="motor"),
    },
    "loop": {
        "rate_hz": Key(float, "Hz", _between(100, 10000)),
    },
    # An optional 6-axis IMU on the rod near its tip (rodgains/imu.py): it sees the bend the motor's encoder
    # cannot. Defaults: TDK ICM-42686-P at +-4000 dps and +-16 g (the catch whips the tip to about 3,000 dps); its noise
    # figures are its sibling ICM-42688-P's datasheet values (docs/sensors.md).
    "sensors": {
        "tip_imu": Key(bool, "-", default=False),
        "imu_mass": Key(float, "kg", _between(0.0, 0.05), default=0.002),
        "imu_from_tip": Key(float, "m", _nonneg, default=0.005),
        "gyro_noise_density": Key(float, "rad/s/sqrt(Hz)", _positive, default=4.9e-5),
        "accel_noise_density": Key(float, "m/s^2/sqrt(Hz)", _positive, default=6.9e-4),
        "gyro_bias_instability": Key(float, "rad/s", _positive, default=2.4e-5),
        "gyro_range": Key(float, "rad/s", _positive, default=69.8),
        "accel_range": Key(float, "m/s^2", _positive, default=156.9),
        "rate_hz": Key(float, "Hz", _between(100, 32000), default=1000.0),
        "latency": Key(float, "s", _between(0.0, 0.01), default=0.001),
        "gyro_bias": Key(float, "rad/s", _between(-1.0, 1.0), default=0.0087),
        "imu_tilt_deg": Key(float, "deg", _between(-10.0, 10.0), default=0.0),
    },
    "design": {
        "method": Key(str, "-", _choice("sampled", "continuous", "robust")),
        # design.method = "robust" (rodgains/robust_design.py): the spectral radius every model of the
        # family must stay below, and the fraction of the torque the loop must stay stable at (saturation)
        "robust_radius": Key(float, "-", _between(0.9, 0.99999), default=0.9996),
        "robust_gain_margin": Key(float, "-", _between(0.05, 1.0), default=0.3),
        # ... and every mode of the nominal models decays at least this fast (0: only the slowest is pushed)
        "robust_nominal_decay": Key(float, "1/s", _between(0.0, 50.0), default=0.0),
        # ... and encoder quantization may drive at most this RMS torque in the nominal models (0: off)
        "robust_noise_torque": Key(float, "N m", _between(0.0, 1.0), default=0.0),
    },
    "lqr": {
        "q_angle": Key(float, "1/rad^2", _nonneg),
        "q_rate": Key(float, "s^2/rad^2", _nonneg),
        # added to q_angle on the shaft's own angle theta_1: a stiffer base (docs/design.md, "A stiffer shaft").
        # Left out, 0 (not default.toml's 325): a file written before it keeps the weights it was tuned with
        "q_shaft_angle": Key(float, "1/rad^2", _nonneg, default=0.0),
        "r_torque": Key(float, "1/(N m)^2", _positive),
        "r_torque_rate": Key(float, "s^2/(N m)^2", _nonneg, default=0.0),
        "imu_flank_torque": Key(float, "N m", _between(0.0, 0.01), default=0.001),
        # with sensors.tip_imu: the gearbox play between the encoder and the rod from which the rod is held leaning
        "imu_lean_from_play_deg": Key(float, "deg", _between(0.0, 10.0), default=0.3),
        "friction_compensation": Key(float, "N m", _nonneg),
    },
    "observer": {
        "process_noise_angle": Key(float, "rad^2/s", _nonneg),
        "process_noise_rate": Key(float, "rad^2/s^3", _nonneg),
        "measurement_noise": Key(float, "rad^2 s", _positive),
        "process_noise_torque": Key(float, "(N m)^2/s", _nonneg),
        # the estimated torque w passes with this time constant (0: a random walk that never does)
        "disturbance_time_constant": Key(float, "s", _between(0.0, 100.0), default=0.0),
        # with sensors.tip_imu: the encoder's offset from the rod's base (boot zero, gearbox flank) as a random walk
        "encoder_offset_walk": Key(float, "rad^2/s", _positive, default=7.6e-2),
        # with sensors.tip_imu: measurement_noise's role for the encoder (it then tracks the motor side's motion)
        "imu_measurement_noise": Key(float, "rad^2 s", _positive, default=4.45e-3),
        # with sensors.tip_imu: the IMU's noise the filter assumes, as a multiple of the part's (model error) [-]
        "imu_noise_scale": Key(float, "-", _between(0.1, 1000.0), default=1.0),
    },
    # the balance set-point trim (firmware/src/core/rod_trim.h): upright found from the holding torque
    "trim": {
        "time_constant": Key(float, "s", _between(0.0, 100.0), default=2.0),
        "band": Key(float, "N m", _between(0.0, 0.05), default=0.0005),
        "flank_hold": Key(float, "N m", _between(0.0, 0.05), default=0.003),
        "band_max": Key(float, "N m", _between(0.0, 0.05), default=0.0015),
        "hold_time_constant": Key(float, "s", _between(0.001, 10.0), default=0.2),
        "gate_deg": Key(float, "deg", _between(0.1, 30.0), default=3.0),
        "limit_deg": Key(float, "deg", _between(0.0, 30.0), default=5.0),
    },
    "swing_up": {
        "amplitude": Key(float, "N m", _nonneg),  # range: check_firmware_limits
        "angle_deg": Key(float, "deg", _above_upto(0, 180)),
        "catch_angle_deg": Key(float, "deg", _above_upto(0, 90)),
        "energy_target": Key(float, "-", _between(0.5, 2.0)),
        "rate_filter_hz": Key(float, "Hz", _positive),
        "stall_steps": Key(int, "-", _between(0, 20), default=5),
    },
    "safety": {
        "torque_limit": Key(float, "N m", _positive),
        "angle_limit_deg": Key(float, "deg", _above_upto(0, 180)),
        "speed_limit": Key(float, "rad/s", _positive),
        "heartbeat_timeout": Key(float, "s", _between(0.2, 10.0)),
    },
    # Monte Carlo draws of the simulated plant for `rodctl robustness` and `rodctl tune`
    # (host/rodctl/robust/uncertainty.py). The design never sees them. *_rel: uniform within
    # +- that fraction of the value; *_factor: log-uniform between value / factor and value x factor.
    "uncertainty": {
        "samples": Key(int, "-", _between(0, MAX_SAMPLES)),
        "seed": Key(int, "-", _between(0, 2**32 - 1)),
        "youngs_modulus_rel": Key(float, "-", _between(0.0, 0.9)),
        "density_rel": Key(float, "-", _between(0.0, 0.9)),
        "length_rel": Key(float, "-", _between(0.0, 0.5)),
        "rod_damping_factor": Key(float, "-", _between(1.0, 1000.0)),
        "viscous_friction_factor": Key(float, "-", _between(1.0, 1000.0)),
        "coulomb_friction_rel": Key(float, "-", _between(0.0, 1.0)),
        "rotor_inertia_rel": Key(float, "-", _between(0.0, 0.9)),
        "torque_constant_rel": Key(float, "-", _between(0.0, 0.9)),
        "supply_voltage_rel": Key(float, "-", _between(0.0, 0.5)),
        "delay_periods_max": Key(int, "periods", _between(0, 10)),
    },
}
# The previous default's soft shaft (docs/tuned/low-ripple.toml) as overrides of the stiff default: past
# ~1.05 x its critical length a rod holds only without the shaft weight (docs/scenarios.md, longest rod).
SOFT_SHAFT_WEIGHTS = ("lqr.q_angle=4.86", "lqr.q_shaft_angle=0.0")


def _cross_checks(p: dict) -> list[tuple[str, str]]:
    """Checks that involve more than one key: (key, problem)."""
    out = []
    if p["safety"]["angle_limit_deg"] <= p["swing_up"]["catch_angle_deg"]:
        out.append(("safety.angle_limit_deg", "must exceed swing_up.catch_angle_deg, or every catch trips the limit"))
    if p["observer"]["process_noise_angle"] == 0 and p["observer"]["process_noise_rate"] == 0:
        out.append(("observer.process_noise_angle", "and process_noise_rate cannot both be 0"))
    if p["lqr"]["q_angle"] == 0 and p["lqr"]["q_rate"] == 0:
        out.append(("lqr.q_angle", "and q_rate cannot both be 0"))
    ceiling = p["loop"]["rate_hz"] / (2.0 * math.pi)
    if p["encoder"]["rate_bandwidth_hz"] > ceiling:
        # the sampled tracking filter's double pole sits at 1 - 2 pi bandwidth / rate (rodgains.codegen
        # rate_filter_gains): negative past this, so the rate estimate rings, and outside the unit circle at rate / pi
        out.append(("encoder.rate_bandwidth_hz", f"must be at most loop.rate_hz / (2 pi) = {ceiling:.3g} [Hz], got "
                    f"{p['encoder']['rate_bandwidth_hz']!r}: past it the sampled rate filter rings"))
    if p["plant"]["hub_length"] >= p["rod"]["length"]:
        out.append(("plant.hub_length", f"must be < rod.length = {p['rod']['length']:g} [m], got {p['plant']['hub_length']!r}"))
    try:
        counts_fraction(p)
    except ValueError as e:
        out.append(("encoder.counts_per_motor_rev", str(e)))
    if p["lqr"]["r_torque_rate"] > 0 and (p["sensors"]["tip_imu"] or p["design"]["method"] != "sampled"
                                          or p["observer"]["process_noise_torque"] == 0):
        out.append(("lqr.r_torque_rate", "is built for the base-only \"sampled\" design with a disturbance estimate "
                    "(observer.process_noise_torque > 0, no sensors.tip_imu): set it to 0 or change those"))
    out += _imu_checks(p)
    out += check_firmware_limits(p)
    return out


def _imu_checks(p: dict) -> list[tuple[str, str]]:
    """The tip IMU must sit on the flexible rod, beyond the hub, and be read at least once a period."""
    s, r = p["sensors"], p["rod"]
    out = []
    free = r["length"] - p["plant"]["hub_length"]
    if s["imu_from_tip"] >= free:
        out.append(("sensors.imu_from_tip", f"must be < {free:g} m (the rod beyond the hub): the IMU is off the rod, "
                    f"got {s['imu_from_tip']!r}"))
    if s["tip_imu"]:
        if s["rate_hz"] < p["loop"]["rate_hz"]:
            out.append(("sensors.rate_hz", f"must be >= loop.rate_hz = {p['loop']['rate_hz']:g} Hz (a new sample every "
                        f"period), got {s['rate_hz']!r}"))
        if s["imu_from_tip"] >= r["length"] * (1.0 - 1.0 / r["edges"]):
            out.append(("sensors.imu_from_tip", f"places the IMU on edge 1 of the {r['edges']}-edge model, which turns "
                        "with the shaft and sees no bend: move it toward the tip or raise rod.edges"))
        if round(s["latency"] * p["loop"]["rate_hz"]) > 3:
            out.append(("sensors.latency", f"is more than 3 control periods; the estimator models at most 3, "
                        f"got {s['latency']!r}"))
    return out


def _set_range(code_name: str) -> tuple[float, float | None]:
    """(min, fixed max) of a SET parameter [device unit], from rodlink.toml's codes.param."""
    from rodctl.link.protocol_spec import load_spec  # the one definition the firmware is generated from

    c = load_spec().codes["param"].by_name(code_name)
    return c.min, c.max


def check_firmware_limits(p: dict) -> list[tuple[str, str]]:
    """What firmware/src/core/rod_config.h asserts at compile time, checked before a header is written.

    One entry per static_assert / #error there that the schema's own checks do not already
    imply (tests/test_params_firmware_limits.py pairs each with a violating override), so `rodctl gains` stops
    with one line instead of writing a header the firmware cannot compile.
    """
    out = []
    sw, sa = p["swing_up"], p["safety"]
    m, drv = p["motor"], p["driver"]
    kt_out = m["gearbox_efficiency"] * m["gear_ratio"] * m["torque_constant"]
    torque_max = min(kt_out * drv["current_limit"], sa["torque_limit"])  # = Params.torque_max = ROD_TORQUE_MAX_NM
    lo, _ = _set_range("SWING_AMPLITUDE")
    if not lo <= sw["amplitude"] <= torque_max:
        which = (f"driver.current_limit {drv['current_limit']:g} A x the motor's torque at the output, "
                 f"motor.gear_ratio {m['gear_ratio']:g} x torque_constant {m['torque_constant']:g} x gearbox_efficiency "
                 f"{m['gearbox_efficiency']:g}" if torque_max < sa["torque_limit"] else "safety.torque_limit")
        out.append(("swing_up.amplitude", f"must be in [{lo:g}, {torque_max:.4g}] N m, the firmware's torque "
                    f"ceiling (set by {which}), got {sw['amplitude']!r}"))
    # compared in radians, as the header holds them: f32 rounding keeps the order, so what passes
    # here passes the C++ static_asserts on the same f32 values
    lo, hi = _set_range("SWING_ANGLE")
    if not lo <= math.radians(sw["angle_deg"]) <= hi:
        out.append(("swing_up.angle_deg", f"must be in [{math.degrees(lo):g}, {math.degrees(hi):g}] deg, "
                    f"got {sw['angle_deg']!r}"))
    lo, hi = _set_range("CATCH_ANGLE")
    cmax = min(math.degrees(hi), sa["angle_limit_deg"])
    if not lo <= math.radians(sw["catch_angle_deg"]) <= min(hi, math.radians(sa["angle_limit_deg"])):
        out.append(("swing_up.catch_angle_deg", f"must be in [{math.degrees(lo):g}, {cmax:g}] deg "
                    f"(at most 90 and safety.angle_limit_deg), got {sw['catch_angle_deg']!r}"))
    lo, hi = _set_range("HEARTBEAT_TIMEOUT")
    if not lo <= sa["heartbeat_timeout"] <= hi:
        out.append(("safety.heartbeat_timeout", f"must be in [{lo:g}, {hi:g}] s, got {sa['heartbeat_timeout']!r}"))
    try:
        cpr = counts_fraction(p)
    except ValueError:
        return out  # reported above
    lo, _ = _set_range("COUNTS_PER_REV")
    if cpr < lo or cpr.numerator > 1_000_000 or cpr.denominator > 1000 or cpr.numerator * cpr.denominator > 10_000_000:
        out.append(("encoder.counts_per_motor_rev", f"times motor.gear_ratio = {cpr} counts per output turn: "
                    f"the firmware needs at least {lo:g} (as SET counts_per_rev) and a fraction NUM/DEN with "
                    "NUM <= 1e6, DEN <= 1000, NUM*DEN <= 1e7"))
    return out


# Physical values outside these are not a testbed's [the key's unit]: a slip of units, most often (mm typed
# as m, kPa as Pa). Refused with the nearest reading that would fit ("155 m: did you mean 0.155 m?").
# Wide on purpose: a research rig may be far from Table I, not a thousand times.
PLAUSIBLE: dict[str, tuple[float, float]] = {
    "rod.length": (0.02, 2.0),
    "rod.width": (0.001, 0.5),
    "rod.thickness": (0.0005, 0.1),
    "rod.density": (100.0, 20000.0),
    "rod.youngs_modulus": (1e3, 2e11),
    "rod.damping": (0.0, 1.0),
    "rod.gravity": (0.0, 30.0),
    "motor.gear_ratio": (1.0, 1000.0),
    "motor.torque_constant": (1e-4, 1.0),
    "motor.back_emf_constant": (0.0, 1.0),
    "motor.resistance": (0.01, 1000.0),
    "motor.rotor_inertia": (0.0, 1e-3),
    "motor.viscous_friction": (0.0, 1.0),
    "motor.coulomb_friction": (0.0, 1.0),
    "plant.hub_length": (0.0, 1.0),
    "driver.current_limit": (0.01, 50.0),
    "gearbox.output_inertia": (0.0, 1e-3),
    "safety.torque_limit": (1e-3, 10.0),
    "safety.speed_limit": (0.1, 1000.0),
    "swing_up.amplitude": (0.0, 10.0),
}
_UNIT_SLIPS = (1e-3, 1e3, 1e-2, 1e2, 1e-6, 1e6, 1e-1, 10.0)


# A value just outside the plausible range is offered a reading only when it lands this many decades nearer the
# range's middle: a unit slip is a factor of 100 or 1000 away, a value just outside the range is a rig of its own
# ("0.015 m: did you mean 1.5 m?" was no help).
SLIP_DECADES = 1.5


def _slip_guess(name: str, value: float, unitless: bool = False) -> float | None:
    """The value read in another unit that lands in the plausible range, if that is clearly the slip; unitless (a
    ratio): only a misplaced decimal point of a thousand (0.0204 for 20.4)."""
    lo, hi = PLAUSIBLE[name]
    if value <= 0:
        return None
    middle = math.sqrt(lo * hi) if lo > 0 else hi / 100.0

    def off(v: float) -> float:  # decades from the middle
        return abs(math.log10(v / middle))

    # Far outside the range (half a decade past its edge) the value is a slip: the commonest reading that fits, mm or
    # kPa first (0.6 for a 0.6 mm strip is 0.0006 m, not 0.006). Just outside it, only a reading that lands
    # SLIP_DECADES nearer the middle (593 Pa for 593 kPa; not 1.5 m for 0.015 m).
    far = (math.log10(lo / value) if value < lo else math.log10(value / hi)) >= 0.5
    return next((value * f for f in ((1e-3, 1e3) if unitless else _UNIT_SLIPS)
                 if lo <= value * f <= hi and (far or off(value) - off(value * f) >= SLIP_DECADES)), None)


def _implausible(name: str, unit: str, value: float) -> str | None:
    lo, hi = PLAUSIBLE[name]
    if lo <= value <= hi:
        return None
    u = "" if unit == "-" else f" {unit}"
    guess = _slip_guess(name, value, unitless=unit == "-")
    hint = f": did you mean {guess:g}{u}?" if guess is not None else ""
    return f"{value:g}{u} is not a testbed's (plausible: {lo:g} to {hi:g}{u}){hint}"


def _toml(value: Any) -> str:
    """A value as the parameter file spells it (true, not Python's True; a date as 1979-05-27)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if hasattr(value, "isoformat"):  # TOML's dates and times
        return value.isoformat()
    return repr(value)


def _coerce(name: str, key: Key, value: Any, plausible: bool = True) -> Any:
    kind = key.kind
    if kind is bool:
        if not isinstance(value, bool):
            raise ParamError(f"{name}: expected true or false, got {value!r}")
    elif kind is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ParamError(f"{name}: expected an integer [{key.unit}], got {_toml(value)}")
    elif kind is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ParamError(f"{name}: expected a number [{key.unit}], got {_toml(value)}")
        value = float(value)
        if not math.isfinite(value):
            raise ParamError(f"{name}: must be finite, got {value!r}")
    elif kind is str:
        if not isinstance(value, str):
            raise ParamError(f"{name}: expected a string, got {_toml(value)}")
    if key.check is not None:
        problem = key.check(value)
        if problem:
            raise ParamError(f"{name}: {problem} [{key.unit}], got {value!r}")
    if plausible and name in PLAUSIBLE:
        problem = _implausible(name, key.unit, value)
        if problem:
            raise ParamError(f"{name} = {problem}")
    return value


def _parse_override(text: str) -> tuple[str, str, Any]:
    if "=" not in text:
        raise ParamError(f"--set {text!r}: expected section.key=value")
    name, raw = text.split("=", 1)
    name = name.strip()
    if name.count(".") != 1:
        raise ParamError(f"--set {text!r}: expected section.key=value")
    section, key = name.split(".")
    try:
        value = tomllib.loads(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()  # bare words are strings: design.method=continuous
        if value.lower().lstrip("+-") in ("nan", "inf", "infinity"):  # TOML spells them lower case only
            value = float(value)
    return section, key, value


def load_params(path: str | Path | None = None, overrides: list[str] | tuple[str, ...] = ()) -> "Params":
    """Read a parameter file (default: Table I), apply `section.key=value` overrides, validate."""
    path = Path(path) if path is not None else DEFAULT_PARAMS
    try:
        text = path.read_text(encoding="utf-8-sig")  # a byte-order mark (some Windows editors) is no statement
    except OSError as e:
        raise ParamError(f"{path}: cannot read parameter file ({e.strerror or e})") from None
    except UnicodeDecodeError:
        raise ParamError(f"{path}: not a parameter file (not UTF-8 text; expected TOML)") from None
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ParamError(f"{path}: not valid TOML ({e})") from None
    given = set()
    for o in overrides:
        section, key, value = _parse_override(o)
        if section not in SCHEMA or key not in SCHEMA[section]:
            raise ParamError(f"--set {section}.{key}: unknown key{_override_hint(section, key)}")
        raw.setdefault(section, {})[key] = value
        given.add(f"{section}.{key}")
    try:
        return Params(validate(raw, source=str(path)), source=str(path))
    except ParamError as e:  # a bad value the file holds is named with the file, as a bad key is
        if given and e.key not in given and _valid(tomllib.loads(text), path):  # the file is fine: a --set made it
            raise ParamError(f"{e} (with {' '.join('--set ' + o for o in overrides)})", key=e.key) from None
        if path != DEFAULT_PARAMS and e.key is not None and e.key not in given:
            raise ParamError(f"{path}: {e}", key=e.key) from None
        raise


def _valid(raw: dict, path: Path) -> bool:
    """Whether a parameter file's own values pass validate."""
    try:
        validate(raw, source=str(path))
    except ParamError:
        return False
    return True


def _did_you_mean(section: str, key: str) -> str:
    """A misspelled key, or one put in the wrong table, named as the schema spells it."""
    import difflib

    close = difflib.get_close_matches(key.lower(), list(SCHEMA[section]), n=1, cutoff=0.75)  # LENGTH: length
    if close:
        return f" (did you mean {section}.{close[0]}?)"
    elsewhere = [s for s, keys in SCHEMA.items() if key.lower() in keys]
    return f" (it belongs in [{elsewhere[0]}])" if elsewhere else ""


def _override_hint(section: str, key: str) -> str:
    """_did_you_mean for a --set, whose table may be misspelled too."""
    import difflib

    if section in SCHEMA:
        return _did_you_mean(section, key)
    close = difflib.get_close_matches(section.lower(), list(SCHEMA), n=1, cutoff=0.75)
    if close and key.lower() in SCHEMA[close[0]]:
        return f" (did you mean {close[0]}.{key.lower()}?)"
    elsewhere = [s for s, keys in SCHEMA.items() if key.lower() in keys]
    return f" (did you mean {elsewhere[0]}.{key.lower()}?)" if elsewhere else ""


def validate(raw: dict, source: str = "parameters", plausible: bool = True) -> dict:
    """The resolved parameters of a raw table; ParamError naming the key. plausible=False skips the guard against
    unit slips (PLAUSIBLE), for values derived from a checked file rather than typed (the matrix's scaled cases)."""
    for section, table in raw.items():
        if section not in SCHEMA:
            raise ParamError(f"{source}: unknown section [{section}]")
        if not isinstance(table, dict):
            raise ParamError(f"{source}: {section} must be a table")
        for key in table:
            if key not in SCHEMA[section]:
                raise ParamError(f"{source}: {section}.{key}: unknown key{_did_you_mean(section, key)}")
    if not raw:
        raise ParamError(f"{source}: no parameters in it (`rodctl params --out FILE` writes a complete file to edit)")
    out: dict[str, dict[str, Any]] = {}
    for section, keys in SCHEMA.items():
        out[section] = {}
        for key, spec in keys.items():
            name = f"{section}.{key}"
            if key not in raw.get(section, {}):
                if spec.default is None:
                    raise ParamError(f"{source}: {name}: missing key [{spec.unit}]")
                out[section][key] = spec.default
                continue
            try:
                out[section][key] = _coerce(name, spec, raw[section][key], plausible)
            except ParamError as e:
                raise ParamError(str(e), key=name) from None
    for name, problem in _cross_checks(out):
        raise ParamError(f"{name}: {problem}", key=name)
    return out


def counts_fraction(p: dict) -> Fraction:
    """Encoder counts per output revolution as an exact fraction (979.2 = 4896/5).

    The firmware wraps angles with integer arithmetic on the numerator and denominator,
    so upright (half a turn, 489.6 counts) is represented without rounding.
    """
    cpr = Fraction(p["encoder"]["counts_per_motor_rev"]) * Fraction(str(p["motor"]["gear_ratio"])).limit_denominator(1000)
    if abs(float(cpr) - p["encoder"]["counts_per_motor_rev"] * p["motor"]["gear_ratio"]) > 1e-9 * float(cpr):
        raise ValueError("times motor.gear_ratio must be a fraction with denominator <= 1000")
    if cpr.numerator > 2**20:
        raise ValueError("times motor.gear_ratio is too many counts per revolution (> 2^20)")
    return cpr


@dataclass(frozen=True)
class Params:
    """Validated parameters with derived quantities. `values[section][key]` holds the file's values."""

    values: dict
    source: str = "parameters"

    def __getitem__(self, section: str) -> dict:
        return self.values[section]

    # --- derived rod quantities -------------------------------------------------
    @property
    def N(self) -> int:
        return self.values["rod"]["edges"]

    @property
    def dt(self) -> float:
        """Control period [s]."""
        return 1.0 / self.values["loop"]["rate_hz"]

    @property
    def edge_length(self) -> float:
        """l = L_tot / N [m]."""
        return self.values["rod"]["length"] / self.N

    @property
    def edge_mass(self) -> float:
        """m = rho w h l [kg]."""
        r = self.values["rod"]
        return r["density"] * r["width"] * r["thickness"] * self.edge_length

    @property
    def EI(self) -> float:
        """Bending stiffness E w h^3 / 12 [N m^2]."""
        r = self.values["rod"]
        return r["youngs_modulus"] * r["width"] * r["thickness"] ** 3 / 12.0

    @property
    def EA(self) -> float:
        """Axial stiffness E w h [N]."""
        r = self.values["rod"]
        return r["youngs_modulus"] * r["width"] * r["thickness"]

    # --- motor and driver at the output shaft ---------------------------------------
    @property
    def rotor_inertia_out(self) -> float:
        """Reflected rotor inertia J_rotor G^2 at the output shaft [kg m^2]: the gearbox's motor side."""
        m = self.values["motor"]
        return m["rotor_inertia"] * m["gear_ratio"] ** 2

    @property
    def base_inertia(self) -> float:
        """Everything that turns with the shaft when the gearbox is taken as rigid [kg m^2]: the reflected
        rotor J_rotor G^2 and the gearbox's output side (output shaft, last gear, hub)."""
        return self.rotor_inertia_out + self.values["gearbox"]["output_inertia"]

    @property
    def base_friction(self) -> float:
        """Viscous friction at the output shaft [N m s/rad]."""
        return self.values["motor"]["viscous_friction"]

    @property
    def design_base_inertia(self) -> float:
        return self.base_inertia if self.values["motor"]["design_includes_motor"] else 0.0

    @property
    def design_base_friction(self) -> float:
        return self.base_friction if self.values["motor"]["design_includes_motor"] else 0.0

    @property
    def kt_out(self) -> float:
        """Output torque per ampere, eta G k_t [N m/A]."""
        m = self.values["motor"]
        return m["gearbox_efficiency"] * m["gear_ratio"] * m["torque_constant"]

    @property
    def ke_out(self) -> float:
        """Back-EMF per output rad/s, G k_e [V s/rad]."""
        m = self.values["motor"]
        return m["gear_ratio"] * m["back_emf_constant"]

    @property
    def torque_max(self) -> float:
        """Usable torque: the smaller of the driver's current limit and the safety limit [N m]."""
        return min(self.kt_out * self.values["driver"]["current_limit"], self.values["safety"]["torque_limit"])

    @property
    def counts_per_rev(self) -> Fraction:
        return counts_fraction(self.values)

    @property
    def rad_per_count(self) -> float:
        """One encoder count at the output shaft [rad] (2 pi / 979.2 for the default)."""
        return 2.0 * math.pi / float(self.counts_per_rev)

    @property
    def encoder_play_deg(self) -> float:
        """The gearbox's play between the encoder and the rod [deg]: gearbox.backlash_deg with a compliant
        gearbox and the encoder on the motor; 0 with a rigid one or the encoder on the output shaft."""
        g = self.values["gearbox"]
        on_motor = self.values["encoder"]["location"] == "motor"
        return float(g["backlash_deg"]) if g["model"] == "compliant" and on_motor else 0.0

    # --- identity ---------------------------------------------------------------------
    def canonical_json(self) -> str:
        return json.dumps(self.values, sort_keys=True, separators=(",", ":"))

    def sha256(self) -> str:
        """Hash of the resolved values: identical physics and weights give identical hashes."""
        return hashlib.sha256(self.canonical_json().encode()).hexdigest()

    def with_overrides(self, *overrides: str, plausible: bool = True) -> "Params":
        """These parameters with "section.key=value" overrides; plausible=False: see validate."""
        raw = json.loads(self.canonical_json())
        for o in overrides:
            section, key, value = _parse_override(o)
            if section not in SCHEMA or key not in SCHEMA[section]:
                raise ParamError(f"--set {section}.{key}: unknown key{_override_hint(section, key)}")
            raw[section][key] = value
        return Params(validate(raw, source=self.source, plausible=plausible), source=self.source)

    def with_counts_per_rev(self, counts: float) -> "Params":
        """These parameters on a rig whose encoder gives `counts` per output turn (a board's run-time
        counts_per_rev setting): encoder.counts_per_motor_rev = counts / motor.gear_ratio."""
        if abs(counts - float(self.counts_per_rev)) <= 1e-4:
            return self
        gear = float(self["motor"]["gear_ratio"])
        per_motor_turn = round(counts / gear)
        if per_motor_turn < 1 or abs(per_motor_turn * gear - counts) > 1e-4:
            raise ParamError(f"{counts:g} counts per output turn is not a whole number of counts per motor turn at "
                             f"motor.gear_ratio {gear:g}: another gear ratio is another design (set it in the "
                             "parameter file and flash)")
        return self.with_overrides(f"encoder.counts_per_motor_rev={per_motor_turn}")

    def to_toml(self) -> str:
        """The resolved values as a complete parameter file, keeping the default file's comments; a value that
        differs from the default file's says so first, since its comment's sources and notes are the default's."""
        out, section = [], None
        default = load_params()
        for line in DEFAULT_PARAMS.read_text().splitlines():
            head = line.split("#", 1)[0].strip()
            if head.startswith("[") and head.endswith("]"):
                section = head[1:-1].strip()
            elif "=" in head and section in SCHEMA:
                key = head.split("=", 1)[0].strip()
                if key in SCHEMA[section]:
                    value = _toml_value(self.values[section][key])
                    comment = line[line.index("#"):] if "#" in line else ""
                    was = default.values[section][key]
                    if self.values[section][key] != was:
                        comment = f"# {changed_note(was)}" + comment.lstrip("# ")
                    line = f"{key} = {value}".ljust(max(28, len(key) + len(value) + 4)) + comment
            out.append(line)
        return "\n".join(out) + "\n"


def changed_note(default_value: Any) -> str:
    """What Params.to_toml puts first in the comment of a value that differs from the default file's."""
    return f"CHANGED (default {_toml_value(default_value)}; the sources and notes here are the default's): "


CHANGED_NOTE = re.compile(r"CHANGED \(default .*?; the sources and notes here are the default's\): ")


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    return repr(v)
