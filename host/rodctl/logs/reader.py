"""read_log: any rodctl log (CSV + sidecar, Parquet, MCAP) as numpy arrays; convert_log between formats.

    meta, data = read_log("run.csv")                    # data: numpy structured array, one row per frame
    log = read_log("run.mcap", columns=["time_s", "theta_hat_*"])   # only what you need (bounded memory)
    log.events                                          # HELLO / ACK / MODE / NOTE rows: the log's, not data's
    df = pandas.DataFrame(data)                         # or pandas.read_csv / read_parquet directly

The format is recognized from the file's first bytes, not its name. Anything that is not a
readable rodctl log is one UserError line (a directory, a foreign or cut Parquet/MCAP file, a
column of the wrong type); a CSV without its sidecar is read with a warning on stderr.
"""

from __future__ import annotations

import fnmatch
from pathlib import Path

import numpy as np

from rodgains.errors import InputError

from rodctl.logs import csvlog, mcaplog, parquetlog, schema
from rodctl.logs.writer import EXTENSIONS, LogWriteFailed, LogWriter, files_of, refused_text


class Log(tuple):
    """(meta, data) that also carries .events (structured array), .format, .path and .trailer (the
    counters written at a clean close, as stored; {} when the logger never closed it; they are in
    meta too)."""

    def __new__(cls, meta, data, events, fmt, path, trailer=None):
        self = super().__new__(cls, (meta, data))
        self.events, self.format, self.path = events, fmt, path
        self.trailer = dict(trailer or {})
        return self

    @property
    def meta(self) -> dict:
        return self[0]

    @property
    def data(self) -> np.ndarray:
        return self[1]


def detect_format(path: Path) -> str:
    if path.is_dir():
        raise InputError(f"{path} is a directory, not a log")
    if not path.exists():
        partial = parquetlog.partial_path(path)
        if partial.exists():
            raise InputError(f"{path}: no such log; {partial.name} is an unfinished Parquet log (the logger was "
                            "killed) and cannot be read: record CSV or MCAP when a run must survive a kill")
        raise InputError(f"{path}: no such log")
    try:
        with open(path, "rb") as f:
            head = f.read(4096)
    except OSError as e:
        raise InputError(f"cannot read {path}: {e.strerror or e}") from None
    if head.startswith(b"PAR1"):
        return "parquet"
    if head.startswith(mcaplog.MAGIC):
        return "mcap"
    named = EXTENSIONS.get(path.suffix.lower(), "csv")  # what the name claims, for the message
    if named == "parquet":
        raise InputError(f"{path}: not a Parquet file (no PAR1 magic)")
    if named == "mcap":
        raise InputError(f"{path}: not an MCAP file")
    if b"\0" in head or not csvlog.is_csv_header(head):
        raise InputError(f"{path}: not a rodctl log (CSV, Parquet or MCAP)")
    return "csv"


def _expand(names, have: list[str] | None) -> list[str] | None:
    if names is None:
        return None
    out: list[str] = []
    for c in names:
        if "*" in c:
            if have is None:
                raise InputError(f"column pattern {c!r} needs the log's header")
            out += [h for h in have if fnmatch.fnmatchcase(h, c) and h not in out]
        elif c not in out:
            out.append(c)
    return out


def _header(path: Path, fmt: str) -> list[str] | None:
    if fmt == "csv":
        with open(path, "rb") as f:
            return [h.strip().strip('"') for h in f.readline(65536).decode("utf-8", errors="replace").split(",")]
    if fmt == "parquet":
        import pyarrow as pa
        import pyarrow.parquet as pq

        try:
            return pq.read_schema(path).names
        except (pa.ArrowInvalid, OSError) as e:
            raise InputError(f"{path}: not a readable Parquet file, or cut short ({str(e).splitlines()[0]})") from None
    return None


def _to_numpy(path: Path, cols: dict, names: list[str]) -> np.ndarray:
    """Columns (arrow arrays or lists) -> structured array with the schema's dtypes; ints with nulls refused."""
    rows = len(cols[names[0]]) if names else 0
    dtype = [(c, schema.dtype_of(c)) for c in names]
    data = np.empty(rows, dtype=dtype)
    for c, d in dtype:
        col = cols[c]
        if hasattr(col, "null_count"):  # pyarrow
            if d == "i8" and col.null_count:
                raise InputError(f"{path}: column {c} has empty values (an integer column)")
            if d.startswith("U"):
                data[c] = np.asarray(col.to_pylist(), dtype=d) if rows else np.zeros(0, dtype=d)
            else:
                data[c] = col.to_numpy(zero_copy_only=False)
        else:  # lists from JSON
            if d == "i8":
                if any(v is None or not isinstance(v, int) for v in col):
                    raise InputError(f"{path}: column {c} holds non-integer values")
                data[c] = np.asarray(col, dtype=np.int64)
            elif d.startswith("U"):
                data[c] = np.asarray(["" if v is None else str(v) for v in col], dtype=d)
            else:
                data[c] = np.asarray([np.nan if v is None else v for v in col], dtype=float)
    return data


def _events_array(events) -> np.ndarray:
    dtype = [(c, d) for c, d, _, _ in schema.EVENT_COLUMNS]
    if events is None:
        return np.zeros(0, dtype=dtype)
    if hasattr(events, "column_names"):  # arrow table
        cols = {c: events.column(c) for c in events.column_names}
        names = [c for c, _ in dtype if c in cols]
        return _to_numpy(Path("events"), cols, names)
    out = np.zeros(len(events), dtype=dtype)
    for i, e in enumerate(events):
        for c, d in dtype:
            v = e.get(c)
            out[c][i] = (np.nan if v is None else v) if d == "f8" else (-1 if v is None else v) if d == "i8" \
                else ("" if v is None else str(v))
    return out


def _check_edges(path: Path, names: list[str]) -> None:
    """InputError unless the estimate's columns are theta_hat_1_rad .. theta_hat_N_rad with none missing:
    readers take N from how many there are (schema.n_edges_of)."""
    n = schema.n_edges_of(names)
    for i in range(1, n + 1):
        if f"theta_hat_{i}_rad" not in names:
            raise InputError(f"{path}: no column theta_hat_{i}_rad (of {n} theta_hat columns, one per edge)")


def read_log(path: str | Path, columns: list[str] | None = None) -> Log:
    """(metadata, data) of a log; data is a numpy structured array with one row per telemetry frame.

    columns: telemetry columns to read (names or patterns like "theta_hat_*"); None reads all.
    Reading only what a plot needs keeps memory near 8 bytes per value. metadata: strings (firmware,
    parameters as params_json, trailer counters such as frames and seq_gaps), plus "columns"
    ({name: {unit, meaning}}) and "incomplete_rows" (a row cut by a kill, skipped).
    """
    path = Path(path)
    fmt = detect_format(path)
    names = _expand(columns, _header(path, fmt)) if columns is not None and fmt != "mcap" else None
    if fmt == "csv":
        meta, table, events = csvlog.read(path, names)
        cols = {c: table.column(c) for c in table.column_names}
    elif fmt == "parquet":
        meta, table, events = parquetlog.read(path, names)
        cols = {c: table.column(c) for c in table.column_names}
    else:
        meta, cols, events = mcaplog.read(path, None)
        names = _expand(columns, list(cols))
        if names is not None:
            missing = [c for c in names if c not in cols]
            if missing:
                raise InputError(f"{path}: no column {missing[0]}")
    order = names if names is not None else list(cols)
    if columns is None or any("*" in c for c in columns):
        _check_edges(path, order)
    data = _to_numpy(path, cols, order)
    del cols
    if "time_s" in order and not np.isfinite(data["time_s"]).all():
        k = int(np.argmin(np.isfinite(data["time_s"])))
        raise InputError(f"{path}: time_s of telemetry row {k + 1} is {data['time_s'][k]}, not a time")
    if "seq_count" in order and data.size and np.any(np.diff(data["seq_count"]) < 0):
        meta["seq_restarts"] = meta.get("seq_restarts", "1")
    trailer = meta.pop(schema.TRAILER_KEY, None) or {}
    return Log(meta, data, _events_array(events), fmt, path, trailer)


def cut_short(log: "Log") -> str | None:
    """One line saying how much of a log was readable when it was cut short (a kill, a full disk, a
    copied file still growing): a row cut in half, fewer rows than its close counted, or no trailer (the
    logger never closed it, or the file is damaged before the trailer). None for a complete log."""
    meta, data = log
    bad = int(meta.get("incomplete_rows", "0") or 0)
    # the trailer is written at a clean close; a CSV's lives in its sidecar, so without one it cannot be looked for
    closed = "closed_utc" in meta or meta.get("sidecar") in ("missing", "unreadable")
    counted = str(meta.get("rows", ""))  # the telemetry rows the close counted (a copy cut at a row's end)
    missing = closed and counted.isdigit() and len(data) < int(counted)
    if not bad and closed and not missing:
        return None
    why = []
    if bad:
        why.append(f"{bad} cut row{'s' if bad != 1 else ''} skipped")
    if missing:
        why.append(f"its close counted {counted} rows")
    if not closed:
        why.append("no trailer: the logger never closed it, or the file is damaged before its end")
    return f"{log.path}: cut short ({'; '.join(why)}); {len(data)} telemetry frames readable"


LARGE_LOG_BYTES = 8 << 20  # a log this large takes seconds to read: plot and log-convert say so first


def reading_note(path: str | Path) -> str | None:
    """"reading PATH (N MB)" for a log large enough to take seconds to read, else None."""
    path = Path(path)
    size = path.stat().st_size if path.is_file() else 0
    return f"reading {path} ({size / 1e6:.0f} MB)" if size >= LARGE_LOG_BYTES else None


def convert_log(src: str | Path, out: str | Path, fmt: str | None = None, overwrite: bool = False,
                warn=None, say=None) -> Path:
    """Write the log `src` (any format) as `out` (format from fmt or out's extension); returns out.
    warn(line) is told when `src` was cut short (cut_short): the copy holds only what was readable. say(line): the
    stages of a large log's copy, reading and writing."""
    src, out = Path(src), Path(out)
    if src.resolve() == out.resolve():
        raise InputError(f"{out} is the log being converted; choose another --out")
    try:
        theirs = {f.resolve() for f in files_of(src) if f.exists()}
    except InputError:  # a log whose extension is not a format's (read by its content): a file alone
        theirs = {src.resolve()}
    for f in files_of(out, fmt):
        if f.resolve() in theirs:  # --force would replace the source's own sidecar or events
            raise InputError(f"{out}: its copy would write {f}, a file of the log being converted; choose another --out")
    note = reading_note(src) if say is not None else None
    if note:
        say(note)
    log = read_log(src)
    short = cut_short(log)
    if short and warn is not None:
        warn(short)
    # the metadata as written (the reader adds columns, incomplete_rows and the trailer's values), and where
    # this copy came from; the trailer is carried over as it is below, or stays absent
    meta = {k: v for k, v in log.meta.items() if k not in ("columns", "incomplete_rows", "rows", "events",
                                                          "closed_utc", *log.trailer)}
    meta["converted_from"] = str(src)
    n = schema.n_edges_of(log.data.dtype.names)
    want = schema.column_names(n)
    missing = [c for c in want if c not in log.data.dtype.names]
    if missing:  # before the writer makes its files: a refused log leaves none behind
        raise InputError(f"{src}: no column {missing[0]}; cannot convert")
    w = LogWriter(out, meta, n=n, fmt=fmt, overwrite=overwrite)
    if note:
        say(f"writing {out} ({len(log.data):,} rows)")
    rows = log.data[want].tolist()
    ev = log.events.tolist()
    try:
        w.append_rows(rows, ev)
        w.close(log.trailer, verbatim=True)  # the recording's own counters and close time, or none: still cut short
    except (OSError, LogWriteFailed) as e:
        w.discard()
        why = refused_text(e if isinstance(e, OSError) else w.failure)
        raise LogWriteFailed(f"{why}: {out} was not written ({src} is unchanged)") from None
    return out


# ---- helpers for plots and tests -------------------------------------------------------------------

def telemetry(data: np.ndarray) -> np.ndarray:
    """The telemetry rows (every row of a rodctl-log 2 file)."""
    return data


def n_edges(data: np.ndarray) -> int:
    return schema.n_edges_of(data.dtype.names)


def theta_hat(data: np.ndarray) -> np.ndarray:
    """(rows, N) estimated edge angles [rad]."""
    n = n_edges(data)
    return np.column_stack([data[f"theta_hat_{i}_rad"] for i in range(1, n + 1)]) if n else np.zeros((len(data), 0))


def device_time_s(data: np.ndarray) -> np.ndarray:
    """Device time [s] from the first row (the log's time_s, else the u32 clock unwrapped)."""
    if "time_s" in data.dtype.names:
        return np.asarray(data["time_s"], dtype=float) - (data["time_s"][0] if len(data) else 0.0)
    return schema.unwrap_us(data["device_time_us"])
