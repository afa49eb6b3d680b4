"""Gain design: the paper's continuous LQR/observer (reference) and the sampled gains the firmware runs.

Firmware loop (current-estimate form), all in deviation z = x - x_upright:
    z_pred = Ad z_prev + Bd u_prev
    z      = z_pred + L (y - C z_pred)          y = theta_1 - pi from the encoder
    u      = -K z                               base torque [N m], then clamped
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import scipy.linalg as sla

from . import imu as imu_model
from . import sampled
from .errors import DesignRefused
from .imu import ImuEstimator, ImuSite
from .imu import closed_loop as imu_closed_loop
from .linearize import linearize_upright
from .params import Params
from .rod_model import RodModel

OBSERVER_FORM = "current"  # x_hat[k|k]; see sampled.kalman_current
# Below this a mode is numerically unreachable/invisible (eigenvector entries at round-off).
VISIBILITY_FLOOR = 1e-13
DEAD_WITHIN_A_PERIOD = 1e-6  # a continuous mode that decays by this within one sample is left out of the checks [-]


def weights(p: Params, N: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(Q, R) of the LQR cost (eq. 19) and (W, V) of the observer, continuous-time intensities."""
    lq, ob = p["lqr"], p["observer"]
    Q = np.diag([lq["q_angle"]] * N + [lq["q_rate"]] * N)
    Q[0, 0] += lq["q_shaft_angle"]
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


def lean_torque(p: Params) -> float:
    """The steady base torque the tip IMU's balance holds the rod leaning by [N m]: lqr.imu_flank_torque
    where the file's rig has play between the encoder and the rod (gearbox.backlash_deg, encoder on the
    motor) from lqr.imu_lean_from_play_deg on, else 0, upright. The lean keeps one flank loaded so the
    motor never crosses the gap; with less play the crossing costs less than the lean. Measured
    (docs/sensors.md, "The gearbox's play"): upright without play 0.34 / 0.96 deg median mean / peak
    against 1.30 / 2.11 leaning; upright's peak grows with the play and meets the lean's at 0.3 to 0.35 deg."""
    return p["lqr"]["imu_flank_torque"] if p.encoder_play_deg >= p["lqr"]["imu_lean_from_play_deg"] else 0.0


class StateSpaces(NamedTuple):
    """python-control models of a Design (see Design.to_statespace)."""

    open_loop: object  # control.StateSpace, continuous
    open_loop_sampled: object  # control.StateSpace, dt = the loop period
    closed_loop: object  # control.StateSpace, dt = the loop period


@dataclass
class Design:
    """The gains the firmware runs, and the models they were designed on (from `design(params)`).

    Conventions: state x = [theta_1..theta_N, dtheta_1..dtheta_N] in deviation from upright
    (z = x - x_upright) [rad, rad/s], theta_i the absolute angle of edge i (pi upright); input u =
    base torque at the output shaft [N m]; measurement y = theta_1 - pi [rad] from the encoder.
    Shapes (n = 2N states): A, Ad (n, n); B, Bd (n, 1); C (1, n); K (1, n) with u = -K z (- w) (- Ku (u_prev + w));
    L (n, 1), the current-estimate observer gain z = z_pred + L (y - C z_pred); Lw the gain of
    the estimated base-torque disturbance w (0: none).

    Attributes: params (Params), rod (RodModel of the design), dt (loop period [s]), A, B
    (continuous linearization about upright), Ad, Bd (zero-order hold at dt), K, L (the sampled
    gains, or the continuous K when params design.method = "continuous"), K_continuous and
    L_continuous (the paper's continuous design, for reference), method, observer_form
    ("current"), checks (controllability, observability, closed_loop_spectral_radius, ...).
    """

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
    Lw: float = 0.0  # gain of the estimated base-torque disturbance w [N m/rad]; u = -K z - w
    w_decay: float = 1.0  # w_pred = w_decay w per period [-] (1: a random walk, < 1: a passing torque)
    imu: ImuEstimator | None = None  # the tip IMU's states and gains (sensors.tip_imu); then L, Lw are its encoder column
    Ku: float = 0.0  # gain on the last period's net torque u_prev + w (lqr.r_torque_rate) [-]; u = -K z - w - Ku (u_prev + w)

    @property
    def N(self) -> int:
        return self.rod.N

    def observer_matrices(self):
        """(Ao, Bo, Co, K, L) of the firmware's estimator with the disturbance state w appended, and with
        Ku the last period's torque u_prev after it: z_pred = Ad z + Bd (u_prev + w), w_pred = w_decay w;
        u = -K z - w - Ku (u_prev + w)."""
        n = 2 * self.N
        m = n + 1 + (self.Ku != 0.0)
        Ao = np.zeros((m, m))
        Ao[:n, :n] = self.Ad
        Ao[:n, n:n + 1] = self.Bd
        Ao[n, n] = self.w_decay
        Bo = np.zeros((m, 1))
        Bo[:n] = self.Bd
        Co = np.zeros((1, m))
        Co[:, :n] = self.C
        Ko = np.zeros((1, m))
        Ko[:, :n] = self.K
        Ko[0, n] = 1.0 + self.Ku
        Lo = np.zeros((m, 1))
        Lo[:n] = self.L
        Lo[n] = self.Lw
        if self.Ku != 0.0:
            Bo[n + 1] = 1.0  # the state u_prev is the last command
            Ko[0, n + 1] = self.Ku
        return Ao, Bo, Co, Ko, Lo

    def flank_feedforward(self) -> float:
        """With the tip IMU: the constant added to u = -K z - w that holds the design model at the lean where
        gravity takes lean_torque(params) (tau0) at the base, the gearbox then always on one flank [N m]:
        the static equilibrium z_ref = -A^-1 B tau0 and u = tau0 - K (z - z_ref); 0 base-only."""
        if self.imu is None:
            return 0.0
        tau0 = lean_torque(self.params)
        z_ref = -np.linalg.solve(self.A, self.B) * tau0
        return float(tau0 - (self.K @ z_ref)[0, 0])

    def estimator(self):
        """(Ao, Bo, Co, K, L) the firmware runs: observer_matrices() with a disturbance state or a torque-rate
        gain, else the plain design (no w: its eigenvalue 1 would not be part of the loop)."""
        if self.Lw == 0.0 and self.Ku == 0.0:
            return self.Ad, self.Bd, self.C, self.K, self.L
        return self.observer_matrices()

    def imu_loop(self, actuator_gain: complex = 1.0, Ad=None, Bd=None, delay: int = 0, C_imu=None,
                 D_imu=None, C_enc=None) -> np.ndarray:
        """The sampled loop with the tip IMU: plant (Ad, Bd; default the design model) read by the encoder
        (C_enc: its row, default theta_1) and the IMU (C_imu, D_imu: the plant's IMU rows, default the design's)
        with the whole estimator."""
        im = self.imu
        Ao, Bo, Co, Do = im.full(self.Ad, self.Bd, self.w_decay)
        Lo = np.vstack([im.L, im.Lw[None, :], im.La])
        Ko = np.hstack([self.K, [[1.0]], np.zeros((1, im.NA))])
        Ap, Bp, Cp, Dp = im.plant(self.Ad if Ad is None else Ad, self.Bd if Bd is None else Bd, C_imu, D_imu, C_enc)
        return imu_closed_loop(Ap, Bp, Cp, Dp, Ao, Bo, Co, Do, Ko, Lo, actuator_gain, delay)

    def loop(self, actuator_gain: complex = 1.0, Ad=None, Bd=None, delay: int = 0) -> np.ndarray:
        """The sampled loop: plant (Ad, Bd; default the design model) with the firmware's estimator;
        delay: extra periods before the command reaches the plant."""
        if self.imu is not None:
            return self.imu_loop(actuator_gain, Ad, Bd, delay)
        Ao, Bo, Co, Ko, Lo = self.estimator()
        return sampled.closed_loop(self.Ad if Ad is None else Ad, self.Bd if Bd is None else Bd, self.C, Ko, Lo,
                                   Ad_obs=Ao, Bd_obs=Bo, actuator_gain=actuator_gain, C_obs=Co, delay=delay)

    def to_statespace(self) -> StateSpaces:
        """python-control StateSpace models: (open_loop, open_loop_sampled, closed_loop).

        open_loop: dz/dt = A z + B u, y = C z (continuous; input torque [N m], output theta_1 - pi [rad]).
        open_loop_sampled: the same held for dt (Ad, Bd, C; dt = the loop period [s]).
        closed_loop: the firmware's sampled loop with its observer and LQR, state [z_k, z_hat_k]
        (plus w_hat with a disturbance estimate) after the measurement update; input a disturbance
        torque d [N m] added to the command and held for one period; outputs [theta_1 - pi [rad],
        commanded torque u [N m]]. Its poles are Design.loop()'s eigenvalues (inside the unit circle).
        """
        import control

        n = self.A.shape[0]
        names = [f"theta_{i}" for i in range(1, self.N + 1)] + [f"dtheta_{i}" for i in range(1, self.N + 1)]
        ol = control.ss(self.A, self.B, self.C, np.zeros((1, 1)), inputs=["torque_Nm"], outputs=["theta_1"],
                        states=names, name="rod_open_loop")
        ols = control.ss(self.Ad, self.Bd, self.C, np.zeros((1, 1)), self.dt, inputs=["torque_Nm"],
                         outputs=["theta_1"], states=names, name="rod_open_loop_sampled")
        Lo, Ko, hats = self.L, self.K, [f"{s}_hat" for s in names]
        if self.Lw != 0.0 or self.Ku != 0.0:
            _, _, _, Ko, Lo = self.observer_matrices()
            hats += ["w_hat"] + (["u_prev"] if self.Ku != 0.0 else [])
        A_cl = self.loop()
        B_cl = np.vstack([self.Bd, Lo @ self.C @ self.Bd])
        C_cl = np.block([[self.C, np.zeros((1, len(hats)))], [np.zeros((1, n)), -Ko]])
        cl = control.ss(A_cl, B_cl, C_cl, np.zeros((2, 1)), self.dt, inputs=["disturbance_Nm"],
                        outputs=["theta_1", "torque_Nm"], states=names + hats, name="rod_closed_loop")
        return StateSpaces(ol, ols, cl)

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
            "L_disturbance": self.Lw,
            "K_torque_prev": self.Ku,  # u = -K z - w - K_torque_prev (u_prev + w) (lqr.r_torque_rate)
            "flank_feedforward_Nm": self.flank_feedforward(),  # with the tip IMU: added to u (lqr.imu_flank_torque)
            "observer_form": self.observer_form,
            "method": self.method,
            "K_continuous": self.K_continuous.tolist(),  # lqr(A, B, Q, R) with this file's weights (Sec. III-A)
            "L_continuous": self.L_continuous.tolist(),  # lqr(A', C', W, V)' (Sec. III-B), for reference
            "state": [f"theta_{i}" for i in range(1, self.N + 1)] + [f"dtheta_{i}" for i in range(1, self.N + 1)],
            "units": {"state": "rad, rad/s (theta = pi upright)", "input": "base torque at the output shaft [N m]", "dt": "s"},
            "closed_loop_spectral_radius": self.checks.get("closed_loop_spectral_radius"),
            "params_sha256": self.params.sha256(),
            **({"imu": self.imu.to_json()} if self.imu is not None else {}),  # then L, L_disturbance: its encoder column
        }


def imu_estimator(p: Params, rod: RodModel, A, B, Ad, Bd, Wd, V_enc, w_decay: float) -> ImuEstimator:
    """The sampled Kalman filter over the design state, the disturbance w, the encoder's offset, the gyro's
    bias and the IMU's readings in flight (ImuEstimator), from the encoder and the tip IMU."""
    dt, n = p.dt, A.shape[0]
    site = ImuSite.on_model(p, rod.N)
    C_imu, D_imu = imu_model.measurement(A, B, rod.l, rod.g, site)
    sg, sa = imu_model.noise(p)
    scale = p["observer"]["imu_noise_scale"]
    V = np.diag([float(V_enc[0, 0]), (scale * sg) ** 2, (scale * sa) ** 2])
    im = ImuEstimator.structure(C_imu, D_imu, imu_model.delay_periods(p), V)
    Af, _, Cf, _ = im.full(Ad, Bd, w_decay)
    W = np.zeros_like(Af)
    W[:n, :n] = Wd
    W[n, n] = max(p["observer"]["process_noise_torque"], 1e-12) * dt
    W[n + 1, n + 1] = p["observer"]["encoder_offset_walk"] * dt
    W[n + 2, n + 2] = imu_model.bias_walk(p) * dt
    vis, lam = sampled.modal_visibility(Af, C=Cf)
    if vis < VISIBILITY_FLOOR:
        raise DesignRefused(f"design refused: the mode at {lam:.4g} of the estimator with the tip IMU is invisible in "
                            f"its readings (modal observability {vis:.2e})")
    Lf, _ = sampled.kalman_current(Af, Cf, W, V)
    im.L, im.Lw, im.La = Lf[:n], Lf[n], Lf[n + 1:]
    return im


def torque_rate_lqr(Ad, Bd, Qd, Rd, Nd, rho: float) -> tuple[np.ndarray, float]:
    """(K, Ku) of the sampled LQR whose cost also weighs the torque's change per period, rho (u_k - u_k-1)^2:
    u_k = -K z_k - Ku u_k-1. The last torque is a state of the design so that fast changes of the torque cost
    something: the buzz once balanced falls, and so does the hold on a much more damped rod's slow mode
    (docs/control.md "The torque buzz")."""
    if rho == 0.0:
        return sampled.dlqr(Ad, Bd, Qd, Rd, Nd)[0], 0.0
    n = Ad.shape[0]
    Aa = np.zeros((n + 1, n + 1))
    Aa[:n, :n] = Ad
    Ba = np.vstack([Bd, [[1.0]]])
    Qa = sla.block_diag(Qd, [[rho]])
    Na = np.vstack([Nd, [[-rho]]])
    Ka, _ = sampled.dlqr(Aa, Ba, Qa, Rd + rho, Na)
    return Ka[:, :n], float(Ka[0, n])


def design(p: Params, progress=None) -> Design:
    """Design the firmware's gains for `p` (a Params from load_params).

    Returns a Design (see its docstring for shapes and conventions). Raises DesignRefused (a
    UserError, exit 3 in the CLI) when the rod is not controllable or observable from theta_1, when
    sampling hides an unstable mode, or when the sampled loop with observer is not stable.
    """
    rod = RodModel.from_params(p, design=True)
    N, dt = rod.N, p.dt
    A, B = linearize_upright(rod)
    C = np.zeros((1, 2 * N))
    C[0, 0] = 1.0
    Q, R, W, V = weights(p, N)

    # a mode decaying by 1e6 within one period is gone before the next sample: at N = 60 the fastest joint damping
    # modes (-1.4e6 rad/s) were refused as "invisible in theta_1" at rounding level (7.7e-14)
    dead_rate_1_s = math.log(DEAD_WITHIN_A_PERIOD) / dt
    ctrb, ctrb_mode = sampled.modal_visibility(A, B=B, dead_below=dead_rate_1_s)
    obsv, obsv_mode = sampled.modal_visibility(A, C=C, dead_below=dead_rate_1_s)
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
        Lw, w_decay = 0.0, 1.0
        qw, tau = p["observer"]["process_noise_torque"], p["observer"]["disturbance_time_constant"]
        if qw > 0:
            # a torque at the base the rod feels beyond the command (friction, k_t error, a push),
            # estimated with the rod and cancelled by the LQR: a random walk, or with a time constant
            # a passing one, which leaves a steady torque to the set-point trim (gains/rodgains/trim.py)
            n = 2 * N
            w_decay = math.exp(-dt / tau) if tau > 0 else 1.0
            Aa = np.block([[Ad, Bd], [np.zeros((1, n)), np.full((1, 1), w_decay)]])
            Ca = np.hstack([C, np.zeros((1, 1))])
            Wa = np.zeros((n + 1, n + 1))
            Wa[:n, :n] = Wd
            Wa[n, n] = qw * dt
            La, _ = sampled.kalman_current(Aa, Ca, Wa, V / dt)
            L, Lw = La[:n], float(La[n, 0])
        imu = None
        if p["sensors"]["tip_imu"]:
            V_enc = np.array([[p["observer"]["imu_measurement_noise"]]])
            imu = imu_estimator(p, rod, A, B, Ad, Bd, Wd, V_enc / dt, w_decay)
            L, Lw = imu.L[:, :1], float(imu.Lw[0])
        Ku = 0.0
        if p["design"]["method"] in ("sampled", "robust"):
            K, Ku = torque_rate_lqr(Ad, Bd, Qd, Rd, Nd, p["lqr"]["r_torque_rate"] / dt)
        else:
            K = K_c
    except (np.linalg.LinAlgError, ValueError) as e:
        raise DesignRefused(f"design refused: discrete Riccati equation failed ({e})") from None

    d = Design(p, rod, dt, A, B, C, Ad, Bd, K, L, K_c, L_c, p["design"]["method"], checks=checks, Lw=Lw,
               w_decay=w_decay, imu=imu, Ku=Ku)
    if d.method == "robust" and imu is not None:
        raise DesignRefused("design refused: design.method = \"robust\" does not refine gains for sensors.tip_imu; "
                            "use \"sampled\"")
    if d.method == "robust":  # the LQG gains refined to hold a family of rods (robust_design.py)
        from .robust_design import refine

        ref = refine(p, dt, *d.estimator(), disturbance=Lw != 0.0, progress=progress)
        d.K, d.L, d.Lw = ref.K, ref.L, ref.Lw
        checks["robust_family_radii"] = ref.radii
        checks["robust_family_radii_lqg"] = ref.radii_lqg
        checks["robust_step"] = ref.step
        checks["robust_runs"] = [ref.agree, ref.runs]
        checks["robust_release"] = ref.release
    rho = sampled.spectral_radius(d.loop())
    checks["closed_loop_spectral_radius"] = rho
    if not np.all(np.isfinite(d.K)) or not np.all(np.isfinite(d.L)):
        raise DesignRefused("design refused: gains are not finite")
    if rho >= 1.0:
        raise DesignRefused(
            f"design refused: sampled closed loop (plant + observer + LQR at {1 / dt:g} Hz, "
            f"method={d.method}) has spectral radius {rho:.3g} >= 1"
        )
    return d
