"""Linearization of the inextensible rod about upright: eqs. (14)-(17), generalized.

The paper prints A and B for a bare rod in terms of two banded matrices. They follow from
the structure of the model: with S the staircase mass pattern (S_ij = N + 1/2 - max(i,j)),
S^-1 is tridiagonal with diagonal (1, 2, ..., 2, 3) and -1 off the diagonal, and

    A_b = -S^-1 Lap,  A_g = S^-1 diag(N + 1/2 - i),  B = S^-1 e_1 / (m l^2).

A base inertia J adds to M_11; by Sherman-Morrison
    M^-1 = (S^-1 - j/(1+j) v v^T) / (m l^2),  v = S^-1 e_1 = e_1 - e_2,  j = J / (m l^2),
so the closed form holds for any N with or without the motor.
"""

from __future__ import annotations

import numpy as np

from .rod_model import RodModel


def staircase_inverse(N: int) -> np.ndarray:
    """Closed-form S^-1: tridiagonal, diagonal (1, 2, ..., 2, 3), off-diagonal -1."""
    Si = 2.0 * np.eye(N) - np.eye(N, k=1) - np.eye(N, k=-1)
    Si[0, 0] = 1.0
    Si[-1, -1] = 3.0
    return Si


def paper_Ab(N: int) -> np.ndarray:
    """Eq. (16) as printed (valid for N >= 5): bending pattern, finite differences of d^4/ds^4."""
    if N < 5:
        raise ValueError("the printed band pattern of eq. (16) needs N >= 5")
    Ab = np.zeros((N, N))
    for i in range(N):
        for j, v in zip(range(i - 2, i + 3), (-1.0, 4.0, -6.0, 4.0, -1.0)):
            if 0 <= j < N:
                Ab[i, j] = v
    Ab[0, :3] = (-2.0, 3.0, -1.0)
    Ab[1, :4] = (3.0, -6.0, 4.0, -1.0)
    Ab[-2, -4:] = (-1.0, 4.0, -6.0, 3.0)
    Ab[-1, -3:] = (-1.0, 5.0, -4.0)
    return Ab


def paper_Ag(N: int) -> np.ndarray:
    """Eq. (17) as printed: a_1 = N - 1/2, a_i = 2(N - i) + 1, a_N = 3/2, b_i = i - N + 1/2, c_i = i - N - 1/2."""
    i = np.arange(1, N + 1, dtype=float)
    a = 2.0 * (N - i) + 1.0
    a[0] = N - 0.5
    a[-1] = 1.5
    k = np.arange(1, N, dtype=float)
    return np.diag(a) + np.diag(k - N + 0.5, 1) + np.diag(k - N - 0.5, -1)


def inverse_mass_upright(rod: RodModel) -> np.ndarray:
    """M^-1 at upright in closed form (Sherman-Morrison for the base inertia); a rod carrying point
    masses (the tip IMU) breaks the staircase's closed-form inverse and is inverted directly."""
    ml2 = rod.m * rod.l**2
    if rod.extra_mass:
        M = ml2 * rod.staircase.copy()
        M[0, 0] += rod.J
        return np.linalg.inv(M)
    Si = staircase_inverse(rod.N)
    j = rod.J / ml2
    v = Si[:, 0]
    return (Si - (j / (1.0 + j)) * np.outer(v, v)) / ml2


def linearize_upright(rod: RodModel) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of z' = A z + B u about theta_i = pi, rates 0, T = 0 (eq. 14).

    z = [theta - pi, dtheta]; u = base torque [N m]. With J = b = 0 this is eq. (15):
    A = [[0, I], [EI/(m l^3) A_b + g/l A_g, d/(m l^2) A_b]], B = [0; 1/(ml^2), -1/(ml^2), 0, ...].
    """
    N = rod.N
    Mi = inverse_mass_upright(rod)
    stiffness = (rod.EI / rod.l) * rod.laplacian - rod.m * rod.g * rod.l * np.diag(rod.mass_below)
    damping = rod.d * rod.laplacian
    damping[0, 0] += rod.b
    A = np.zeros((2 * N, 2 * N))
    A[:N, N:] = np.eye(N)
    A[N:, :N] = -Mi @ stiffness
    A[N:, N:] = -Mi @ damping
    B = np.zeros((2 * N, 1))
    B[N:, 0] = Mi[:, 0]
    return A, B


def paper_linearization(rod: RodModel) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (15) assembled literally from the printed A_b and A_g (bare rod, J = b = 0)."""
    N, l, m = rod.N, rod.l, rod.m
    Ab = paper_Ab(N)
    A = np.zeros((2 * N, 2 * N))
    A[:N, N:] = np.eye(N)
    A[N:, :N] = rod.EI / (m * l**3) * Ab + rod.g / l * paper_Ag(N)
    A[N:, N:] = rod.d / (m * l**2) * Ab
    B = np.zeros((2 * N, 1))
    B[N, 0] = 1.0 / (m * l**2)
    B[N + 1, 0] = -1.0 / (m * l**2)
    return A, B


def numerical_jacobian(rod: RodModel, eps: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """Central differences of the nonlinear f(q, T) of eq. (13) about upright."""
    q0 = rod.upright
    n = q0.size
    A = np.zeros((n, n))
    for k in range(n):
        dq = np.zeros(n)
        dq[k] = eps
        A[:, k] = (rod.f(q0 + dq, 0.0) - rod.f(q0 - dq, 0.0)) / (2 * eps)
    B = ((rod.f(q0, eps) - rod.f(q0, -eps)) / (2 * eps))[:, None]
    return A, B
