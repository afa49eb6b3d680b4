"""The simulated tip IMU: what the C plant is told about the part (native/rod_plant.h, "The IMU").

The plant makes each control period's sample from the true motion of the rod at the IMU's place:
the mean rate of its edge and the mean specific force over the period (the part's decimation
filter), in the sensor's frame, then the part's white noise, the gyro's bias and its random walk,
rounding to one LSB, clipping at full scale, and the pipelined read's delay.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rodgains import imu as imu_model
from rodgains.params import Params

FAULTS = {"none": 0, "silent": 1, "stuck": 2, "range": 3}  # ROD_IMU_FAULT_*


@dataclass(frozen=True)
class ImuConfig:
    """The simulated IMU (SI units); see rod_plant.h for the model."""

    mass: float  # [kg]
    position: float  # arc length from the motor axis [m]
    gyro_sigma: float  # white noise per sample [rad/s]
    accel_sigma: float  # [m/s^2]
    gyro_bias: float  # turn-on bias [rad/s]
    bias_step: float  # random-walk step of the bias per control period [rad/s]
    gyro_lsb: float  # [rad/s]
    accel_lsb: float  # [m/s^2]
    delay: int  # control periods of pipeline [-]
    seed: int = 1
    fault: str = "none"  # from fault_time on: "silent" (no data), "stuck" (the same sample), "range" (full scale)
    fault_time: float = math.inf  # [s] of plant time
    tilt: float = 0.0  # the part's mounting tilt in the swing plane [rad]

    @classmethod
    def from_params(cls, p: Params, **changes) -> "ImuConfig":
        s = p["sensors"]
        half_band = 0.5 * s["rate_hz"]
        base = dict(mass=s["imu_mass"], position=p["rod"]["length"] - s["imu_from_tip"],
                    gyro_sigma=s["gyro_noise_density"] * math.sqrt(half_band),
                    accel_sigma=s["accel_noise_density"] * math.sqrt(half_band), gyro_bias=s["gyro_bias"],
                    bias_step=math.sqrt(imu_model.bias_walk(p) * p.dt), gyro_lsb=s["gyro_range"] / 32768.0,
                    accel_lsb=s["accel_range"] / 32768.0, delay=imu_model.delay_periods(p),
                tilt=math.radians(s["imu_tilt_deg"]))
        base.update(changes)
        return cls(**base)

    def c_fields(self) -> tuple:
        """The rod_plant_config fields from imu_on to imu_tilt, in order."""
        return (1, self.mass, self.position, self.gyro_sigma, self.accel_sigma, self.gyro_bias, self.bias_step,
                self.gyro_lsb, self.accel_lsb, int(self.delay), int(self.seed) & 0xFFFFFFFF,
                self.fault_time if math.isfinite(self.fault_time) else 1e300, FAULTS[self.fault], 0, self.tilt)


NO_IMU_FIELDS = (0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 1.0, 0, 0, 1e300, 0, 0, 0.0)


def site_on_plant(pl, position: float) -> tuple[int, float]:
    """(edge index, fraction along it) of arc length `position` [m] from the axis on the plant's edges."""
    arc = pl.node_arc()
    j = int(np.clip(np.searchsorted(arc, position) - 1, 0, len(arc) - 2))
    return j, float(np.clip((position - arc[j]) / (arc[j + 1] - arc[j]), 0.0, 1.0))


def linear_rows(pl, y0: np.ndarray, A: np.ndarray, B: np.ndarray, position: float, g: float):
    """(C, D) of the IMU at `position` on plant pl linearized at rest at y0 = [q, qd] (its A, B over y):
    rows gyro [rad/s] and accelerometer y [m/s^2], as rodgains.imu.measurement gives them on the design
    model. At rest no velocity term is first order: gyro = d theta_j/dq qd, and the normal specific
    force = n . (d site/dq qdd) + g sin theta_j, qdd = the rate rows of A and B."""
    j, frac = site_on_plant(pl, position)
    n = pl.n
    q0, qd0 = y0[:n], y0[n:]

    def geometry(q):
        pl.set_raw_state(q, qd0)
        x = pl.nodes()
        e = x[j + 1] - x[j]
        return math.atan2(e[0], -e[1]), x[j] + frac * e

    keep = pl.raw_state()
    th0, _ = geometry(q0)
    dth, dsite = np.zeros(n), np.zeros((2, n))
    for k in range(n):
        h = 1e-7 * max(1.0, abs(q0[k]))
        qp, qm = q0.copy(), q0.copy()
        qp[k] += h
        qm[k] -= h
        tp, sp = geometry(qp)
        tm, sm = geometry(qm)
        dth[k] = math.remainder(tp - tm, 2 * math.pi) / (2 * h)
        dsite[:, k] = (sp - sm) / (2 * h)
    pl.set_raw_state(*keep)
    normal = np.array([math.cos(th0), math.sin(th0)])
    m = A.shape[0]
    C, D = np.zeros((2, m)), np.zeros((2, 1))
    C[0, n:2 * n] = dth
    C[1] = normal @ dsite @ A[n:2 * n]
    C[1, :n] += g * math.cos(th0) * dth
    D[1, 0] = normal @ dsite @ B[n:2 * n, 0]
    return C, D
