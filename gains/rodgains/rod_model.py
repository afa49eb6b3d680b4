"""Inextensible N-link rod with nonlinear torsional springs: eqs. (7)-(13) of the paper.

State q = [theta_1..theta_N, dtheta_1..dtheta_N]: absolute edge angles [rad] with 0 hanging
down and pi upright, and their rates [rad/s]. Input T: torque on edge 1 at the motor axis
[N m], positive accelerating theta_1. Node 0 sits on the axis.

Departures from the printed paper (see docs/physics-notes.md):
- eq. (10) gravity uses sin(theta_i) for every i (the paper prints sin(theta_1));
- the motor adds a base inertia J to M_11 and a viscous friction b to D_11 (J = b = 0 is the paper).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .params import Params


DAMPING_REFERENCE_EDGES = 5  # rod.damping is the joint damping of Table I's N = 5 rod (Kelvin-Voigt)


def _read_only(a: np.ndarray) -> np.ndarray:
    """A cached array no caller can change in place."""
    a.setflags(write=False)
    return a


@dataclass(frozen=True)
class RodModel:
    N: int
    l: float  # edge length [m]
    m: float  # edge mass [kg]
    EI: float  # bending stiffness [N m^2]
    d: float  # inter-edge damping [N m s/rad]
    g: float  # gravity [m/s^2]
    J: float = 0.0  # base inertia at the output shaft [kg m^2]
    b: float = 0.0  # base viscous friction [N m s/rad]
    extra_mass: tuple[float, ...] = ()  # point masses at nodes 0..N beyond the rod's own (the tip IMU) [kg]

    @classmethod
    def from_params(cls, p: Params, design: bool = True, edges: int | None = None) -> "RodModel":
        """The rod of `p`; `design=True` uses the motor terms the gains assume, else the physical ones."""
        r = p["rod"]
        N = edges or p.N
        l = r["length"] / N
        extra = ()
        if p["sensors"]["tip_imu"]:
            from .imu import ImuSite

            extra = tuple(float(v) for v in ImuSite.on_model(p, N).node_masses(N, p["sensors"]["imu_mass"]))
        return cls(
            N=N,
            l=l,
            m=r["density"] * r["width"] * r["thickness"] * l,
            EI=p.EI,
            d=r["damping"],
            g=r["gravity"],
            J=p.design_base_inertia if design else p.base_inertia,
            b=p.design_base_friction if design else p.base_friction,
            extra_mass=extra,
        )

    def kelvin_voigt(self) -> "RodModel":
        """The same rod with its joint damping scaled as a continuum's (Kelvin-Voigt): Table I's
        5-edge value x N / 5, as the family of the robust design and the simulated plant use it."""
        return dataclasses.replace(self, d=self.d * self.N / DAMPING_REFERENCE_EDGES)

    # --- constant structure (computed once per rod: f() runs thousands of times a simulation) ---
    @cached_property
    def mass_below(self) -> np.ndarray:
        """c_i = N + 1/2 - i: mass beyond node i-1 in units of m (node masses m/2, m, ..., m, m/2), plus
        the point masses of extra_mass beyond it."""
        c = self.N + 0.5 - np.arange(1, self.N + 1)
        if self.extra_mass:
            c = c + np.cumsum(np.asarray(self.extra_mass)[::-1])[::-1][1:] / self.m
        return _read_only(c)

    @cached_property
    def staircase(self) -> np.ndarray:
        """S_ij = c_max(i,j): M(theta) / (m l^2) at cos(theta_i - theta_j) = 1."""
        c = self.mass_below
        idx = np.arange(self.N)
        return _read_only(c[np.maximum.outer(idx, idx)])

    @cached_property
    def laplacian(self) -> np.ndarray:
        """Path-graph Laplacian: the pattern of D in eq. (11) and of the linearized bending springs."""
        N = self.N
        Lp = 2.0 * np.eye(N) - np.eye(N, k=1) - np.eye(N, k=-1)
        Lp[0, 0] = Lp[-1, -1] = 1.0
        return _read_only(Lp)

    # --- eqs. (8)-(12) ------------------------------------------------------------------
    def mass_matrix(self, theta: np.ndarray) -> np.ndarray:
        M = self.m * self.l**2 * np.cos(np.subtract.outer(theta, theta)) * self.staircase
        M[0, 0] += self.J
        return M

    def coriolis(self, theta: np.ndarray, dtheta: np.ndarray) -> np.ndarray:
        return self.m * self.l**2 * (np.sin(np.subtract.outer(theta, theta)) * self.staircase) @ (dtheta**2)

    def potential_gradient(self, theta: np.ndarray) -> np.ndarray:
        """V(theta) = dE/dtheta: bending (kappa = 2 tan(phi/2), straight rest shape) plus gravity."""
        half = 0.5 * np.diff(theta)
        # dE_b/dphi_k for E_b = (EI / 2l) kappa_k^2
        dEb = (self.EI / self.l) * 2.0 * np.tan(half) / np.cos(half) ** 2
        V = np.zeros(self.N)
        V[:-1] -= dEb
        V[1:] += dEb
        V += self.m * self.g * self.l * self.mass_below * np.sin(theta)
        return V

    def damping_force(self, dtheta: np.ndarray) -> np.ndarray:
        D = self.d * (self.laplacian @ dtheta)
        D[0] += self.b * dtheta[0]
        return D

    def accel(self, theta: np.ndarray, dtheta: np.ndarray, torque: float) -> np.ndarray:
        """h(theta, dtheta, T) of eq. (7) [rad/s^2]."""
        rhs = -(self.coriolis(theta, dtheta) + self.potential_gradient(theta) + self.damping_force(dtheta))
        rhs[0] += torque
        return np.linalg.solve(self.mass_matrix(theta), rhs)

    def f(self, q: np.ndarray, torque: float) -> np.ndarray:
        """Eq. (13): dq/dt."""
        th, dth = q[: self.N], q[self.N :]
        return np.concatenate([dth, self.accel(th, dth, torque)])

    # --- energy and geometry -------------------------------------------------------------
    def energy(self, q: np.ndarray) -> float:
        """Kinetic + bending + gravitational energy [J] (gravity zero at the axis height)."""
        th, dth = q[: self.N], q[self.N :]
        kinetic = 0.5 * dth @ self.mass_matrix(th) @ dth
        bending = 0.5 * (self.EI / self.l) * np.sum((2.0 * np.tan(0.5 * np.diff(th))) ** 2)
        gravity = self.g * self.m * self.l * np.sum(-self.mass_below * np.cos(th))
        return float(kinetic + bending + gravity)

    def nodes(self, theta: np.ndarray) -> np.ndarray:
        """Node positions x_0..x_N, shape (N+1, 2) [m], node 0 at the axis, y up."""
        xy = np.zeros((self.N + 1, 2))
        xy[1:, 0] = np.cumsum(self.l * np.sin(theta))
        xy[1:, 1] = np.cumsum(-self.l * np.cos(theta))
        return xy

    @property
    def upright(self) -> np.ndarray:
        return np.concatenate([np.full(self.N, np.pi), np.zeros(self.N)])
