"""Torque to duty through the motor model: i = tau / kt, V = i R + ke rate, duty = V / V_supply."""

import math

import pytest

from firmware_sil import ACK, MODE, Sil, count_of


@pytest.fixture
def sil():
    return Sil()


def motor(sil):
    p = sil.p
    return p.kt_out, p.ke_out, p["motor"]["resistance"], p["driver"]["supply_voltage"], p.torque_max


def test_stall_duty_is_current_times_resistance_over_supply(sil):
    kt, ke, R, V, _ = motor(sil)
    tau = sil.catch_at(489)  # at rest: no back-EMF; 0.2 deg from upright stays below the torque limit
    assert sil.rate == 0.0  # the shaft at rest [rad/s], simulated
    assert 0.0 < abs(tau) < 0.2
    current = tau / kt
    assert sil.duty == pytest.approx(current * R / V, rel=1e-5)


def test_back_emf_adds_to_the_voltage_in_the_direction_of_motion():
    sil = Sil(("swing_up.stall_steps=0",))  # the imposed swing turns back at the same angle: the watch would raise the pump
    kt, ke, R, V, _ = motor(sil)
    amplitude = sil.p["swing_up"]["amplitude"]
    sil.arm(2)
    for k in range(20):  # moving + at ~13 rad/s through the bottom
        tau = sil.step(-20 + 2 * k)
    shaft_rad_s = sil.rate  # the firmware's estimate of the simulated shaft's angular rate, not a wall-clock speed
    assert shaft_rad_s > 5.0 and tau == pytest.approx(amplitude, rel=1e-6)
    assert sil.duty == pytest.approx((tau / kt * R + ke * shaft_rad_s) / V, rel=1e-5)
    assert sil.duty > tau / kt * R / V  # more than at stall
    for k in range(30):  # and moving - : torque and back-EMF both negative
        tau = sil.step(20 - 2 * k)
    shaft_rad_s = sil.rate
    assert shaft_rad_s < -5.0 and tau == pytest.approx(-amplitude, rel=1e-6)
    assert sil.duty == pytest.approx((tau / kt * R + ke * shaft_rad_s) / V, rel=1e-5)
    assert sil.duty < tau / kt * R / V


def test_torque_is_limited(sil):
    kt, ke, R, V, tmax = motor(sil)
    catch = math.radians(sil.p["swing_up"]["catch_angle_deg"])
    tau = sil.catch_at(count_of(math.pi - 0.9 * catch))  # far from upright: -K z asks for much more
    assert tau == pytest.approx(tmax, rel=1e-6)
    assert sil.duty == pytest.approx(tmax / kt * R / V, rel=1e-5)


def test_duty_is_limited_and_the_torque_reported_is_what_the_supply_gives(sil):
    kt, ke, R, V, tmax = motor(sil)
    assert sil.set("SWING_AMPLITUDE", tmax) == ACK["OK"]
    sil.arm(2)
    sil.past_runaway_watch()
    limit = sil.p["safety"]["speed_limit"]
    amp = 0.45
    omega = 0.93 * limit / amp
    clamped = []
    for k in range(1500):
        tau = sil.step(count_of(amp * math.sin(omega * k * sil.p.dt)))
        assert abs(sil.duty) <= 1.0
        if abs(sil.duty) == 1.0:
            clamped.append((tau, sil.duty, sil.rate))
    assert sil.mode == MODE["SWING_UP"]
    assert clamped, "never reached the duty limit"
    for tau, duty, shaft_rad_s in clamped:
        assert tau == pytest.approx((duty * V - ke * shaft_rad_s) / R * kt, rel=1e-4)
        assert abs(tau) < tmax
