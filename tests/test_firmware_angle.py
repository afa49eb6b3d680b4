"""Encoder count to theta_1: exact wrap on 979.2 counts per turn, multi-turn, and the base rate."""

import math

import pytest

from firmware_sil import MODE, RAD_PER_COUNT, UPRIGHT, Sil, count_of


def catch_torque(count: int) -> tuple[float, list[float]]:
    sil = Sil()
    tau = sil.catch_at(count)
    return tau, sil.status()[1]


@pytest.mark.parametrize("count", [489, 490])
def test_upright_counts_are_within_half_a_count(count):
    """489.6 counts is upright: 489 and 490 sit 0.6 and 0.4 counts from it, not rounded to 0 or 1."""
    _, theta = catch_torque(count)
    error = theta[0] - math.pi
    exact = (count - UPRIGHT) * RAD_PER_COUNT
    assert abs(error - exact) < 1e-6
    assert abs(error - exact) < 0.5 * RAD_PER_COUNT
    assert abs(error) < RAD_PER_COUNT


def test_deviation_is_exact_in_every_turn():
    """Same phase in turn m: identical catch torque, bit for bit, however far the count has run."""
    base, _ = catch_torque(489)
    for turns5 in (-7, -1, 1, 3, 40, 400):  # whole multiples of 5 turns = 4896 counts
        tau, _ = catch_torque(489 + 4896 * turns5)
        assert tau == base, turns5


def test_fractional_uprights_of_other_turns():
    """Upright of turn k is 489.6 + 979.2 k counts: the deviation keeps the fraction exactly."""
    tau_489, _ = catch_torque(489)  # -0.6 count
    per_count = tau_489 / -0.6
    for count, dev in ((1468, -0.8), (1469, 0.2), (-490, -0.4), (-489, 0.6), (2448, 0.0), (2447, -1.0)):
        tau, theta = catch_torque(count)
        assert tau == pytest.approx(per_count * dev, rel=1e-5, abs=1e-9), count
        assert theta[0] == pytest.approx(count * RAD_PER_COUNT, abs=1e-5)


def test_upright_nearest_is_multi_turn_safe():
    for turn in (-2, -1, 0, 1, 3):
        count = round(UPRIGHT + 979.2 * turn)
        _, theta = catch_torque(count)
        assert theta[0] == pytest.approx((2 * turn + 1) * math.pi, abs=RAD_PER_COUNT)


def test_rate_is_exactly_zero_at_rest_and_tracks_a_steady_turn():
    sil = Sil()
    sil.hold(7, 50)
    assert sil.rate == 0.0
    count = 7
    for _ in range(200):
        count += 3
        sil.step(count)
    assert sil.rate == pytest.approx(3 * RAD_PER_COUNT / sil.p.dt, rel=1e-4)
    assert sil.mode == MODE["DISARMED"]


def test_rate_across_int32_wrap():
    """The extended hardware count may wrap after 2^31 counts; the rate must not notice."""
    sil = Sil()
    count = 2**31 - 300
    for _ in range(200):
        c = (count + 2**31) % 2**32 - 2**31
        sil.step(c)
        count += 3
    assert sil.rate == pytest.approx(3 * RAD_PER_COUNT / sil.p.dt, rel=1e-4)


def test_measured_theta_reported_outside_balance():
    sil = Sil()
    sil.hold(count_of(1.0), 3)
    mode, theta, rate = sil.status()
    assert mode == MODE["DISARMED"]
    assert theta == pytest.approx([count_of(1.0) * RAD_PER_COUNT] * sil.n, abs=1e-6)
    assert rate == [0.0] * sil.n
