"""Firmware modes through the SIL library: power-on, swing-up (energy pump + kick), catch, balance, disarm."""

import math

import pytest

from rodgains.codegen import pendulum_frequency

from firmware_sil import ACK, MODE, RAD_PER_COUNT, REASON, UPRIGHT, Sil, count_of


@pytest.fixture
def sil():
    return Sil()


def test_abi_basics(sil):
    assert sil.lib.rod_sil_abi_version() == 1
    assert sil.lib.rod_sil_edges() == sil.p.N
    assert sil.lib.rod_sil_period() == pytest.approx(sil.p.dt)


def test_boots_disarmed_with_driver_off(sil):
    for count in (0, 3, -2, 490):
        assert sil.step(count) == 0.0
        assert sil.duty == 0.0
        assert sil.enable == 0
        assert sil.mode == MODE["DISARMED"]
        assert sil.reason == REASON["NONE"]


def test_swing_up_from_rest_kicks_with_the_configured_amplitude(sil):
    amplitude = sil.p["swing_up"]["amplitude"]
    sil.hold(0, 10)
    assert sil.arm(2) == ACK["OK"]
    u = sil.step(0)
    assert sil.mode == MODE["SWING_UP"]
    assert u == pytest.approx(amplitude, rel=1e-6)
    assert sil.enable == 1 and sil.duty > 0.0
    # still at rest: it keeps pushing in the + direction rather than waiting for sign(0)
    assert sil.hold(0, 20) == pytest.approx(amplitude, rel=1e-6)


def test_kick_uses_a_new_amplitude(sil):
    assert sil.set("SWING_AMPLITUDE", 0.05) == ACK["OK"]
    sil.arm(2)
    assert sil.step(0) == pytest.approx(0.05, rel=1e-6)


def test_swing_up_pumps_with_the_sign_of_the_rate_inside_the_swing_angle(sil):
    amplitude = sil.p["swing_up"]["amplitude"]
    sil.arm(2)
    sil.past_runaway_watch(20)
    # swinging through the bottom in the - direction, 1 count per step (~6 rad/s)
    u = 0.0
    for k in range(1, 30):
        u = sil.step(20 - k)
    assert u == pytest.approx(-amplitude, rel=1e-6)
    # and in the + direction
    for k in range(30):
        u = sil.step(-10 + k)
    assert u == pytest.approx(amplitude, rel=1e-6)


def imposed_swing(sil, peaks_deg):
    """Half-swings from bottom to bottom at the rigid pendulum's frequency, peaking at peaks_deg in turn on
    alternate sides (a motion no torque made: past the runaway watch); the pump's largest |torque| in each [N m]."""
    omega0 = pendulum_frequency(sil.p)
    steps = int(round(math.pi / omega0 / sil.p.dt))
    sil.arm(2)
    sil.past_runaway_watch(0)
    pumps = []
    for k, peak in enumerate(peaks_deg):
        side = 1 if k % 2 == 0 else -1
        pumps.append(max(abs(sil.step(count_of(side * math.radians(peak) * math.sin(math.pi * i / steps))))
                         for i in range(steps)))
    assert sil.mode == MODE["SWING_UP"]
    return pumps


def test_a_stalled_swing_raises_the_pump_to_twice_its_amplitude(sil):
    """A swing that turns back at the same angle half-swing after half-swing is a stall (rod_swingup.h): the
    pump rises a quarter at each, to 2 x, and a rod that still rises 20 deg a half-swing is left alone."""
    amplitude = sil.p["swing_up"]["amplitude"]
    stalled = imposed_swing(sil, [100.0] * 7)
    # the first two set the level; each later one is a stall
    assert [round(u / amplitude, 4) for u in stalled] == [1.0, 1.0, 1.25, 1.5625, 1.9531, 2.0, 2.0]
    sil.lib.rod_sil_reset()
    rising = imposed_swing(sil, [20.0, 40.0, 60.0, 80.0, 100.0])
    assert rising == pytest.approx([amplitude] * 5, rel=1e-6)


def test_the_stall_watch_can_be_turned_off():
    sil = Sil(("swing_up.stall_steps=0",))
    amplitude = sil.p["swing_up"]["amplitude"]
    assert imposed_swing(sil, [100.0] * 5) == pytest.approx([amplitude] * 5, rel=1e-6)


def test_no_swing_torque_outside_the_swing_angle():
    sil = Sil(("swing_up.angle_deg=30.0",))  # the default pumps at every angle up to the catch
    swing = sil.p["swing_up"]["angle_deg"]
    beyond = count_of(math.radians(swing) + 0.1)
    sil.arm(2)
    for k in range(40):
        u = sil.step(beyond + k)  # moving, but outside |theta_1| < swing angle
    assert u == 0.0
    assert sil.mode == MODE["SWING_UP"] and sil.enable == 1


def test_catch_initializes_the_estimate_as_in_the_paper(sil):
    """Rising into the catch angle at speed: BALANCE, every theta-hat = theta_1, every rate = the base rate."""
    catch = math.radians(sil.p["swing_up"]["catch_angle_deg"])
    sil.arm(2)
    start = count_of(math.pi - catch - 0.3)
    count = start
    while True:
        count += 3  # ~19 rad/s, below the speed limit
        sil.step(count)
        if sil.mode != MODE["SWING_UP"]:
            break
    assert sil.mode == MODE["BALANCE"]
    assert abs(count * RAD_PER_COUNT - math.pi) <= catch
    mode, theta, rate = sil.status()
    measured = count * RAD_PER_COUNT
    assert theta == pytest.approx([measured] * sil.n, abs=1e-5)
    assert rate == pytest.approx([sil.rate] * sil.n, abs=1e-6)
    assert sil.rate == pytest.approx(3 * RAD_PER_COUNT / sil.p.dt, rel=0.1)
    assert sil.enable == 1
    # from the next step on the observer runs: the edges no longer move in lockstep
    sil.step(count + 3)
    _, theta2, _ = sil.status()
    assert max(theta2) - min(theta2) > 1e-6


def test_catch_of_a_later_turn_uses_that_upright(sil):
    """Multi-turn: the upright two turns on is pi + 4 pi, and the estimate says so."""
    count = round(UPRIGHT + 2 * 979.2) + 3
    sil.catch_at(count)
    _, theta, _ = sil.status()
    assert theta == pytest.approx([count * RAD_PER_COUNT] * sil.n, abs=1e-4)
    assert abs(theta[0] - 5 * math.pi) < 0.05


def test_arm_balance_waits_with_the_driver_off_until_inside_the_catch_angle(sil):
    sil.arm(1)
    for _ in range(20):
        assert sil.step(0) == 0.0
    assert sil.mode == MODE["CATCH"]
    assert sil.enable == 0 and sil.duty == 0.0
    catch = math.radians(sil.p["swing_up"]["catch_angle_deg"])
    count = 0
    while True:  # carried up by hand, 2 counts per step
        count += 2
        u = sil.step(count)
        if sil.mode != MODE["CATCH"]:
            break
        assert u == 0.0 and sil.enable == 0
    assert sil.mode == MODE["BALANCE"] and sil.enable == 1
    assert math.pi - count * RAD_PER_COUNT == pytest.approx(catch, abs=2 * RAD_PER_COUNT)


def test_balance_pushes_back_toward_upright(sil):
    u = sil.catch_at(480)  # leaning back (theta_1 < pi)
    assert u > 0.0
    sil.lib.rod_sil_reset()
    u = sil.catch_at(500)
    assert u < 0.0


def test_host_disarm_lands_in_disarmed_with_reason_host(sil):
    sil.catch_at(490)
    assert sil.arm(0) == ACK["OK"]
    assert sil.mode == MODE["DISARMED"]
    assert sil.reason == REASON["HOST"]
    assert sil.step(490) == 0.0 and sil.enable == 0 and sil.duty == 0.0
    # and it can be armed again straight away
    assert sil.arm(1) == ACK["OK"]


def test_unknown_arm_mode_is_refused(sil):
    assert sil.arm(3) == ACK["BAD_VALUE"]
    assert sil.mode == MODE["DISARMED"]
