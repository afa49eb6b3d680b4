"""Sampled-data building blocks: ZOH discretization, discretized costs and noise, loop analysis.

The rod's fast modes reach 5e4 rad/s at N = 20, so e^{A t} spans e^{-50} over one 1 ms
period. Van Loan's block-exponential formula for the integrals then cancels catastrophically;
here the integrals are built by interval doubling, X(2t) = X(t) + Phi(t)^T X(t) Phi(t), which
only ever adds positive semidefinite terms.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla


def zoh(A: np.ndarray, B: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretization (Ad, Bd)."""
    n, m = B.shape
    F = np.zeros((n + m, n + m))
    F[:n, :n] = A
    F[:n, n:] = B
    E = sla.expm(F * dt)
    return E[:n, :n], E[:n, n:]


def _gramian_integral(F: np.ndarray, W: np.ndarray, dt: float, outer: bool) -> np.ndarray:
    """Integral over [0, dt] of Phi(t)^T W Phi(t) (outer=False) or Phi(t) W Phi(t)^T (outer=True)."""
    k = max(0, int(np.ceil(np.log2(max(np.linalg.norm(F, 1) * dt, 1e-12) / 0.05))) + 1)
    h = dt / 2**k
    Phi_h2 = sla.expm(F * h / 2)
    Phi_h = Phi_h2 @ Phi_h2

    def sandwich(P, X):
        return P @ X @ P.T if outer else P.T @ X @ P

    X = h / 6.0 * (W + 4.0 * sandwich(Phi_h2, W) + sandwich(Phi_h, W))  # Simpson on [0, h]
    Phi = Phi_h
    for _ in range(k):
        X = X + sandwich(Phi, X)
        Phi = Phi @ Phi
    return 0.5 * (X + X.T)


def sampled_cost(A, B, Q, R, dt):
    """(Qd, Rd, Nd): the continuous cost integral of (x'Qx + u'Ru) over one period with u held."""
    n, m = B.shape
    F = np.zeros((n + m, n + m))
    F[:n, :n] = A
    F[:n, n:] = B
    W = sla.block_diag(Q, R)
    X = _gramian_integral(F, W, dt, outer=False)
    return X[:n, :n], X[n:, n:], X[:n, n:]


def sampled_process_noise(A, Wc, dt):
    """Covariance added over one period by continuous white process noise of intensity Wc."""
    return _gramian_integral(A, Wc, dt, outer=True)


def dlqr(Ad, Bd, Qd, Rd, Nd):
    P = sla.solve_discrete_are(Ad, Bd, Qd, Rd, s=Nd)
    K = np.linalg.solve(Rd + Bd.T @ P @ Bd, Bd.T @ P @ Ad + Nd.T)
    return K, P


def kalman_current(Ad, C, Wd, V):
    """Current-estimate (filter) gain L = P C^T (C P C^T + V)^-1, P the prior covariance.

    The firmware runs x_pred = Ad x_prev + Bd u_prev; x = x_pred + L (y - C x_pred); u = -K x,
    so L must be the filter form, not the predictor gain Ad P C^T (...)^-1 of python-control's dlqe.
    """
    P = sla.solve_discrete_are(Ad.T, C.T, Wd, V)
    L = P @ C.T @ np.linalg.inv(C @ P @ C.T + V)
    return L, P


def closed_loop(Ad, Bd, C, K, L, Ad_obs=None, Bd_obs=None, actuator_gain: complex = 1.0, C_obs=None,
                delay: int = 0):
    """Linear sampled loop: plant (Ad, Bd) with the firmware's observer (Ad_obs, Bd_obs) and LQR.

    State [x_k, xhat_k] after the measurement update at step k. The actuator multiplies the
    command by `actuator_gain` (real: gain margin, unit complex: phase margin); the observer
    predicts with the command it sent. The observer may carry more states than the plant (an
    estimated input disturbance): then Ad_obs, Bd_obs, C_obs and K are the observer's size.
    delay: extra periods before the command reaches the plant (the observer does not know); the
    state then ends with the commands in flight [u_k, ..., u_{k-delay+1}].
    """
    Ao = Ad if Ad_obs is None else Ad_obs
    Bo = Bd if Bd_obs is None else Bd_obs
    no = Ao.shape[0]
    LC = L @ C
    LCo = LC if C_obs is None else L @ C_obs
    I = np.eye(no)
    if delay == 0:
        top = np.hstack([Ad, -actuator_gain * Bd @ K])
        bottom = np.hstack([LC @ Ad, (I - LCo) @ (Ao - Bo @ K) - actuator_gain * LC @ Bd @ K])
        return np.vstack([top, bottom])
    npl = Ad.shape[0]
    n = npl + no + delay
    M = np.zeros((n, n), dtype=np.result_type(Ad, actuator_gain))
    M[:npl, :npl] = Ad
    M[:npl, n - 1:] = actuator_gain * Bd  # the plant runs on the oldest command in flight
    M[npl:npl + no, :npl] = LC @ Ad
    M[npl:npl + no, npl:npl + no] = (I - LCo) @ (Ao - Bo @ K)
    M[npl:npl + no, n - 1:] = actuator_gain * LC @ Bd
    M[npl + no, npl:npl + no] = -K[0]
    for i in range(1, delay):
        M[npl + no + i, npl + no + i - 1] = 1.0
    return M


def spectral_radius(M: np.ndarray) -> float:
    return float(np.max(np.abs(np.linalg.eigvals(M))))


def modal_visibility(A: np.ndarray, B: np.ndarray | None = None, C: np.ndarray | None = None,
                     unstable_only_discrete: bool = False, dead_below: float = -np.inf) -> tuple[float, complex]:
    """Worst modal controllability |w_i^T B| (left eigenvectors) or observability |C v_i| (right).

    Each eigenvector is normalized, so the number is the fraction of a unit mode the input
    reaches or the output sees; 0 means uncontrollable/unobservable. The paper's rod is
    observable from theta_1 in exact arithmetic, but its fastest damping modes are faint
    (3e-10 at N = 20), so an unscaled PBH rank test calls them unobservable. Returns
    (worst value, its eigenvalue); unstable_only_discrete restricts to |lambda| >= 1; dead_below [1/s] leaves out
    the continuous modes decaying faster (gone within a sample: neither the sampled estimator nor the torque
    has anything of them to see or move).
    """
    lam, V = np.linalg.eig(A)
    if C is not None:
        vis = np.linalg.norm(C @ V, axis=0) / np.linalg.norm(V, axis=0)
    else:
        W = np.linalg.inv(V)
        vis = np.linalg.norm(W @ B, axis=1) / np.linalg.norm(W, axis=1)
    if dead_below > -np.inf:
        keep = lam.real >= dead_below
        lam, vis = lam[keep], vis[keep]
    if unstable_only_discrete:
        keep = np.abs(lam) >= 1.0
        if not np.any(keep):
            return float("inf"), 0j
        lam, vis = lam[keep], vis[keep]
    i = int(np.argmin(vis))
    return float(vis[i]), complex(lam[i])


def stable_gain_interval(loop, tol: float = 1e-3) -> tuple[float, float]:
    """Actuator gains [lo, hi] around 1 that keep the loop stable (`loop(alpha)` gives its matrix)."""

    def stable(a):
        return spectral_radius(loop(a)) < 1.0

    def edge(a_in, a_out):
        for _ in range(60):
            mid = 0.5 * (a_in + a_out)
            if stable(mid):
                a_in = mid
            else:
                a_out = mid
            if abs(a_out - a_in) < tol * max(abs(a_in), 1e-9):
                break
        return a_in

    hi = 1.0
    while hi < 1e4 and stable(hi * 2):
        hi *= 2
    hi = edge(hi, hi * 2) if hi < 1e4 else float("inf")
    lo = 1.0
    while lo > 1e-4 and stable(lo / 2):
        lo /= 2
    lo = edge(lo, lo / 2) if lo > 1e-4 else 0.0
    return lo, hi


def phase_margin(loop, step_deg: float = 1.0) -> float:
    """Smallest phase rotation [deg] of the actuator that destabilizes the loop (scan, then bisect)."""

    def stable(deg):
        return spectral_radius(loop(np.exp(1j * np.radians(deg)))) < 1.0

    prev = 0.0
    deg = step_deg
    while deg <= 180.0:
        if not (stable(deg) and stable(-deg)):
            lo, hi = prev, deg
            for _ in range(30):
                mid = 0.5 * (lo + hi)
                if stable(mid) and stable(-mid):
                    lo = mid
                else:
                    hi = mid
            return lo
        prev = deg
        deg += step_deg
    return 180.0
