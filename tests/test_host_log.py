"""Logs: CSV that pandas/polars/PlotJuggler open as is, Parquet and MCAP, one read_log, crashes, bad input."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from host_tools import rodctl_env, run_rodctl
from rodgains.params import load_params

from rodctl import paths
from rodctl.link import protocol as P
from rodctl.logs import (LogWriter, columns, device_metadata, device_time_s, identify_params, params_of,
                         read_log, simulator_metadata, theta_hat)
from rodctl.logs.schema import DeviceClock, from_upright

UNIT_SUFFIXES = ("_s", "_us", "_rad", "_rad_s", "_m_s2", "_Nm", "_frac", "_count", "_code", "_name", "_bits", "_text")
FORMATS = ("csv", "parquet", "mcap")


def tlm(k: int, n: int = 5, mode=P.Mode.BALANCE) -> P.Telemetry:
    return P.Telemetry(mode=mode, reason=P.Reason.NONE, flags=5, n=n, encoder_count=489 + k % 3,
                       base_rate=np.float32(0.1 * k), torque=np.float32(-0.0123), duty=np.float32(0.25),
                       step_us=42, overruns=0, frames_dropped=0, rx_errors=0,
                       theta_hat=tuple(float(np.float32(math.pi + 0.01 * i + 1e-4 * k)) for i in range(n)),
                       rate_hat=tuple(float(np.float32(0.5 * i - 0.001 * k)) for i in range(n)))


def _write(path, frames=300, start_us=0, **kw):
    w = LogWriter(path, simulator_metadata(load_params(), n=5), **kw)
    hello = P.Hello(0, 1, 0, 1, 5, P.Mode.DISARMED, P.Reason.NONE, 0, 1000, 1, 0.01, 0.5, 0.5, 0.5, 0.2, bytes(range(32)), 4896, 5)
    w.write_frame(P.decode_frame(P.encode_hello(hello, seq=0, time_us=start_us)), host_time_s=0.0)
    for k in range(frames):
        mode = P.Mode.CATCH if k < 100 else P.Mode.BALANCE
        w.write_telemetry(tlm(k, mode=mode), seq=k + 1, time_us=(start_us + 1000 * (k + 1)) & 0xFFFFFFFF,
                          host_time_s=0.001 * k + 0.01)
    w.write_frame(P.decode_frame(P.encode_ack(P.MsgType.ARM, P.AckResult.OK, 77, P.Mode.CATCH, seq=frames + 1,
                                              time_us=start_us + 1000 * (frames + 1))), host_time_s=0.5)
    return w


def test_every_column_name_carries_its_unit():
    cols = [c for c, *_ in columns(5)]
    assert "theta_hat_1_rad" in cols and "rate_hat_5_rad_s" in cols and "torque_Nm" in cols and cols[0] == "time_s"
    assert all(c.endswith(UNIT_SUFFIXES) for c in cols), [c for c in cols if not c.endswith(UNIT_SUFFIXES)]


def test_the_code_columns_say_every_code_the_protocol_has():
    """The mode column's text left out IDENTIFY (5), which `rodctl check` and `identify` log."""
    meaning = {c: m for c, _, _, m in columns(5)}
    assert all(f"{int(m)} {m.name}" in meaning["mode_code"] for m in P.Mode)
    assert all(f"{f.name} {int(f)}" in meaning["flags_bits"] for f in P.TelemetryFlag)


def test_csv_opens_in_pandas_and_polars_with_default_options(tmp_path):
    import pandas
    import polars

    path = tmp_path / "run.csv"
    _write(path).close({"frames": 302})
    assert path.read_text().splitlines()[0].startswith("time_s,host_time_s,seq_count,")  # the header is line 1
    df = pandas.read_csv(path)
    assert len(df) == 300  # one row per telemetry frame: HELLO and ACK are events, not rows
    for c in ("seq_count", "device_time_us", "mode_code", "reason_code", "flags_bits", "encoder_count",
              "step_time_us", "overruns_count", "frames_dropped_count", "rx_errors_count"):
        assert df[c].dtype == np.int64, c  # integer columns stay integer
    assert df["theta_hat_3_rad"].dtype == np.float64
    pl = polars.read_csv(path)
    assert pl.shape == (300, len(columns(5))) and pl["seq_count"].dtype == polars.Int64
    assert pl["time_s"].is_sorted()


def test_a_float_column_that_is_zero_all_run_is_still_read_as_floats(tmp_path):
    """An idle log's torque and duty are 0 in every row: written "0", pandas and polars read them as int64, so a
    column's type depended on what the run did."""
    import pandas
    import polars

    path = tmp_path / "idle.csv"
    w = LogWriter(path, simulator_metadata(load_params(), n=5))
    for k in range(20):
        w.write_telemetry(tlm(k)._replace(torque=0.0, duty=0.0, base_rate=0.0), seq=k + 1, time_us=1000 * (k + 1),
                          host_time_s=0.001 * k)
    w.close()
    # the IMU's too: NaN in every row of a log without one (empty cells, polars read them as text)
    floats = [c for c, kind, *_ in columns(5) if kind == "f8"]
    df, pl = pandas.read_csv(path), polars.read_csv(path)
    assert all(df[c].dtype == np.float64 for c in floats), [c for c in floats if df[c].dtype != np.float64]
    assert all(pl[c].dtype == polars.Float64 for c in floats), [c for c in floats if pl[c].dtype != polars.Float64]
    assert (df["torque_Nm"] == 0).all() and read_log(path).data["duty_frac"].tolist() == [0.0] * 20


def test_a_round_trip_through_csv_gives_the_same_arrays_as_parquet_and_mcap(tmp_path):
    """A CSV cell holds an f32's 9 digits, read back as the nearest double (-12.4932213, where Parquet holds the f32
    -12.493221282958984), and the host time to the microsecond: 18 columns of the same run differed by format."""
    import pyarrow.parquet as pq

    first = tmp_path / "a.parquet"
    w = _write(first, frames=500)
    w.write_telemetry(tlm(0)._replace(base_rate=float(np.float32(-12.493221282958984))), seq=600, time_us=600_000,
                      host_time_s=0.5057747959981498)
    w.close({"frames": 503})
    assert run_rodctl("log-convert", str(first), "--out", str(tmp_path / "b.csv")).returncode == 0
    assert run_rodctl("log-convert", str(tmp_path / "b.csv"), "--out", str(tmp_path / "c.parquet")).returncode == 0
    a, c = pq.read_table(first), pq.read_table(tmp_path / "c.parquet")
    assert a.schema.names == c.schema.names and a.equals(c.replace_schema_metadata(a.schema.metadata))
    assert a.column("host_time_s")[-1].as_py() == 0.505775 and a.column("base_rate_rad_s")[-1].as_py() == \
        float(np.float32(-12.493221282958984))
    by_format = [read_log(tmp_path / name).data for name in ("a.parquet", "b.csv")]
    for name in by_format[0].dtype.names:
        assert np.array_equal(by_format[0][name], by_format[1][name], equal_nan=by_format[0][name].dtype.kind == "f"), name


def test_time_is_the_device_clock_unwrapped_and_monotonic(tmp_path):
    path = tmp_path / "wrap.csv"
    _write(path, start_us=0xFFFFFFFF - 150_000).close()  # the u32 clock wraps 150 frames in
    meta, data = read_log(path)
    t = data["time_s"]
    assert np.all(np.diff(t) > 0) and t[-1] - t[0] == pytest.approx(0.299)
    assert data["device_time_us"].min() < 1_000_000 < data["device_time_us"].max()  # it did wrap
    c = DeviceClock()
    assert [c(x) for x in (5, 3, 10)] == [0.0, 0.0, pytest.approx(7e-6)]  # a step back (reset) holds, then counts on


def test_metadata_units_and_events_beside_the_csv(tmp_path):
    path = tmp_path / "run.csv"
    _write(path).close({"frames": 302})
    side = json.loads((tmp_path / "run.csv.json").read_text())
    assert side["metadata"]["rodctl-log"] == "3" and side["metadata"]["params_sha256"] == load_params().sha256()
    assert side["columns"]["torque_Nm"]["unit"] == "N m" and side["trailer"]["frames"] == "302"
    log = read_log(path)
    ev = log.events
    assert list(ev["event_name"]) == ["HELLO", "MODE", "MODE", "ACK"]
    assert list(ev["info_text"][1:3]) == ["start in CATCH", "CATCH -> BALANCE"]
    assert ev["info_text"][3] == "ACK ARM command_seq 77 OK"
    assert log.data["time_s"][100] == pytest.approx(ev["time_s"][2])  # events on the telemetry's time axis
    assert params_of(log.meta).sha256() == load_params().sha256()


@pytest.mark.parametrize("fmt", FORMATS)
def test_every_format_reads_back_bit_for_bit(tmp_path, fmt):
    path = tmp_path / f"run.{fmt}"
    _write(path).close({"frames": 302})
    log = read_log(path)
    meta, data = log
    assert log.format == fmt and len(data) == 300 and meta["rows"] == "300" and meta["frames"] == "302"
    assert np.array_equal(data["seq_count"], np.arange(1, 301)) and data["seq_count"].dtype == np.int64
    assert np.array_equal(theta_hat(data).astype(np.float32),
                          np.array([tlm(k).theta_hat for k in range(300)], dtype=np.float32))
    assert device_time_s(data)[-1] == pytest.approx(0.299)
    assert list(log.events["event_name"]) == ["HELLO", "MODE", "MODE", "ACK"]
    only = read_log(path, columns=["time_s", "theta_hat_*"]).data
    assert only.dtype.names == ("time_s", *(f"theta_hat_{i}_rad" for i in range(1, 6)))


def test_parquet_has_units_in_its_schema_and_nulls_not_nan(tmp_path):
    import pandas
    import pyarrow.parquet as pq

    path = tmp_path / "run.parquet"
    w = LogWriter(path, simulator_metadata(load_params(), n=5))
    w.write_telemetry(tlm(0), seq=0, time_us=0)  # host time unknown: a null
    w.close()
    t = pq.read_table(path)
    assert t.schema.field("torque_Nm").metadata[b"unit"] == b"N m"
    assert t.column("host_time_s").null_count == 1 and t.column("torque_Nm").null_count == 0
    assert json.loads(t.schema.metadata[b"rodctl"])["n_edges"] == "5"
    assert pandas.read_parquet(path)["seq_count"].dtype == np.int64


def test_mcap_holds_telemetry_events_and_the_rod_shape(tmp_path):
    from mcap.reader import make_reader

    path = tmp_path / "run.mcap"
    _write(path).close()
    with open(path, "rb") as f:
        reader = make_reader(f)
        topics: dict[str, list] = {}
        for schema, channel, message in reader.iter_messages():
            assert channel.message_encoding == "json" and schema.encoding == "jsonschema"
            topics.setdefault(channel.topic, []).append(json.loads(message.data))
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
    assert len(topics["/telemetry"]) == 300 and topics["/telemetry"][5]["seq_count"] == 6
    assert [e["event_name"] for e in topics["/events"]] == ["HELLO", "MODE", "MODE", "ACK"]
    shape = topics["/rod_shape"][0]
    l = load_params()["rod"]["length"] / 5
    assert len(shape["x_m"]) == 6 and shape["y_m"][0] == 0.0
    assert shape["y_m"][-1] == pytest.approx(5 * l, rel=1e-3)  # upright: the tip straight above the axis
    assert 14 <= len(topics["/rod_shape"]) <= 16  # one every 20 ms of device time over 0.3 s
    assert meta["rodctl"]["rodctl-log"] == "3" and meta["rodctl_trailer"]["rows"] == "300"


def test_a_csv_cut_mid_row_keeps_every_complete_row(tmp_path):
    path = tmp_path / "cut.csv"
    w = _write(path, frames=100)
    w.flush()  # a killed logger: flushed rows on disk, no trailer
    raw = path.read_bytes()
    path.write_bytes(raw[:-37])  # and, worse than our writer ever leaves it, half a row
    meta, data = read_log(path)
    assert len(data) == 99 and meta["incomplete_rows"] == "1"
    assert np.array_equal(data["seq_count"], np.arange(1, 100))


def test_a_killed_mcap_log_keeps_its_finished_chunks(tmp_path):
    path = tmp_path / "cut.mcap"
    w = _write(path, frames=3000)
    w.flush()
    w._sink._f.flush()
    raw = path.read_bytes()  # killed: no summary, no footer, the last chunk not written
    path.write_bytes(raw[: len(raw) - 100] if len(raw) > 100 else raw)
    meta, data = read_log(path)
    assert 1000 <= len(data) <= 3000 and meta["incomplete_rows"] == "1"
    assert np.array_equal(data["seq_count"], np.arange(1, len(data) + 1))


@pytest.mark.parametrize("command", ["plot", "log-convert"])
@pytest.mark.parametrize("fmt", ["csv", "mcap"])
def test_plotting_or_converting_a_cut_log_says_how_much_was_readable(tmp_path, fmt, command):
    from host_tools import run_rodctl

    path = tmp_path / f"cut.{fmt}"
    w = _write(path, frames=3000)
    w.flush()
    if fmt == "mcap":
        w._sink._f.flush()
    raw = path.read_bytes()
    path.write_bytes(raw[:-37] if fmt == "csv" else raw[: len(raw) - 100])
    n = len(read_log(path).data)
    out = {"plot": "p.png", "log-convert": "p.parquet"}[command]
    r = run_rodctl(command, str(path), "--out", str(tmp_path / out))
    assert r.returncode == 0, r.stderr
    warning = [ln for ln in r.stderr.splitlines() if ln.startswith("warning: ")]
    assert len(warning) == 1 and "cut short" in warning[0] and f"{n} telemetry frames readable" in warning[0]
    assert "no trailer" in warning[0]
    if command == "log-convert":
        assert len(read_log(tmp_path / out).data) == n
    whole = tmp_path / f"whole.{fmt}"
    _write(whole).close({"frames": 300})
    r = run_rodctl(command, str(whole), "--out", str(tmp_path / ("q" + Path(out).suffix)))
    assert r.returncode == 0 and "warning" not in r.stderr, r.stderr


@pytest.mark.parametrize("name, fmt, needle", [
    ("run.xlsx", None, "a log is .csv, .parquet or .mcap, not .xlsx"),
    ("run.csv", "parquet", "--format parquet but the name says csv"),
])
def test_a_log_name_that_misstates_its_format_is_refused_before_the_board(tmp_path, name, fmt, needle):
    from host_tools import run_rodctl

    extra = ["--format", fmt] if fmt else []
    r = run_rodctl("log", "--port", "sim://", "--duration", "0.5", "--out", str(tmp_path / name), *extra)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert needle in r.stderr.strip().splitlines()[-1]
    assert not list(tmp_path.iterdir())


def test_the_log_format_follows_the_extension(tmp_path):
    from rodctl.logs.writer import log_format

    assert [log_format(f"a.{e}") for e in ("csv", "parquet", "pq", "mcap", "CSV")] == \
        ["csv", "parquet", "parquet", "mcap", "csv"]
    assert log_format("a", "mcap") == "mcap" and log_format("a") == "csv"


def test_plot_out_into_a_missing_folder_is_refused_before_reading(tmp_path):
    from host_tools import run_rodctl

    log = tmp_path / "a.csv"
    _write(log).close({"frames": 300})
    r = run_rodctl("plot", str(log), "--out", str(tmp_path / "nope" / "deeper" / "x.png"))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.strip().splitlines()[-1].startswith("rodctl: --out ") and "does not exist" in r.stderr
    assert not (tmp_path / "nope").exists()


@pytest.mark.parametrize("src,dst", [("csv", "parquet"), ("parquet", "mcap"), ("mcap", "csv")])
def test_log_convert_between_formats(tmp_path, src, dst):
    a = tmp_path / f"a.{src}"
    _write(a).close({"frames": 302})
    b = tmp_path / f"b.{dst}"
    r = run_rodctl("log-convert", str(a), "--out", str(b))
    assert r.returncode == 0, r.stderr
    la, lb = read_log(a), read_log(b)
    for c in la.data.dtype.names:
        if c == "host_time_s":  # host times are kept to the microsecond in CSV
            assert np.allclose(la.data[c], lb.data[c], rtol=0, atol=5e-7), c
        elif la.data[c].dtype.kind == "f" and c != "time_s":  # the device's f32 values, bit for bit
            assert np.array_equal(la.data[c].astype(np.float32), lb.data[c].astype(np.float32), equal_nan=True), c
        else:
            assert np.array_equal(la.data[c], lb.data[c]), c
    assert list(lb.events["event_name"]) == list(la.events["event_name"])
    r = run_rodctl("log-convert", str(a), "--out", str(b))
    assert r.returncode == 2 and "exists" in r.stderr and "--force" in r.stderr


def _one_line(r) -> str:
    assert "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    return lines[0]


def test_bad_logs_are_one_clear_line(tmp_path):
    (tmp_path / "garbage.parquet").write_bytes(b"PAR1" + bytes(range(200)))
    (tmp_path / "foreign.parquet").write_bytes(b"not parquet at all")
    (tmp_path / "foreign.mcap").write_bytes(b"\x89MCAP0\r\n" + bytes(50))
    good = tmp_path / "good.parquet"
    _write(good).close()
    (tmp_path / "cut.parquet").write_bytes(good.read_bytes()[:-200])
    bad = tmp_path / "badseq.csv"
    _write(bad).close()
    lines = bad.read_text().splitlines(keepends=True)
    cells = lines[5].split(",")
    cells[2] = "1.5"  # a non-integer sequence number
    lines[5] = ",".join(cells)
    bad.write_text("".join(lines))
    import pyarrow as pa
    import pyarrow.parquet as pq

    pq.write_table(pa.table({"a": [1, 2]}), tmp_path / "other.parquet")
    expect = {
        tmp_path: "is a directory, not a log",
        tmp_path / "garbage.parquet": "not a readable Parquet file, or cut short",
        tmp_path / "foreign.parquet": "not a Parquet file",
        tmp_path / "cut.parquet": "not a readable Parquet file, or cut short",
        tmp_path / "other.parquet": "a Parquet file, but not a rodctl log",
        tmp_path / "foreign.mcap": "MCAP",
        tmp_path / "badseq.csv": "not a readable rodctl log",
        tmp_path / "missing.csv": "no such log",
    }
    for path, text in expect.items():
        r = run_rodctl("plot", str(path), "--out", str(tmp_path / "x.png"))
        assert r.stderr.strip(), (path, r.returncode, r.stdout)
        line = _one_line(r)
        assert r.returncode == 2 and line.startswith("rodctl: ") and text in line, (path, r.stderr)
    assert not (tmp_path / "x.png").exists()


def test_a_csv_without_its_sidecar_still_plots_with_a_warning(tmp_path):
    path = tmp_path / "run.csv"
    _write(path).close()
    (tmp_path / "run.csv.json").unlink()
    r = run_rodctl("plot", str(path), "--out", str(tmp_path / "run.png"))
    assert r.returncode == 0, r.stderr
    assert "warning: " in r.stderr and "no sidecar run.csv.json" in r.stderr and "Traceback" not in r.stderr
    assert (tmp_path / "run.png").stat().st_size > 10_000
    # one warning: the trailer lives in the sidecar, so its absence says nothing of a cut (it said "cut short")
    assert len(r.stderr.strip().splitlines()) == 1 and "cut short" not in r.stderr


def test_an_existing_log_is_not_replaced_without_force(tmp_path):
    out = tmp_path / "run.csv"
    out.write_text("precious\n")
    r = run_rodctl("log", "--port", "sim://", "--duration", "0.5", "--out", str(out))
    assert r.returncode == 2 and "run.csv exists: choose another file name, or --force" in _one_line(r)
    assert out.read_text() == "precious\n"
    r = run_rodctl("log", "--port", "sim://", "--duration", "0.5", "--out", str(out), "--force")
    assert r.returncode == 0, r.stderr
    assert len(read_log(out).data) > 300


@pytest.mark.parametrize("existing", ["s.csv", "s.truth.csv"])
def test_sim_log_is_not_replaced_without_force(tmp_path, existing):
    (tmp_path / existing).write_text("precious\n")
    r = run_rodctl("sim", "--scenario", "balance", "--duration", "0.2", "--no-plot", "--log", str(tmp_path / "s.csv"))
    assert r.returncode == 2 and f"{existing} exists" in _one_line(r)
    assert [p.name for p in tmp_path.iterdir()] == [existing] and (tmp_path / existing).read_text() == "precious\n"


def test_sim_figure_named_is_not_replaced_without_force(tmp_path):
    fig = tmp_path / "s.png"
    fig.write_bytes(b"another run's figure")
    r = run_rodctl("sim", "--scenario", "balance", "--duration", "0.2", "--no-log", "--plot", str(fig))
    assert r.returncode == 2 and _one_line(r) == f"rodctl: --plot {fig} exists: choose another file name, or --force to replace it"
    assert fig.read_bytes() == b"another run's figure"
    r = run_rodctl("sim", "--scenario", "balance", "--duration", "0.2", "--no-log", "--plot", str(fig), "--force")
    assert fig.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", r.stderr


def test_the_device_design_is_identified_by_its_header_hash():
    committed = load_params(paths.COMMITTED_PARAMS)
    p, source = identify_params(committed.sha256())
    assert p.sha256() == committed.sha256() and source == "firmware/include/rod_gains.toml"
    other = load_params(None, ["rod.edges=7"])
    assert identify_params(other.sha256()) == (None, "unknown")
    p, source = identify_params(other.sha256(), [(other, "mine.toml")])
    assert source == "mine.toml"


def test_unknown_design_is_recorded_as_unknown_with_the_hash():
    hello = P.Hello(0, 1, 0, 1, 5, 0, 0, 0, 1000, 1, 0.01, 0.5, 0.5, 0.5, 0.2, b"\x11" * 32, 4896, 5)
    meta = device_metadata(hello, port="/dev/ttyACM0")
    assert meta["params_source"] == "unknown" and meta["header_sha256"] == "11" * 32
    assert "params_json" not in meta


def test_angles_are_shown_from_the_nearest_upright():
    deg = np.degrees(from_upright([math.pi, -math.pi, 3 * math.pi + 0.1, math.pi - 0.1, 0.0]))
    assert np.allclose(deg, [0, 0, math.degrees(0.1), -math.degrees(0.1), -180])


@pytest.mark.parametrize("fmt", FORMATS)
def test_log_command_writes_every_format(tmp_path, fmt):
    out = tmp_path / f"run.{fmt}"
    r = run_rodctl("log", "--port", "sim://", "--duration", "1.5", "--out", str(out))
    assert r.returncode == 0, r.stderr
    log = read_log(out)
    # --duration is wall time: however loaded the machine, no more rows than 1.5 s at 1 kHz (and a margin
    # for the board's first frames), and every row 1 ms of the board's clock after the one before
    assert 100 <= len(log.data) <= 1800 and int(log.meta["rows"]) == len(log.data)
    assert log.meta["seq_gaps"] == "0" and "HELLO" in set(log.events["event_name"])
    assert np.allclose(np.diff(log.data["time_s"]), 1e-3, atol=1e-6)


def test_log_60_seconds_at_1khz_loses_no_frame(tmp_path):
    """60 s through the virtual board at 1 kHz, armed (CATCH) the whole time: every frame kept. Judged on the
    board's clock: on a loaded machine the virtual board runs fewer steps (it skips what a stall leaves
    behind), never with a gap; the rate itself is `rodctl bench`'s (docs/benchmarks.md)."""
    out = tmp_path / "long.csv"
    r = run_rodctl("log", "--port", "sim://", "--duration", "60", "--arm", "balance", "--out", str(out), timeout=180)
    assert r.returncode == 0, r.stderr
    log = read_log(out)
    meta, tl = log
    seq = tl["seq_count"]
    assert meta["incomplete_rows"] == "0"
    # every frame is a telemetry row or an event (heartbeat ACKs are counted only)
    assert meta["seq_gaps"] == "0" and meta["crc_errors"] == "0" and meta["decode_errors"] == "0"
    assert meta["device_frames_dropped"] == "0" and np.max(tl["frames_dropped_count"]) == 0
    assert np.all(np.diff(seq) >= 1) and int(meta["rows"]) == len(tl)
    frame_events = np.count_nonzero(np.isin(log.events["event_name"], ["HELLO", "ACK"]))
    assert int(meta["frames"]) == len(tl) + frame_events + int(meta["heartbeat_acks"])  # every frame accounted for
    assert 1_000 <= len(tl) <= 61_000  # 60 s of wall time at most; at least a second of the board's clock
    assert np.allclose(np.diff(tl["time_s"]), 1e-3, atol=1e-6)  # every step's frame, none lost
    modes = "".join({"DISARMED": "d", "CATCH": "c"}.get(m, "?") for m in tl["mode_name"])
    assert re.fullmatch(r"d*c{1000,}d+", modes), set(tl["mode_name"])  # armed once, held, disarmed at the end
    assert tl["mode_name"][-1] == "DISARMED" and tl["reason_name"][-1] == "HOST"


def test_plot_snapshots_are_taken_at_events():
    from rodctl.logs.plots import events_of

    t = np.arange(3000) * 1e-3
    mode = np.where(t < 1.0, P.Mode.SWING_UP, P.Mode.BALANCE)
    dev = np.where(t < 1.0, 0.5, 0.3 * np.exp(-(t - 1.0) / 0.1))  # caught at 17 deg, within 2 deg from 1.2151 s on
    th = np.column_stack([math.pi + dev] * 3)
    ev = dict(events_of(mode, th, t))
    assert ev == {"start": 0, "catch": 1000, "estimate settled": 1216, "end": 2999}


def test_a_killed_parquet_log_is_named_not_misread(tmp_path):
    from rodgains.errors import InputError

    path = tmp_path / "run.parquet"
    w = _write(path, frames=100)
    w.flush()  # killed before close: no footer yet, and the name says so
    assert not path.exists() and (tmp_path / "run.parquet.partial").exists()
    with pytest.raises(InputError, match="run.parquet.partial is an unfinished Parquet log"):
        read_log(path)


@pytest.mark.parametrize("src,dst", [("csv", "parquet"), ("parquet", "mcap"), ("mcap", "csv")])
def test_log_convert_carries_the_trailer_over_unchanged(tmp_path, src, dst):
    """The recording's own counters and close time, not the conversion's: heartbeat_acks stays, closed_utc
    is when the logger closed it."""
    from rodctl.logs.reader import cut_short

    a = tmp_path / f"a.{src}"
    w = _write(a)
    w.heartbeat_acks = 42
    w.close({"frames": 302, "seq_gaps": 1, "end": "Ctrl-C"})
    b = tmp_path / f"b.{dst}"
    r = run_rodctl("log-convert", str(a), "--out", str(b))
    assert r.returncode == 0, r.stderr
    la, lb = read_log(a), read_log(b)
    assert la.trailer["heartbeat_acks"] == "42" and la.trailer["closed_utc"]
    assert lb.trailer == la.trailer
    for k in ("closed_utc", "heartbeat_acks", "rows", "events", "frames", "seq_gaps", "end"):
        assert lb.meta[k] == la.meta[k], k
    assert lb.meta["converted_from"] == str(a) and cut_short(lb) is None


def test_a_closed_csv_copied_while_short_by_whole_rows_reads_as_cut_short(tmp_path):
    """Cut at a row's end, its sidecars whole (copied before the log was): every row reads, the trailer is there,
    and only the count its close wrote says rows are missing."""
    from rodctl.logs.reader import cut_short

    a = tmp_path / "a.csv"
    _write(a).close({"end": "duration"})
    lines = a.read_text().splitlines(keepends=True)
    a.write_text("".join(lines[:101]))  # the header and 100 of the 300 telemetry rows
    log = read_log(a)
    assert len(log.data) == 100 and log.meta["rows"] == "300"
    assert cut_short(log) == f"{a}: cut short (its close counted 300 rows); 100 telemetry frames readable"


@pytest.mark.parametrize("dst", ["parquet", "mcap", "csv"])
def test_log_convert_of_a_cut_short_log_still_reads_as_cut_short(tmp_path, dst):
    from rodctl.logs.reader import cut_short

    a = tmp_path / "cut.csv"
    w = _write(a)  # never closed: the logger was killed
    w.flush()
    assert "no trailer" in cut_short(read_log(a))
    b = tmp_path / f"b.{dst}"
    r = run_rodctl("log-convert", str(a), "--out", str(b))
    assert r.returncode == 0, r.stderr
    lb = read_log(b)
    assert lb.trailer == {} and "closed_utc" not in lb.meta and "heartbeat_acks" not in lb.meta
    assert "no trailer: the logger never closed it" in cut_short(lb)
    assert len(lb.data) == len(read_log(a).data)


def test_a_damaged_events_file_or_an_infinite_cell_still_plots_and_converts(tmp_path):
    """The events are the log's notes: a file of that name with a foreign header is named in a warning and the
    telemetry plots. An inf cell draws as a gap (it set the axis range and crashed), and MCAP's JSON gets null for
    it as for NaN (Infinity is not JSON)."""
    w = _write(tmp_path / "a.csv")
    w.close({"end": "duration"})
    (tmp_path / "a.csv.events.csv").write_text("garbage,,,\n1,2,3,4\n")
    r = run_rodctl("plot", str(tmp_path / "a.csv"), "--out", str(tmp_path / "a.png"), env=rodctl_env(MPLBACKEND="Agg"))
    assert r.returncode == 0 and (tmp_path / "a.png").stat().st_size > 0, r.stderr
    assert _one_line(r) == (f"rodctl: warning: {tmp_path / 'a.csv.events.csv'}: not a rodctl events file (its columns "
                            "are ['garbage', '', '', '']); reading the log without its events")
    (tmp_path / "a.csv.events.csv").unlink()
    lines = (tmp_path / "a.csv").read_text().splitlines()
    col = lines[0].split(",").index("theta_hat_1_rad")
    cells = lines[5].split(",")
    cells[col] = "inf"
    lines[5] = ",".join(cells)
    (tmp_path / "a.csv").write_text("\n".join(lines) + "\n")
    r = run_rodctl("plot", str(tmp_path / "a.csv"), "--out", str(tmp_path / "b.png"), env=rodctl_env(MPLBACKEND="Agg"))
    assert r.returncode == 0 and r.stderr == "", r.stderr
    r = run_rodctl("log-convert", str(tmp_path / "a.csv"), "--out", str(tmp_path / "a.mcap"))
    assert r.returncode == 0, r.stderr
    from mcap.reader import make_reader

    with open(tmp_path / "a.mcap", "rb") as f:
        rows = [json.loads(m.data) for _, ch, m in make_reader(f).iter_messages() if ch.topic == "/telemetry"]
    assert rows[4]["theta_hat_1_rad"] is None and math.isfinite(rows[5]["theta_hat_1_rad"])


def test_arming_a_board_in_fault_writes_nothing_and_keeps_the_log_force_named(tmp_path):
    """The ARM would be refused: no log of a run that never started, and the good log that --force named stays."""
    keep = tmp_path / "keep.csv"
    w = _write(keep)
    w.close({"end": "duration"})
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    r = run_rodctl("arm", "--balance", "--port", "sim://?restart=watchdog", "--duration", "1", "--out", str(keep),
                   "--force", timeout=60)
    assert r.returncode == 1 and _one_line(r).endswith(f"; nothing was armed or written to {keep}")
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


def test_a_default_log_name_never_collides_with_the_last_runs(tmp_path, monkeypatch):
    from rodctl.logs.writer import default_log_name

    first = default_log_name("csv", tmp_path)
    (tmp_path / first).write_text("x")
    second = default_log_name("csv", tmp_path)
    if second[:19] == first[:19]:  # the same second (a slow machine may have crossed into the next)
        assert second == first.replace(".csv", "-2.csv")
    (tmp_path / second).write_text("x")
    assert default_log_name("csv", tmp_path) not in {first, second}


@pytest.mark.parametrize("argv, code, says", [
    (["log", "--port", "sim://", "--duration", "0.2", "--out", "a" * 300 + ".csv"], 2, "File name too long"),
])
def test_what_the_system_refuses_is_one_line(tmp_path, argv, code, says):
    r = run_rodctl(*argv, cwd=tmp_path)
    assert r.returncode == code and _one_line(r).endswith(says) and "internal error" not in r.stderr
    assert list(tmp_path.iterdir()) == []


def test_a_full_disk_on_stdout_is_one_line():
    import subprocess

    from host_tools import RODCTL

    with open("/dev/full", "w") as full:
        r = subprocess.run([*RODCTL, "status", "--port", "sim://"], stdout=full, stderr=subprocess.PIPE, text=True,
                           env=rodctl_env(), timeout=60)
    assert r.returncode == 1 and r.stderr.strip() == "rodctl: writing the output: No space left on device"


@pytest.mark.parametrize("fmt", ["csv", "mcap", "parquet"])
def test_a_copy_that_fills_its_disk_leaves_nothing_and_the_source_unchanged(tmp_path, fmt):
    """log-convert is all or nothing: a copy the system refuses part way (here a file-size limit, EFBIG, as a FAT32
    stick at 4 GB) is removed, one line says so, and the source log is untouched."""
    import resource
    import signal
    import subprocess

    from host_tools import RODCTL

    src = tmp_path / "src.csv"
    _write(src, frames=20000).close({"frames": 20002})
    before = src.read_bytes()
    out = tmp_path / "copy" / f"copy.{fmt}"

    def limit() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (60_000, 60_000))  # the source is ~2 MB, its copy no smaller
    r = subprocess.run([*RODCTL, "log-convert", str(src), "--out", str(out)], capture_output=True, text=True,
                       env=rodctl_env(), timeout=120, preexec_fn=limit)
    assert r.returncode == 1 and _one_line(r) == (f"rodctl: the file reached the largest size its disk or the system "
                                                  f"allows: {out} was not written ({src} is unchanged)")
    assert list(out.parent.iterdir()) == [] and src.read_bytes() == before


def test_a_copy_that_would_write_over_the_source_s_own_files_is_refused(tmp_path):
    """--force replaced the source's events file with the copy (`--out a.csv.events.csv`): the log lost its events."""
    src = tmp_path / "a.csv"
    _write(src).close()
    before = {f.name: f.read_bytes() for f in tmp_path.iterdir()}
    for victim in ("a.csv.events.csv",):  # the sidecar's .json is no log's extension: refused as such
        r = run_rodctl("log-convert", str(src), "--out", str(tmp_path / victim), "--force")
        assert r.returncode == 2 and _one_line(r) == (f"rodctl: {tmp_path / victim}: its copy would write "
                                                      f"{tmp_path / victim}, a file of the log being converted; "
                                                      "choose another --out"), victim
    assert {f.name: f.read_bytes() for f in tmp_path.iterdir()} == before


def test_a_large_log_s_copy_and_plot_say_what_they_are_doing(tmp_path, monkeypatch, capsys):
    """Five minutes at 1 kHz took 10 s to convert and 8 s to plot without a word."""
    from rodctl import cli
    from rodctl.logs import reader

    src = tmp_path / "a.mcap"
    _write(src, frames=1000).close()
    monkeypatch.setattr(reader, "LARGE_LOG_BYTES", 1)  # this small log stands for a large one
    assert cli.main(["log-convert", str(src), "--out", str(tmp_path / "b.parquet")]) == 0
    size = f"({src.stat().st_size / 1e6:.0f} MB)"
    assert capsys.readouterr().err.splitlines() == [f"reading {src} {size} ...", f"writing {tmp_path / 'b.parquet'} "
                                                    "(1,000 rows) ..."]
    assert cli.main(["plot", str(src), "--out", str(tmp_path / "a.png")]) == 0
    assert capsys.readouterr().err.splitlines()[0] == f"reading {src} {size} ..."
