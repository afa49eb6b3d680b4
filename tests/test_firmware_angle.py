"""Encoder count to theta_1: exact wrap on 979.2 counts per turn (or the rig's own), multi-turn, and the base rate."""

import contextlib
import ctypes as C
import math

import pytest

from firmware_sil import ACK, MODE, RAD_PER_COUNT, UPRIGHT, Sil, count_of, library
from rodctl.link import protocol as P


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


# ---- counts per output turn as a run-time rig setting (SET COUNTS_PER_REV, SAVE_RIG) ----------------

class Counts(C.Structure):
    _fields_ = [("num", C.c_int32), ("den", C.c_int32), ("rad_per_tick", C.c_float), ("rad_per_count", C.c_float)]


class Rig(C.Structure):
    _fields_ = [("encoder_sign", C.c_int8), ("motor_sign", C.c_int8), ("counts", Counts)]


def core():
    lib = library()
    lib.rod_counts_from_value.restype = C.c_bool
    lib.rod_counts_from_value.argtypes = [C.c_float, C.POINTER(Counts)]
    lib.rod_rig_decode.restype = C.c_uint8
    lib.rod_rig_decode.argtypes = [C.c_char_p, C.c_size_t, Rig, C.POINTER(Rig)]
    lib.rod_rig_encode.restype = None
    lib.rod_rig_encode.argtypes = [C.POINTER(Rig), C.c_char_p]
    lib.rod_counts_make.restype = C.c_bool
    lib.rod_counts_make.argtypes = [C.c_int32, C.c_int32, C.POINTER(Counts)]
    return lib


@pytest.mark.parametrize("value, fraction", [(979.2, (4896, 5)), (1958.4, (9792, 5)), (48.0, (48, 1)),
                                             (500.5, (1001, 2)), (1000.0 / 3.0, (1000, 3)), (1e6, (1000000, 1))])
def test_a_counts_value_becomes_its_exact_fraction(value, fraction):
    """The board keeps counts per turn as the simplest num / den within 1e-4 count, so the gear ratio's
    fraction (20.4 x 48 = 4896 / 5) lands every upright on an exact tick, as the compiled one does."""
    c = Counts()
    assert core().rod_counts_from_value(value, C.byref(c))
    assert (c.num, c.den) == fraction


@pytest.mark.parametrize("value", [1.0, 15.0, 1e6 + 1.0, math.nan, math.inf, -979.2])
def test_a_counts_value_out_of_range_is_refused(value):
    assert not core().rod_counts_from_value(value, C.byref(Counts()))


def test_another_counts_per_turn_reduces_the_count_exactly():
    """SET counts_per_rev = 1958.4: upright is 979.2 counts; every 5 turns (9792 counts) gives the same catch
    torque bit for bit, and a count reads count x 2 pi / 1958.4."""
    def catch(count):
        sil = Sil()
        assert sil.set("COUNTS_PER_REV", 1958.4) == ACK["OK"]
        return sil.catch_at(count), sil.status()[1]

    base, theta = catch(979)
    assert theta[0] - math.pi == pytest.approx((979 - 979.2) * 2 * math.pi / 1958.4, abs=1e-6)
    for turns5 in (-3, 1, 40):
        assert catch(979 + 9792 * turns5)[0] == base
    sil = Sil()
    assert sil.set("COUNTS_PER_REV", 8.0) == ACK["BAD_VALUE"]
    sil.catch_at(490)
    assert sil.set("COUNTS_PER_REV", 1958.4) == ACK["BAD_STATE"]


def test_the_stored_rig_keeps_the_counts_and_reads_the_older_layout():
    lib = core()
    defaults = Rig(1, 1, Counts(4896, 5, 0.0, 0.0))
    mine = Rig(-1, 1, Counts(9792, 5, 0.0, 0.0))
    buf = C.create_string_buffer(16)
    lib.rod_rig_encode(C.byref(mine), buf)
    out = Rig()
    assert lib.rod_rig_decode(buf.raw, 16, defaults, C.byref(out)) == 0x04  # STORED
    assert (out.encoder_sign, out.motor_sign, out.counts.num, out.counts.den) == (-1, 1, 9792, 5)
    assert out.counts.rad_per_count == pytest.approx(2 * math.pi / 1958.4, rel=1e-6)
    # layout 1 (a board stored before counts were a setting): its signs, the compiled counts
    old = b"RG\x01\xff\x01\x00" + P.crc16(b"RG\x01\xff\x01\x00").to_bytes(2, "little") + b"\xff" * 8
    assert lib.rod_rig_decode(old, 16, defaults, C.byref(out)) == 0x04
    assert (out.encoder_sign, out.counts.num, out.counts.den) == (-1, 4896, 5)
    # a record with den 0 (valid CRC) or cut short is corrupt: the defaults, and HELLO says so
    bad = bytearray(buf.raw)
    bad[10:12] = b"\0\0"
    bad[14:16] = P.crc16(bytes(bad[:14])).to_bytes(2, "little")
    # ... and so is one with fewer counts per turn than SET accepts (2 / 1000: angles would overflow)
    few = Rig(1, 1, Counts(2, 1000, 0.0, 0.0))
    raw = bytearray(buf.raw)
    raw[6:10], raw[10:12] = (2).to_bytes(4, "little"), (1000).to_bytes(2, "little")
    raw[14:16] = P.crc16(bytes(raw[:14])).to_bytes(2, "little")
    assert lib.rod_rig_decode(bytes(raw), 16, defaults, C.byref(few)) == 0x08
    assert not lib.rod_counts_make(15, 1, C.byref(Counts())) and lib.rod_counts_make(16, 1, C.byref(Counts()))
    for data, n in ((bytes(bad), 16), (buf.raw, 8)):
        assert lib.rod_rig_decode(data, n, defaults, C.byref(out)) == 0x08  # STORE_CORRUPT
        assert (out.encoder_sign, out.counts.num) == (1, 4896)


def test_save_rig_stores_the_settings_as_they_were_when_it_arrived():
    """A SET handled after SAVE_RIG, before the main loop writes the EEPROM, is not stored: the record is
    the settings the host asked to keep (the virtual board's main loop takes it after each step)."""
    from rodctl.sim.device import VirtualDevice

    dev = VirtualDevice.from_options()
    try:
        dev.step()
        dev.write(P.encode(P.SaveRig(), 1) + P.encode(P.Set(P.Param.ENCODER_SIGN, -1.0), 2)
                  + P.encode(P.Set(P.Param.COUNTS_PER_REV, 1958.4), 3))
        dev.step()
        dev.write(P.encode(P.HelloRequest(), 4))
        dev.step()
        frames = P.Decoder().feed(dev.read())
        acks = [f.msg.result for f in frames if f.type == P.MsgType.ACK]
        assert acks[:3] == [P.AckResult.OK] * 3  # SAVE_RIG and both SETs were taken ...
        hello = [f.msg for f in frames if f.type == P.MsgType.HELLO][-1]
        assert hello.rig & P.RigFlag.ENCODER_REVERSED and (hello.counts_num, hello.counts_den) == (9792, 5)
        assert len(dev.eeprom) == 16  # ... but the record is the settings SAVE_RIG found
        out = Rig()
        assert core().rod_rig_decode(dev.eeprom, 16, Rig(1, 1, Counts(4896, 5, 0.0, 0.0)), C.byref(out)) == 0x04
        assert (out.encoder_sign, out.counts.num, out.counts.den) == (1, 4896, 5)
    finally:
        dev.close()


def test_save_rig_while_armed_is_refused_and_writes_nothing():
    """SAVE_RIG while swinging up: BAD_STATE, the EEPROM untouched (a write holds the board's main loop for
    milliseconds, heartbeats uncounted, nearer the watchdog); disarmed, the same command stores the record."""
    from rodctl.sim.device import VirtualDevice

    dev = VirtualDevice.from_options()
    try:
        dev.step()
        dev.write(P.encode(P.Arm(P.ArmMode.SWING_UP), 1) + P.encode(P.SaveRig(), 2))
        dev.step()
        dev.step()
        assert len(dev.eeprom) == 0  # nothing written while armed
        dev.write(P.encode(P.Disarm(), 3) + P.encode(P.SaveRig(), 4))
        dev.step()
        dev.step()
        acks = {f.msg.command_seq: f.msg.result for f in P.Decoder().feed(dev.read()) if f.type == P.MsgType.ACK}
        assert acks == {1: P.AckResult.OK, 2: P.AckResult.BAD_STATE, 3: P.AckResult.OK, 4: P.AckResult.OK}
        assert len(dev.eeprom) == 16  # written by the disarmed SAVE_RIG
        # an ARM right behind a SAVE_RIG waits for the write: the board's main loop is held while it runs
        dev.write(P.encode(P.SaveRig(), 5) + P.encode(P.Arm(P.ArmMode.SWING_UP), 6))
        dev.step()
        dev.write(P.encode(P.Arm(P.ArmMode.SWING_UP), 7))
        dev.step()
        acks = {f.msg.command_seq: f.msg.result for f in P.Decoder().feed(dev.read()) if f.type == P.MsgType.ACK}
        assert acks == {5: P.AckResult.OK, 6: P.AckResult.BUSY, 7: P.AckResult.OK}, acks
    finally:
        dev.close()


def test_hello_flags_stored_only_while_the_settings_in_use_are_the_stored_ones(tmp_path):
    """STORED means the settings survive a power cycle as they are: a SET after SAVE_RIG (or after a
    power-on from storage) clears it, setting the stored value back raises it again."""
    from rodctl.sim.device import VirtualDevice

    def hello_after(dev, *msgs):
        dev.write(b"".join(P.encode(m, i + 1) for i, m in enumerate((*msgs, P.HelloRequest()))))
        dev.step()
        frames = P.Decoder().feed(dev.read())
        assert [f.msg.result for f in frames if f.type == P.MsgType.ACK] == [P.AckResult.OK] * (len(msgs) + 1)
        return [f.msg for f in frames if f.type == P.MsgType.HELLO][-1]

    @contextlib.contextmanager
    def powered_on(eeprom):
        dev = VirtualDevice.from_options(eeprom=str(eeprom))
        try:
            dev.step()
            dev.read()
            yield dev
        finally:
            dev.close()

    eeprom = tmp_path / "eeprom.bin"
    with powered_on(eeprom) as dev:
        assert not hello_after(dev).rig & P.RigFlag.STORED  # nothing stored: the compiled defaults
        # STORED once the board's main loop has written the record (after the step)
        assert not hello_after(dev, P.Set(P.Param.ENCODER_SIGN, -1.0), P.SaveRig()).rig & P.RigFlag.STORED
        assert hello_after(dev).rig & P.RigFlag.STORED and len(dev.eeprom) == 16
        flipped = hello_after(dev, P.Set(P.Param.MOTOR_SIGN, -1.0))
        assert flipped.rig & P.RigFlag.MOTOR_REVERSED and not flipped.rig & P.RigFlag.STORED
        assert hello_after(dev, P.Set(P.Param.MOTOR_SIGN, 1.0)).rig & P.RigFlag.STORED
        assert not hello_after(dev, P.Set(P.Param.COUNTS_PER_REV, 1958.4)).rig & P.RigFlag.STORED
    with powered_on(eeprom) as dev:  # from the record
        hello = hello_after(dev)
        assert hello.rig & P.RigFlag.STORED and hello.rig & P.RigFlag.ENCODER_REVERSED
        assert (hello.counts_num, hello.counts_den) == (4896, 5)
        assert not hello_after(dev, P.Set(P.Param.ENCODER_SIGN, 1.0)).rig & P.RigFlag.STORED
    # a layout-1 record (signs only, 8 bytes) is the stored record: STORED, with the compiled counts
    raw = bytearray(b"RG\x01\xff\x01\x00")
    raw += P.crc16(bytes(raw)).to_bytes(2, "little")
    eeprom.write_bytes(bytes(raw))
    with powered_on(eeprom) as dev:
        hello = hello_after(dev)
        assert hello.rig & P.RigFlag.STORED and hello.rig & P.RigFlag.ENCODER_REVERSED
        assert (hello.counts_num, hello.counts_den) == (4896, 5)
    # an unreadable record: the compiled defaults, STORE_CORRUPT until a SAVE_RIG replaces it
    eeprom.write_bytes(bytes(raw[:6]) + b"\x00\x00")
    with powered_on(eeprom) as dev:
        hello = hello_after(dev)
        assert hello.rig & P.RigFlag.STORE_CORRUPT and not hello.rig & (P.RigFlag.STORED | P.RigFlag.ENCODER_REVERSED)
        hello_after(dev, P.SaveRig())
        hello = hello_after(dev)
        assert hello.rig & P.RigFlag.STORED and not hello.rig & P.RigFlag.STORE_CORRUPT


def test_a_counts_value_with_no_small_fraction_gets_the_closest_that_fits():
    c = Counts()
    assert core().rod_counts_from_value(314.159265, C.byref(c))
    assert c.den <= 1000 and abs(c.num / c.den - 314.159265) < 1.2e-4  # 35500 / 113: 2.7e-5 count/turn off
