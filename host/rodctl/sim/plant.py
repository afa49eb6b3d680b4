"""The simulated plant (C library host/rodctl/sim/native/rod_plant.c) and the C closed-loop runner.

    from rodgains.params import load_params
    from rodctl.sim.plant import Plant, run_closed_loop
    plant = Plant(load_params(), kind="inextensible", edges=5, input_mode="torque")
    log = run_closed_loop(plant, "build/native/librod_sil-....so", periods=5000, arm_mode=2)

Plants: "inextensible" (gains/rodgains/rod_model.py in C) or "der" (gains/rodgains/der_model.py in C), each with
the motor's reflected inertia J and friction b on the shaft. By default they are the physical
rod: J and b are the motor's (Params.base_inertia / base_friction) whatever the design assumed.
Input modes: "torque" (shaft torque [N m]) or "duty" (signed duty; MAX14870 + DC motor model,
current clamped to the driver limit, electrical time constant neglected).

Integrators and the automatic step (choose_integrator; `method=` / `step=` override)
--------------------------------------------------------------------------------------
The wrapper linearizes the C model hanging and upright and reads the spectrum:
omega_osc = largest |lambda| with damping ratio < 0.95 (the modes the step must resolve),
rho = largest |lambda| overall (the stiff, overdamped modes: d acting on tiny edges).
- inextensible, stiff (Table I, N = 20: rho = 5.2e4, omega_osc = 572 rad/s): ROS2, an order-2
  L-stable W-method with the damping and bending springs implicit, h = 0.1 / omega_osc
  (0.175 ms, 6 steps per 1 ms period); max angle error 5e-4 rad on a violent 2 s swing.
- inextensible, mildly stiff (N = 5: rho = 537, omega_osc = 171 rad/s): RK4,
  h = min(2 / rho, 0.5 / omega_osc, 1 ms) = 1 ms, one step per period, error 4e-7 rad.
  "auto" takes RK4 whenever it needs no more steps per period than ROS2.
- DER: velocity Verlet with implicit damping; its undamped elastic frequencies (axial modes,
  1500 rad/s at N = 5, 6000 rad/s at N = 20) need h omega < 2: h = 1 / omega_max (0.674 and
  0.166 ms); error 8e-5 and 3e-5 rad.
Every step is capped at 1 ms. `python -m rodctl.sim.accuracy` prints the accuracy table,
`python -m rodctl.sim.plant SIL.so` the speed table.
"""

from __future__ import annotations

import ctypes
import math
import statistics
import time
from dataclasses import dataclass, replace
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from rodgains.errors import InputError, UserError
from rodgains.der_model import DERModel
from rodgains.params import Params, load_params
from rodgains.rod_model import DAMPING_REFERENCE_EDGES, RodModel

from rodctl.build.native import compile_shared
from rodctl.sim.imu import NO_IMU_FIELDS, ImuConfig

NATIVE = Path(__file__).resolve().parent / "native"
SOURCES = [NATIVE / "rod_plant.c"]
FLAGS = ("-O2", "-Wall", "-Wextra")

KINDS = {"inextensible": 0, "der": 1}
INPUTS = {"torque": 0, "duty": 1}
METHODS = {"ros2": 0, "rk4": 1, "verlet": 2}
SIL_ABI_VERSION = 1
MODE_NAMES = {0: "DISARMED", 1: "BALANCE", 2: "SWING_UP", 3: "FAULT", 4: "CATCH", 5: "IDENTIFY"}

ROS2_ACCURACY = 0.1  # ROS2: h * omega_osc
ROS2_GEAR_ACCURACY = 1.0  # ROS2: h * the gear train's own frequency (plant.choose_integrator)
RK4_ACCURACY = 0.5  # RK4: h * omega_osc
RK4_STABILITY = 2.0  # RK4: h * max|lambda| (its region reaches 2.78 on the real and 2.83 on the imaginary axis)
VERLET_MARGIN = 1.0  # DER: h * omega_max (the stability bound is 2)
MAX_AUTO_STEP = 1e-3  # [s]
OSCILLATORY_ZETA = 0.95

_D = ctypes.c_double
_P = ctypes.POINTER


class _Config(ctypes.Structure):
    _fields_ = [
        ("kind", ctypes.c_int32),
        ("edges", ctypes.c_int32),
        ("input_mode", ctypes.c_int32),
        ("method", ctypes.c_int32),
        ("l", _D),
        ("m", _D),
        ("EI", _D),
        ("EA", _D),
        ("d", _D),
        ("g", _D),
        ("J", _D),
        ("b", _D),
        ("kt_out", _D),
        ("ke_out", _D),
        ("resistance", _D),
        ("supply_voltage", _D),
        ("current_limit", _D),
        ("counts_per_rev", _D),
        ("encoder_phase", _D),
        ("max_step", _D),
        ("hub_length", _D),
        ("hub_mass", _D),
        ("hub_stiffness", _D),
        ("hub_damping", _D),
        ("coulomb", _D),
        ("coulomb_rate", _D),
        ("gear_stiffness", _D),
        ("gear_damping", _D),
        ("backlash", _D),
        ("output_inertia", _D),
        ("output_viscous", _D),
        ("inductance", _D),
        ("zero_error", _D),
        ("rest_curvature", _D),
        ("encoder_on_shaft", ctypes.c_int32),
        ("imu_on", ctypes.c_int32),
        ("imu_mass", _D),
        ("imu_position", _D),
        ("imu_gyro_sigma", _D),
        ("imu_accel_sigma", _D),
        ("imu_gyro_bias", _D),
        ("imu_bias_step", _D),
        ("imu_gyro_lsb", _D),
        ("imu_accel_lsb", _D),
        ("imu_delay", ctypes.c_int32),
        ("imu_seed", ctypes.c_uint32),
        ("imu_fault_time", _D),
        ("imu_fault", ctypes.c_int32),
        ("reserved", ctypes.c_int32),
        ("imu_tilt", _D),
    ]


class _SilApi(ctypes.Structure):
    _fields_ = [("reset", ctypes.c_void_p), ("arm", ctypes.c_void_p), ("step", ctypes.c_void_p),
                ("status", ctypes.c_void_p), ("duty", ctypes.c_void_p), ("imu", ctypes.c_void_p)]


class _RunOptions(ctypes.Structure):
    _fields_ = [
        ("periods", ctypes.c_int64),
        ("period", _D),
        ("est_len", ctypes.c_int32),
        ("reset", ctypes.c_int32),
        ("arm_mode", ctypes.c_int32),
        ("delay_periods", ctypes.c_int32),
        ("stop_on_mode", ctypes.c_int32),
        ("jitter_seed", ctypes.c_uint32),
        ("jitter", _D),
    ]


class _RunLog(ctypes.Structure):
    _fields_ = [
        ("time", _P(_D)),
        ("theta", _P(_D)),
        ("dtheta", _P(_D)),
        ("est", _P(ctypes.c_float)),
        ("torque_cmd", _P(ctypes.c_float)),
        ("duty", _P(ctypes.c_float)),
        ("torque", _P(_D)),
        ("current", _P(_D)),
        ("mode", _P(ctypes.c_int32)),
        ("count", _P(ctypes.c_int32)),
        ("motor", _P(_D)),
        ("imu", _P(ctypes.c_float)),
    ]


class _RunResult(ctypes.Structure):
    _fields_ = [("periods_run", ctypes.c_int64), ("nonfinite_commands", ctypes.c_int64),
                ("stopped_on_mode", ctypes.c_int32), ("error", ctypes.c_int32)]


ERRORS = {-1: "invalid configuration", -2: "the state left the model (non-finite, or a singular matrix)",
          -3: "bad argument", -4: "controller ABI mismatch or missing function"}


@lru_cache(maxsize=None)
def library_path() -> Path:
    return compile_shared("rod_plant", SOURCES, [NATIVE], FLAGS)


@lru_cache(maxsize=None)
def library() -> ctypes.CDLL:
    """Build (cached by content) and load the plant library."""
    lib = ctypes.CDLL(str(library_path()))
    vp, dp, i32 = ctypes.c_void_p, _P(_D), ctypes.c_int32
    sig = {
        "rod_plant_api_version": (ctypes.c_int, []),
        "rod_plant_new": (vp, [_P(_Config)]),
        "rod_plant_free": (None, [vp]),
        "rod_plant_size": (ctypes.c_int, [vp]),
        "rod_plant_edges": (ctypes.c_int, [vp]),
        "rod_plant_set_max_step": (ctypes.c_int, [vp, _D]),
        "rod_plant_set_method": (ctypes.c_int, [vp, ctypes.c_int]),
        "rod_plant_method": (ctypes.c_int, [vp]),
        "rod_plant_max_step": (_D, [vp]),
        "rod_plant_set_encoder_phase": (ctypes.c_int, [vp, _D]),
        "rod_plant_time": (_D, [vp]),
        "rod_plant_set_time": (None, [vp, _D]),
        "rod_plant_set_state": (ctypes.c_int, [vp, dp, dp]),
        "rod_plant_get_state": (None, [vp, dp, dp]),
        "rod_plant_set_raw_state": (ctypes.c_int, [vp, dp, dp]),
        "rod_plant_get_raw_state": (None, [vp, dp, dp]),
        "rod_plant_nodes": (None, [vp, dp]),
        "rod_plant_energy": (_D, [vp]),
        "rod_plant_motor_torque": (_D, [vp, _D, _D, dp]),
        "rod_plant_deriv": (ctypes.c_int, [vp, dp, _D, dp]),
        "rod_plant_force": (ctypes.c_int, [vp, dp, _D, dp]),
        "rod_plant_mass": (ctypes.c_int, [vp, dp, dp]),
        "rod_plant_advance": (ctypes.c_int, [vp, _D, _D]),
        "rod_plant_last_torque": (_D, [vp]),
        "rod_plant_last_current": (_D, [vp]),
        "rod_plant_encoder": (i32, [vp]),
        "rod_plant_set_external_torque": (None, [vp, _D]),
        "rod_plant_encoder_count": (i32, [vp, _D]),
        "rod_plant_motor_state": (None, [vp, dp, dp, dp]),
        "rod_plant_set_motor_state": (ctypes.c_int, [vp, _D, _D, _D]),
        "rod_plant_gear_torque": (_D, [vp]),
        "rod_plant_imu_read": (ctypes.c_int, [vp, _D, _P(ctypes.c_float)]),
        "rod_run_closed_loop": (ctypes.c_int64, [vp, _P(_SilApi), _P(_RunOptions), _P(_RunLog), _P(_RunResult)]),
    }
    for name, (res, args) in sig.items():
        f = getattr(lib, name)
        f.restype = res
        f.argtypes = args
    if lib.rod_plant_api_version() != 4:
        raise UserError("rod_plant library API version mismatch")
    return lib


class SimulationError(RuntimeError):
    """The plant failed during a closed-loop run; `log` holds the periods up to the failure."""

    def __init__(self, message: str, log: dict[str, Any]):
        super().__init__(message)
        self.log = log


def _ptr(a: np.ndarray | None, ctype):
    return None if a is None else a.ctypes.data_as(_P(ctype))


def _check(code: int, what: str) -> None:
    if code < 0:
        raise RuntimeError(f"{what}: {ERRORS.get(code, f'error {code}')}")


@dataclass(frozen=True)
class PlantConfig:
    """Everything the C plant is built from (SI units)."""

    kind: str
    edges: int
    input_mode: str
    l: float
    m: float
    EI: float
    EA: float
    d: float
    g: float
    J: float
    b: float
    kt_out: float
    ke_out: float
    resistance: float
    supply_voltage: float
    current_limit: float
    counts_per_rev: float
    encoder_phase: float
    hub_length: float  # edge 1, clamped in the hub [m]
    hub_mass: float  # [kg]
    hub_stiffness: float  # joint between edge 1 and 2 [N m/rad]
    hub_damping: float  # [N m s/rad]
    coulomb: float = 0.0  # Coulomb friction at the shaft (rigid) or the motor side (compliant gearbox) [N m]
    coulomb_rate: float = 0.01  # its tanh smoothing rate [rad/s]: below 80 % of breakaway the shaft creeps < 0.011 rad/s
    gear_stiffness: float = 0.0  # gear train at the output [N m/rad]; 0: rigid (J, b, coulomb act on theta_1)
    gear_damping: float = 0.0  # [N m s/rad] while the teeth touch
    backlash: float = 0.0  # total gap at the output [rad]
    output_inertia: float = 0.0  # rod side of the gearbox [kg m^2]
    output_viscous: float = 0.0  # rod side's viscous friction [N m s/rad] (b is the motor side's when compliant)
    inductance: float = 0.0  # winding inductance [H] (duty mode)
    zero_error: float = 0.0  # the encoder reads the angle plus this [rad]
    rest_curvature: float = 0.0  # the rod's curvature at rest [1/m]
    encoder_on_shaft: bool = False  # the encoder reads theta_1 (an output-shaft encoder), not the motor side
    imu: ImuConfig | None = None  # a tip IMU on the rod (its mass, its readings to the controller)

    @property
    def back_emf_damping(self) -> float:
        """kt ke / R [N m s/rad]: the damping the driver's voltage drive adds in duty mode."""
        return self.kt_out * self.ke_out / self.resistance

    def to_c(self, max_step: float, method: str) -> _Config:
        return _Config(KINDS[self.kind], self.edges, INPUTS[self.input_mode], METHODS[method], self.l, self.m,
                       self.EI, self.EA, self.d, self.g, self.J, self.b, self.kt_out, self.ke_out, self.resistance,
                       self.supply_voltage, self.current_limit, self.counts_per_rev, self.encoder_phase, max_step,
                       self.hub_length, self.hub_mass, self.hub_stiffness, self.hub_damping, self.coulomb,
                       self.coulomb_rate, self.gear_stiffness, self.gear_damping, self.backlash, self.output_inertia,
                       self.output_viscous, self.inductance, self.zero_error, self.rest_curvature,
                       int(self.encoder_on_shaft), *(self.imu.c_fields() if self.imu else NO_IMU_FIELDS))

    @property
    def compliant(self) -> bool:
        """A gearbox with a motor side of its own (the encoder reads it), else the rigid shaft."""
        return self.gear_stiffness > 0.0


@dataclass(frozen=True)
class GearTrain:
    """The gearbox between the motor (and its encoder) and the rod, at the output (SI units).

    stiffness 0 is the rigid gearbox: everything turns with theta_1 and the encoder reads it."""

    stiffness: float  # [N m/rad]
    damping: float = 0.0  # [N m s/rad] while the teeth touch
    backlash: float = 0.0  # total gap [rad]
    output_inertia: float = 0.0  # rod side: output shaft, last gear, hub [kg m^2]
    output_friction_share: float = 0.0  # part of the viscous friction on the rod side [-]

    @classmethod
    def from_params(cls, p: Params) -> "GearTrain":
        g = p["gearbox"]
        rigid = g["model"] == "rigid"
        return cls(stiffness=0.0 if rigid else g["stiffness"], damping=0.0 if rigid else g["damping"],
                   backlash=0.0 if rigid else math.radians(g["backlash_deg"]), output_inertia=g["output_inertia"],
                   output_friction_share=g["output_friction_share"])


class Plant:
    """One simulated rod + motor + driver + encoder (a C object; not thread-safe).

    params: Params (default: the default parameter file). kind: "inextensible" | "der".
    edges: the plant's N (may differ from the controller's; default params N).
    input_mode: "torque" | "duty". phase: encoder phase in [0, 1).
    J, b: base inertia / friction overrides [kg m^2, N m s/rad] (default: the physical motor,
    Params.base_inertia / base_friction, whether or not the design included it).
    d, g: damping / gravity overrides (tests: d = 0 for energy, g = 0 for the free-running motor).
    method: "auto" (default), or "ros2" / "rk4" (inextensible), "verlet" (DER).
    step: integrator step bound [s]; None picks it from the model (see module doc).
    period: the control period the automatic choice is costed for (default Params.dt).
    hub_length: None (default) is the paper's model: edge 1 of N equal edges is the clamped one. A
    length [m] makes the faithful rod (faithful_plant): a rigid hub edge of that length (independent of
    N), then `edges` flexible edges over the rest; N (the coordinates) is then edges + 1. Its joints
    carry the continuum's bending stiffness and damping per Voronoi length (see hub_joint).
    coulomb: Coulomb friction at the shaft [N m] (default 0: the paper's model has none).
    gear: the gearbox (GearTrain; None: the rigid shaft carrying J and b). A compliant one gives the motor
    side a coordinate of its own (the last raw coordinate), which the encoder reads; J is then the
    reflected rotor alone (Params.rotor_inertia_out) and the Coulomb friction acts there.
    inductance [H] (duty mode), zero_error [rad] (the encoder reads the angle plus it), rest_curvature
    [1/m] (the rod's at rest), jitter [s] (run_closed_loop's default control-interrupt jitter),
    encoder_on_shaft (the encoder reads theta_1, an output-shaft encoder, instead of the motor side).
    """

    def __init__(self, params: Params | None = None, *, kind: str = "inextensible", edges: int | None = None,
                 input_mode: str = "torque", phase: float = 0.5, J: float | None = None, b: float | None = None,
                 d: float | None = None, g: float | None = None, method: str = "auto", step: float | None = None,
                 period: float | None = None, hub_length: float | None = None, coulomb: float = 0.0,
                 gear: GearTrain | None = None, inductance: float = 0.0, zero_error: float = 0.0,
                 rest_curvature: float = 0.0, jitter: float = 0.0, encoder_on_shaft: bool = False,
                 imu: ImuConfig | None = None):
        if kind not in KINDS:
            raise ValueError(f"kind must be one of {sorted(KINDS)}, got {kind!r}")
        if input_mode not in INPUTS:
            raise ValueError(f"input_mode must be one of {sorted(INPUTS)}, got {input_mode!r}")
        p = params if params is not None else load_params()
        N = int(edges or p.N)
        if N < 2:
            raise ValueError("edges must be >= 2")
        if not 0.0 <= phase < 1.0:
            raise ValueError("phase must be in [0, 1)")
        rod = RodModel.from_params(p, design=False, edges=N)  # the physical rod and motor, whatever the design
        self.params = p
        self.hub = hub_length
        if coulomb < 0:
            raise ValueError("coulomb must be >= 0")
        if hub_length is None:  # the paper's model
            geo = dict(l=rod.l, m=rod.m, d=rod.d if d is None else float(d), hub_length=rod.l, hub_mass=rod.m,
                       hub_stiffness=rod.EI / rod.l, hub_damping=rod.d if d is None else float(d))
        else:
            L = p["rod"]["length"]
            if not 0 <= hub_length < L:
                raise ValueError(f"hub_length must be in [0, {L:g}) m")
            geo = hub_geometry(p, N, float(hub_length), d)
            N += 1
        if gear is None:  # the rigid shaft: the whole motor on theta_1
            gear_kw = {}
            J_plant = rod.J if J is None else float(J)
            b_plant = rod.b if b is None else float(b)
        else:
            b_total = rod.b if b is None else float(b)
            share = gear.output_friction_share
            gear_kw = dict(gear_stiffness=gear.stiffness, gear_damping=gear.damping, backlash=gear.backlash,
                           output_inertia=gear.output_inertia, output_viscous=share * b_total)
            J_plant = p.rotor_inertia_out if J is None else float(J)
            b_plant = (1.0 - share) * b_total
        self.gear = gear
        self.jitter = float(jitter)
        self.config = PlantConfig(
            kind=kind, edges=N, input_mode=input_mode, l=geo["l"], m=geo["m"],
            EI=rod.EI, EA=p.EA, d=geo["d"], g=rod.g if g is None else float(g),
            J=J_plant, b=b_plant,
            kt_out=p.kt_out, ke_out=p.ke_out, resistance=p["motor"]["resistance"],
            supply_voltage=p["driver"]["supply_voltage"], current_limit=p["driver"]["current_limit"],
            counts_per_rev=float(p.counts_per_rev), encoder_phase=float(phase), hub_length=geo["hub_length"],
            hub_mass=geo["hub_mass"], hub_stiffness=geo["hub_stiffness"], hub_damping=geo["hub_damping"],
            coulomb=float(coulomb), inductance=float(inductance), zero_error=float(zero_error),
            rest_curvature=float(rest_curvature), encoder_on_shaft=bool(encoder_on_shaft), imu=imu, **gear_kw)
        self._lib = library()
        cfg = self.config.to_c(1e-4, "verlet" if kind == "der" else "ros2")
        self._h = self._lib.rod_plant_new(ctypes.byref(cfg))
        if not self._h:
            raise ValueError(f"invalid plant configuration: {self.config}")
        self.N = N
        self.n = self._lib.rod_plant_size(self._h)
        self.integrator = choose_integrator(self, method, p.dt if period is None else float(period))
        self.method = self.integrator["method"]
        self.step = float(step) if step is not None else self.integrator["step"]
        self.set_state(np.zeros(N))

    def __del__(self):
        h, self._h = getattr(self, "_h", None), None
        if h:
            self._lib.rod_plant_free(h)

    def __repr__(self) -> str:
        c = self.config
        gear = (f", gear=({c.gear_stiffness:g} N m/rad, {math.degrees(c.backlash):g} deg)" if c.compliant else "")
        return (f"Plant(kind={c.kind!r}, edges={c.edges}, input_mode={c.input_mode!r}, J={c.J:.3g}, b={c.b:.3g}"
                f"{gear}, method={self.method!r}, step={self.step:.3g})")

    def twin(self, **changes) -> "Plant":
        """A plant like this one with some PlantConfig fields changed (e.g. backlash=0.0), at rest hanging,
        with this one's integrator where it has one."""
        t = object.__new__(Plant)
        t.params, t.hub, t.gear, t.jitter, t._lib = self.params, self.hub, self.gear, self.jitter, self._lib
        t.config = replace(self.config, **changes)
        method = getattr(self, "integrator", {}).get("method", "verlet" if self.kind == "der" else "ros2")
        t._h = t._lib.rod_plant_new(ctypes.byref(t.config.to_c(1e-4, method)))
        if not t._h:
            raise ValueError(f"invalid plant configuration: {t.config}")
        t.N, t.n = self.N, t._lib.rod_plant_size(t._h)
        if hasattr(self, "integrator"):
            t.integrator = self.integrator
            t.step = self.step
        t.set_state(np.zeros(t.N))
        return t

    @property
    def motor_index(self) -> int:
        """The raw coordinate of the motor side: the last (compliant gearbox) or theta_1 (rigid)."""
        return self.n - 1 if self.config.compliant else 0

    @property
    def encoder_index(self) -> int:
        """The raw coordinate the encoder reads: the motor side, or theta_1 for an output-shaft encoder."""
        return 0 if self.config.encoder_on_shaft else self.motor_index

    def motor_state(self) -> tuple[float, float, float]:
        """(theta_m [rad], omega_m [rad/s], current [A]): the gearbox's motor side at the output (theta_1
        when rigid) and the winding current."""
        a, b, c = _D(), _D(), _D()
        self._lib.rod_plant_motor_state(self._h, ctypes.byref(a), ctypes.byref(b), ctypes.byref(c))
        return a.value, b.value, c.value

    def start_hanging(self, motor_angle: float, rest=None) -> None:
        """At rest with the motor side at motor_angle [rad, 0 hanging]: the rod hangs wherever the play lets it,
        its hub at its free-hanging angle if the gap around the motor side reaches that far, otherwise against the
        nearer flank, where the motor's dry friction holds it. rest: a rod curved at rest's
        rodctl.sim.statics.HangingShape (its bend follows the hub's angle); None: straight, hanging vertically.
        With the encoder on the output shaft (or no gearbox) the rod's hub is at motor_angle."""
        turns = 2.0 * math.pi * round(motor_angle / (2.0 * math.pi))  # the angle may be turns from hanging
        c = self.config
        if not c.compliant or c.encoder_on_shaft:
            hub = motor_angle
        else:
            half = 0.5 * c.backlash
            hub = min(max(turns + (rest.hub_rad if rest is not None else 0.0), motor_angle - half), motor_angle + half)
        self.set_state(hub + (rest.bend_at(hub - turns) if rest is not None else 0.0))
        if c.compliant and not c.encoder_on_shaft:
            self.set_motor_state(motor_angle)

    def set_motor_state(self, theta_m: float, omega_m: float = 0.0, current: float = 0.0) -> None:
        _check(self._lib.rod_plant_set_motor_state(self._h, float(theta_m), float(omega_m), float(current)),
               "set_motor_state")

    @property
    def gear_torque(self) -> float:
        """The gear train's torque on the shaft now [N m] (0 in the gap or when rigid)."""
        return self._lib.rod_plant_gear_torque(self._h)

    # --- configuration -------------------------------------------------------------------
    @property
    def kind(self) -> str:
        return self.config.kind

    @property
    def input_mode(self) -> str:
        return self.config.input_mode

    @property
    def method(self) -> str:
        """Integrator: "ros2" or "rk4" (inextensible), "verlet" (DER)."""
        return {v: k for k, v in METHODS.items()}[self._lib.rod_plant_method(self._h)]

    @method.setter
    def method(self, name: str) -> None:
        if name not in METHODS or self._lib.rod_plant_set_method(self._h, METHODS[name]) < 0:
            raise ValueError(f"method {name!r} is not available for a {self.kind} plant")

    @property
    def step(self) -> float:
        """Integrator step bound [s]; advance(dt) takes ceil(dt / step) equal steps."""
        return self._lib.rod_plant_max_step(self._h)

    @step.setter
    def step(self, h: float) -> None:
        _check(self._lib.rod_plant_set_max_step(self._h, float(h)), "step")

    @property
    def phase(self) -> float:
        return self.config.encoder_phase

    @phase.setter
    def phase(self, value: float) -> None:
        _check(self._lib.rod_plant_set_encoder_phase(self._h, float(value)), "phase")
        self.config = replace(self.config, encoder_phase=float(value))

    @property
    def time(self) -> float:
        return self._lib.rod_plant_time(self._h)

    @time.setter
    def time(self, t: float) -> None:
        self._lib.rod_plant_set_time(self._h, float(t))

    def model(self):
        """The Python reference model with this plant's values (RodModel or DERModel); the paper's model only."""
        c = self.config
        if self.hub is not None:
            raise NotImplementedError("no Python reference model for a plant with a hub (faithful_plant)")
        if c.kind == "der":
            return DERModel(N=c.edges, l=c.l, m=c.m, EI=c.EI, EA=c.EA, d=c.d, g=c.g, J=c.J, b=c.b)
        return RodModel(N=c.edges, l=c.l, m=c.m, EI=c.EI, d=c.d, g=c.g, J=c.J, b=c.b)

    # --- state ----------------------------------------------------------------------------
    def set_state(self, theta, dtheta=None) -> None:
        """Edge angles and rates (rad, rad/s; pi = upright). For the DER: an unstretched rod."""
        th = np.ascontiguousarray(np.broadcast_to(np.asarray(theta, float), (self.N,)))
        dth = np.zeros(self.N) if dtheta is None else np.ascontiguousarray(np.broadcast_to(np.asarray(dtheta, float), (self.N,)))
        _check(self._lib.rod_plant_set_state(self._h, _ptr(th, _D), _ptr(dth, _D)), "set_state")

    def state(self) -> tuple[np.ndarray, np.ndarray]:
        """(theta, dtheta), each (N,): edge angles unwrapped from theta_1, edge rates."""
        th, dth = np.empty(self.N), np.empty(self.N)
        self._lib.rod_plant_get_state(self._h, _ptr(th, _D), _ptr(dth, _D))
        return th, dth

    def raw_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Generalized coordinates and rates: theta (inextensible) or [phi, x2, y2, ...] (DER)."""
        q, qd = np.empty(self.n), np.empty(self.n)
        self._lib.rod_plant_get_raw_state(self._h, _ptr(q, _D), _ptr(qd, _D))
        return q, qd

    def set_raw_state(self, q, qd) -> None:
        q = np.ascontiguousarray(q, float)
        qd = np.ascontiguousarray(qd, float)
        if q.shape != (self.n,) or qd.shape != (self.n,):
            raise ValueError(f"raw state needs {self.n} values each")
        self._lib.rod_plant_set_raw_state(self._h, _ptr(q, _D), _ptr(qd, _D))

    def nodes(self) -> np.ndarray:
        """Node positions x_0..x_N, shape (N+1, 2) [m], node 0 on the axis, y up."""
        xy = np.empty(2 * (self.N + 1))
        self._lib.rod_plant_nodes(self._h, _ptr(xy, _D))
        return xy.reshape(-1, 2)

    def label(self) -> str:
        """Which plant this is, for tables: "der, 20 edges + 10 mm hub" or "paper's inextensible N = 5 model"."""
        c = self.config
        if self.hub is None:
            return f"paper's {c.kind} N = {c.edges} model"
        return f"{c.kind}, {c.edges - 1} edges + {1e3 * c.hub_length:g} mm hub"

    def edge_lengths(self) -> np.ndarray:
        """Length of each edge, hub first [m]."""
        out = np.full(self.N, self.config.l)
        out[0] = self.config.hub_length
        return out

    def node_arc(self) -> np.ndarray:
        """Arc length of each node from the axis, nodes 0..N [m] (straight rod)."""
        return np.concatenate([[0.0], np.cumsum(self.edge_lengths())])

    @property
    def external_torque(self) -> float:
        """An external torque on the shaft [N m] (a disturbance), held until changed."""
        return getattr(self, "_ext", 0.0)

    @external_torque.setter
    def external_torque(self, value: float) -> None:
        self._ext = float(value)
        self._lib.rod_plant_set_external_torque(self._h, self._ext)

    def energy(self) -> float:
        """Kinetic + elastic + gravitational energy [J], gravity zero at the axis."""
        return self._lib.rod_plant_energy(self._h)

    # --- dynamics -------------------------------------------------------------------------
    def advance(self, input: float, dt: float) -> None:
        """Hold `input` (torque [N m] or duty) for dt seconds."""
        _check(self._lib.rod_plant_advance(self._h, float(input), float(dt)), "advance")

    @property
    def last_torque(self) -> float:
        """Mean motor torque over the last advance [N m]."""
        return self._lib.rod_plant_last_torque(self._h)

    @property
    def last_current(self) -> float:
        return self._lib.rod_plant_last_current(self._h)

    def motor_torque(self, input: float, omega: float) -> tuple[float, float]:
        """(torque [N m], current [A]) for `input` at shaft rate omega."""
        cur = _D()
        T = self._lib.rod_plant_motor_torque(self._h, float(input), float(omega), ctypes.byref(cur))
        return T, cur.value

    def deriv(self, y, input: float = 0.0) -> np.ndarray:
        """d/dt of the raw state y = [q, qd] (2n) for a held input."""
        y = np.ascontiguousarray(y, float)
        out = np.empty(2 * self.n)
        _check(self._lib.rod_plant_deriv(self._h, _ptr(y, _D), float(input), _ptr(out, _D)), "deriv")
        return out

    def force(self, y, input: float = 0.0) -> np.ndarray:
        """Generalized force: M(q) qdd = F (inextensible: T e1 - C - V - D; DER: node forces)."""
        y = np.ascontiguousarray(y, float)
        out = np.empty(self.n)
        _check(self._lib.rod_plant_force(self._h, _ptr(y, _D), float(input), _ptr(out, _D)), "force")
        return out

    def mass(self, y) -> np.ndarray:
        y = np.ascontiguousarray(y, float)
        out = np.empty((self.n, self.n))
        _check(self._lib.rod_plant_mass(self._h, _ptr(y, _D), _ptr(out, _D)), "mass")
        return out

    def encoder(self) -> int:
        return self._lib.rod_plant_encoder(self._h)

    def imu_read(self, period: float) -> tuple[float, float, float] | None:
        """The tip IMU's sample a control step reads now (gyro [rad/s], accel x, y [m/s^2]), for a caller that
        advances the plant one period at a time; None when none came (or the plant has no IMU)."""
        out = (ctypes.c_float * 3)()
        r = self._lib.rod_plant_imu_read(self._h, float(period), out)
        return (out[0], out[1], out[2]) if r == 1 else None

    def encoder_count(self, theta1: float) -> int:
        return self._lib.rod_plant_encoder_count(self._h, float(theta1))

    def rest_state(self, theta: float) -> np.ndarray:
        """Raw state y of a straight rod at rest with every edge at angle theta."""
        keep = self.raw_state()
        self.set_state(np.full(self.N, float(theta)))
        q, qd = self.raw_state()
        self.set_raw_state(*keep)
        return np.concatenate([q, qd])

    def linearization(self, theta: float, y0: np.ndarray | None = None, rel_step: float = 1e-6) -> np.ndarray:
        """Jacobian of deriv (zero input) at a straight rod at rest at angle theta, or at the raw state y0
        (central differences, steps rel_step times the coordinate's scale)."""
        y0 = self.rest_state(theta) if y0 is None else np.asarray(y0, float)
        n2 = y0.size
        scale = np.ones(n2)
        if self.kind == "der":
            scale[1:self.n - (1 if self.config.compliant else 0)] = self.config.l
        A = np.empty((n2, n2))
        for k in range(n2):
            e = np.zeros(n2)
            e[k] = rel_step * scale[k]
            A[:, k] = (self.deriv(y0 + e) - self.deriv(y0 - e)) / (2 * e[k])
        return A


def _oscillatory_max_ev(ev: np.ndarray) -> float:
    mag = np.abs(ev)
    zeta = -ev.real / np.maximum(mag, 1e-300)
    osc = mag[zeta < OSCILLATORY_ZETA]
    return float(osc.max()) if osc.size else 0.0


def _elastic_max(plant: Plant, theta: float) -> float:
    """Largest undamped frequency sqrt(eig(M^-1 K)) of the DER's elastic + gravity forces."""
    y0 = plant.rest_state(theta)
    n = plant.n
    scale = np.full(n, plant.config.l)
    scale[0] = 1.0
    scale[plant.motor_index] = 1.0
    K = np.empty((n, n))
    for k in range(n):
        e = np.zeros(2 * n)
        e[k] = 1e-6 * scale[k]
        K[:, k] = -(plant.force(y0 + e) - plant.force(y0 - e)) / (2 * e[k])
    md = np.diag(plant.mass(y0))
    Ks = 0.5 * (K + K.T) / np.sqrt(np.outer(md, md))
    return float(math.sqrt(max(np.linalg.eigvalsh(Ks).max(), 0.0)))


def choose_integrator(plant: Plant, method: str = "auto", period: float = 1e-3) -> dict[str, Any]:
    """Integrator and step for this plant's model, from its linearization hanging and upright.

    Inextensible: omega_osc = largest |lambda| with damping ratio < 0.95, rho = largest |lambda|.
      ROS2 (L-stable, stiff modes implicit): h = 0.1 / omega_osc.
      RK4 (explicit, 4th order): h = min(2 / rho, 0.5 / omega_osc): only when the stiff modes are mild.
      "auto" takes RK4 when it needs no more steps per control period than ROS2 (an RK4 step costs
      ~1.4 ROS2 steps but is far more accurate), else ROS2.
    DER: velocity Verlet with implicit damping, h = 1 / omega_max of the undamped elastic part.
    Every step is capped at 1 ms. Returns method, step and the frequencies used.
    """
    angles = (0.0, math.pi) if plant.config.g > 0 else (0.0,)
    if plant.config.backlash > 0:  # the stiffest moments are the teeth in contact: judge the closed gap
        plant = plant.twin(backlash=0.0)
    if plant.kind == "der":
        if method not in ("auto", "verlet"):
            raise ValueError(f"method {method!r}: the DER plant integrates with 'verlet'")
        w = max(_elastic_max(plant, a) for a in angles)
        h = min(VERLET_MARGIN / w if w > 0 else MAX_AUTO_STEP, MAX_AUTO_STEP)
        return {"method": "verlet", "step": h, "omega_elastic": w}
    if method not in ("auto", "ros2", "rk4"):
        raise ValueError(f"method {method!r}: the inextensible plant integrates with 'ros2' or 'rk4'")
    eig = [np.linalg.eigvals(plant.linearization(a)) for a in angles]
    w_osc = max(_oscillatory_max_ev(ev) for ev in eig)
    rho = max(float(np.abs(ev).max()) for ev in eig)
    h_ros2 = min(ROS2_ACCURACY / w_osc if w_osc > 0 else MAX_AUTO_STEP, MAX_AUTO_STEP)
    if plant.config.compliant:
        # the rod's modes as accurately as the rigid plant's; the gear train's own (the hub against its
        # spring, thousands of rad/s) to ROS2_GEAR_ACCURACY: it carries little energy, and ROS2 is L-stable
        rigid = plant.twin(gear_stiffness=0.0, gear_damping=0.0, J=plant.config.J + plant.config.output_inertia,
                           output_inertia=0.0, b=plant.config.b + plant.config.output_viscous, output_viscous=0.0)
        w_rod = max(_oscillatory_max_ev(np.linalg.eigvals(rigid.linearization(a))) for a in angles)
        h_ros2 = min(ROS2_ACCURACY / w_rod if w_rod > 0 else MAX_AUTO_STEP, ROS2_GEAR_ACCURACY / w_osc, MAX_AUTO_STEP)
    h_rk4 = min(RK4_STABILITY / rho, RK4_ACCURACY / w_osc if w_osc > 0 else MAX_AUTO_STEP, MAX_AUTO_STEP)
    n_ros2, n_rk4 = math.ceil(period / h_ros2 - 1e-9), math.ceil(period / h_rk4 - 1e-9)
    if method == "auto":
        method = "rk4" if n_rk4 <= n_ros2 else "ros2"
    return {"method": method, "step": h_rk4 if method == "rk4" else h_ros2, "omega_osc": w_osc, "rho": rho,
            "steps_per_period": {"ros2": n_ros2, "rk4": n_rk4}}


def hub_geometry(p: Params, edges: int, hub_length: float, d: float | None = None) -> dict[str, float]:
    """Edge length, masses and joint constants of the faithful rod: a rigid hub of hub_length [m], then
    `edges` flexible edges of l = (L - hub) / edges.

    Bending: E I kappa^2 / 2 integrated per Voronoi length gives EI / l at the interior joints; the
    clamp sits at the hub's end and edge 2's angle belongs to its midpoint, half an edge away, so
    the hub joint carries EI / (l / 2). The rod's damping is Kelvin-Voigt like its stiffness: the
    per-joint value d of Table I's N = 5 rod (Voronoi length L / 5) becomes d (L / 5) / l_Voronoi,
    so the dissipation converges as N grows instead of vanishing (a constant d per joint dissipates
    ~ d l^2 kappa_dot^2 per joint, which goes to 0 with l)."""
    r = p["rod"]
    L = r["length"]
    l = (L - hub_length) / edges
    rho_A = r["density"] * r["width"] * r["thickness"]
    dd = r["damping"] if d is None else float(d)
    c = dd * L / DAMPING_REFERENCE_EDGES  # continuum damping [N m^2 s]
    return dict(l=l, m=rho_A * l, d=c / l, hub_length=hub_length, hub_mass=rho_A * hub_length,
                hub_stiffness=2.0 * p.EI / l, hub_damping=2.0 * c / l)


def check_faithful(params: Params) -> None:
    """InputError, one line naming the key, when the parameter file cannot make its faithful plant: what a command
    calls before it prints or compiles anything. The parameter ranges allow 0 for these because other plants (the
    paper's model without hub or motor) use them."""
    if params["plant"]["model"] == "der" and params["plant"]["hub_length"] == 0:
        raise InputError('plant.hub_length: must be > 0 with plant.model = "der" (the rod\'s foot is clamped in a hub), '
                         'got 0')
    if params["motor"]["rotor_inertia"] == 0 and (params["gearbox"]["model"] == "compliant" or params["plant"]["hub_length"] == 0):
        raise InputError('motor.rotor_inertia: must be > 0 with a compliant gearbox or no hub (the motor side of the gear '
                         'train needs its inertia), got 0')


def faithful_plant(params: Params, *, input_mode: str = "duty", phase: float = 0.5, at_rest: bool = True,
                   **kw) -> Plant:
    """The plant the parameter file's [plant] table describes (model, edges, hub_length), with the
    physical motor (rotor inertia, viscous and Coulomb friction, inductance), the [gearbox] between the
    motor and the rod, the encoder's zero error, the rod's rest curvature and the interrupt's jitter:
    what every pass/fail scenario judges (docs/plant.md). Keyword arguments override Plant's.
    It starts hanging at rest, the motor side at 0: a rod curved at rest in its static shape, its hub as near its
    free-hanging angle as the play lets it (Plant.start_hanging; at_rest=False: straight, for a caller that sets
    the state itself).
    InputError (one line naming the key) when the file cannot make it (check_faithful)."""
    check_faithful(params)
    pp = params["plant"]
    args = dict(kind=pp["model"], edges=pp["edges"], input_mode=input_mode, phase=phase,
                hub_length=pp["hub_length"], coulomb=params["motor"]["coulomb_friction"],
                gear=GearTrain.from_params(params), inductance=params["motor"]["inductance"],
                zero_error=math.radians(params["encoder"]["zero_error_deg"]),
                rest_curvature=params["rod"]["rest_curvature"], jitter=1e-6 * pp["isr_jitter_us"],
                encoder_on_shaft=params["encoder"]["location"] == "output",
                imu=ImuConfig.from_params(params) if params["sensors"]["tip_imu"] else None)
    args.update(kw)
    pl = Plant(params, **args)
    # started straight, a bent rod would swing with nothing applied (a plant of other edges than the file's: as is)
    if at_rest and not {"kind", "edges", "hub_length"} & kw.keys():
        from rodctl.sim.statics import hanging_shape

        rest = hanging_shape(params)
        if rest is not None:
            pl.start_hanging(0.0, rest)
    return pl


# --- controller (firmware SIL library) ---------------------------------------------------------

class SilController:
    """A SIL shared library with the rod_sil ABI (version 1), loaded with ctypes."""

    def __init__(self, lib: str | Path | ctypes.CDLL):
        self.lib = lib if isinstance(lib, ctypes.CDLL) else ctypes.CDLL(str(lib))
        L = self.lib
        for name in ("rod_sil_abi_version", "rod_sil_reset", "rod_sil_period", "rod_sil_edges", "rod_sil_arm",
                     "rod_sil_step", "rod_sil_status"):
            if not hasattr(L, name):
                raise UserError(f"{self.path}: not a rod_sil library (no {name})")
        L.rod_sil_abi_version.restype = ctypes.c_int
        L.rod_sil_period.restype = ctypes.c_float
        L.rod_sil_edges.restype = ctypes.c_int
        version = L.rod_sil_abi_version()
        if version != SIL_ABI_VERSION:
            raise UserError(f"{self.path}: rod_sil ABI version {version}, the simulator speaks {SIL_ABI_VERSION}")
        raw = L.rod_sil_period()
        # The ABI returns a float: 0.001f is 1.00000005e-3 s as a double. Use the shortest decimal
        # that rounds to the same float (0.001), so simulated time does not drift by 50 ppm.
        self.period = float(np.format_float_positional(np.float32(raw), unique=True)) if math.isfinite(raw) else raw
        self.edges = int(L.rod_sil_edges())
        if not (self.period > 0 and math.isfinite(self.period)):
            raise UserError(f"{self.path}: rod_sil_period() = {self.period}")
        if not 1 <= self.edges <= 128:
            raise UserError(f"{self.path}: rod_sil_edges() = {self.edges}")
        self.has_duty = hasattr(L, "rod_sil_duty")
        self.has_imu = hasattr(L, "rod_sil_imu")
        addr = lambda name: ctypes.cast(getattr(L, name), ctypes.c_void_p).value  # noqa: E731
        self.api = _SilApi(addr("rod_sil_reset"), addr("rod_sil_arm"), addr("rod_sil_step"), addr("rod_sil_status"),
                           addr("rod_sil_duty") if self.has_duty else None,
                           addr("rod_sil_imu") if self.has_imu else None)

    @property
    def path(self) -> str:
        return getattr(self.lib, "_name", "?")


def _controller(sil) -> SilController:
    return sil if isinstance(sil, SilController) else SilController(sil)


def run_closed_loop(plant: Plant, sil, periods: int, arm_mode: int = 0, delay_periods: int = 0, *,
                    reset: bool = True, stop_on_mode: int | None = None, jitter: float | None = None,
                    jitter_seed: int = 1) -> dict[str, Any]:
    """Run the firmware controller (SIL library path, CDLL or SilController) against `plant` in C.

    Per period k: count = encoder(plant) -> cmd = rod_sil_step(count) -> [delay_periods = 1: the
    plant gets the previous command] -> torque (torque mode) or rod_sil_duty() (duty mode) held for
    one period while the plant integrates. reset: rod_sil_reset() first, then rod_sil_arm(arm_mode)
    if arm_mode != 0. stop_on_mode: stop after the first period in that mode (e.g. 3 = FAULT).
    A NaN/inf command is logged as is but the plant gets 0 (counted in nonfinite_commands).

    Returns arrays with one row per period run: time [s] (t_k, the encoder read), theta and dtheta
    (true, plant N), est (controller's status: theta-hat_1..Nc then rates, float32), torque_cmd
    (float32), duty (float32), torque and current (mean applied over the period), mode, count
    (int32); and scalars periods_run, nonfinite_commands, stopped_on_mode, period, controller_edges,
    plant_edges; motor: the motor side's angle at each encoder read [rad] (theta_1 when rigid); imu: the
    tip IMU's sample given to each step (gyro [rad/s], accelerometer x, y [m/s^2]; NaN without one).
    jitter [s] (default: the plant's): the encoder read and the new command come j_k late, j_k uniform in
    [0, jitter) from the seeded sequence jitter_seed (reset=True restarts it). If the plant fails (its
    state left the model), SimulationError carries the log up to and including the failed period. The
    SIL library has global state: one run at a time.
    """
    ctl = _controller(sil)
    if plant.input_mode == "duty" and not ctl.has_duty:
        raise UserError(f"{ctl.path}: a duty-mode plant needs rod_sil_duty()")
    if delay_periods not in (0, 1):
        raise ValueError("delay_periods must be 0 or 1")
    periods = int(periods)
    if periods < 0:
        raise ValueError("periods must be >= 0")
    N, ne = plant.N, 2 * ctl.edges
    out = {
        "time": np.zeros(periods),
        "theta": np.zeros((periods, N)),
        "dtheta": np.zeros((periods, N)),
        "est": np.zeros((periods, ne), np.float32),
        "torque_cmd": np.zeros(periods, np.float32),
        "duty": np.zeros(periods, np.float32),
        "torque": np.zeros(periods),
        "current": np.zeros(periods),
        "mode": np.zeros(periods, np.int32),
        "count": np.zeros(periods, np.int32),
        "motor": np.zeros(periods),
        "imu": np.full((periods, 3), np.nan, np.float32),
    }
    log = _RunLog(_ptr(out["time"], _D), _ptr(out["theta"], _D), _ptr(out["dtheta"], _D),
                  _ptr(out["est"], ctypes.c_float), _ptr(out["torque_cmd"], ctypes.c_float),
                  _ptr(out["duty"], ctypes.c_float), _ptr(out["torque"], _D), _ptr(out["current"], _D),
                  _ptr(out["mode"], ctypes.c_int32), _ptr(out["count"], ctypes.c_int32), _ptr(out["motor"], _D),
                  _ptr(out["imu"], ctypes.c_float))
    jit = plant.jitter if jitter is None else float(jitter)
    if not 0.0 <= jit < ctl.period:
        raise ValueError(f"jitter must be in [0, {ctl.period:g}) s, got {jit!r}")
    opt = _RunOptions(periods, ctl.period, ne, int(bool(reset)), int(arm_mode), int(delay_periods),
                      -1 if stop_on_mode is None else int(stop_on_mode), int(jitter_seed) & 0xFFFFFFFF, jit)
    res = _RunResult()
    ret = plant._lib.rod_run_closed_loop(plant._h, ctypes.byref(ctl.api), ctypes.byref(opt), ctypes.byref(log),
                                         ctypes.byref(res))
    if ret < 0 and res.periods_run == 0:
        _check(int(ret), "run_closed_loop")
    k = int(res.periods_run)
    if k < periods:
        out = {key: v[:k].copy() for key, v in out.items()}
    out.update(periods_run=k, nonfinite_commands=int(res.nonfinite_commands),
               stopped_on_mode=bool(res.stopped_on_mode), period=ctl.period, controller_edges=ctl.edges,
               plant_edges=N)
    if res.error:
        raise SimulationError(f"plant failed in period {k - 1} (t = {out['time'][-1]:.6g} s): "
                              f"{ERRORS.get(int(res.error), res.error)}", out)
    return out


def measure_realtime_factor(plant: Plant, sil, seconds: float = 10.0, repeats: int = 5, arm_mode: int = 2,
                            theta0: float = 0.0) -> dict[str, Any]:
    """Simulated seconds per wall second of run_closed_loop (controller call and logging included).

    Each repeat starts the plant at rest at theta0 and runs `seconds`; returns the median factor,
    every factor, and the wall time per control period.
    """
    ctl = _controller(sil)
    periods = max(1, int(round(seconds / ctl.period)))
    factors = []
    for _ in range(max(1, repeats)):
        plant.set_state(np.full(plant.N, float(theta0)))
        plant.time = 0.0
        t0 = time.perf_counter()
        log = run_closed_loop(plant, ctl, periods, arm_mode)
        wall = time.perf_counter() - t0
        factors.append(log["periods_run"] * ctl.period / wall)
    med = statistics.median(factors)
    return {"factor": med, "factors": factors, "us_per_period": 1e6 * ctl.period / med, "periods": periods,
            "plant": repr(plant)}


def benchmark(sil, params: Params | None = None, seconds: float = 10.0, repeats: int = 5,
              cases=(("inextensible", 5), ("inextensible", 20), ("der", 5), ("der", 20))) -> list[dict[str, Any]]:
    """Realtime factors of the closed loop for several plants (the release gate: N = 5 >= 1000x,
    N = 20 >= 50x at a 1 kHz control rate)."""
    rows = []
    for kind, N in cases:
        plant = Plant(params, kind=kind, edges=N)
        r = measure_realtime_factor(plant, sil, seconds=seconds, repeats=repeats)
        r.update(kind=kind, edges=N, method=plant.method, step=plant.step,
                 steps_per_period=math.ceil(_controller(sil).period / plant.step - 1e-9))
        rows.append(r)
    return rows


def main(argv=None) -> int:
    import argparse

    ap = argparse.ArgumentParser(prog="python -m rodctl.sim.plant", description="closed-loop speed benchmark")
    ap.add_argument("sil", help="rod_sil shared library")
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args(argv)
    for r in benchmark(a.sil, seconds=a.seconds, repeats=a.repeats):
        print(f"{r['kind']:>12} N={r['edges']:<3} {r['method']:>6} step={1e3 * r['step']:.4f} ms ({r['steps_per_period']}/period)  "
              f"{r['factor']:9.0f}x real time  ({r['us_per_period']:.2f} us/period)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
