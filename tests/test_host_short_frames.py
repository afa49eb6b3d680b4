"""A CRC-valid TELEMETRY frame with a 0-1 byte payload, from a fake board on a pseudo-terminal:
the decoder counts it as bad and goes on; and should the reader ever stop, the heartbeats stop, a
DISARM goes out and the command exits non-zero."""

from __future__ import annotations

import os
import re
import time

import pytest

from fake_board import FakeBoard
from rodgains.errors import UserError

from rodctl import cli
from rodctl.cli import record
from rodctl.link import protocol as P
from rodctl.link.session import Session

pytestmark = pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs pseudo-terminals")


@pytest.mark.parametrize("payload", [b"", b"\x02", bytes(3)])
def test_decoder_counts_a_short_telemetry_as_bad_and_never_raises(payload):
    d = P.Decoder()
    wire = P.encode_packet(P.MsgType.TELEMETRY, 1, 0, payload)
    ok = P.encode(P.Ack(command=P.MsgType.ARM, result=0, command_seq=1, mode=1), 2)
    frames = d.feed(wire + ok)
    assert [f.type for f in frames] == [P.MsgType.ACK]  # the next frame still decodes
    assert (d.length_errors, d.errors) == (1, 1)
    with pytest.raises(P.ProtocolError, match="payload length"):
        P.decode_frame(wire)


def _wait(cond, timeout: float = 20.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if cond():
            return True
        time.sleep(0.02)
    return False


def test_short_telemetry_from_the_board_is_counted_and_the_session_goes_on():
    with FakeBoard() as board, Session(board.path) as s:
        s.arm(P.ArmMode.SWING_UP)
        board.inject += [board.short_telemetry(b""), board.short_telemetry(b"\x02")]
        assert _wait(lambda: s.decoder.length_errors == 2)
        seen = s.telemetry_seen
        assert _wait(lambda: s.telemetry_seen > seen + 5)  # the reader still reads
        t_bad = time.monotonic()
        assert _wait(lambda: any(t > t_bad for t in board.times_of(P.MsgType.HEARTBEAT)))  # still armed, still alive
        assert s.counters()["errors"] == 2
    assert board.times_of(P.MsgType.DISARM)  # closing disarmed it


def test_arm_command_keeps_going_over_a_short_frame(monkeypatch, capsys):
    sessions = []  # the command's session, to read what its decoder counted
    real_session_for = record.session_for

    def session_for(args, **kw):
        sessions.append(real_session_for(args, **kw))
        return sessions[-1]

    monkeypatch.setattr(record, "session_for", session_for)
    board = FakeBoard()
    # Right before the ARM's ACK, so that it arrives inside the session (frames queued before the port opened
    # are flushed) and the command's arming depends on the frame after it. Made before the board runs: its
    # sequence number goes by before the session, so only a frame lost after it would show as a gap.
    board.before_arm_ack.append(board.short_telemetry(b""))
    with board:
        assert cli.main(["arm", "--swing-up", "--duration", "1", "--port", board.path]) == 0
    assert board.times_of(P.MsgType.DISARM)
    s = sessions[0]
    assert (s.decoder.length_errors, s.counters()["errors"]) == (1, 1)  # received in the session, and skipped
    lines = capsys.readouterr().err.splitlines()
    assert "armed swing-up: mode SWING_UP" in lines  # the ACK right after the short frame
    end = re.fullmatch(r"arm ended \(duration\): (\d+) frames, seq gaps 0, CRC errors 0; disarmed", lines[-1])
    assert end, lines
    # The telemetry sent while armed follows the short frame and precedes the DISARM's ACK, which arrived
    # ("disarmed"), so the command counted all of it, with the two ACKs: at least armed + 1, as one telemetry
    # can race each mode change. About 100 in the 1 s on an idle machine; the bound holds however late the
    # board's thread ran. And no more frames than the board sent.
    armed = board.telemetry_by_mode[P.Mode.SWING_UP]
    answers = len(board.received) - len(board.times_of(P.MsgType.HEARTBEAT))  # an ACK each
    answers += len(board.times_of(P.MsgType.HELLO_REQUEST))  # and a HELLO
    assert armed + 1 <= int(end[1]) <= board.telemetry_sent + answers


def test_when_the_reader_stops_heartbeats_stop_disarm_goes_out_and_the_command_fails(monkeypatch, capsys):
    """Any failure in the reader thread (here an injected one) must not leave the board armed."""
    real = Session._dispatch

    def failing_dispatch(self, frames, t):
        if self._started and self.telemetry_seen > 20:
            raise RuntimeError("injected reader failure")
        return real(self, frames, t)

    monkeypatch.setattr(Session, "_dispatch", failing_dispatch)
    with FakeBoard() as board:
        # --duration far beyond any stall: had the failure not ended the command, it would end as
        # "arm ended (duration)" with exit 0, which the asserts below tell apart
        rc = cli.main(["arm", "--swing-up", "--duration", "60", "--port", board.path])
        disarms = board.times_of(P.MsgType.DISARM)
        assert disarms, "no DISARM after the reader stopped"
        time.sleep(0.5)  # 5 heartbeat intervals: none may come after the DISARM
        beats_after = [t for t in board.times_of(P.MsgType.HEARTBEAT) if t > disarms[0]]
        port = board.path
    assert rc == 1
    assert beats_after == []
    err = capsys.readouterr().err
    assert err.splitlines()[-1] == (f"rodctl: {port}: the host stopped reading the link (RuntimeError: injected "
                                    "reader failure); heartbeats stopped, DISARM sent")
    assert "arm ended" not in err
    assert "Traceback" not in err


def test_session_check_fails_once_the_reader_stopped(monkeypatch):
    with FakeBoard() as board, Session(board.path) as s:
        s._reader_died("RuntimeError: x")
        with pytest.raises(UserError, match="stopped reading the link"):
            s.check()
        assert s.disarm_sent
