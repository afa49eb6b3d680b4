"""Extensible planar discrete elastic rod (PDER), eqs. (3)-(5), in node coordinates.

Generalized coordinates: phi, the motor shaft angle (= theta_1), and the Cartesian positions
of nodes 2..N [m]. Node 0 is on the motor axis. The rod is clamped in the shaft hub, so
edge 1 turns with the shaft and keeps its rest length l; node 1 = l (sin phi, -cos phi).
Edges 2..N stretch (E_s), every interior node bends (E_b, kappa = 2 tan(turning/2)), and all
nodes carry gravity (E_g). The base torque acts on phi, which also carries the reflected motor
inertia J and friction b, so the plant and the inextensible model share their input and output.

Damping is the paper's d on the relative angular velocity of neighbouring edges
(edge rate omega_k = (e_k x de_k/dt) / |e_k|^2), which reduces to eq. (11) when edges keep
their length. Stretching is undamped, as in the paper's PDER.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .params import Params
from .rod_model import RodModel


def _perp(v: np.ndarray) -> np.ndarray:
    """Rotate +90 deg in the plane: (x, y) -> (-y, x)."""
    return np.stack([-v[..., 1], v[..., 0]], axis=-1)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


@dataclass(frozen=True)
class DERModel:
    N: int
    l: float
    m: float
    EI: float
    EA: float
    d: float
    g: float
    J: float = 0.0
    b: float = 0.0

    @classmethod
    def from_params(cls, p: Params, design: bool = False, edges: int | None = None) -> "DERModel":
        rod = RodModel.from_params(p, design=design, edges=edges)
        return cls(N=rod.N, l=rod.l, m=rod.m, EI=rod.EI, EA=p.EA, d=rod.d, g=rod.g, J=rod.J, b=rod.b)

    # state: q = [phi, x_2, y_2, ..., x_N, y_N], qd its rate
    @property
    def size(self) -> int:
        return 1 + 2 * (self.N - 1)

    @property
    def node_masses(self) -> np.ndarray:
        """m_0..m_N [kg]: m/2 at both ends, m inside."""
        mk = np.full(self.N + 1, self.m)
        mk[0] = mk[-1] = 0.5 * self.m
        return mk

    @property
    def mass_diagonal(self) -> np.ndarray:
        """Diagonal generalized mass: J + m_1 l^2 for phi, then m_k for x_k and y_k (k >= 2)."""
        mk = self.node_masses
        return np.concatenate([[self.J + mk[1] * self.l**2], np.repeat(mk[2:], 2)])

    def nodes(self, q: np.ndarray) -> np.ndarray:
        """x_0..x_N, shape (N+1, 2) [m]."""
        xy = np.zeros((self.N + 1, 2))
        xy[1] = self.l * np.array([np.sin(q[0]), -np.cos(q[0])])
        xy[2:] = q[1:].reshape(-1, 2)
        return xy

    def node_velocities(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        v = np.zeros((self.N + 1, 2))
        v[1] = self.l * qd[0] * np.array([np.cos(q[0]), np.sin(q[0])])
        v[2:] = qd[1:].reshape(-1, 2)
        return v

    # --- energy (eq. 4) and its gradient in node coordinates ---------------------------
    def energy_terms(self, q: np.ndarray) -> dict[str, float]:
        x = self.nodes(q)
        e = np.diff(x, axis=0)
        r = np.linalg.norm(e, axis=1)
        stretch = 0.5 * self.EA * self.l * np.sum((r[1:] / self.l - 1.0) ** 2)
        kappa = 2.0 * _cross(e[:-1], e[1:]) / (r[:-1] * r[1:] + np.sum(e[:-1] * e[1:], axis=1))
        bend = 0.5 * (self.EI / self.l) * np.sum(kappa**2)
        grav = self.g * np.sum(self.node_masses * x[:, 1])
        return {"stretch": float(stretch), "bend": float(bend), "gravity": float(grav)}

    def energy(self, q: np.ndarray, qd: np.ndarray) -> float:
        kinetic = 0.5 * np.sum(self.mass_diagonal * qd**2)
        return float(kinetic + sum(self.energy_terms(q).values()))

    def node_gradient(self, q: np.ndarray) -> np.ndarray:
        """dE_t/dx_k for k = 0..N, shape (N+1, 2) [N]."""
        x = self.nodes(q)
        e = np.diff(x, axis=0)
        r = np.linalg.norm(e, axis=1)
        t = e / r[:, None]
        ge = np.zeros_like(e)  # dE/de_k
        ge[1:] += (self.EA * (r[1:] / self.l - 1.0))[:, None] * t[1:]
        a, bvec = e[:-1], e[1:]
        c = _cross(a, bvec)
        s = r[:-1] * r[1:] + np.sum(a * bvec, axis=1)
        kappa = 2.0 * c / s
        dEdk = (self.EI / self.l) * kappa
        ds_da = (r[1:] / r[:-1])[:, None] * a + bvec
        ds_db = (r[:-1] / r[1:])[:, None] * bvec + a
        dk_da = 2.0 * (-_perp(bvec) * s[:, None] - c[:, None] * ds_da) / (s**2)[:, None]
        dk_db = 2.0 * (_perp(a) * s[:, None] - c[:, None] * ds_db) / (s**2)[:, None]
        ge[:-1] += dEdk[:, None] * dk_da
        ge[1:] += dEdk[:, None] * dk_db
        gx = np.zeros_like(x)
        gx[1:] += ge
        gx[:-1] -= ge
        gx[:, 1] += self.g * self.node_masses
        return gx

    def edge_rates(self, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """omega_k = (e_k x de_k/dt) / |e_k|^2 [rad/s]; eq. (6) for a stretched edge."""
        x = self.nodes(q)
        v = self.node_velocities(q, qd)
        e, de = np.diff(x, axis=0), np.diff(v, axis=0)
        return _cross(e, de) / np.sum(e * e, axis=1)

    def generalized_force(self, q: np.ndarray, qd: np.ndarray, torque: float) -> np.ndarray:
        """-dE/dq - dR/dqd + input, R = d/2 sum (omega_k+1 - omega_k)^2 + b/2 phi'^2."""
        gx = self.node_gradient(q)
        x = self.nodes(q)
        e = np.diff(x, axis=0)
        w = self.edge_rates(q, qd)
        dw = self.d * np.diff(w)  # d (omega_{k+1} - omega_k), k = 1..N-1
        # dR/d(omega_k) for each edge, then omega_k depends on de_k via perp(e_k)/|e_k|^2
        dR_dw = np.zeros(self.N)
        dR_dw[:-1] -= dw
        dR_dw[1:] += dw
        dR_dde = dR_dw[:, None] * _perp(e) / np.sum(e * e, axis=1)[:, None]
        dR_dv = np.zeros_like(x)
        dR_dv[1:] += dR_dde
        dR_dv[:-1] -= dR_dde
        # edge 1 turns with the shaft (omega_1 = phi'), and node 1 moves edge 2's rate too
        tangent1 = self.l * np.array([np.cos(q[0]), np.sin(q[0])])  # d x_1 / d phi
        F = np.empty(self.size)
        F[0] = torque - gx[1] @ tangent1 - dR_dw[0] + dR_dde[1] @ tangent1 - self.b * qd[0]
        F[1:] = -(gx[2:] + dR_dv[2:]).ravel()
        return F

    def accel(self, q: np.ndarray, qd: np.ndarray, torque: float) -> np.ndarray:
        return self.generalized_force(q, qd, torque) / self.mass_diagonal

    # --- conversions to and from the inextensible state (eq. 6) ---------------------------
    def from_angles(self, theta: np.ndarray, dtheta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """DER state of an unstretched rod with edge angles theta and rates dtheta."""
        rod_x = np.cumsum(self.l * np.stack([np.sin(theta), -np.cos(theta)], axis=1), axis=0)
        rod_v = np.cumsum(self.l * dtheta[:, None] * np.stack([np.cos(theta), np.sin(theta)], axis=1), axis=0)
        q = np.concatenate([[theta[0]], rod_x[1:].ravel()])
        qd = np.concatenate([[dtheta[0]], rod_v[1:].ravel()])
        return q, qd

    def to_angles(self, q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Edge angles (unwrapped next to theta_1) and rates, eq. (6)."""
        e = np.diff(self.nodes(q), axis=0)
        th = np.unwrap(np.arctan2(e[:, 0], -e[:, 1]))
        th += 2.0 * np.pi * np.round((q[0] - th[0]) / (2.0 * np.pi))
        return th, self.edge_rates(q, qd)
