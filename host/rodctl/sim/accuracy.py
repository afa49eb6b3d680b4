"""Integrator accuracy of the C plant against scipy's Radau at tight tolerance.

The scenario is deliberately violent and nonlinear: the rod starts bent (theta_i from 2.2 to
2.6 rad, at rest) and is driven by a random piecewise-constant torque (+-0.05 N m, new value every
0.1 s, held per 1 ms control period), so it swings through large angles at up to 30-40 rad/s.

    python -m rodctl.sim.accuracy            # the table for N = 5 and 20, both plants

The reference integrates the Python model (gains/rodgains/rod_model.py, gains/rodgains/der_model.py) with Radau;
`rhs="c"` integrates the C model's own derivative instead (same equations, checked against the
Python model to 1e-11 in tests/test_plant.py), which is ~20x faster for the DER.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
from scipy.integrate import solve_ivp

from rodgains.params import Params

from rodctl.sim.plant import Plant


def scenario(N: int, seconds: float = 2.0, seed: int = 1, amplitude: float = 0.05, hold: float = 0.1):
    """(theta0, torques, hold): a bent rod at rest and a torque per `hold` seconds."""
    theta0 = 2.2 + 0.4 * np.linspace(0.0, 1.0, N) ** 2
    rng = np.random.default_rng(seed)
    return theta0, rng.uniform(-amplitude, amplitude, int(round(seconds / hold))), hold


def _python_rhs(plant: Plant):
    model = plant.model()
    if plant.kind == "inextensible":
        return lambda y, T: model.f(y, T)
    n = plant.n
    return lambda y, T: np.concatenate([y[n:], model.accel(y[:n], y[n:], T)])


def reference(plant: Plant, theta0, torques, hold: float, sample: float = 0.01, rhs: str = "python",
              rtol: float = 1e-10, atol: float = 1e-12) -> np.ndarray:
    """Raw states y = [q, qd] every `sample` seconds (first row: the initial state), by Radau."""
    f = _python_rhs(plant) if rhs == "python" else (lambda y, T: plant.deriv(y, T))
    keep = plant.raw_state()
    plant.set_state(theta0)
    y = np.concatenate(plant.raw_state())
    plant.set_raw_state(*keep)
    per = int(round(hold / sample))
    out = [y]
    for T in torques:
        t_eval = sample * np.arange(1, per + 1)
        sol = solve_ivp(lambda t, yy: f(yy, T), (0.0, hold), y, method="Radau", t_eval=t_eval, rtol=rtol, atol=atol)
        if not sol.success:
            raise RuntimeError(f"Radau failed: {sol.message}")
        out += list(sol.y.T)
        y = sol.y[:, -1]
    return np.array(out)


def simulate(plant: Plant, theta0, torques, hold: float, sample: float = 0.01, period: float = 1e-3) -> np.ndarray:
    """The plant's raw states every `sample` seconds, advancing one control period at a time."""
    plant.set_state(theta0)
    per, sub = int(round(hold / sample)), int(round(sample / period))
    out = [np.concatenate(plant.raw_state())]
    for T in torques:
        for _ in range(per):
            for _ in range(sub):
                plant.advance(float(T), period)
            out.append(np.concatenate(plant.raw_state()))
    return np.array(out)


def edge_angles(plant: Plant, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Edge angles and rates of raw states (the Python model's eq. 6 for the DER)."""
    if plant.kind == "inextensible":
        return Y[:, :plant.N], Y[:, plant.N:]
    der, n = plant.model(), plant.n
    ang = [der.to_angles(y[:n], y[n:]) for y in Y]
    return np.array([a[0] for a in ang]), np.array([a[1] for a in ang])


def accuracy(params: Params | None = None, kind: str = "inextensible", edges: int = 5, method: str = "auto",
             seconds: float = 2.0, rhs: str = "python", rtol: float = 1e-10, atol: float = 1e-12,
             step: float | None = None) -> dict[str, Any]:
    """Max angle and rate errors of the plant (automatic step unless given) against Radau."""
    plant = Plant(params, kind=kind, edges=edges, method=method, step=step)
    theta0, torques, hold = scenario(edges, seconds)
    t0 = time.perf_counter()
    ref = reference(plant, theta0, torques, hold, rhs=rhs, rtol=rtol, atol=atol)
    t_ref = time.perf_counter() - t0
    sim = simulate(plant, theta0, torques, hold)
    a_ref, r_ref = edge_angles(plant, ref)
    a_sim, r_sim = plant_angles(plant, sim)
    return {"kind": kind, "edges": edges, "method": plant.method, "step": plant.step, "seconds": seconds,
            "max_angle_error": float(np.abs(a_sim - a_ref).max()), "max_rate_error": float(np.abs(r_sim - r_ref).max()),
            "max_rate": float(np.abs(r_ref).max()), "reference": rhs, "reference_seconds": t_ref,
            "reference_states": ref}


def plant_angles(plant: Plant, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Edge angles and rates of raw states by the C plant's own conversion."""
    keep = plant.raw_state()
    th, w = [], []
    for y in Y:
        plant.set_raw_state(y[:plant.n], y[plant.n:])
        a, b = plant.state()
        th.append(a)
        w.append(b)
    plant.set_raw_state(*keep)
    return np.array(th), np.array(w)


def main() -> int:
    print("automatic step for each method; * marks the method 'auto' picks")
    print(f"{'plant':>12} {'N':>3} {'method':>7} {'step ms':>8} {'max angle err':>14} {'max rate err':>13}  reference")
    for kind, N, rhs in (("inextensible", 5, "python"), ("inextensible", 20, "python"), ("der", 5, "python"),
                         ("der", 20, "c")):
        methods = ("rk4", "ros2") if kind == "inextensible" else ("verlet",)
        for m in methods:
            r = accuracy(kind=kind, edges=N, method=m, rhs=rhs)
            star = "*" if Plant(kind=kind, edges=N).method == m else " "
            print(f"{kind:>12} {N:3d} {r['method'] + star:>7} {1e3 * r['step']:8.4f} {r['max_angle_error']:14.2e} "
                  f"{r['max_rate_error']:13.2e}  Radau on the {rhs} model, {r['seconds']:.0f} s "
                  f"(rates up to {r['max_rate']:.0f} rad/s)", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
