"""Gain design: the paper's continuous LQR/observer (reference) and the sampled gains the firmware runs.

Firmware loop (current-estimate form), all in deviation z = x - x_upright:
    z_pred = Ad z_prev + Bd u_prev
    z      = z_pred + L (y - C z_pred)          y = theta_1 - pi from the encoder
    u      = -K z                               base torque [N m], then clamped
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg as sla

from . import sampled
from .errors import DesignRefused
from .linearize import linearize_upright
from .params import Params
from .rod_model import RodModel

OBSERVER_FORM = "current"  # x_hat[k|k]; see sampled.kalman_current
# Below this a mode is numerically unreachable/invisible (eigenvector entries at round-off).
VISIBILITY_FLOOR = 1e-13


def weights(p: Params, N: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(Q, R) of the LQR cost (eq. 19) and (W, V) of the observer, continuous-time intensities."""
    lq, ob = p["lqr"], p["observer"]
    Q = np.diag([lq["q_angle"]] * N + [lq["q_rate"]] * N)
    R = np.array([[lq["r_torque"]]])
    W = np.diag([ob["process_noise_angle"]] * N + [ob["process_noise_rate"]] * N)
    V = np.array([[ob["measurement_noise"]]])
    return Q, R, W, V


def continuous_gains(A, B, C, Q, R, W, V) -> tuple[np.ndarray, np.ndarray]:
    """The paper's design (Sec. III): K = lqr(A, B, Q, R), L = lqr(A^T, C^T, W, V)^T."""
    P = sla.solve_continuous_are(A, B, Q, R)
    K = np.linalg.solve(R, B.T @ P)
    Po = sla.solve_continuous_are(A.T, C.T, W, V)
    L = (np.linalg.solve(V, C @ Po)).T
    return K, L


@dataclass
class Design:
    params: Params
    rod: RodModel
    dt: float
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    Ad: np.ndarray
    Bd: np.ndarray
    K: np.ndarray
    L: np.ndarray
    K_continuous: np.ndarray
    L_continuous: np.ndarray
    method: str
    observer_form: str = OBSERVER_FORM
    checks: dict = field(default_factory=dict)

    @property
    def N(self) -> int:
        return self.rod.N

    def loop(self, actuator_gain: complex = 1.0) -> np.ndarray:
        return sampled.closed_loop(self.Ad, self.Bd, self.C, self.K, self.L, actuator_gain=actuator_gain)

    def to_json(self) -> dict:
        return {
            "N": self.N,
            "dt": self.dt,
            "A": self.A.tolist(),
            "B": self.B.tolist(),
            "Ad": self.Ad.tolist(),
            "Bd": self.Bd.tolist(),
            "C": self.C.tolist(),
            "K": self.K.tolist(),
            "L": self.L.tolist(),
            "observer_form": self.observer_form,
            "method": self.method,
            "K_continuous": self.K_continuous.tolist(),  # lqr(A, B, Q, R) with this file's weights (Sec. III-A)
            "L_continuous": self.L_continuous.tolist(),  # lqr(A', C', W, V)' (Sec. III-B), for reference
            "state": [f"theta_{i}" for i in range(1, self.N + 1)] + [f"dtheta_{i}" for i in range(1, self.N + 1)],
            "units": {"state": "rad, rad/s (theta = pi upright)", "input": "base torque at the output shaft [N m]", "dt": "s"},
            "closed_loop_spectral_radius": self.checks.get("closed_loop_spectral_radius"),
            "params_sha256": self.params.sha256(),
        }


def design(p: Params) -> Design:
    """Design the firmware's gains for `p`; raise DesignRefused unless the sampled loop is stable."""
    rod = RodModel.from_params(p, design=True)
    N, dt = rod.N, p.dt
    A, B = linearize_upright(rod)
    C = np.zeros((1, 2 * N))
    C[0, 0] = 1.0
    Q, R, W, V = weights(p, N)

    ctrb, ctrb_mode = sampled.modal_visibility(A, B=B)
    obsv, obsv_mode = sampled.modal_visibility(A, C=C)
    checks = {"controllability": ctrb, "observability": obsv}
    if ctrb < VISIBILITY_FLOOR:
        raise DesignRefused(f"design refused: the mode at {ctrb_mode:.4g} rad/s cannot be moved by the base torque "
                            f"(modal controllability {ctrb:.2e}); (A, B) is not stabilizable")
    if obsv < VISIBILITY_FLOOR:
        raise DesignRefused(f"design refused: the mode at {obsv_mode:.4g} rad/s is invisible in theta_1 "
                            f"(modal observability {obsv:.2e}); (A, C) is not observable")

    Ad, Bd = sampled.zoh(A, B, dt)
    sctrb, _ = sampled.modal_visibility(Ad, B=Bd, unstable_only_discrete=True)
    sobsv, _ = sampled.modal_visibility(Ad, C=C, unstable_only_discrete=True)
    checks["sampled_controllability"], checks["sampled_observability"] = sctrb, sobsv
    if sctrb < VISIBILITY_FLOOR or sobsv < VISIBILITY_FLOOR:
        raise DesignRefused(
            f"design refused: sampling at {1 / dt:g} Hz hides an unstable mode (pathological rate); change loop.rate_hz"
        )

    try:
        K_c, L_c = continuous_gains(A, B, C, Q, R, W, V)
    except (np.linalg.LinAlgError, ValueError) as e:
        raise DesignRefused(f"design refused: continuous Riccati equation failed ({e})") from None

    try:
        Qd, Rd, Nd = sampled.sampled_cost(A, B, Q, R, dt)
        Wd = sampled.sampled_process_noise(A, W, dt)
        L, _ = sampled.kalman_current(Ad, C, Wd, V / dt)
        if p["design"]["method"] == "sampled":
            K, _ = sampled.dlqr(Ad, Bd, Qd, Rd, Nd)
        else:
            K = K_c
    except (np.linalg.LinAlgError, ValueError) as e:
        raise DesignRefused(f"design refused: discrete Riccati equation failed ({e})") from None

    d = Design(p, rod, dt, A, B, C, Ad, Bd, K, L, K_c, L_c, p["design"]["method"], checks=checks)
    rho = sampled.spectral_radius(d.loop())
    checks["closed_loop_spectral_radius"] = rho
    if not np.all(np.isfinite(K)) or not np.all(np.isfinite(L)):
        raise DesignRefused("design refused: gains are not finite")
    if rho >= 1.0:
        raise DesignRefused(
            f"design refused: sampled closed loop (plant + observer + LQR at {1 / dt:g} Hz, "
            f"method={d.method}) has spectral radius {rho:.3g} >= 1"
        )
    return d
