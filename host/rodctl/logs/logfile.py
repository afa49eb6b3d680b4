"""Telemetry logs: one row per frame, metadata on top, readable after a crash.

CSV layout (format "rodctl-log 1")::

    # rodctl-log: 1
    # created_utc: 2025-01-01T12:00:00Z
    # source: device            (or simulator)
    # port: sim://
    # protocol_version: 1
    # firmware_version: 0.1.0
    # gains_schema: 1
    # header_sha256: bf6962...   (SHA-256 of the parameters the firmware's gains were designed from)
    # params_source: firmware/include/rod_gains.toml   (or a file, or "unknown")
    # params_sha256: bf6962...   (or "unknown")
    # n_edges: 5
    # period_us: 1000
    # decimation: 1
    # settings: {"swing_amplitude_Nm": 0.01, ...}
    # params_json: {...}         (the parameters, canonical JSON; absent when unknown)
    host_time_s,type_name,seq_count,device_time_us,mode_code,...
    0.0123,TELEMETRY,0,0,0,...
    ...
    # closed_utc: ...            (trailer lines after a clean close: counters of the session)

Every line starting with '#' is metadata ("# key: value"); everything else is CSV with one header
row, so `pandas.read_csv(path, comment="#")` reads it too. Every frame is one row: telemetry rows
carry every telemetry field; HELLO and ACK rows carry mode (and reason for HELLO) and a one-line
summary in info_text, with the telemetry-only columns empty. Columns (units in the names):

    host_time_s          host receive time, seconds since the session opened
    type_name            TELEMETRY | HELLO | ACK
    seq_count            device sequence number (contiguous unless frames were lost)
    device_time_us       device clock at the frame's creation [us] (u32, wraps after 71.6 min)
    mode_code, mode_name, reason_code, reason_name      (reason -1 / empty on ACK rows)
    flags_bits           telemetry flags (DRIVER_ENABLED 1, NFAULT_LOW 2, HEARTBEAT_OK 4)
    encoder_count        raw encoder count
    base_rate_rad_s, torque_Nm, duty_frac (signed duty, -1..1), step_time_us,
    overruns_count, frames_dropped_count (device, since boot), rx_errors_count,
    theta_hat_1_rad .. theta_hat_N_rad, rate_hat_1_rad_s .. rate_hat_N_rad_s,
    info_text            ACK / HELLO summary

Writing: rows go to the file as whole lines with one write() at least every `flush_interval`
(0.25 s), so a killed process leaves a file that ends on a row boundary (at most the last 0.25 s
missing). Parquet (--format parquet, needs pyarrow): rows are journaled to PATH.journal.csv in
exactly the CSV layout above and converted at a clean close (the journal is then removed); after
a kill the journal stays and read_log(PATH) reads it (`rodctl log-convert` makes the Parquet).

The simulator writes the same format with LogWriter.write_telemetry(P.Telemetry(...), seq, time_us)
and simulator_metadata(params).
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import threading
import time
from pathlib import Path

import numpy as np

from rodgains.errors import UserError

from rodctl import __version__

from rodctl import paths
from rodctl.link import protocol as P

FORMAT_VERSION = "1"
JOURNAL_SUFFIX = ".journal.csv"
FLUSH_INTERVAL_S = 0.25

# (name, numpy dtype); f8 columns are empty (NaN) on rows where they do not apply.
BASE_COLUMNS = [
    ("host_time_s", "f8"),
    ("type_name", "U9"),
    ("seq_count", "i8"),
    ("device_time_us", "i8"),
    ("mode_code", "i8"),
    ("mode_name", "U8"),
    ("reason_code", "i8"),
    ("reason_name", "U12"),
    ("flags_bits", "f8"),
    ("encoder_count", "f8"),
    ("base_rate_rad_s", "f8"),
    ("torque_Nm", "f8"),
    ("duty_frac", "f8"),
    ("step_time_us", "f8"),
    ("overruns_count", "f8"),
    ("frames_dropped_count", "f8"),
    ("rx_errors_count", "f8"),
]
TAIL_COLUMNS = [("info_text", "U400")]


def columns(n: int) -> list[tuple[str, str]]:
    """The columns of a log of an n-edge estimate."""
    return (BASE_COLUMNS + [(f"theta_hat_{i}_rad", "f8") for i in range(1, n + 1)]
            + [(f"rate_hat_{i}_rad_s", "f8") for i in range(1, n + 1)] + TAIL_COLUMNS)


def _enum_name(enum_cls, v) -> str:
    try:
        return enum_cls(int(v)).name
    except ValueError:
        return str(int(v))


def _g(v) -> str:
    """A float as text that round-trips an f32 (and keeps host times to the microsecond)."""
    v = float(v)
    if math.isnan(v):
        return ""
    return f"{v:.9g}"


def _utc() -> str:
    return _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def _text(s: str) -> str:
    return " ".join(str(s).replace(",", ";").replace('"', "'").replace("#", "no.").split())


# ---- metadata -------------------------------------------------------------------------------------

def _settings_json(hello) -> str:
    return json.dumps({
        "swing_amplitude_Nm": float(hello.swing_amplitude),
        "swing_angle_rad": float(hello.swing_angle),
        "catch_angle_rad": float(hello.catch_angle),
        "heartbeat_timeout_s": float(hello.heartbeat_timeout),
        "torque_max_Nm": float(hello.torque_max),
    }, sort_keys=True)


def identify_params(header_sha256: str, candidates=()):
    """The parameters the firmware's gains were designed from: (Params, source) or (None, "unknown").

    Matches the device's header SHA-256 (HELLO) against Params.sha256() of the candidates
    (iterable of (Params or path, label)), the committed firmware/include/rod_gains.toml and the
    default parameter file.
    """
    from rodgains.params import DEFAULT_PARAMS, load_params

    tried = list(candidates) + [(paths.COMMITTED_PARAMS, _shown(paths.COMMITTED_PARAMS)),
                                (DEFAULT_PARAMS, _shown(DEFAULT_PARAMS))]
    for cand, label in tried:
        try:
            p = cand if hasattr(cand, "sha256") else load_params(cand)
        except (UserError, OSError):
            continue
        if p.sha256() == header_sha256:
            return p, label
    return None, "unknown"


def _shown(p) -> str:
    try:
        return str(Path(p).resolve().relative_to(paths.REPO))
    except ValueError:
        return str(p)


def device_metadata(hello, *, port: str, params=None, params_source: str = "unknown",
                    start_unix: float | None = None) -> dict[str, str]:
    """Metadata of a log recorded from a device that sent `hello`."""
    sha = bytes(hello.header_sha256).hex()
    meta = {
        "rodctl-log": FORMAT_VERSION,
        "created_utc": _utc(),
        "rodctl_version": __version__,
        "source": "device",
        "port": port,
        "protocol_version": str(P.VERSION),
        "firmware_version": f"{hello.fw_major}.{hello.fw_minor}.{hello.fw_patch}",
        "gains_schema": str(hello.gains_schema),
        "header_sha256": sha,
        "params_source": params_source if params is not None else "unknown",
        "params_sha256": params.sha256() if params is not None else "unknown",
        "n_edges": str(hello.n),
        "period_us": str(hello.period_us),
        "decimation": str(hello.decimation),
        "settings": _settings_json(hello),
        "host_start_unix_s": f"{start_unix if start_unix is not None else time.time():.6f}",
    }
    if params is not None:
        meta["params_json"] = params.canonical_json()
    return meta


def simulator_metadata(params, *, n: int | None = None, period_us: int | None = None, decimation: int = 1,
                       firmware_version: str = "sim", header_sha256: str | None = None,
                       settings: dict | None = None, source: str = "simulator") -> dict[str, str]:
    """Metadata for a log written by the simulator from arrays (same format as a device log)."""
    sw = params["swing_up"]
    s = settings or {
        "swing_amplitude_Nm": sw["amplitude"], "swing_angle_rad": math.radians(sw["angle_deg"]),
        "catch_angle_rad": math.radians(sw["catch_angle_deg"]),
        "heartbeat_timeout_s": params["safety"]["heartbeat_timeout"], "torque_max_Nm": params.torque_max,
    }
    sha = header_sha256 or params.sha256()
    return {
        "rodctl-log": FORMAT_VERSION,
        "created_utc": _utc(),
        "rodctl_version": __version__,
        "source": source,
        "port": "",
        "protocol_version": str(P.VERSION),
        "firmware_version": firmware_version,
        "gains_schema": "",
        "header_sha256": sha,
        "params_source": "simulator",
        "params_sha256": params.sha256(),
        "n_edges": str(n if n is not None else params.N),
        "period_us": str(period_us if period_us is not None else int(round(params.dt * 1e6))),
        "decimation": str(decimation),
        "settings": json.dumps(s, sort_keys=True),
        "host_start_unix_s": f"{time.time():.6f}",
        "params_json": params.canonical_json(),
    }


def params_of(meta: dict):
    """The Params recorded in a log's metadata, or None when the log says "unknown"."""
    text = meta.get("params_json")
    if not text:
        return None
    from rodgains.params import Params, validate

    try:
        return Params(validate(json.loads(text), source="log"), source="log")
    except (UserError, ValueError):
        return None


# ---- writing ---------------------------------------------------------------------------------------

def log_format(path: str | Path, fmt: str | None = None) -> str:
    if fmt:
        return fmt
    return "parquet" if str(path).endswith(".parquet") else "csv"


def require_pyarrow():
    try:
        import pyarrow  # noqa: F401
        import pyarrow.parquet  # noqa: F401
    except ImportError:
        raise UserError("--format parquet needs pyarrow: pip install pyarrow (or pip install -e '.[parquet]'), "
                        "or log as CSV (--format csv)") from None


class LogWriter:
    """Writes a log as frames arrive (thread-safe); see the module doc for the format.

    path: the log (.csv, or .parquet with fmt="parquet": a CSV journal beside it until close).
    metadata: device_metadata(...) or simulator_metadata(...). n: edges (default metadata n_edges).
    """

    def __init__(self, path: str | Path, metadata: dict, *, n: int | None = None, fmt: str | None = None,
                 flush_interval: float = FLUSH_INTERVAL_S, overwrite: bool = True):
        self.path = Path(path)
        self.format = log_format(path, fmt)
        if self.format not in ("csv", "parquet"):
            raise UserError(f"unknown log format {self.format!r}: csv or parquet")
        if self.format == "parquet":
            require_pyarrow()
            self.file_path = Path(str(self.path) + JOURNAL_SUFFIX)
        else:
            self.file_path = self.path
        if not overwrite and self.path.exists():
            raise UserError(f"{self.path} exists; choose another --out")
        self.metadata = dict(metadata)
        self.n = int(n if n is not None else metadata.get("n_edges", 0))
        self.columns = columns(self.n)
        self.flush_interval = flush_interval
        self.rows = 0
        self.telemetry_rows = 0
        self._buf: list[str] = []
        self._lock = threading.Lock()
        self._last_flush = time.monotonic()
        self._nan_tlm = "," * (9 + 2 * self.n - 1)  # empty telemetry-only fields
        try:
            self.file_path.parent.mkdir(parents=True, exist_ok=True)
            self._f = open(self.file_path, "wb", buffering=0)
        except OSError as e:
            raise UserError(f"cannot write {self.file_path}: {e.strerror or e}") from None
        head = "".join(f"# {k}: {v}\n" for k, v in self.metadata.items())
        head += ",".join(c for c, _ in self.columns) + "\n"
        self._write(head.encode())
        self.closed = False

    # --- rows -------------------------------------------------------------------------------
    def _row(self, text: str) -> None:
        with self._lock:
            self._buf.append(text)
            self.rows += 1
            if time.monotonic() - self._last_flush >= self.flush_interval or len(self._buf) >= 20000:
                self._flush_locked()

    def write_telemetry(self, msg, seq: int, time_us: int, host_time_s: float = float("nan")) -> None:
        """One telemetry row from a protocol.Telemetry tuple (also the simulator's entry point)."""
        n = self.n
        th = list(msg.theta_hat[:n]) + [float("nan")] * (n - len(msg.theta_hat))
        rt = list(msg.rate_hat[:n]) + [float("nan")] * (n - len(msg.rate_hat))
        info = "" if len(msg.theta_hat) == n else f"n={len(msg.theta_hat)} (log has {n})"
        mode, reason = int(msg.mode), int(msg.reason)
        g = _g
        text = ",".join((
            g(host_time_s), "TELEMETRY", str(int(seq)), str(int(time_us)), str(mode), _enum_name(P.Mode, mode),
            str(reason), _enum_name(P.Reason, reason), str(int(msg.flags)), str(int(msg.encoder_count)),
            g(msg.base_rate), g(msg.torque), g(msg.duty), str(int(msg.step_us)), str(int(msg.overruns)),
            str(int(msg.frames_dropped)), str(int(msg.rx_errors)),
            *map(g, th), *map(g, rt), info)) + "\n"
        self.telemetry_rows += 1
        self._row(text)

    def _other(self, kind: str, seq, time_us, mode, reason, info, host_time_s) -> None:
        rc = "-1" if reason is None else str(int(reason))
        rn = "" if reason is None else _enum_name(P.Reason, reason)
        text = ",".join((_g(host_time_s), kind, str(int(seq)), str(int(time_us)), str(int(mode)),
                         _enum_name(P.Mode, mode), rc, rn, self._nan_tlm, _text(info))) + "\n"
        self._row(text)

    def write_hello(self, msg, seq: int, time_us: int, host_time_s: float = float("nan")) -> None:
        info = (f"HELLO fw {msg.fw_major}.{msg.fw_minor}.{msg.fw_patch} schema {msg.gains_schema} n {msg.n} "
                f"period_us {msg.period_us} decimation {msg.decimation} swing_amplitude_Nm {msg.swing_amplitude:.6g} "
                f"swing_angle_rad {msg.swing_angle:.6g} catch_angle_rad {msg.catch_angle:.6g} "
                f"heartbeat_timeout_s {msg.heartbeat_timeout:.6g} torque_max_Nm {msg.torque_max:.6g} "
                f"header_sha256 {bytes(msg.header_sha256).hex()}")
        self._other("HELLO", seq, time_us, msg.mode, msg.reason, info, host_time_s)

    def write_ack(self, msg, seq: int, time_us: int, host_time_s: float = float("nan")) -> None:
        info = (f"ACK {_enum_name(P.MsgType, msg.command)} command_seq {msg.command_seq} "
                f"{_enum_name(P.AckResult, msg.result)}")
        self._other("ACK", seq, time_us, msg.mode, None, info, host_time_s)

    def write_frame(self, frame, host_time_s: float = float("nan")) -> None:
        """One row for any decoded frame (protocol.Frame)."""
        t = frame.type
        if t == P.MsgType.TELEMETRY:
            self.write_telemetry(frame.msg, frame.seq, frame.time_us, host_time_s)
        elif t == P.MsgType.HELLO:
            self.write_hello(frame.msg, frame.seq, frame.time_us, host_time_s)
        elif t == P.MsgType.ACK:
            self.write_ack(frame.msg, frame.seq, frame.time_us, host_time_s)
        else:  # a host->device type from a device: still a frame, still a row
            self._other(_enum_name(P.MsgType, t), frame.seq, frame.time_us, 0, None, repr(frame.msg), host_time_s)

    __call__ = write_frame  # a Session listener: fn(frame, host_time_s)

    # --- file -------------------------------------------------------------------------------
    def _write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            k = self._f.write(view)
            view = view[k:]

    def _flush_locked(self) -> None:
        if self._buf:
            data = "".join(self._buf).encode()
            self._buf.clear()
            self._write(data)
        self._last_flush = time.monotonic()

    def flush(self) -> None:
        with self._lock:
            if not self.closed:
                self._flush_locked()

    def maybe_flush(self) -> None:
        if time.monotonic() - self._last_flush >= self.flush_interval:
            self.flush()

    def close(self, trailer: dict | None = None) -> Path:
        """Write what is left and the trailer; for Parquet convert the journal. Returns the log path."""
        with self._lock:
            if self.closed:
                return self.path
            self._flush_locked()
            tr = {"closed_utc": _utc(), "rows": str(self.rows)}
            tr.update({k: str(v) for k, v in (trailer or {}).items()})
            self._write("".join(f"# {k}: {v}\n" for k, v in tr.items()).encode())
            try:
                os.fsync(self._f.fileno())
            except OSError:
                pass
            self._f.close()
            self.closed = True
        if self.format == "parquet":
            convert_to_parquet(self.file_path, self.path)
            self.file_path.unlink()
        return self.path


# ---- reading ---------------------------------------------------------------------------------------

def _dtype_of(name: str) -> str:
    for c, d in BASE_COLUMNS + TAIL_COLUMNS:
        if c == name:
            return d
    return "f8"


def _read_csv(path: Path) -> tuple[dict, np.ndarray]:
    meta: dict[str, str] = {}
    header = None
    rows: list[list[str]] = []
    bad = 0
    with open(path, "rb") as f:
        raw = f.read()
    text = raw.decode("utf-8", errors="replace")
    lines = text.split("\n")
    incomplete = 0
    if lines and lines[-1] != "":
        incomplete = 1  # the process died mid-line: not a complete row
    lines = lines[:-1]
    for line in lines:
        if not line:
            continue
        if line[0] == "#":
            body = line[1:].strip()
            if ":" in body:
                k, v = body.split(":", 1)
                meta[k.strip()] = v.strip()
            continue
        if header is None:
            header = line.split(",")
            continue
        parts = line.split(",")
        if len(parts) != len(header):
            bad += 1
            continue
        rows.append(parts)
    if header is None:
        raise UserError(f"{path}: not a rodctl log (no header row)")
    if "rodctl-log" not in meta:
        raise UserError(f"{path}: not a rodctl log (no '# rodctl-log:' line)")
    dtype = [(c, _dtype_of(c)) for c in header]
    data = np.zeros(len(rows), dtype=dtype)
    cols = list(zip(*rows)) if rows else [()] * len(header)
    for (name, d), col in zip(dtype, cols):
        if d == "f8":
            data[name] = np.array([float(x) if x else np.nan for x in col], dtype=float)
        elif d == "i8":
            data[name] = np.array([int(x) for x in col], dtype=np.int64)
        else:
            data[name] = np.array(col, dtype=d) if col else np.array([], dtype=d)
    meta["incomplete_rows"] = str(incomplete + bad)
    return meta, data


def _read_parquet(path: Path) -> tuple[dict, np.ndarray]:
    require_pyarrow()
    import pyarrow.parquet as pq

    table = pq.read_table(path)
    md = table.schema.metadata or {}
    raw = md.get(b"rodctl")
    if raw is None:
        raise UserError(f"{path}: not a rodctl log (no rodctl metadata)")
    meta = json.loads(raw.decode())
    names = table.column_names
    dtype = [(c, _dtype_of(c)) for c in names]
    data = np.zeros(table.num_rows, dtype=dtype)
    for name, d in dtype:
        col = table.column(name)
        if d == "f8":
            data[name] = col.to_numpy(zero_copy_only=False).astype(float)
        elif d == "i8":
            data[name] = col.to_numpy(zero_copy_only=False).astype(np.int64)
        else:
            data[name] = np.array(col.to_pylist(), dtype=d)
    meta.setdefault("incomplete_rows", "0")
    return meta, data


def read_log(path: str | Path) -> tuple[dict, np.ndarray]:
    """(metadata, rows) of a log: metadata as a dict of strings, rows as a numpy structured array.

    CSV: a last line cut by a kill is skipped (metadata["incomplete_rows"] counts skipped lines).
    Parquet: when PATH is missing but its journal PATH.journal.csv exists (the logger was
    killed), the journal is read and metadata["recovered_from"] names it.
    """
    path = Path(path)
    if str(path).endswith(".parquet"):
        if path.exists():
            return _read_parquet(path)
        journal = Path(str(path) + JOURNAL_SUFFIX)
        if journal.exists():
            meta, data = _read_csv(journal)
            meta["recovered_from"] = str(journal)
            return meta, data
        raise UserError(f"{path}: no such log")
    if not path.exists():
        journal = Path(str(path) + JOURNAL_SUFFIX) if not str(path).endswith(JOURNAL_SUFFIX) else None
        raise UserError(f"{path}: no such log" + (f" (nor {journal})" if journal and journal.exists() else ""))
    return _read_csv(path)


def convert_to_parquet(journal: str | Path, out: str | Path | None = None) -> Path:
    """Convert a CSV log (or a Parquet journal) to Parquet; returns the Parquet path."""
    require_pyarrow()
    import pyarrow as pa
    import pyarrow.parquet as pq

    journal = Path(journal)
    if out is None:
        s = str(journal)
        out = Path(s[: -len(JOURNAL_SUFFIX)] if s.endswith(JOURNAL_SUFFIX) else str(journal.with_suffix(".parquet")))
    out = Path(out)
    meta, data = _read_csv(journal)
    arrays = {}
    for name in data.dtype.names:
        col = data[name]
        arrays[name] = pa.array(col.tolist() if col.dtype.kind == "U" else col)
    table = pa.table(arrays)
    table = table.replace_schema_metadata({b"rodctl": json.dumps(meta).encode()})
    tmp = out.with_name(out.name + ".tmp")
    pq.write_table(table, tmp)
    os.replace(tmp, out)
    return out


# ---- helpers for plots and tests -------------------------------------------------------------------

def telemetry(data: np.ndarray) -> np.ndarray:
    """The telemetry rows."""
    return data[data["type_name"] == "TELEMETRY"]


def n_edges(data: np.ndarray) -> int:
    return sum(1 for c in data.dtype.names if c.startswith("theta_hat_"))


def theta_hat(data: np.ndarray) -> np.ndarray:
    """(rows, N) estimated edge angles [rad]."""
    n = n_edges(data)
    return np.column_stack([data[f"theta_hat_{i}_rad"] for i in range(1, n + 1)]) if n else np.zeros((len(data), 0))


def device_time_s(data: np.ndarray) -> np.ndarray:
    """Device time [s] from the first row, the u32 microsecond clock unwrapped."""
    t = np.asarray(data["device_time_us"], dtype=np.int64)
    if t.size == 0:
        return np.zeros(0)
    d = np.diff(t) % (1 << 32)
    d = np.where(d >= (1 << 31), d - (1 << 32), d)
    return np.concatenate([[0], np.cumsum(d)]) * 1e-6
