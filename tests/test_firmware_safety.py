"""Every safety trip: FAULT with the right reason, driver off and zero duty at once, latched until clear-fault."""

import math

import pytest

from firmware_sil import ACK, MODE, RAD_PER_COUNT, REASON, UPRIGHT, Dev, Sil, count_of
from rodctl.link import protocol as P


def assert_faulted(dev, reason: str, torque: float) -> None:
    assert dev.mode == MODE["FAULT"]
    assert dev.reason == REASON[reason]
    assert torque == 0.0
    assert dev.duty == 0.0
    assert dev.enable == 0


def assert_latched_until_cleared(sil: Sil) -> None:
    """Arm is refused in FAULT; clear-fault leaves it for DISARMED; then arm works again."""
    for mode in (1, 2):
        assert sil.arm(mode) == ACK["BAD_STATE"]
        assert sil.mode == MODE["FAULT"]
    assert sil.arm(0) == ACK["OK"] and sil.mode == MODE["FAULT"]  # disarm does not clear it
    assert sil.step(490) == 0.0 and sil.enable == 0
    assert sil.clear_fault() == ACK["OK"]
    assert sil.mode == MODE["DISARMED"]
    assert sil.arm(1) == ACK["OK"]


# ---- through the SIL ABI ---------------------------------------------------------------------

def test_angle_limit_trips_exactly_beyond_the_limit():
    sil = Sil()
    limit = math.radians(sil.p["safety"]["angle_limit_deg"])
    sil.catch_at(490)
    first_beyond = math.floor(UPRIGHT + limit / RAD_PER_COUNT) + 1
    count = 490
    while count < first_beyond - 1:
        count += 1  # pushed over by hand, ~6 rad/s
        sil.step(count)
        assert sil.mode == MODE["BALANCE"], count
    u = sil.step(first_beyond)
    assert_faulted(sil, "ANGLE_LIMIT", u)
    assert_latched_until_cleared(sil)


def test_angle_limit_the_other_way():
    sil = Sil()
    limit = math.radians(sil.p["safety"]["angle_limit_deg"])
    sil.catch_at(489)
    count = 489
    while sil.mode == MODE["BALANCE"]:
        count -= 1
        u = sil.step(count)
    assert_faulted(sil, "ANGLE_LIMIT", u)
    assert (UPRIGHT - count) * RAD_PER_COUNT > limit
    assert (UPRIGHT - count - 1) * RAD_PER_COUNT <= limit


def test_speed_limit_trips_in_swing_up():
    sil = Sil()
    limit = sil.p["safety"]["speed_limit"]
    sil.arm(2)
    sil.step(0)
    count, u = 0, 0.0
    per_step = math.ceil(1.15 * limit * sil.p.dt / RAD_PER_COUNT)
    for _ in range(100):
        count += per_step
        u = sil.step(count)
        if sil.mode == MODE["FAULT"]:
            break
    assert_faulted(sil, "SPEED_LIMIT", u)
    assert_latched_until_cleared(sil)


def test_speed_below_the_limit_does_not_trip():
    """Swinging hard through the bottom, peak base speed at 75 % of the limit."""
    sil = Sil()
    limit = sil.p["safety"]["speed_limit"]
    sil.arm(2)
    sil.past_runaway_watch()
    amplitude = 0.6  # rad, inside the swing region, far from the catch angle
    omega = 0.75 * limit / amplitude
    peak = 0.0
    for k in range(2000):
        sil.step(count_of(amplitude * math.sin(omega * k * sil.p.dt)))
        peak = max(peak, abs(sil.rate))
    assert sil.mode == MODE["SWING_UP"]
    assert peak == pytest.approx(0.75 * limit, rel=0.1)


def test_speed_limit_applies_while_waiting_to_catch():
    sil = Sil()
    sil.arm(1)
    count = 0
    for _ in range(100):
        count += 9
        sil.step(count)
    assert sil.mode == MODE["FAULT"] and sil.reason == REASON["SPEED_LIMIT"]


def test_nan_in_the_estimate_trips_non_finite():
    sil = Sil()
    sil.catch_at(490)
    sil.hold(490, 5)
    sil.lib.rod_sil_inject_nan()
    u = sil.step(490)
    assert_faulted(sil, "NON_FINITE", u)
    assert not math.isnan(sil.duty)
    assert_latched_until_cleared(sil)


# ---- through the virtual device (explicit time, nFAULT, real protocol) -------------------------

def armed_dev(**kw) -> Dev:
    dev = Dev(**kw)
    dev.step(490)
    dev.send(P.encode_arm, P.ArmMode.BALANCE)
    dev.step()
    assert dev.mode == MODE["BALANCE"]
    return dev


def test_nfault_trips_in_the_same_step():
    dev = armed_dev()
    dev.run(10)
    assert dev.enable == 1
    u = dev.step(fault=True)
    assert_faulted(dev, "DRIVER_FAULT", u)
    # stays latched after nFAULT recovers
    dev.run(5)
    assert dev.mode == MODE["FAULT"] and dev.enable == 0


def test_nfault_while_disarmed_latches_fault_so_arming_is_refused():
    dev = Dev()
    dev.step(0)
    dev.step(fault=True)
    assert dev.mode == MODE["FAULT"] and dev.reason == REASON["DRIVER_FAULT"]
    seq = dev.send(P.encode_arm, P.ArmMode.SWING_UP)
    dev.step()
    acks = [a for a in dev.acks(dev.frames()) if a.command_seq == seq]
    assert acks and acks[0].result == P.AckResult.BAD_STATE
    assert dev.mode == MODE["FAULT"] and dev.enable == 0


@pytest.mark.parametrize("timeout", [None, 0.2, 2.0])
def test_heartbeat_timeout_trips_at_the_configured_time(timeout):
    dev = Dev()
    dev.step(490)
    if timeout is not None:
        dev.send(P.encode_set, P.Param.HEARTBEAT_TIMEOUT, timeout)
    else:
        timeout = dev.p["safety"]["heartbeat_timeout"]
    dev.send(P.encode_arm, P.ArmMode.BALANCE)
    t_arm = dev.now
    dev.step()
    assert dev.mode == MODE["BALANCE"]
    t_trip, u = None, None
    for _ in range(round(2 * timeout / dev.p.dt) + 10):
        t = dev.now
        u = dev.step()
        if dev.mode != MODE["BALANCE"]:
            t_trip = t
            break
    assert t_trip is not None
    assert_faulted(dev, "HEARTBEAT", u)
    elapsed_us = t_trip - t_arm
    assert abs(elapsed_us - round(timeout * 1e6)) <= dev.period_us


def test_heartbeats_keep_it_armed():
    dev = armed_dev()
    timeout = dev.p["safety"]["heartbeat_timeout"]
    every = round(0.4 * timeout / dev.p.dt)
    for k in range(round(5 * timeout / dev.p.dt)):
        if k % every == 0:
            dev.send(P.encode_heartbeat)
        dev.step()
    assert dev.mode == MODE["BALANCE"]


def test_no_heartbeat_needed_while_disarmed():
    dev = Dev()
    dev.run(3000, count=0)
    assert dev.mode == MODE["DISARMED"]


def test_overrun_by_a_late_step_trips():
    dev = armed_dev()
    dev.run(5)
    dev.step(dt_us=int(1.5 * dev.period_us))  # exactly 1.5 periods: still on time
    dev.step()
    assert dev.mode == MODE["BALANCE"]
    dev.step(dt_us=int(1.5 * dev.period_us) + 1)
    u = dev.step()
    assert_faulted(dev, "OVERRUN", u)


def test_overrun_by_a_long_step_trips():
    dev = armed_dev()
    dev.step(last_step_us=dev.period_us)  # a full period of CPU time: still on time
    assert dev.mode == MODE["BALANCE"]
    u = dev.step(last_step_us=dev.period_us + 1)
    assert_faulted(dev, "OVERRUN", u)


def test_overruns_are_counted_in_telemetry_even_while_disarmed():
    dev = Dev()
    dev.run(3, count=0)
    dev.step(last_step_us=5000)
    dev.run(2)
    assert dev.mode == MODE["DISARMED"]
    tlm = [f.msg for f in dev.frames() if f.type == P.MsgType.TELEMETRY]
    assert tlm[-1].overruns == 1


def test_fault_then_clear_through_the_protocol():
    dev = armed_dev()
    dev.step(fault=True)
    seq_arm = dev.send(P.encode_arm, P.ArmMode.BALANCE)
    dev.step()
    seq_clear = dev.send(P.encode_clear_fault)
    dev.step()
    seq_arm2 = dev.send(P.encode_arm, P.ArmMode.BALANCE)
    dev.step()
    acks = {a.command_seq: a for a in dev.acks(dev.frames())}
    assert acks[seq_arm].result == P.AckResult.BAD_STATE and acks[seq_arm].mode == P.Mode.FAULT
    assert acks[seq_clear].result == P.AckResult.OK and acks[seq_clear].mode == P.Mode.DISARMED
    assert acks[seq_arm2].result == P.AckResult.OK
    assert dev.mode == MODE["BALANCE"]
