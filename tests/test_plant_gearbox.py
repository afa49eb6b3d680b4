"""The rig between the encoder and the rod (host/rodctl/sim/native/rod_plant.c, docs/plant.md "The
gearbox"): the gear train's play and compliance, the motor side the encoder reads, the winding's
inductance, the boot zero's error, a rod curved at rest and the interrupt's jitter."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rodgains.params import load_params
from rodctl.sim import convergence, matrix
from rodctl.sim.plant import GearTrain, faithful_plant

P = load_params()
LOSSLESS = ("rod.damping=0.0", "motor.viscous_friction=0.0", "gearbox.damping=0.0", "motor.coulomb_friction=0.0")


def _energy_drift(model: str, step_factor: float) -> float:
    """Largest energy error [J] over 0.5 s of a lossless rod swinging from 30 deg with its motor side
    set spinning at 1 rad/s across a 1 deg gap: the teeth hit, part, and hit again."""
    q = P.with_overrides(f'plant.model="{model}"', "plant.edges=10", *LOSSLESS)
    # the inextensible rod on RK4: ROS2 is L-stable, so it damps the hub's stiff mode by design
    pl = faithful_plant(q, input_mode="torque", method="verlet" if model == "der" else "rk4")
    pl.step = pl.step * step_factor
    pl.set_state(np.full(pl.N, math.radians(30)))
    pl.set_motor_state(math.radians(30.0), 1.0)
    e0 = pl.energy()
    drift = 0.0
    for _ in range(500):
        pl.advance(0.0, 1e-3)
        drift = max(drift, abs(pl.energy() - e0))
    return drift


@pytest.mark.parametrize("model", ["der", "inextensible"])
def test_a_lossless_rod_behind_a_gap_keeps_its_energy_and_the_error_shrinks_with_the_step(model):
    coarse, fine = _energy_drift(model, 1.0), _energy_drift(model, 0.25)
    # the swing carries about 0.01 J above the hanging rest: the books close to parts in 1e4 at the
    # automatic step, and the error is the integrator's (it shrinks with the step), not a leak
    assert coarse < 6e-5
    assert fine < coarse / 4


def _tip_path(gear: GearTrain | None) -> np.ndarray:
    """Tip position every 1 ms under a 0.05 N m square wave at the pendulum period, no dry friction."""
    pl = faithful_plant(P.with_overrides("motor.coulomb_friction=0.0"), input_mode="torque", gear=gear)
    out = []
    for k in range(400):
        pl.advance(0.05 if math.sin(2 * math.pi * k * 1e-3 / 0.73) >= 0 else -0.05, 1e-3)
        out.append(pl.nodes()[-1].copy())
    return np.array(out)


def test_with_no_play_and_a_stiffening_gear_train_the_plant_becomes_the_rigid_shaft():
    rigid = _tip_path(None)
    errors = []
    for k in (1e3, 1e4):
        gear = GearTrain(stiffness=k, damping=0.002 * math.sqrt(k / 60), backlash=0.0,
                         output_inertia=P["gearbox"]["output_inertia"], output_friction_share=0.1)
        errors.append(np.abs(_tip_path(gear) - rigid).max())
    assert errors[0] < 2e-5  # [m]: 20 um of the 155 mm rod after 0.4 s of forcing
    assert errors[1] < errors[0] / 5  # about 1 / stiffness


def _hanging_period(p) -> float:
    pl = faithful_plant(p, input_mode="torque", J=convergence.CLAMP_INERTIA, b=0.0, coulomb=0.0,
                        **({} if p["gearbox"]["model"] == "compliant" else {"gear": None}))
    A, _ = convergence.linearization(pl, upright=False)
    ev = np.linalg.eigvals(A)
    periods = 2 * math.pi / ev[ev.imag > 1e-9].imag
    return float(periods[periods < 5.0].max())


def test_the_hanging_period_behind_the_gear_train_is_the_rigid_rods_lengthened_by_its_compliance():
    rigid = _hanging_period(P.with_overrides('gearbox.model="rigid"'))
    soft = _hanging_period(P.with_overrides("gearbox.stiffness=20.0", "gearbox.backlash_deg=0.0"))
    nominal = _hanging_period(P.with_overrides("gearbox.backlash_deg=0.0"))
    stiff = _hanging_period(P.with_overrides("gearbox.stiffness=2000.0", "gearbox.backlash_deg=0.0"))
    assert rigid == pytest.approx(0.41196, abs=2e-4)  # docs/plant.md: 411.96 ms
    assert rigid < stiff < nominal < soft < rigid * 1.005
    assert stiff - rigid < 0.03 * (soft - rigid)


def test_the_encoder_reads_the_motor_and_crosses_the_gap_before_the_rod_moves():
    pl = faithful_plant(P.with_overrides("motor.coulomb_friction=0.0", "encoder.zero_error_deg=0.0"),
                        input_mode="torque")
    pl.set_state(np.zeros(pl.N))
    start = pl.encoder()
    for _ in range(18):  # 18 ms of 10 mN m on the motor side alone (2.1e-4 kg m^2): 0.45 deg
        pl.advance(0.01, 1e-3)
    assert 0.4 < math.degrees(pl.motor_state()[0]) < 0.5  # inside the 1 deg gap
    assert abs(math.degrees(pl.state()[0][0])) < 0.01  # the rod's hub has not moved
    assert pl.encoder() - start >= 1  # but the encoder saw the motor move
    for _ in range(30):  # the teeth meet: the rod turns with the motor
        pl.advance(0.01, 1e-3)
    assert math.degrees(pl.state()[0][0]) > 0.3


def test_the_encoder_on_the_output_shaft_reads_the_hub_instead():
    pl = faithful_plant(P.with_overrides('encoder.location="output"', "encoder.zero_error_deg=0.0",
                                         "motor.coulomb_friction=0.0"), input_mode="torque")
    pl.set_state(np.zeros(pl.N))
    for _ in range(15):
        pl.advance(0.005, 1e-3)
    assert pl.encoder() == pl.encoder_count(pl.state()[0][0])


def test_the_zero_error_moves_every_count_by_that_angle():
    base = faithful_plant(P.with_overrides("encoder.zero_error_deg=0.0"))
    off = faithful_plant(P.with_overrides("encoder.zero_error_deg=0.5"))
    per_count = 360.0 / float(P.counts_per_rev)
    for deg in (0.0, 10.0, -40.0, 180.0):
        assert off.encoder_count(math.radians(deg)) == base.encoder_count(math.radians(deg + 0.5))
    assert per_count < 0.5 < 2 * per_count  # half a degree is more than a count: a real offset


def test_the_curved_case_puts_the_hanging_tip_5_mm_to_the_side():
    q = P.with_overrides(f"rod.rest_curvature={matrix.CURVED_REST_CURVATURE}", "rod.damping=0.02")
    pl = faithful_plant(q, input_mode="torque", gear=None, J=1e3)  # the shaft held, the rod settling
    pl.set_state(np.zeros(pl.N))
    for _ in range(40):
        pl.advance(0.0, 0.1)
    assert pl.nodes()[-1][0] == pytest.approx(matrix.CURVED_TIP_M, abs=3e-4)


def test_the_current_lags_the_voltage_by_inductance_over_resistance():
    q = P.with_overrides("motor.inductance=0.0018")  # 0.75 ms on 2.4 ohm
    pl = faithful_plant(q, input_mode="duty", J=1e3, gear=None, coulomb=0.0)  # the shaft held: no back-EMF
    pl.set_state(np.zeros(pl.N))
    target = 0.2 * P["driver"]["supply_voltage"] / P["motor"]["resistance"]
    currents = []
    for _ in range(30):
        pl.advance(0.2, 0.05e-3)
        currents.append(pl.motor_state()[2])
    t = 0.05e-3 * (np.arange(30) + 1)
    assert np.interp(0.75e-3, t, currents) == pytest.approx(target * (1 - math.exp(-1)), rel=0.02)
    assert currents[-1] == pytest.approx(target * (1 - math.exp(-1.5 / 0.75)), rel=0.02)


def test_jitter_changes_the_run_and_the_same_seed_repeats_it():
    from rodctl.build.sil_build import build_sil
    from rodctl.sim.plant import SilController, run_closed_loop

    ctl = SilController(build_sil(P))

    def run(jitter, seed=1):
        pl = faithful_plant(P)
        pl.set_state(np.full(pl.N, math.pi - 0.2))
        return run_closed_loop(pl, ctl, 300, arm_mode=1, jitter=jitter, jitter_seed=seed)["theta"][:, -1]

    calm, a, b, c = run(0.0), run(200e-6), run(200e-6), run(200e-6, seed=7)
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - calm).max() > 1e-6
    assert np.abs(a - c).max() > 1e-6


@pytest.mark.parametrize("override, needle", [
    ("gearbox.backlash_deg=-1", "gearbox.backlash_deg"),
    ("gearbox.stiffness=-5", "gearbox.stiffness"),
    ("encoder.zero_error_deg=12", "encoder.zero_error_deg"),
    ("motor.inductance=2.0", "motor.inductance"),
])
def test_a_rig_value_out_of_range_is_one_line_naming_the_key(override, needle):
    from rodgains.errors import ParamError

    with pytest.raises(ParamError) as e:
        P.with_overrides(override)
    assert str(e.value).startswith(needle) and "\n" not in str(e.value)
