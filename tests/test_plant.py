"""The C plant (host/rodctl/sim/native/rod_plant.c) against the Python reference models, and its
encoder, motor/driver and Python API. Integrator accuracy is in test_plant_integrators.py,
the closed-loop runner in test_plant_closed_loop.py."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rodgains.params import load_params
from rodctl.sim.plant import Plant

P = load_params()


def random_angles(rng, N, spread=1.0):
    """Edge angles with neighbouring turning angles within +-spread (the tan springs are finite)."""
    return rng.uniform(-math.pi, math.pi) + np.concatenate([[0.0], np.cumsum(rng.uniform(-spread, spread, N - 1))])


# --- the equations of motion -------------------------------------------------------------------

@pytest.mark.parametrize("N", [2, 3, 5, 8, 20])
def test_inextensible_matches_rod_model(N):
    plant = Plant(P, kind="inextensible", edges=N)
    rod = plant.model()
    rng = np.random.default_rng(N)
    worst = {"force": 0.0, "mass": 0.0, "accel": 0.0}
    for _ in range(25):
        th, w, T = random_angles(rng, N), rng.uniform(-20, 20, N), rng.uniform(-0.2, 0.2)
        y = np.concatenate([th, w])
        F_py = -(rod.coriolis(th, w) + rod.potential_gradient(th) + rod.damping_force(w))
        F_py[0] += T
        for key, c, py in (("force", plant.force(y, T), F_py), ("mass", plant.mass(y), rod.mass_matrix(th)),
                           ("accel", plant.deriv(y, T)[N:], rod.accel(th, w, T))):
            worst[key] = max(worst[key], np.abs(c - py).max() / np.abs(py).max())
        np.testing.assert_array_equal(plant.deriv(y, T)[:N], w)
    assert max(worst.values()) < 1e-11, worst


@pytest.mark.parametrize("N", [2, 3, 5, 20])
def test_der_matches_der_model(N):
    plant = Plant(P, kind="der", edges=N)
    der = plant.model()
    rng = np.random.default_rng(100 + N)
    worst_F = worst_a = 0.0
    for _ in range(25):
        q, qd = der.from_angles(random_angles(rng, N), rng.uniform(-20, 20, N))
        q[1:] += rng.normal(0, 0.02 * der.l, q.size - 1)  # stretched and sheared
        qd[1:] += rng.normal(0, 0.5, qd.size - 1)
        T = rng.uniform(-0.2, 0.2)
        y = np.concatenate([q, qd])
        F_py = der.generalized_force(q, qd, T)
        worst_F = max(worst_F, np.abs(plant.force(y, T) - F_py).max() / np.abs(F_py).max())
        a_py = der.accel(q, qd, T)
        worst_a = max(worst_a, np.abs(plant.deriv(y, T)[plant.n:] - a_py).max() / np.abs(a_py).max())
    assert worst_F < 1e-11 and worst_a < 1e-11, (worst_F, worst_a)


@pytest.mark.parametrize("kind", ["inextensible", "der"])
def test_energy_and_nodes_match_python(kind):
    plant = Plant(P, kind=kind, edges=6)
    model = plant.model()
    rng = np.random.default_rng(7)
    for _ in range(10):
        th, w = random_angles(rng, 6), rng.uniform(-10, 10, 6)
        plant.set_state(th, w)
        if kind == "inextensible":
            E_py, xy_py = model.energy(np.concatenate([th, w])), model.nodes(th)
        else:
            q, qd = model.from_angles(th, w)
            E_py, xy_py = model.energy(q, qd), model.nodes(q)
        assert plant.energy() == pytest.approx(E_py, rel=1e-12, abs=1e-15)
        np.testing.assert_allclose(plant.nodes(), xy_py, atol=1e-15)


def test_state_roundtrip_and_der_angles():
    rng = np.random.default_rng(3)
    for kind in ("inextensible", "der"):
        plant = Plant(P, kind=kind, edges=7)
        th, w = random_angles(rng, 7) + 4 * math.pi, rng.uniform(-5, 5, 7)  # several turns: unwrapped
        plant.set_state(th, w)
        th2, w2 = plant.state()
        np.testing.assert_allclose(th2, th, atol=1e-12)
        np.testing.assert_allclose(w2, w, atol=1e-12)
    der = plant.model()
    q, qd = plant.raw_state()
    th_py, w_py = der.to_angles(q, qd)
    np.testing.assert_allclose(plant.state()[0], th_py, atol=1e-12)
    np.testing.assert_allclose(plant.state()[1], w_py, atol=1e-12)


def test_hanging_rest_is_an_equilibrium():
    for kind in ("inextensible", "der"):
        plant = Plant(P, kind=kind, edges=5)
        plant.advance(0.0, 1.0)
        th, w = plant.state()
        assert np.abs(th).max() < 1e-12 and np.abs(w).max() < 1e-12


# --- encoder ------------------------------------------------------------------------------------

@pytest.mark.parametrize("phase, expected", [(0.0, 489), (0.25, 489), (0.5, 490), (0.75, 490), (0.99, 490)])
def test_encoder_upright_is_489_6_counts(phase, expected):
    plant = Plant(P, edges=5, phase=phase)
    assert float(P.counts_per_rev) == 979.2
    assert plant.encoder_count(math.pi) == expected == math.floor(489.6 + phase)
    assert plant.encoder_count(-math.pi) == math.floor(-489.6 + phase)
    plant.set_state(np.full(5, math.pi))
    assert plant.encoder() == expected


def test_encoder_quantization_sweep():
    plant = Plant(P, edges=3, phase=0.5)
    theta = np.linspace(-40.0, 40.0, 20001)
    counts = np.array([plant.encoder_count(t) for t in theta])
    np.testing.assert_array_equal(counts, np.floor(theta * 979.2 / (2 * math.pi) + 0.5).astype(int))
    assert plant.encoder_count(0.0) == 0  # power-on, hanging at rest
    step = 2 * math.pi / 979.2
    assert plant.encoder_count(0.49 * step) == 0 and plant.encoder_count(0.51 * step) == 1  # phase 0.5 rounds
    plant.phase = 0.0
    assert plant.encoder_count(0.99 * step) == 0 and plant.encoder_count(-0.01 * step) == -1  # phase 0 floors
    assert plant.encoder_count(float("nan")) == -2**31
    with pytest.raises(RuntimeError):
        plant.phase = 1.0


# --- motor and driver -----------------------------------------------------------------------------

def test_duty_mode_stall_torque_is_the_driver_current_limit():
    plant = Plant(P, edges=5, input_mode="duty")
    kt, ilim = P.kt_out, P["driver"]["current_limit"]
    T, i = plant.motor_torque(1.0, 0.0)  # 12 V / 2.4 ohm = 5 A wanted, 1.7 A allowed
    assert (T, i) == (pytest.approx(kt * ilim, rel=1e-15), ilim)
    assert plant.motor_torque(-1.0, 0.0)[0] == pytest.approx(-kt * ilim, rel=1e-15)
    assert plant.motor_torque(3.0, 0.0)[0] == pytest.approx(kt * ilim, rel=1e-15)  # duty clamped to 1
    # unclamped: i = (V d - ke w) / R
    T, i = plant.motor_torque(0.2, 3.0)
    assert i == pytest.approx((12.0 * 0.2 - P.ke_out * 3.0) / 2.4, rel=1e-14) and T == pytest.approx(kt * i, rel=1e-15)
    for kind in ("inextensible", "der"):  # held against the stop: the mean torque over a period is the limit
        plant = Plant(P, kind=kind, edges=5, input_mode="duty")
        plant.advance(1.0, 1e-3)
        assert plant.last_current == pytest.approx(ilim, rel=1e-12)
        assert plant.last_torque == pytest.approx(kt * ilim, rel=1e-12)
        assert 0.2025 == pytest.approx(plant.last_torque, abs=1e-4)


@pytest.mark.parametrize("kind", ["inextensible", "der"])
def test_back_emf_free_running_speed(kind):
    """b = 0, no gravity, duty 1: the shaft settles where V = ke w, 12 V / 0.229 V s/rad = 52.4 rad/s."""
    plant = Plant(P, kind=kind, edges=5, input_mode="duty", b=0.0, g=0.0)
    for _ in range(3000):
        plant.advance(1.0, 1e-3)
    w = plant.state()[1]
    w_free = P["driver"]["supply_voltage"] / P.ke_out
    assert w_free == pytest.approx(52.38, abs=0.01)
    assert abs(w[0] - w_free) / w_free < 0.01
    assert np.abs(w - w[0]).max() < 0.01 * w_free  # the rod turns rigidly with the shaft
    assert abs(plant.last_current) < 0.01  # no load: no current


def test_torque_mode_mean_torque_and_current():
    plant = Plant(P, edges=5)
    plant.advance(0.05, 1e-3)
    assert plant.last_torque == 0.05
    assert plant.last_current == pytest.approx(0.05 / P.kt_out, rel=1e-15)


# --- configuration, build --------------------------------------------------------------------------

def test_nan_survives_the_plant():
    """A NaN input is never replaced by a number: it reaches the state, or the step fails loudly."""
    for kind, mode in (("inextensible", "torque"), ("inextensible", "duty"), ("der", "torque"), ("der", "duty")):
        plant = Plant(P, kind=kind, edges=5, input_mode=mode)
        with pytest.raises(RuntimeError, match="left the model"):
            plant.advance(float("nan"), 1e-3)
            assert np.isnan(plant.state()[1]).any()  # reached only if this step did not fail
            plant.advance(0.0, 1e-3)


def test_library_builds_with_the_firmware_warning_set(monkeypatch):
    from rodctl.build.native import FIRMWARE_WARNINGS, compile_shared
    from rodctl.sim import plant as sim
    from rodctl.sim.plant import NATIVE, SOURCES

    assert "-Werror" in FIRMWARE_WARNINGS  # any warning of the set fails the build
    strict_path = compile_shared("rod_plant_strict", SOURCES, [NATIVE],
                                 ("-O2", "-Wshadow", "-pedantic", *FIRMWARE_WARNINGS))
    normal = Plant(P, edges=5)
    # The plant's whole ABI declared on the strict build (its API version checked), and a Plant made on it.
    monkeypatch.setattr(sim, "library_path", lambda: strict_path)
    strict_lib = sim.library.__wrapped__()
    monkeypatch.setattr(sim, "library", lambda: strict_lib)
    strict = Plant(P, edges=5)
    assert strict._lib is strict_lib and normal._lib is not strict_lib
    # Warning flags change no code: the same numbers, bit for bit.
    for plant in (normal, strict):
        plant.set_state(np.linspace(0.4, 2.9, 5), np.linspace(3.0, -2.0, 5))
    assert strict.energy() == normal.energy()
    for plant in (normal, strict):
        plant.advance(0.05, 1e-2)
    np.testing.assert_array_equal(np.concatenate(strict.state()), np.concatenate(normal.state()))


def test_plant_options():
    plant = Plant(P, edges=5, J=0.0, b=0.0)
    assert (plant.config.J, plant.config.b) == (0.0, 0.0)
    phys = Plant(P, edges=5)
    # the physical motor with the gearbox's output side, as a rigid shaft carries them
    assert phys.config.J == pytest.approx(5e-7 * 20.4**2 + P["gearbox"]["output_inertia"]) and phys.config.b == 5e-4
    assert Plant(P).N == P.N == P["rod"]["edges"]
    with pytest.raises(ValueError):
        Plant(P, kind="soft")
    with pytest.raises(ValueError):
        Plant(P, input_mode="voltage")
    with pytest.raises(ValueError):
        Plant(P, kind="der", method="rk4")
    with pytest.raises(ValueError):
        Plant(P, edges=1)
    plant.step = 2e-4
    assert plant.step == 2e-4
    with pytest.raises(RuntimeError):
        plant.step = 0.0
    with pytest.raises(RuntimeError):
        plant.advance(0.0, -1.0)
