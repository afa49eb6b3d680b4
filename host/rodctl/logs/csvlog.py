"""CSV logs: PATH (telemetry, header on line 1), PATH.json (metadata, units, trailer), PATH.events.csv.

`pandas.read_csv(PATH)`, `polars.read_csv(PATH)` and PlotJuggler open PATH with default options:
one header line, one row per TELEMETRY frame, integer columns always integer. Rows are appended as
whole lines at least every flush interval (0.25 s), so a killed logger leaves a log that ends on a
row boundary (at most the last 0.25 s missing) and a sidecar written at the start (the trailer with
the session's counters is added at a clean close).
"""

from __future__ import annotations

import json
import math
import os
import sys
from pathlib import Path

import numpy as np

from rodgains.atomic_file import atomic_write
from rodgains.errors import InputError, UserError

from rodctl.logs import schema
from rodctl.logs.schema import TRAILER_KEY

SIDECAR_SUFFIX = ".json"
EVENTS_SUFFIX = ".events.csv"


def sidecar_path(path: Path) -> Path:
    return Path(str(path) + SIDECAR_SUFFIX)


def events_path(path: Path) -> Path:
    return Path(str(path) + EVENTS_SUFFIX)


def _fmt(kind: str, name: str):
    if kind == "i8":
        return lambda v: str(int(v))
    if kind.startswith("U"):
        return lambda v: " ".join(str(v).replace(",", ";").replace('"', "'").split())
    if name.endswith("time_s"):
        return lambda v: "" if math.isnan(v) else f"{v:.6f}"
    return _float_cell


def _float_cell(v) -> str:
    """9 significant digits (round-trips an f32), and always a float's spelling: a column that is 0 all run (an idle
    log's torque and duty) is read as floats by pandas and polars, not as integers, and so is one that is NaN all run."""
    if math.isnan(v):
        return "NaN"  # not empty: a column empty all run (the IMU's, without one) is read as text by polars
    s = f"{float(v):.9g}"
    return s if any(ch in s for ch in ".eEn") else s + ".0"


def _line(fmts, row) -> str:
    return ",".join([f(v) for f, v in zip(fmts, row)]) + "\n"


def _write_json(path: Path, obj) -> None:
    atomic_write(path, json.dumps(obj, indent=1) + "\n")


class CsvSink:
    files = ("log", "sidecar", "events")

    def __init__(self, path: Path, meta: dict, n: int):
        self.path = path
        self.meta = meta
        self.n = n
        self.cols = schema.columns(n)
        self.fmts = [_fmt(d, c) for c, d, _, _ in self.cols]
        self.efmts = [_fmt(d, c) for c, d, _, _ in schema.EVENT_COLUMNS]
        self._f = open(path, "wb", buffering=0)
        self._e = open(events_path(path), "wb", buffering=0)
        self._write(self._f, ",".join(c[0] for c in self.cols) + "\n")
        self._write(self._e, ",".join(c[0] for c in schema.EVENT_COLUMNS) + "\n")
        _write_json(sidecar_path(path), self._sidecar({}))

    def _sidecar(self, trailer: dict) -> dict:
        return {"metadata": self.meta, "trailer": trailer, "columns": schema.units(self.n),
                "events_file": events_path(self.path).name}

    @staticmethod
    def _write(f, text: str) -> None:
        view = memoryview(text.encode())
        while view:
            view = view[f.write(view):]

    def write_rows(self, rows) -> None:
        fm = self.fmts
        self._write(self._f, "".join([_line(fm, r) for r in rows]))

    def write_events(self, rows) -> None:
        self._write(self._e, "".join([_line(self.efmts, r) for r in rows]))

    def abandon(self) -> None:
        """After a refused write: the files as they are (the last row may be cut, which the reader skips; the sidecar
        has no trailer)."""
        for f in (self._f, self._e):
            try:
                f.close()
            except OSError:
                pass

    def close(self, trailer: dict) -> None:
        for f in (self._f, self._e):
            try:
                os.fsync(f.fileno())
            except OSError:
                pass
            f.close()
        _write_json(sidecar_path(self.path), self._sidecar(trailer))


# ---- reading -------------------------------------------------------------------------------------

def _warn(text: str) -> None:
    print(f"rodctl: warning: {text}", file=sys.stderr)


def _complete_buffer(path: Path):
    """The file's bytes up to its last newline (memory-mapped) and whether a cut row was dropped."""
    import pyarrow as pa

    size = path.stat().st_size
    if size == 0:
        raise InputError(f"{path}: empty file, not a rodctl log")
    with open(path, "rb") as f:
        f.seek(max(0, size - 65536))
        tail = f.read()
    end = size - (len(tail) - tail.rfind(b"\n") - 1) if b"\n" in tail else 0
    mm = pa.memory_map(str(path))
    return mm.read_buffer(end), end < size


# Arrow's thread pool, once started, can abort the process as the interpreter exits ("terminate called without
# an active exception", apache/arrow#34314): an interrupted `rodctl identify` on sim:// did so once in CI. So a
# log is parsed on one thread unless it is large enough for the pool to matter (the 1,000,000-frame log of
# `rodctl bench --only host` reads at 1.08 M frames/s on one thread, 1.70 M on the pool).
THREADED_READ_BYTES = 32 << 20


def threaded_read(path: Path) -> bool:
    """Whether Arrow parses the log `path` on its thread pool (only a large one)."""
    try:
        return Path(path).stat().st_size >= THREADED_READ_BYTES
    except OSError:
        return False


def _csv_table(path: Path, source, types: dict, include=None):
    """An arrow table of the CSV `source` (a path or a buffer), rows of the wrong width skipped."""
    import pyarrow as pa
    import pyarrow.csv as pc

    bad = [0]

    def skip(_row):
        bad[0] += 1
        return "skip"

    try:
        # Only the included columns are converted and kept.
        table = pc.read_csv(
            pa.BufferReader(source) if isinstance(source, pa.Buffer) else source,
            read_options=pc.ReadOptions(block_size=4 << 20, use_threads=threaded_read(path)),
            parse_options=pc.ParseOptions(invalid_row_handler=skip),
            convert_options=pc.ConvertOptions(column_types=types, include_columns=include,
                                              strings_can_be_null=False, quoted_strings_can_be_null=False))
    except (pa.ArrowInvalid, pa.ArrowTypeError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: not a readable rodctl log ({str(e).strip().splitlines()[0]})") from None
    return table, bad[0]


def _source(path: Path):
    """What to parse: the file itself (streamed), or, when a kill cut its last row, its bytes up to the last newline."""
    size = path.stat().st_size
    if size == 0:
        raise InputError(f"{path}: empty file, not a rodctl log")
    with open(path, "rb") as f:
        f.seek(size - 1)
        if f.read(1) == b"\n":
            return str(path), False
    buf, cut = _complete_buffer(path)
    return buf, cut


def read(path: Path, names: list[str] | None):
    """(meta, arrow table of the telemetry columns `names` (None: all), events table or None, warnings)."""
    import pyarrow as pa

    with open(path, "rb") as f:
        head = f.readline(65536).decode("utf-8", errors="replace").strip()
    if head.startswith("#"):
        raise InputError(f"{path}: an old rodctl-log 1 CSV (metadata lines before the header); record it again")
    header = [h.strip().strip('"') for h in head.split(",")]
    if "seq_count" not in header or "time_s" not in header:
        raise InputError(f"{path}: not a rodctl log (line 1 is not a header with time_s and seq_count)")
    meta: dict = {}
    side = sidecar_path(path)
    if side.exists():
        try:
            doc = json.loads(side.read_text())
            meta.update(doc.get("metadata", {}))
            trailer = {k: str(v) for k, v in (doc.get("trailer") or {}).items()}
            meta.update(trailer)
            meta[TRAILER_KEY] = trailer
            meta["columns"] = doc.get("columns", {})
        except (ValueError, OSError, AttributeError) as e:
            _warn(f"{side}: unreadable sidecar ({e}); plotting without metadata")
            meta["sidecar"] = "unreadable"
    else:
        _warn(f"{path}: no sidecar {side.name}: firmware, parameters and units unknown")
        meta["sidecar"] = "missing"
    if names is not None:
        missing = [c for c in names if c not in header]
        if missing:
            raise InputError(f"{path}: no column {missing[0]} (columns: {', '.join(header[:6])}, ...)")
    want = header if names is None else names
    types = {c: (pa.int64() if schema.dtype_of(c) == "i8" else pa.string() if schema.dtype_of(c).startswith("U")
                 else pa.float64()) for c in want}
    src, cut = _source(path)
    table, bad = _csv_table(path, src, types, include=want)
    for i, name in enumerate(table.column_names):  # a cell's 9 digits name an f32: the same value Parquet and MCAP hold
        if schema.is_device_f32(name):
            table = table.set_column(i, name, table.column(i).cast(pa.float32()).cast(pa.float64()))
    meta["incomplete_rows"] = str(bad + int(cut))
    events = None
    ev = events_path(path)
    if ev.exists() and not ev.is_file():
        _warn(f"{ev}: not a file; reading the log without its events")
    elif ev.exists():
        etypes = {c: (pa.int64() if d == "i8" else pa.string() if d.startswith("U") else pa.float64())
                  for c, d, _, _ in schema.EVENT_COLUMNS}
        if ev.stat().st_size:
            try:
                events, _ = _csv_table(ev, _source(ev)[0], etypes)
            except (pa.ArrowException, ValueError, KeyError, UserError) as e:
                events, why = None, str(e).splitlines()[0] if str(e) else type(e).__name__
            else:  # a file of that name whose header is not the events' (duplicate or foreign columns)
                header = events.column_names
                why = "" if len(set(header)) == len(header) and "event_name" in header else f"its columns are {header}"
                events = events if not why else None
            if events is None:  # the events are the log's notes, not its data: the telemetry still reads
                _warn(f"{ev}: not a rodctl events file ({why}); reading the log without its events")
    return meta, table, events


def is_csv_header(first: bytes) -> bool:
    """A rodctl CSV log's first bytes: its header, or an old rodctl-log 1 CSV's metadata comments (a header
    with seq_count follows them; any other file that starts with a comment, a TOML file, is not a log)."""
    line = first.split(b"\n", 1)[0]
    if line.startswith(b"#"):
        return b"seq_count" in first and b"time_s" in first
    return b"seq_count" in line and b"time_s" in line


def empty_events() -> np.ndarray:
    return np.zeros(0, dtype=[(c, d) for c, d, _, _ in schema.EVENT_COLUMNS])
