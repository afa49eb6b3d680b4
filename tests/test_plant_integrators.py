"""The plant's integrators: accuracy against scipy Radau, stability over long runs, energy drift.

Measured (Table I + the physical motor, automatic steps; see `python -m rodctl.sim.accuracy`):
  inextensible N=5  RK4  h=1 ms      max angle error ~4e-7 rad over 2 s
  inextensible N=5  ROS2 h=0.58 ms   ~1e-3 rad
  inextensible N=20 ROS2 h=0.175 ms  ~5e-4 rad
  DER N=5  Verlet h=0.674 ms         ~9e-5 rad
  DER N=20 Verlet h=0.166 ms         ~3e-5 rad
One encoder count is 6.4e-3 rad. Each bound below is about 2-3x the measured error.
`pytest --full-reference` also integrates the DER references on the Python model (minutes; conftest.py).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from rodgains.params import load_params
from rodctl.sim.accuracy import accuracy, edge_angles, plant_angles, reference, scenario, simulate
from rodctl.sim.plant import Plant

P = load_params()


def report(r):
    print(f"\n{r['kind']} N={r['edges']} {r['method']} h={1e3 * r['step']:.4f} ms: max angle error "
          f"{r['max_angle_error']:.2e} rad, max rate error {r['max_rate_error']:.2e} rad/s over {r['seconds']} s "
          f"(rates to {r['max_rate']:.0f} rad/s; Radau on the {r['reference']} model)")


# --- the automatic choice ----------------------------------------------------------------------

def test_automatic_integrator_choice_for_table_1():
    """These choices set the simulator's speed: steps per 1 ms period 1, 6, 2 and 7."""
    expect = {("inextensible", 5): ("rk4", 1), ("inextensible", 20): ("ros2", 6), ("der", 5): ("verlet", 2),
              ("der", 20): ("verlet", 7)}
    for (kind, N), (method, steps) in expect.items():
        plant = Plant(P, kind=kind, edges=N)
        assert plant.method == method
        assert math.ceil(1e-3 / plant.step * (1 - 1e-6)) == steps, (kind, N, plant.step)
    info = Plant(P, edges=20).integrator
    assert 560 < info["omega_osc"] < 580  # the lightly damped modes
    assert 5.0e4 < info["rho"] < 5.3e4  # the stiff overdamped ones: RK4 would need h < 4e-5 s
    assert 5900 < Plant(P, kind="der", edges=20).integrator["omega_elastic"] < 6200  # axial modes


def test_choice_follows_stiffness():
    """RK4 while the stiffest mode allows about the control period, ROS2 beyond."""
    for N in (3, 5, 8, 10):
        assert Plant(P, edges=N).method == "rk4", N
    stiff = Plant(P, edges=5, d=0.01)  # ten times the damping: a -6500 rad/s mode
    assert stiff.integrator["rho"] > 6000 and stiff.method == "ros2"
    assert stiff.step == 1e-3  # the slow modes need no more


# --- accuracy against Radau ---------------------------------------------------------------------

@pytest.fixture(scope="module")
def ref_inextensible_5():
    plant = Plant(P, edges=5)
    theta0, torques, hold = scenario(5, 2.0)
    return reference(plant, theta0, torques, hold, rhs="python", rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("method, bound", [("auto", 2e-6), ("ros2", 2.5e-3)])
def test_accuracy_inextensible_n5(ref_inextensible_5, method, bound):
    plant = Plant(P, edges=5, method=method)
    theta0, torques, hold = scenario(5, 2.0)

    sim = simulate(plant, theta0, torques, hold)
    a_ref, r_ref = edge_angles(plant, ref_inextensible_5)
    a_sim, r_sim = plant_angles(plant, sim)
    err = np.abs(a_sim - a_ref).max()
    report({"kind": "inextensible", "edges": 5, "method": plant.method, "step": plant.step, "max_angle_error": err,
            "max_rate_error": np.abs(r_sim - r_ref).max(), "seconds": 2.0, "max_rate": np.abs(r_ref).max(),
            "reference": "python"})
    assert np.abs(r_ref).max() > 15  # the scenario really is violent
    assert err < bound


def test_accuracy_inextensible_n20():
    r = accuracy(P, kind="inextensible", edges=20, seconds=2.0, rhs="python", rtol=1e-8, atol=1e-10)
    report(r)
    assert r["method"] == "ros2"
    assert r["max_angle_error"] < 1.5e-3
    assert r["max_rate_error"] < 0.1


def _accuracy_der(N: int, rhs: str, seconds: float) -> dict:
    r = accuracy(P, kind="der", edges=N, seconds=seconds, rhs=rhs, rtol=1e-9 if N == 5 else 1e-8,
                 atol=1e-11 if N == 5 else 1e-10)
    report(r)
    return r


@pytest.mark.parametrize("N, bound", [(5, 3e-4), (20, 1e-4)])
def test_accuracy_der(N, bound):
    """Radau on the C model's derivative: seconds, where the Python model's takes minutes."""
    r = _accuracy_der(N, "c", 1.0)
    assert r["max_angle_error"] < bound
    # what makes the C reference stand for the Python one: the same derivative along the whole trajectory
    plant = Plant(P, kind="der", edges=N)
    der, n = plant.model(), plant.n
    for y in r["reference_states"][::10]:
        a_py = der.accel(y[:n], y[n:], 0.03)
        assert np.abs(plant.deriv(y, 0.03)[n:] - a_py).max() < 1e-10 * np.abs(a_py).max()


@pytest.mark.full_reference
@pytest.mark.parametrize("N, bound", [(5, 3e-4), (20, 1e-4)])
def test_accuracy_der_against_radau_on_the_python_model(N, bound):
    assert _accuracy_der(N, "python", 2.0)["max_angle_error"] < bound


# --- long runs ------------------------------------------------------------------------------------

@pytest.mark.parametrize("kind", ["inextensible", "der"])
def test_no_blow_up_n20_over_10_s(kind):
    """N = 20, spun hard (30 rad/s, bent) and left alone for 10 s: the energy only ever falls
    (d and b dissipate) and every value stays finite."""
    plant = Plant(P, kind=kind, edges=20)
    plant.set_state(0.5 + 0.05 * np.arange(20), np.full(20, 30.0))
    E0, E_prev, worst_rise = plant.energy(), plant.energy(), 0.0
    for _ in range(10000):
        plant.advance(0.0, 1e-3)
        E = plant.energy()
        worst_rise = max(worst_rise, E - E_prev)
        E_prev = E
    th, w = plant.state()
    assert np.all(np.isfinite(th)) and np.all(np.isfinite(w))
    assert worst_rise < 1e-6 * E0
    E_end = E_prev
    plant.set_state(np.zeros(20))
    E_rest = plant.energy()
    assert E_end - E_rest < 0.02 * (E0 - E_rest)  # 98 % of the swing energy dissipated


@pytest.mark.parametrize("kind", ["inextensible", "der"])
def test_no_blow_up_n20_driven(kind):
    """10 s of bang-bang driver current (+-1.7 A, flipped every 50 ms) in duty mode."""
    plant = Plant(P, kind=kind, edges=20, input_mode="duty")
    for k in range(10000):
        plant.advance(1.0 if (k // 50) % 2 == 0 else -1.0, 1e-3)
    th, w = plant.state()
    assert np.all(np.isfinite(th)) and np.abs(w).max() < 200.0


@pytest.mark.parametrize("kind, N, method, bound", [
    ("inextensible", 5, "auto", 1e-4),    # RK4: measured 2.7e-5
    ("inextensible", 5, "ros2", 1e-2),    # ROS2 is L-stable, so dissipative: measured 4.3e-3
    ("inextensible", 20, "ros2", 5e-3),   # measured 1.9e-3
    ("der", 5, "auto", 1e-4),             # Verlet: bounded, no drift: measured 2.6e-5
    ("der", 20, "auto", 1e-4),            # measured 4.8e-5
])
def test_energy_drift_without_damping(kind, N, method, bound):
    """d = b = 0, T = 0, 5 s of large swings: |E(t) - E0| relative to the swing energy E0 - E_rest."""
    plant = Plant(P, kind=kind, edges=N, method=method, d=0.0, b=0.0)
    E_rest = plant.energy()
    plant.set_state(2.2 + 0.4 * np.linspace(0, 1, N) ** 2)
    E0 = plant.energy()
    worst = 0.0
    for _ in range(5000):
        plant.advance(0.0, 1e-3)
        worst = max(worst, abs(plant.energy() - E0))
    rel = worst / (E0 - E_rest)
    print(f"\n{kind} N={N} {plant.method} h={1e3 * plant.step:.4f} ms: energy drift {rel:.2e} of the swing energy "
          f"({E0 - E_rest:.3f} J) over 5 s")
    assert rel < bound
