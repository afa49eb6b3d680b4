"""The tip IMU in the design: where it sits on the N-edge model, its mass, and what it measures.

Sensor frame, in the swing plane, on edge j of the model (the edge its centre lies on):
    x along the rod toward the tip, t = (sin theta_j, -cos theta_j);
    y its normal toward increasing theta, n = (cos theta_j, sin theta_j);
    the gyro's z axis reads dtheta_j (+ its bias).
The accelerometer reads the specific force f = a - g_vec, g_vec = (0, -g). At the site s (arc length
from the axis, a fraction `frac` along edge j):
    f_n = sum_{i<j} l [ddtheta_i cos(theta_i - theta_j) + dtheta_i^2 sin(theta_j - theta_i)] + frac l ddtheta_j
          + g sin theta_j
    f_t = ... + (- g cos theta_j): g upright at rest, no first-order term there.
About upright (theta = pi + z) f_n = l (sum_{i<j} ddz_i + frac ddz_j) - g z_j, and ddz = A_r z + B_r u
from the linearization, so the IMU adds y = C z + D u: the accelerometer's normal axis sees the tip's
angle from gravity and the torque through the rod's acceleration. f_t carries no first-order
information about upright; the firmware uses it only to check the part is alive.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .params import Params

GYRO, ACCEL = 0, 1  # rows of the IMU's measurement: [gyro z [rad/s], accelerometer normal axis [m/s^2]]
BIAS_DRIFT_TIME = 100.0  # the gyro's bias instability is the drift over this long [s] (its random walk)


@dataclass(frozen=True)
class ImuSite:
    """Where the IMU is on an N-edge rod of equal edges l [m]: on edge `edge` (0-based), `frac` of the way out."""

    edge: int
    frac: float
    position: float  # arc length from the motor axis [m]

    @classmethod
    def on_model(cls, p: Params, N: int | None = None) -> "ImuSite":
        N = N or p.N
        L = p["rod"]["length"]
        s = L - p["sensors"]["imu_from_tip"]
        l = L / N
        j = min(int(s / l), N - 1)
        return cls(edge=j, frac=float(s / l - j), position=float(s))

    def node_masses(self, N: int, mass: float) -> np.ndarray:
        """The IMU's mass split between the two nodes of its edge by the lever rule, nodes 0..N [kg]."""
        out = np.zeros(N + 1)
        out[self.edge] += (1.0 - self.frac) * mass
        out[self.edge + 1] += self.frac * mass
        return out


def measurement(A: np.ndarray, B: np.ndarray, l: float, g: float, site: ImuSite) -> tuple[np.ndarray, np.ndarray]:
    """(C, D) of the IMU about upright: y = C z + D u, rows GYRO [rad/s] and ACCEL (normal axis) [m/s^2];
    z the design state [angles, rates] from upright, u the base torque [N m]."""
    n = A.shape[0]
    N = n // 2
    j = site.edge
    C = np.zeros((2, n))
    D = np.zeros((2, 1))
    C[GYRO, N + j] = 1.0
    lever = np.zeros(N)
    lever[:j] = l
    lever[j] = site.frac * l
    C[ACCEL] = lever @ A[N:, :]
    C[ACCEL, j] -= g
    D[ACCEL, 0] = lever @ B[N:, 0]
    return C, D


def white_noise(p: Params) -> tuple[float, float]:
    """Per-sample standard deviations of the part's white noise (gyro [rad/s], accelerometer [m/s^2]) at its
    data rate: the noise density over half the rate (one-sided)."""
    s = p["sensors"]
    half_band = 0.5 * s["rate_hz"]
    return (float(s["gyro_noise_density"] * np.sqrt(half_band)), float(s["accel_noise_density"] * np.sqrt(half_band)))


def lsb(p: Params) -> tuple[float, float]:
    """One count of the 16-bit readings at full scale (gyro [rad/s], accelerometer [m/s^2])."""
    s = p["sensors"]
    return s["gyro_range"] / 32768.0, s["accel_range"] / 32768.0


def noise(p: Params) -> tuple[float, float]:
    """Per-sample standard deviations (gyro [rad/s], accelerometer [m/s^2]) the estimator assumes: the white
    noise and one LSB's rounding."""
    return tuple(float(np.hypot(w, q / np.sqrt(12))) for w, q in zip(white_noise(p), lsb(p)))


def delay_periods(p: Params) -> int:
    """The IMU's latency in whole control periods, as the estimator models it."""
    return int(round(p["sensors"]["latency"] * p["loop"]["rate_hz"]))


def bias_walk(p: Params) -> float:
    """Intensity of the gyro bias's random walk [(rad/s)^2/s]: it drifts by the instability in BIAS_DRIFT_TIME."""
    return p["sensors"]["gyro_bias_instability"] ** 2 / BIAS_DRIFT_TIME


@dataclass
class ImuEstimator:
    """The estimator's extra states and gains when the tip IMU is read (design.py; firmware rod_observer.c).

    Measurement y = [theta_1 - upright from the encoder [rad], gyro [rad/s], accelerometer normal [m/s^2]].
    Extra states a = [o, b, s_1 .. s_d]: o the encoder's offset from the rod's base (the boot zero, the
    gearbox's flank: what the IMU's gravity reference makes observable) [rad], b the gyro's bias [rad/s],
    s_i the IMU's reading i periods in flight (gyro, accelerometer), d = delay periods. With the
    design state z, the disturbance w and the torque held u (firmware order):
        z_pred = Ad z + Bd (u + w);  w_pred = w_decay w;  a_pred = AZ z + AA a + BA (u + w)
        y_hat  = CZ z_pred + CA a_pred + DY (u + w_pred)
        e = y - y_hat;  z = z_pred + L e;  w = w_pred + Lw e;  a = a_pred + La e;   u = -K z - w
    Shapes: NA = 2 + 2 d; AZ (NA, NX), AA (NA, NA), BA (NA,), CZ (3, NX), CA (3, NA), DY (3,),
    L (NX, 3), Lw (3,), La (NA, 3)."""

    delay: int
    C_imu: np.ndarray  # (2, NX): IMU rows about upright on the design model
    D_imu: np.ndarray  # (2, 1)
    AZ: np.ndarray
    AA: np.ndarray
    BA: np.ndarray
    CZ: np.ndarray
    CA: np.ndarray
    DY: np.ndarray
    V: np.ndarray  # (3, 3) per-sample measurement covariance the filter assumes
    L: np.ndarray | None = None
    Lw: np.ndarray | None = None
    La: np.ndarray | None = None

    NY = 3

    def to_json(self) -> dict:
        """Every matrix of the IMU estimator, as the design's --json carries it (the class doc's equations)."""
        d = self.delay
        out = {"measurement": ["encoder theta_1 - upright [rad]", "gyro [rad/s]", "accelerometer normal [m/s^2]"],
               "extra_state": ["encoder_offset [rad]", "gyro_bias [rad/s]"]
               + [f"{name}_in_flight_{i} [{unit}]" for i in range(1, d + 1)
                  for name, unit in (("gyro", "rad/s"), ("accel", "m/s^2"))],
               "delay_periods": d}
        for name in ("C_imu", "D_imu", "AZ", "AA", "BA", "CZ", "CA", "DY", "V", "L", "Lw", "La"):
            out[name] = np.asarray(getattr(self, name)).tolist()
        return out

    @property
    def NA(self) -> int:
        return 2 + 2 * self.delay

    @classmethod
    def structure(cls, C_imu: np.ndarray, D_imu: np.ndarray, delay: int, V: np.ndarray) -> "ImuEstimator":
        NX = C_imu.shape[1]
        NA = 2 + 2 * delay
        AZ, AA, BA = np.zeros((NA, NX)), np.zeros((NA, NA)), np.zeros(NA)
        CZ, CA, DY = np.zeros((3, NX)), np.zeros((3, NA)), np.zeros(3)
        AA[0, 0] = AA[1, 1] = 1.0  # the offset and the bias walk
        CZ[0, 0] = 1.0
        CA[0, 0] = 1.0  # the encoder reads the base plus its offset
        CA[1, 1] = 1.0  # the gyro reads the rate plus its bias
        if delay == 0:
            CZ[1:] = C_imu
            DY[1:] = D_imu[:, 0]
        else:
            AZ[2:4] = C_imu
            BA[2:4] = D_imu[:, 0]
            AA[2:, 2:] = in_flight_shift(delay)
            CA[1, NA - 2] = 1.0
            CA[2, NA - 1] = 1.0
        return cls(delay, C_imu, D_imu, AZ, AA, BA, CZ, CA, DY, V)

    def full(self, Ad: np.ndarray, Bd: np.ndarray, w_decay: float):
        """(A, B, C, D) of the estimator's whole model, state [z, w, a], input u held, y = C x + D u."""
        NX, NA = Ad.shape[0], self.NA
        n = NX + 1 + NA
        A = np.zeros((n, n))
        A[:NX, :NX] = Ad
        A[:NX, NX] = Bd[:, 0]
        A[NX, NX] = w_decay
        A[NX + 1:, :NX] = self.AZ
        A[NX + 1:, NX] = self.BA
        A[NX + 1:, NX + 1:] = self.AA
        B = np.concatenate([Bd[:, 0], [0.0], self.BA])[:, None]
        C = np.hstack([self.CZ, self.DY[:, None], self.CA])
        D = self.DY[:, None]
        return A, B, C, D

    def plant(self, Ad: np.ndarray, Bd: np.ndarray, C_imu=None, D_imu=None, C_enc=None):
        """(A, B, C, D) of a plant (Ad, Bd) read by this IMU arrangement: state [x, s_1..s_d] (no offset, no
        bias: those have nothing to be stabilized), y = C x + D u. C_imu, D_imu: the IMU rows of that plant,
        C_enc its encoder's row (default: the design model's: the IMU's rows, and theta_1)."""
        C_imu = self.C_imu if C_imu is None else C_imu
        D_imu = self.D_imu if D_imu is None else D_imu
        nx, d = Ad.shape[0], self.delay
        if C_enc is None:
            C_enc = np.zeros(nx)
            C_enc[0] = 1.0
        n = nx + 2 * d
        A = np.zeros((n, n))
        A[:nx, :nx] = Ad
        B = np.zeros((n, 1))
        B[:nx] = Bd
        C = np.zeros((3, n))
        D = np.zeros((3, 1))
        C[0, :nx] = np.ravel(C_enc)
        if d == 0:
            C[1:, :nx] = C_imu
            D[1:] = D_imu
        else:
            A[nx:nx + 2, :nx] = C_imu
            B[nx:nx + 2] = D_imu
            A[nx:, nx:] = in_flight_shift(d)
            C[1:, n - 2:] = np.eye(2)
        return A, B, C, D


def in_flight_shift(delay: int) -> np.ndarray:
    """(2 delay, 2 delay): one period of the readings in flight, s_{i+1} <- s_i (the newest s_1 comes in from
    the state, the oldest s_delay is what the step reads)."""
    return np.eye(2 * delay, k=-2)


def closed_loop(Ap, Bp, Cp, Dp, Ao, Bo, Co, Do, Ko, Lo, actuator_gain: complex = 1.0, delay: int = 0) -> np.ndarray:
    """The sampled loop with a multi-output estimator: plant x_k = Ap x_{k-1} + Bp a u_{k-1-delay},
    y_k = Cp x_k + Dp a u_{k-1-delay}; estimator xh- = Ao xh + Bo u, e = y - Co xh- - Do u, xh = xh- + Lo e,
    u = -Ko xh (a: the actuator's gain). State [x, xh, u in flight]."""
    a = actuator_gain
    n_p, n_o = Ap.shape[0], Ao.shape[0]
    n = n_p + n_o + delay
    M = np.zeros((n, n), dtype=np.result_type(Ap, a))
    Io = np.eye(n_o)
    Acl_o = Ao - Bo @ Ko
    # the plant's input this period: u_{k-1} (no delay) or the oldest in flight
    if delay == 0:
        Pu = -a * Ko  # as a function of xh_{k-1}
        M[:n_p, :n_p] = Ap
        M[:n_p, n_p:n_p + n_o] = Bp @ Pu
        M[n_p:n_p + n_o, :n_p] = Lo @ Cp @ Ap
        M[n_p:n_p + n_o, n_p:n_p + n_o] = ((Io - Lo @ Co) @ Acl_o + Lo @ (Cp @ Bp @ Pu + Dp @ Pu)
                                           + Lo @ Do @ Ko)
        return M
    last = n - 1
    M[:n_p, :n_p] = Ap
    M[:n_p, last:] = a * Bp
    M[n_p:n_p + n_o, :n_p] = Lo @ Cp @ Ap
    M[n_p:n_p + n_o, n_p:n_p + n_o] = (Io - Lo @ Co) @ Acl_o + Lo @ Do @ Ko
    M[n_p:n_p + n_o, last:] = a * Lo @ (Cp @ Bp + Dp)
    M[n_p + n_o, n_p:n_p + n_o] = -Ko[0]
    for i in range(1, delay):
        M[n_p + n_o + i, n_p + n_o + i - 1] = 1.0
    return M


def observability(p: Params, A: np.ndarray, B: np.ndarray, l: float, g: float) -> list[dict]:
    """What the tip IMU adds, mode by mode of the design model about upright (A, B; rod edges l [m]):
    how strongly one sample sees a mode of unit angle amplitude (its angles' norm 1 rad), against each
    sensor's per-sample noise: the encoder alone (one count / sqrt 12) and the encoder with the IMU
    (noise(p)). Rows sorted slowest first: s [1/s] (complex), seen_encoder, seen_with_imu [-]."""
    n = A.shape[0]
    N = n // 2
    lam, V = np.linalg.eig(A)
    C_imu, _ = measurement(A, B, l, g, ImuSite.on_model(p, N))
    sg, sa = noise(p)
    s_enc = p.rad_per_count / np.sqrt(12.0)
    rows = []
    for k in np.argsort(np.abs(lam)):
        if lam[k].imag < -1e-9:
            continue  # one of each conjugate pair
        v = V[:, k] / np.linalg.norm(V[:N, k])
        enc = abs(v[0]) / s_enc
        imu = np.hypot(abs(C_imu[GYRO] @ v) / sg, abs(C_imu[ACCEL] @ v) / sa)
        rows.append({"s": complex(lam[k]), "seen_encoder": float(enc), "seen_with_imu": float(np.hypot(enc, imu))})
    return rows
