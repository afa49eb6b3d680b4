"""Logs: the format (writer API, reader, units, metadata), crash tolerance, Parquet, and 60 s at 1 kHz."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from host_tools import run_rodctl
from rodgains.params import load_params

from rodctl import paths
from rodctl.link import protocol as P
from rodctl.logs.logfile import (JOURNAL_SUFFIX, LogWriter, columns, device_time_s, identify_params, params_of, read_log,
                            simulator_metadata, telemetry, theta_hat)

UNIT_SUFFIXES = ("_s", "_us", "_rad", "_rad_s", "_Nm", "_frac", "_count", "_code", "_name", "_bits", "_text")


def tlm(k: int, n: int = 5) -> P.Telemetry:
    return P.Telemetry(mode=P.Mode.BALANCE, reason=P.Reason.NONE, flags=5, n=n, encoder_count=489 + k % 3,
                       base_rate=np.float32(0.1 * k), torque=np.float32(-0.0123), duty=np.float32(0.25),
                       step_us=42, overruns=0, frames_dropped=0, rx_errors=0,
                       theta_hat=tuple(float(np.float32(math.pi + 0.01 * i + 1e-4 * k)) for i in range(n)),
                       rate_hat=tuple(float(np.float32(0.5 * i - 0.001 * k)) for i in range(n)))


def test_every_column_name_carries_its_unit():
    cols = [c for c, _ in columns(5)]
    assert "theta_hat_1_rad" in cols and "rate_hat_5_rad_s" in cols and "torque_Nm" in cols
    assert all(c.endswith(UNIT_SUFFIXES) for c in cols), [c for c in cols if not c.endswith(UNIT_SUFFIXES)]


def test_simulator_writes_the_log_format_from_telemetry_tuples(tmp_path):
    p = load_params()
    path = tmp_path / "sim.csv"
    w = LogWriter(path, simulator_metadata(p))
    sent = [tlm(k) for k in range(500)]
    for k, m in enumerate(sent):
        w.write_telemetry(m, seq=k, time_us=1000 * k)
    w.close()
    meta, data = read_log(path)
    assert len(data) == 500 and meta["rows"] == "500" and meta["incomplete_rows"] == "0"
    assert meta["source"] == "simulator" and meta["n_edges"] == "5" and meta["params_sha256"] == p.sha256()
    assert params_of(meta).sha256() == p.sha256()
    assert np.array_equal(data["seq_count"], np.arange(500))
    assert device_time_s(data)[-1] == pytest.approx(0.499)
    # f32 values come back bit for bit
    th = theta_hat(data)
    assert np.array_equal(th.astype(np.float32), np.array([m.theta_hat for m in sent], dtype=np.float32))
    assert np.all(data["torque_Nm"].astype(np.float32) == np.float32(-0.0123))
    assert np.all(data["mode_name"] == "BALANCE")


def test_every_frame_type_is_one_row(tmp_path):
    path = tmp_path / "mixed.csv"
    w = LogWriter(path, simulator_metadata(load_params()))
    hello = P.Hello(0, 1, 0, 1, 5, P.Mode.DISARMED, P.Reason.NONE, 1000, 1, 0.01, 0.5, 0.5, 0.5, 0.2, bytes(range(32)))
    frames = [P.decode_frame(P.encode_hello(hello, seq=0)), P.decode_frame(P.encode_telemetry(tlm(1), seq=1)),
              P.decode_frame(P.encode_ack(P.MsgType.ARM, P.AckResult.OK, 77, P.Mode.CATCH, seq=2))]
    for i, f in enumerate(frames):
        w.write_frame(f, host_time_s=0.001 * i)
    w.close()
    meta, data = read_log(path)
    assert list(data["type_name"]) == ["HELLO", "TELEMETRY", "ACK"]
    assert list(data["mode_name"]) == ["DISARMED", "BALANCE", "CATCH"]
    assert "ACK ARM command_seq 77 OK" == data["info_text"][2]
    assert data["info_text"][0].startswith("HELLO fw 0.1.0") and bytes(range(32)).hex() in data["info_text"][0]
    assert np.isnan(data["torque_Nm"][0]) and np.isnan(data["torque_Nm"][2])
    assert len(telemetry(data)) == 1


def test_a_log_cut_mid_row_keeps_every_complete_row(tmp_path):
    path = tmp_path / "cut.csv"
    w = LogWriter(path, simulator_metadata(load_params()))
    for k in range(100):
        w.write_telemetry(tlm(k), seq=k, time_us=1000 * k)
    w.flush()  # a killed logger: flushed rows on disk, no trailer
    raw = path.read_bytes()
    path.write_bytes(raw[:-37])  # and, worse than our writer ever leaves it, half a row
    meta, data = read_log(path)
    assert len(data) == 99 and meta["incomplete_rows"] == "1"
    assert np.array_equal(data["seq_count"], np.arange(99))


def test_the_device_design_is_identified_by_its_header_hash():
    committed = load_params(paths.COMMITTED_PARAMS)
    p, source = identify_params(committed.sha256())
    assert p.sha256() == committed.sha256() and source == "firmware/include/rod_gains.toml"
    other = load_params(None, ["rod.edges=7"])
    assert identify_params(other.sha256()) == (None, "unknown")
    p, source = identify_params(other.sha256(), [(other, "mine.toml")])
    assert source == "mine.toml"


def test_unknown_design_is_recorded_as_unknown_with_the_hash(tmp_path):
    hello = P.Hello(0, 1, 0, 1, 5, 0, 0, 1000, 1, 0.01, 0.5, 0.5, 0.5, 0.2, b"\x11" * 32)
    from rodctl.logs.logfile import device_metadata

    meta = device_metadata(hello, port="/dev/ttyACM0")
    assert meta["params_source"] == "unknown" and meta["header_sha256"] == "11" * 32
    assert "params_json" not in meta


def _has_pyarrow() -> bool:
    try:
        import pyarrow  # noqa: F401
        return True
    except ImportError:
        return False


@pytest.mark.skipif(not _has_pyarrow(), reason="pyarrow not installed")
def test_parquet_log_and_its_journal_after_a_kill(tmp_path):
    path = tmp_path / "run.parquet"
    w = LogWriter(path, simulator_metadata(load_params()))
    for k in range(300):
        w.write_telemetry(tlm(k), seq=k, time_us=1000 * k)
    w.flush()
    # killed here: the journal is a complete CSV log, read in place of the missing Parquet
    journal = tmp_path / ("run.parquet" + JOURNAL_SUFFIX)
    assert journal.exists() and not path.exists()
    meta, data = read_log(path)
    assert len(data) == 300 and meta["recovered_from"] == str(journal)
    w.close()
    assert path.exists() and not journal.exists()
    meta, data = read_log(path)
    assert len(data) == 300 and meta["rows"] == "300"
    assert np.array_equal(data["seq_count"], np.arange(300))
    assert data["theta_hat_3_rad"].astype(np.float32)[7] == np.float32(tlm(7).theta_hat[2])


def test_parquet_without_pyarrow_is_one_clear_line(tmp_path):
    code = ("import sys; sys.modules['pyarrow'] = None\n"
            "from rodctl import cli\n"
            f"sys.exit(cli.main(['log', '--port', 'sim://', '--duration', '1', '--out', r'{tmp_path / 'x.parquet'}']))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 1
    assert r.stderr.strip().splitlines() == [
        "rodctl: --format parquet needs pyarrow: pip install pyarrow (or pip install -e '.[parquet]'), "
        "or log as CSV (--format csv)"]


@pytest.mark.skipif(not _has_pyarrow(), reason="pyarrow not installed")
def test_log_command_writes_parquet(tmp_path):
    out = tmp_path / "run.parquet"
    r = run_rodctl("log", "--port", "sim://", "--duration", "1.5", "--out", str(out))
    assert r.returncode == 0, r.stderr
    meta, data = read_log(out)
    assert meta["rows"] == meta["frames"] == str(len(data))
    assert 1400 <= len(telemetry(data)) <= 1600


def test_log_60_seconds_at_1khz_loses_no_frame(tmp_path):
    """60 s through the virtual board at 1 kHz, armed (CATCH) the whole time: every frame kept."""
    out = tmp_path / "long.csv"
    r = run_rodctl("log", "--port", "sim://", "--duration", "60", "--arm", "balance", "--out", str(out), timeout=180)
    assert r.returncode == 0, r.stderr
    meta, data = read_log(out)
    tl = telemetry(data)
    seq = data["seq_count"]
    print(f"\n60 s log: {len(data)} frames ({len(tl)} telemetry), seq gaps {meta['seq_gaps']}, "
          f"device dropped {meta['device_frames_dropped']}, CRC errors {meta['crc_errors']}")
    assert meta["incomplete_rows"] == "0"
    assert int(meta["frames"]) == len(data) == int(meta["rows"])  # row count == frame count
    assert np.array_equal(seq, np.arange(seq[0], seq[0] + len(seq)))  # contiguous: nothing lost anywhere
    assert meta["seq_gaps"] == "0" and meta["crc_errors"] == "0" and meta["decode_errors"] == "0"
    assert meta["device_frames_dropped"] == "0" and np.nanmax(tl["frames_dropped_count"]) == 0
    assert 59_000 <= len(tl) <= 61_000
    span = device_time_s(tl)[-1]
    assert 59.0 <= span <= 61.0
    # the heartbeat held the board armed for the whole minute, and leaving disarmed it
    armed = tl[tl["mode_name"] == "CATCH"]
    assert len(armed) >= 59_000 and not np.any(tl["mode_name"] == "FAULT")
    assert tl["mode_name"][-1] == "DISARMED" and tl["reason_name"][-1] == "HOST"
