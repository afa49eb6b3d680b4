"""The device side of rodlink through the virtual device: HELLO, ACKs, telemetry, numbering, drops."""

import pytest

from firmware_sil import MODE, Dev, header_path
from rodctl.link import protocol as P


def version_from_header() -> tuple[int, int, int]:
    from rodctl import paths

    text = (paths.CORE_SRC / "rod_version.h").read_text()
    vals = {}
    for key in ("MAJOR", "MINOR", "PATCH"):
        line = next(l for l in text.splitlines() if f"ROD_FW_VERSION_{key}" in l and l.startswith("#define"))
        vals[key] = int(line.split()[2])
    return vals["MAJOR"], vals["MINOR"], vals["PATCH"]


def test_hello_at_start_up_describes_firmware_and_settings():
    dev = Dev()
    dev.step(0)
    frames = dev.frames()
    hellos = [f for f in frames if f.type == P.MsgType.HELLO]
    assert len(hellos) == 1
    h = hellos[0].msg
    p = dev.p
    assert (h.fw_major, h.fw_minor, h.fw_patch) == version_from_header()
    assert h.gains_schema == 5
    assert h.n == p.N
    assert h.mode == P.Mode.DISARMED
    assert h.period_us == round(p.dt * 1e6)
    assert h.decimation == 1
    assert h.swing_amplitude == pytest.approx(p["swing_up"]["amplitude"], rel=1e-6)
    assert h.heartbeat_timeout == pytest.approx(p["safety"]["heartbeat_timeout"], rel=1e-6)
    assert h.torque_max == pytest.approx(p.torque_max, rel=1e-6)
    assert bytes(h.header_sha256) == bytes.fromhex(p.sha256())
    assert p.sha256() in header_path().read_text()


def test_hello_once_per_second_and_on_request():
    dev = Dev()
    dev.run(2500, count=0)
    hellos = [f for f in dev.frames() if f.type == P.MsgType.HELLO]
    assert len(hellos) == 3
    times = [f.time_us for f in hellos]
    assert times[1] - times[0] == pytest.approx(1_000_000, abs=dev.period_us)
    seq = dev.send(P.encode_hello_request)
    dev.step()
    frames = dev.frames()
    assert any(f.type == P.MsgType.HELLO for f in frames)
    assert any(a.command_seq == seq and a.result == P.AckResult.OK for a in dev.acks(frames))


def test_every_command_is_acked_with_its_seq_and_the_mode_after_it():
    dev = Dev()
    dev.step(490)
    sent = [
        (dev.send(P.encode_heartbeat), P.MsgType.HEARTBEAT, P.AckResult.OK),
        (dev.send(P.encode_set, P.Param.SWING_ANGLE, 0.3), P.MsgType.SET, P.AckResult.OK),
        (dev.send(P.encode_arm, P.ArmMode.BALANCE), P.MsgType.ARM, P.AckResult.OK),
    ]
    dev.step()
    sent.append((dev.send(P.encode_disarm), P.MsgType.DISARM, P.AckResult.OK))
    dev.step()
    acks = {a.command_seq: a for a in dev.acks(dev.frames())}
    for seq, kind, result in sent:
        assert acks[seq].command == kind
        assert acks[seq].result == result
    assert acks[sent[2][0]].mode == P.Mode.CATCH  # mode right after the ARM (caught in the same step)
    assert acks[sent[3][0]].mode == P.Mode.DISARMED
    assert dev.mode == MODE["DISARMED"]


def test_telemetry_reports_the_step():
    dev = Dev()
    dev.step(490)
    dev.send(P.encode_arm, P.ArmMode.BALANCE)
    for _ in range(10):
        u = dev.step(490)
    tlm = [f.msg for f in dev.frames() if f.type == P.MsgType.TELEMETRY]
    t = tlm[-1]
    mode, theta, rate = dev.status()
    assert t.mode == P.Mode.BALANCE and t.reason == P.Reason.NONE
    assert t.flags & P.TelemetryFlag.DRIVER_ENABLED
    assert t.flags & P.TelemetryFlag.HEARTBEAT_OK
    assert not t.flags & P.TelemetryFlag.NFAULT_LOW
    assert t.n == dev.n and t.encoder_count == 490
    assert t.torque == pytest.approx(u, abs=1e-7)
    assert t.duty == pytest.approx(dev.duty, abs=1e-7)
    assert list(t.theta_hat) == pytest.approx(theta, abs=1e-6)
    assert list(t.rate_hat) == pytest.approx(rate, abs=1e-6)


def test_telemetry_flags_follow_nfault_and_host_silence():
    dev = Dev()
    dev.step(0)
    dev.step(fault=True)
    t = [f.msg for f in dev.frames() if f.type == P.MsgType.TELEMETRY][-1]
    assert t.flags & P.TelemetryFlag.NFAULT_LOW
    assert not t.flags & P.TelemetryFlag.DRIVER_ENABLED
    dev.run(round(dev.p["safety"]["heartbeat_timeout"] / dev.p.dt) + 5)
    t = [f.msg for f in dev.frames() if f.type == P.MsgType.TELEMETRY][-1]
    assert not t.flags & P.TelemetryFlag.HEARTBEAT_OK


def test_frames_are_numbered_by_one_counter_without_gaps():
    dev = Dev()
    for k in range(300):
        if k % 50 == 0:
            dev.send(P.encode_heartbeat)
        dev.step(0)
    frames = dev.frames()
    seqs = [f.seq for f in frames]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))
    assert {f.type for f in frames} == {P.MsgType.TELEMETRY, P.MsgType.ACK, P.MsgType.HELLO}
    assert dev.decoder.counters()["seq_gaps"] == 0


def test_a_host_that_does_not_read_loses_frames_as_counted_gaps():
    dev = Dev(tx_capacity=512)  # like the Teensy's 8 USB packets of 64 bytes
    dev.run(20, count=0)
    dev.reading = False
    dev.run(200)  # host not reading: USB buffer full, frames dropped
    dev.reading = True
    dev.run(50)
    frames = dev.frames()
    seqs = [f.seq for f in frames]
    missing = (seqs[-1] - seqs[0] + 1) - len(seqs)
    assert missing > 100
    tlm = [f.msg for f in frames if f.type == P.MsgType.TELEMETRY]
    assert tlm[-1].frames_dropped == missing


def test_a_burst_of_commands_is_delayed_never_lost():
    """More commands than the command ring holds arrive at once: all are applied and acked, in order."""
    dev = Dev()
    dev.step(0)
    seqs = [dev.send(P.encode_heartbeat) for _ in range(60)]
    dev.run(10)
    acked = [a.command_seq for a in dev.acks(dev.frames())]
    assert acked == seqs
