"""The C closed-loop runner driving a controller through the rod_sil ABI (version 1).

The controller here is tests/c/standin_sil.c (a PD on the base angle plus the paper's swing kick),
not the firmware: it exercises the runner's semantics, which the firmware's SIL library then uses.
"""

from __future__ import annotations

import ctypes
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from rodgains.errors import UserError
from rodgains.params import load_params
from rodctl.build.native import compile_shared
from rodctl.sim import plant as sim
from rodctl.sim.plant import Plant, SilController, SimulationError, measure_realtime_factor, run_closed_loop

P = load_params()
STANDIN = Path(__file__).resolve().parent / "c" / "standin_sil.c"
RAD_PER_COUNT = np.float32(6.2831853071795864) * np.float32(5.0) / np.float32(4896.0)


@pytest.fixture(scope="module")
def standin():
    return compile_shared("standin_sil", [STANDIN], [], ("-O2",))


@pytest.fixture(scope="module")
def standin3():
    return compile_shared("standin_sil3", [STANDIN], [], ("-O2", "-DSTANDIN_EDGES=3"))


def wrap(x):
    return (np.asarray(x) + np.pi) % (2 * np.pi) - np.pi


def test_swing_up_and_balance_logs(standin):
    plant = Plant(P, edges=5)
    n = 6000
    log = run_closed_loop(plant, standin, n, arm_mode=2)
    assert log["periods_run"] == n and log["controller_edges"] == 5 and log["period"] == 1e-3
    shapes = {"time": (n,), "theta": (n, 5), "dtheta": (n, 5), "est": (n, 10), "torque_cmd": (n,), "duty": (n,),
              "torque": (n,), "current": (n,), "mode": (n,), "count": (n,)}
    assert {k: log[k].shape for k in shapes} == shapes
    assert log["est"].dtype == np.float32 and log["count"].dtype == np.int32
    np.testing.assert_array_equal(log["time"], np.arange(n) * 1e-3)
    # the encoder count each step saw is the true angle at that instant, quantized
    np.testing.assert_array_equal(log["count"], np.floor(log["theta"][:, 0] * 979.2 / (2 * np.pi) + 0.5))
    # the stand-in's estimate is that count in radians (float32), and its status is logged per step
    np.testing.assert_array_equal(log["est"][:, :5], (log["count"].astype(np.float32) * RAD_PER_COUNT)[:, None]
                                  * np.ones(5, np.float32))
    # torque mode without delay: the plant got exactly the command, and the mean current is T / kt
    np.testing.assert_array_equal(log["torque"], log["torque_cmd"].astype(float))
    np.testing.assert_allclose(log["current"], log["torque"] / P.kt_out, rtol=1e-15)
    assert np.abs(log["torque_cmd"]).max() <= 0.2
    # it swung up from hanging (kicks of 0.05 N m), caught and now balances upright
    assert log["mode"][0] == 2 and log["theta"][0, 0] == 0.0
    k_catch = int(np.argmax(log["mode"] == 1))
    assert 0 < k_catch < 5000 and np.all(log["mode"][k_catch:] == 1)
    assert np.abs(wrap(log["theta"][-500:] - np.pi)).max() < 0.05
    assert log["nonfinite_commands"] == 0 and not log["stopped_on_mode"]


def test_one_period_delay(standin):
    plant = Plant(P, edges=5)
    log = run_closed_loop(plant, standin, 3000, arm_mode=2, delay_periods=1)
    assert log["torque"][0] == 0.0
    np.testing.assert_array_equal(log["torque"][1:], log["torque_cmd"][:-1].astype(float))
    assert np.any(log["torque_cmd"] != 0)


def test_duty_mode_applies_the_motor_model(standin):
    plant = Plant(P, edges=5, input_mode="duty")
    assert plant.method == "rk4" and plant.step == 1e-3  # one step per period: the mean is the start value
    log = run_closed_loop(plant, standin, 3000, arm_mode=2)
    np.testing.assert_allclose(log["duty"], log["torque_cmd"] / np.float32(0.2), rtol=1e-6)  # the stand-in's map
    V, R, ke, kt, ilim = 12.0, P["motor"]["resistance"], P.ke_out, P.kt_out, P["driver"]["current_limit"]
    i = np.clip((log["duty"].astype(float) * V - ke * log["dtheta"][:, 0]) / R, -ilim, ilim)
    np.testing.assert_allclose(log["current"], i, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(log["torque"], kt * i, rtol=1e-12, atol=1e-15)
    assert log["current"][0] == pytest.approx(0.25 * V / R, rel=1e-12)  # first kick from rest: 3 V / 2.4 ohm


def test_plant_and_controller_edges_may_differ(standin, standin3):
    for kind in ("inextensible", "der"):
        plant = Plant(P, kind=kind, edges=8)
        log = run_closed_loop(plant, standin, 500, arm_mode=2)
        assert log["theta"].shape == (500, 8) and log["est"].shape == (500, 10)
        np.testing.assert_array_equal(log["count"], np.floor(log["theta"][:, 0] * 979.2 / (2 * np.pi) + 0.5))
    log = run_closed_loop(Plant(P, edges=5), standin3, 500, arm_mode=2)
    assert log["controller_edges"] == 3 and log["est"].shape == (500, 6)


def test_stop_on_mode_fault(standin):
    plant = Plant(P, edges=5)
    plant.set_state(np.full(5, math.pi - 0.2), np.full(5, -30.0))  # caught, but falling too fast for the PD
    log = run_closed_loop(plant, standin, 2000, arm_mode=1, stop_on_mode=3)
    assert log["stopped_on_mode"] and log["periods_run"] < 2000
    assert log["mode"][-1] == 3 and np.all(log["mode"][:-1] != 3)
    assert log["theta"].shape == (log["periods_run"], 5)
    assert abs(wrap(log["theta"][-1, 0] - math.pi)) > math.radians(60) - 0.05


def test_nonfinite_command_reaches_the_log_not_the_plant(standin):
    lib = ctypes.CDLL(str(standin))
    lib.standin_set_nan(10)
    try:
        log = run_closed_loop(Plant(P, edges=5), standin, 50, arm_mode=2)
    finally:
        lib.standin_set_nan(-1)
    assert math.isnan(log["torque_cmd"][10]) and log["torque"][10] == 0.0
    assert log["nonfinite_commands"] == 1
    assert np.all(np.isfinite(log["theta"])) and np.isfinite(log["torque_cmd"][:10]).all()


def test_plant_failure_raises_with_the_log(standin):
    plant = Plant(P, edges=5)
    plant.set_state(np.full(5, math.nan))
    with pytest.raises(SimulationError, match="period 0") as e:
        run_closed_loop(plant, standin, 100, arm_mode=2)
    assert e.value.log["periods_run"] == 1 and e.value.log["count"][0] == -2**31


def test_continuing_a_run_equals_one_run(standin):
    a = Plant(P, edges=5)
    whole = run_closed_loop(a, standin, 2000, arm_mode=2, delay_periods=1)
    b = Plant(P, edges=5)
    first = run_closed_loop(b, standin, 1200, arm_mode=2, delay_periods=1)
    rest = run_closed_loop(b, standin, 800, arm_mode=2, delay_periods=1, reset=False)
    assert rest["time"][0] == pytest.approx(1.2, abs=1e-12)
    for key in ("theta", "torque", "torque_cmd", "count", "mode"):
        np.testing.assert_array_equal(np.concatenate([first[key], rest[key]]), whole[key])


def test_disarmed_controller_leaves_the_rod_hanging(standin):
    log = run_closed_loop(Plant(P, kind="der", edges=5), standin, 200, arm_mode=0)
    assert np.all(log["mode"] == 0) and np.all(log["torque"] == 0) and np.all(log["count"] == 0)
    assert np.abs(log["theta"]).max() < 1e-12


def test_abi_checks(standin):
    with pytest.raises(UserError, match="not a rod_sil library"):
        SilController(sim.library_path())
    ctl = SilController(standin)
    assert ctl.period == 1e-3 and ctl.edges == 5 and ctl.has_duty
    with pytest.raises(ValueError):
        run_closed_loop(Plant(P, edges=5), ctl, 10, delay_periods=2)


def test_realtime_factor_measurement_runs(standin, monkeypatch):
    # A faked clock makes the factors exact whatever the machine's load; the iterator also fails the
    # test if the measurement reads the clock more than twice per repeat.
    clock = iter([0.0, 0.1, 1.0, 1.2])
    monkeypatch.setattr(sim, "time", SimpleNamespace(perf_counter=clock.__next__))
    r = measure_realtime_factor(Plant(P, edges=5), standin, seconds=0.2, repeats=2)
    assert r["periods"] == 200
    # 0.2 simulated s in 0.1 and 0.2 faked wall s; the median of two is their mean.
    assert r["factors"] == pytest.approx([2.0, 1.0], rel=1e-12)
    assert r["factor"] == pytest.approx(1.5, rel=1e-12)
    assert r["us_per_period"] == pytest.approx(1e3 / 1.5, rel=1e-12)
