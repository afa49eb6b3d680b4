"""rodctl processes against `rodctl sim-device --pty` in another process: kill, Ctrl-C, unplug."""

from __future__ import annotations

import signal
import subprocess
import time

import numpy as np
import pytest

from host_tools import Listener, ctrl_c_as_at_a_terminal, run_rodctl, sim_device, start_rodctl

from rodctl.link import protocol as P
from rodctl.logs import read_log, telemetry

pytestmark = pytest.mark.skipif(not hasattr(__import__("os"), "openpty"), reason="needs pseudo-terminals")


def _wait_rows(path, rows: int, timeout: float = 30):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if path.exists():
            try:
                _, data = read_log(path)
                if len(data) >= rows:
                    return data
            except Exception:  # noqa: BLE001 - header not written yet
                pass
        time.sleep(0.1)
    raise AssertionError(f"{path}: fewer than {rows} rows after {timeout} s")


def test_sim_device_serves_another_rodctl_over_a_pty():
    with sim_device() as (_, pts):
        r = run_rodctl("status", "--port", pts)
        assert r.returncode == 0, r.stderr
        assert f"port        {pts}" in r.stdout
        assert "parameters firmware/include/rod_gains.toml" in r.stdout
        assert "mode        DISARMED" in r.stdout


def test_arming_with_a_design_the_board_does_not_run_warns_and_logs_the_boards_own(tmp_path):
    """Tutorial step 5 arms with --params my_rig.toml: when the board was not flashed with it, the run went on with
    the board's own gains and said nothing (the log named them)."""
    from rodctl.logs import read_log

    out = tmp_path / "run.csv"
    with sim_device() as (_, pts):
        r = run_rodctl("arm", "--balance", "--port", pts, "--duration", "0.3", "--set", "rod.length=0.14",
                       "--out", str(out))
        same = run_rodctl("arm", "--balance", "--port", pts, "--duration", "0.3")
    assert r.returncode == 0, r.stderr
    warning = [ln for ln in r.stderr.splitlines() if ln.startswith("rodctl: warning:")]
    assert warning == ["rodctl: warning: the board does not run the design of defaults with --set rod.length=0.14: "
                       "its header " + read_log(out).meta["header_sha256"][:12] + " is the design of "
                       "firmware/include/rod_gains.toml, and that design runs (the log names it); to run yours: "
                       "rodctl flash --set rod.length=0.14"]
    assert read_log(out).meta["params_source"] == "firmware/include/rod_gains.toml"
    assert same.returncode == 0 and "warning" not in same.stderr


def test_sigkill_of_log_leaves_a_readable_csv_and_a_board_that_disarms_itself(tmp_path):
    out = tmp_path / "killed.csv"
    with sim_device() as (dev, pts):
        log = start_rodctl("log", "--port", pts, "--arm", "balance", "--out", str(out))
        try:
            data = _wait_rows(out, 1500)
            assert telemetry(data)["mode_name"][-1] == "CATCH"  # armed when killed
            log.send_signal(signal.SIGKILL)
            t_kill = time.monotonic()
            log.wait(timeout=10)
        finally:
            if log.poll() is None:
                log.kill()
            log.communicate()
        # reconnect passively (no heartbeat of ours) and watch the board trip its watchdog
        listener = Listener(pts)
        try:
            hit = listener.wait_for(lambda f: f.type == P.MsgType.TELEMETRY and f.msg.mode == P.Mode.FAULT, 60.0)
        finally:
            listener.close()
        assert hit is not None, "the board stayed armed without a host"
        t_fault, frame = hit
        print(f"\nFAULT (HEARTBEAT) seen {t_fault - t_kill:.3f} s after the SIGKILL")
        assert frame.msg.reason == P.Reason.HEARTBEAT
        assert not frame.msg.flags & P.TelemetryFlag.DRIVER_ENABLED
        # It trips by itself; when, by the device's own clock, is pinned in test_firmware_safety.py
        # (wall-clock delays here depend on the machine's load).
        # a user reconnecting sees why it stopped
        r = run_rodctl("status", "--port", pts)
        assert "mode        FAULT (heartbeat lost): run `rodctl clear-fault`" in r.stdout, (r.stdout, r.stderr)

    meta, data = read_log(out)  # every complete row parses
    assert meta["incomplete_rows"] == "0"  # whole rows only: the writer never leaves half a line
    assert len(data) >= 1500
    assert np.all(np.diff(data["seq_count"]) >= 1) and np.all(np.diff(data["time_s"]) > 0)
    assert "closed_utc" not in meta  # no clean close happened


def _as_under_nohup() -> None:
    """Popen preexec_fn: SIGHUP ignored, as `nohup` leaves it (and SIGINT as a terminal gives it)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGHUP, signal.SIG_IGN)


def test_a_log_under_nohup_outlives_the_terminal_that_started_it(tmp_path):
    """`nohup rodctl log ... &` then logging out: the SIGHUP the terminal sends is ignored, as nohup asks, and
    the log runs its whole duration (rodctl put its own handler over the ignore and stopped as at a Ctrl-C)."""
    out = tmp_path / "unattended.csv"
    log = start_rodctl("log", "--port", "sim://", "--duration", "4", "--out", str(out), preexec_fn=_as_under_nohup)
    try:
        _wait_rows(out, 500)
        log.send_signal(signal.SIGHUP)
        _, err = log.communicate(timeout=60)
    finally:
        if log.poll() is None:
            log.kill()
    assert log.returncode == 0, err
    meta, data = read_log(out)
    assert meta["end"] == "duration" and len(data) > 500, meta  # not "SIGHUP"


@pytest.mark.parametrize("sig, ended", [(signal.SIGINT, "Ctrl-C"), (signal.SIGTERM, "SIGTERM")])
def test_ctrl_c_or_sigterm_of_log_leaves_a_valid_file_and_disarms(tmp_path, sig, ended):
    """SIGTERM (a service manager, `timeout`) stops as Ctrl-C does, and the log's trailer says which it was."""
    out = tmp_path / "interrupted.csv"
    with sim_device() as (dev, pts):
        log = start_rodctl("log", "--port", pts, "--arm", "balance", "--out", str(out))
        try:
            _wait_rows(out, 1500)
            log.send_signal(sig)
            _, err = log.communicate(timeout=20)
        finally:
            if log.poll() is None:
                log.kill()
        assert log.returncode == 0, err
        assert "Traceback" not in err
        assert err.strip().splitlines()[-1].endswith("; disarmed")
        # the board: DISARMED by the host, not FAULT, and it stays so with nobody attached, past twice its
        # heartbeat timeout by its own clock
        def span_us(frames):
            return (frames[-1].time_us - frames[0].time_us) % 2**32 if frames else 0

        listener = Listener(pts)
        try:
            frames, end = [], time.monotonic() + 60.0
            while span_us(frames) < 1_000_000 and time.monotonic() < end:
                frames += [f for _, f in listener.frames(0.05) if f.type == P.MsgType.TELEMETRY]
        finally:
            listener.close()
        assert span_us(frames) >= 1_000_000, "the board's clock did not advance 1 s"
        assert all((f.msg.mode, f.msg.reason) == (P.Mode.DISARMED, P.Reason.HOST) for f in frames)

    log = read_log(out)
    meta, data = log
    assert meta["end"] == ended and meta["incomplete_rows"] == "0"
    ev = log.events
    frame_events = ev[np.isin(ev["event_name"], ["HELLO", "ACK"])]
    assert int(meta["frames"]) == len(data) + len(frame_events) + int(meta["heartbeat_acks"]) and \
        int(meta["rows"]) == len(data)
    assert meta["seq_gaps"] == "0" and meta["device_frames_dropped"] == "0"
    seqs = np.sort(np.concatenate([data["seq_count"], frame_events["seq_count"]]))
    assert len(seqs) == len(set(seqs)) and np.all(np.diff(data["time_s"]) > 0)
    acks = [a for a in ev[ev["event_name"] == "ACK"]["info_text"] if not a.startswith("ACK HEARTBEAT")]
    assert acks[0].startswith("ACK HELLO_REQUEST ") and acks[1].startswith("ACK ARM ") and acks[1].endswith(" OK")
    assert acks[-1].startswith("ACK DISARM ") and acks[-1].endswith(" OK")  # the disarm is in the log


def test_board_lost_mid_log_ends_with_one_line_and_a_closed_file(tmp_path):
    out = tmp_path / "unplugged.csv"
    with sim_device() as (dev, pts):
        log = start_rodctl("log", "--port", pts, "--out", str(out))
        try:
            _wait_rows(out, 500)
            dev.kill()  # the board vanishes (like pulling the USB cable)
            dev.wait()
            _, err = log.communicate(timeout=20)
        finally:
            if log.poll() is None:
                log.kill()
    assert log.returncode == 1
    lines = err.strip().splitlines()
    assert lines[-1].startswith(f"rodctl: {pts}: device disconnected")
    assert "Traceback" not in err
    log = read_log(out)
    meta, data = log
    assert meta["end"] == "error" and "disconnected" in meta
    frame_events = np.count_nonzero(np.isin(log.events["event_name"], ["HELLO", "ACK"]))
    assert int(meta["frames"]) == len(data) + frame_events + int(meta["heartbeat_acks"])  # everything received


def test_board_lost_under_the_console_is_said_once():
    """The console printed the lost link twice, as its own `error:` and then as rodctl's last line."""
    with sim_device() as (dev, pts):
        con = start_rodctl("console", "--port", pts, stdin=subprocess.PIPE)
        try:
            con.stdin.write("status\n")
            con.stdin.flush()
            deadline = time.monotonic() + 60
            while "mode DISARMED" not in con.stdout.readline():  # the console is up and the board answers
                assert con.poll() is None and time.monotonic() < deadline, con.stderr.read()
            dev.kill()  # the board vanishes (like pulling the USB cable)
            dev.wait()
            out, err = con.communicate("status\n", timeout=20)
        finally:
            if con.poll() is None:
                con.kill()
    assert con.returncode == 1
    assert "device disconnected" not in out  # no `error:` line before rodctl's own
    assert err.strip().splitlines()[-1].startswith(f"rodctl: {pts}: device disconnected") and "Traceback" not in err


def _file_size_limit(limit_bytes: int):
    """Popen preexec_fn: a Ctrl-C as at a terminal, and files no larger than limit_bytes (writes past it fail with
    EFBIG, as on a FAT32 stick at 4 GB), standing in for a disk that fills while the logger runs."""
    import resource

    def limit() -> None:
        ctrl_c_as_at_a_terminal()
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))
    return limit


# each limit lets several seconds of frames in (CSV ~106 B a row, MCAP ~43): the ARM comes first on a loaded machine
@pytest.mark.parametrize("fmt,limit_bytes", [("csv", 1_000_000), ("mcap", 400_000), ("parquet", 40_000)])
def test_a_log_that_fills_its_disk_stops_there_disarmed_with_what_it_kept(tmp_path, fmt, limit_bytes):
    """The write the system refuses ends the run: the board disarmed, one line, and the log is what a reader
    finds in it (CSV and MCAP keep the rows written, cut short; an unfinished Parquet file is removed)."""
    import re

    out = tmp_path / f"full.{fmt}"
    with sim_device() as (dev, pts):
        log = start_rodctl("log", "--port", pts, "--arm", "balance", "--duration", "60", "--out", str(out),
                           preexec_fn=_file_size_limit(limit_bytes))
        try:
            _, err = log.communicate(timeout=90)
        finally:
            if log.poll() is None:
                log.kill()
    assert log.returncode == 1 and "Traceback" not in err and "internal error" not in err
    last = err.strip().splitlines()[-1]
    said = "rodctl: the file reached the largest size its disk or the system allows: "
    assert last.startswith(said) and last.endswith("; disarmed"), last
    if fmt == "parquet":
        assert last == f"{said}nothing was kept of {out} (a Parquet file cannot be read before its end; CSV and MCAP " \
                       "logs keep what was written); disarmed"
        assert list(tmp_path.iterdir()) == []
        return
    m = re.search(rf"{re.escape(str(out))} keeps its first (\d+) rows \(([\d.]+) s\), cut short", last)
    assert m, last
    data = read_log(out).data
    assert len(data) == int(m.group(1)) > 500  # what the line says is what a reader finds
    assert abs(data["time_s"][-1] - data["time_s"][0] - float(m.group(2))) < 0.06
    assert "CATCH" in set(telemetry(data)["mode_name"])  # it was armed before the disk filled
