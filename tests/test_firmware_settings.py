"""Runtime settings (SET): bounds checked, refused values change nothing; command state rules."""

import math

import pytest

from firmware_sil import ACK, MODE, Dev, Sil
from rodctl.link import protocol as P

NAN, INF = float("nan"), float("inf")


def hello_of(dev: Dev):
    seq = dev.send(P.encode_hello_request)
    dev.step()
    hellos = [f.msg for f in dev.frames() if f.type == P.MsgType.HELLO]
    assert hellos, "no HELLO after HELLO_REQUEST"
    return seq, hellos[-1]


def settings_of(dev: Dev) -> dict:
    _, h = hello_of(dev)
    return {"SWING_AMPLITUDE": h.swing_amplitude, "SWING_ANGLE": h.swing_angle, "CATCH_ANGLE": h.catch_angle,
            "TELEMETRY_DECIMATION": h.decimation, "HEARTBEAT_TIMEOUT": h.heartbeat_timeout}


def f32(x: float) -> float:
    import struct

    return struct.unpack("<f", struct.pack("<f", x))[0]


TWO_DEG = f32(math.radians(2.0))  # the smallest swing and catch angle (rodlink.toml codes.param)

CASES = {
    # param: (accepted values, refused values); the ranges are rodlink.toml's, inclusive
    "SWING_AMPLITUDE": ([f32(0.001), 0.05, f32(0.2)], [0.0, 0.0009, 1e-40, -0.001, 0.2001, 1.0, NAN, INF, -INF]),
    "SWING_ANGLE": ([TWO_DEG, 1.0, f32(math.pi)], [0.0, 0.03, 1e-40, -0.1, 3.1416, 4.0, NAN, INF]),
    "CATCH_ANGLE": ([TWO_DEG, 0.5, 1.04, f32(math.radians(60.0))],
                    [0.0, 0.03, 1e-40, -0.2, 1.05, 1.2, NAN, INF]),
    "TELEMETRY_DECIMATION": ([1.0, 7.0, 1000.0], [0.0, 0.5, 2.5, 1001.0, -1.0, NAN, INF]),
    "HEARTBEAT_TIMEOUT": ([f32(0.2), 1.0, 10.0], [0.199, 0.05, 10.01, 0.0, -1.0, NAN, INF]),
}


@pytest.mark.parametrize("param", list(CASES))
def test_set_bounds(param):
    dev = Dev()
    dev.step(0)
    before = settings_of(dev)
    good, bad = CASES[param]
    for value in bad:
        seq = dev.send(P.encode_set, P.Param[param], value)
        dev.step()
        acks = [a for a in dev.acks(dev.frames()) if a.command_seq == seq]
        assert acks[0].result == P.AckResult.BAD_VALUE, (param, value)
        assert settings_of(dev) == before, (param, value)
    for value in good:
        seq = dev.send(P.encode_set, P.Param[param], value)
        dev.step()
        acks = [a for a in dev.acks(dev.frames()) if a.command_seq == seq]
        assert acks[0].result == P.AckResult.OK, (param, value)
        assert settings_of(dev)[param] == pytest.approx(value, rel=1e-6), (param, value)


def test_unknown_param_is_refused():
    sil = Sil()
    assert sil.lib.rod_sil_set(0, 1.0) == ACK["BAD_VALUE"]
    assert sil.lib.rod_sil_set(max(int(v) for v in P.Param) + 1, 1.0) == ACK["BAD_VALUE"]


def test_catch_angle_setting_moves_the_catch():
    sil = Sil()
    assert sil.set("CATCH_ANGLE", 0.1) == ACK["OK"]
    sil.arm(1)
    count = 420
    while sil.mode == MODE["CATCH"]:
        count += 1
        sil.step(count)
    assert abs(count * 2 * math.pi / 979.2 - math.pi) <= 0.1 + 1e-6
    assert abs((count - 1) * 2 * math.pi / 979.2 - math.pi) > 0.1


def test_swing_angle_setting_limits_the_pumping_region():
    sil = Sil()
    assert sil.set("SWING_ANGLE", 0.2) == ACK["OK"]
    sil.arm(2)
    u_inside = [sil.step(10 + k) for k in range(15)][-1]   # rising through 0.15 rad: pumping
    u_outside = [sil.step(40 + k) for k in range(10)][-1]  # rising past 0.26 rad: outside
    assert u_inside == pytest.approx(sil.p["swing_up"]["amplitude"], rel=1e-6)
    assert u_outside == 0.0


def test_decimation_sets_the_telemetry_rate():
    dev = Dev()
    dev.send(P.encode_set, P.Param.TELEMETRY_DECIMATION, 10.0)
    dev.run(200, count=0)
    tlm = [f for f in dev.frames() if f.type == P.MsgType.TELEMETRY]
    assert len(tlm) in (20, 21)


def test_clear_fault_when_not_faulted_is_an_ok_no_op():
    sil = Sil()
    assert sil.clear_fault() == ACK["OK"]
    assert sil.mode == MODE["DISARMED"]
    sil.catch_at(490)
    assert sil.clear_fault() == ACK["OK"]
    assert sil.mode == MODE["BALANCE"]


def test_arm_switches_between_armed_modes():
    sil = Sil()
    sil.arm(2)
    sil.step(0)
    assert sil.arm(1) == ACK["OK"] and sil.mode == MODE["CATCH"]
    assert sil.step(0) == 0.0 and sil.enable == 0


def test_malformed_input_changes_nothing_and_is_counted():
    dev = Dev()
    dev.step(0)
    junk = [b"\x00", b"\x01\x02\x03\x00", bytes(range(1, 200)) + b"\x00", b"\xff" * 700 + b"\x00"]
    wire = bytearray(P.encode_arm(P.ArmMode.SWING_UP, seq=1))
    wire[5] ^= 0x40  # corrupt a byte: CRC must reject it
    junk.append(bytes(wire))
    for j in junk:
        dev.write_raw(j)
        dev.step()
    assert dev.mode == MODE["DISARMED"] and dev.enable == 0
    dev.step()
    tlm = [f.msg for f in dev.frames() if f.type == P.MsgType.TELEMETRY]
    # One error per malformed frame (the overlong one counted once, when it overflows); the lone 0x00 is an
    # idle line, not a frame: 5 junk writes, 4 errors.
    assert tlm[-1].rx_errors == 4
    assert tlm[-1].mode == P.Mode.DISARMED
    # a good frame right after still works
    seq = dev.send(P.encode_arm, P.ArmMode.SWING_UP)
    dev.step()
    assert dev.mode == MODE["SWING_UP"]
    assert any(a.command_seq == seq and a.result == P.AckResult.OK for a in dev.acks(dev.frames()))


def test_wrong_length_command_is_refused_and_changes_nothing():
    dev = Dev()
    dev.step(0)
    # an ARM packet with no payload: CRC-valid, wrong length
    wire = P.encode_packet(P.MsgType.ARM, 9, 0, b"")
    dev.write_raw(wire)
    dev.step()
    acks = [a for a in dev.acks(dev.frames()) if a.command_seq == 9]
    assert acks and acks[0].result == P.AckResult.BAD_LENGTH
    assert dev.mode == MODE["DISARMED"]
