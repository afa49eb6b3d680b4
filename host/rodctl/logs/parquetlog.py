"""Parquet logs: one file, written in row groups while logging (pyarrow ParquetWriter).

Each field's unit and meaning are in its field metadata; the log's metadata is the file metadata
key "rodctl" (JSON), the events "rodctl_events" and the trailer "rodctl_trailer", added at close.
Missing values are nulls. Until a clean close the file is PATH.partial (a Parquet file has its
index at the end, so a killed logger's rows cannot be read back: log CSV or MCAP when that matters).
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from rodgains.errors import InputError

from rodctl.logs import schema
from rodctl.logs.csvlog import threaded_read
from rodctl.logs.schema import TRAILER_KEY

PARTIAL_SUFFIX = ".partial"


def partial_path(path: Path) -> Path:
    return Path(str(path) + PARTIAL_SUFFIX)


def _arrow_type(dtype: str):
    import pyarrow as pa

    return pa.int64() if dtype == "i8" else pa.string() if dtype.startswith("U") else pa.float64()


def arrow_schema(cols, meta: dict | None = None):
    import pyarrow as pa

    fields = [pa.field(c, _arrow_type(d), nullable=True, metadata={"unit": u, "meaning": w}) for c, d, u, w in cols]
    return pa.schema(fields, metadata={"rodctl": json.dumps(meta)} if meta is not None else None)


def arrow_columns(rows, cols):
    """Row tuples -> pyarrow arrays (NaN floats become nulls)."""
    import numpy as np
    import pyarrow as pa

    out = []
    for values, (c, d, _, _) in zip(zip(*rows), cols):
        if d == "f8":
            a = np.asarray(values, dtype=float)
            out.append(pa.array(a, type=pa.float64(), mask=np.isnan(a)))
        else:
            out.append(pa.array(values, type=_arrow_type(d)))
    return out


class ParquetSink:
    files = ("log",)

    def __init__(self, path: Path, meta: dict, n: int):
        import pyarrow.parquet as pq

        self.path = path
        self.cols = schema.columns(n)
        self.schema = arrow_schema(self.cols, meta)
        self.events: list = []
        self.tmp = partial_path(path)
        self._w = pq.ParquetWriter(self.tmp, self.schema, compression="zstd")

    def write_rows(self, rows) -> None:
        import pyarrow as pa

        if rows:
            self._w.write_table(pa.Table.from_arrays(arrow_columns(rows, self.cols), schema=self.schema))

    def write_events(self, rows) -> None:
        self.events.extend(rows)

    def abandon(self) -> None:
        """After a refused write: the unfinished file goes (without its footer no reader opens it)."""
        try:
            self._w.close()
        except Exception:  # noqa: BLE001 - the footer's own write fails as the last one did; the file goes anyway
            pass
        self.tmp.unlink(missing_ok=True)

    def close(self, trailer: dict) -> None:
        names = [c[0] for c in schema.EVENT_COLUMNS]
        self._w.add_key_value_metadata({
            "rodctl_events": json.dumps([dict(zip(names, r)) for r in self.events]),
            "rodctl_trailer": json.dumps(trailer)})
        self._w.close()
        os.replace(self.tmp, self.path)


def read(path: Path, names: list[str] | None):
    """(meta, arrow table, events list of dicts)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        pf = pq.ParquetFile(path)
        md = dict(pf.metadata.metadata or {})
    except (pa.ArrowInvalid, OSError) as e:
        raise InputError(f"{path}: not a readable Parquet file, or cut short ({str(e).strip().splitlines()[0]})") from None
    if b"rodctl" not in md:
        raise InputError(f"{path}: a Parquet file, but not a rodctl log (no rodctl metadata)")
    try:
        meta = json.loads(md[b"rodctl"])
        trailer = {k: str(v) for k, v in (json.loads(md.get(b"rodctl_trailer", b"{}")) or {}).items()}
        meta.update(trailer)
        meta[TRAILER_KEY] = trailer
        events = json.loads(md.get(b"rodctl_events", b"[]"))
    except ValueError as e:
        raise InputError(f"{path}: damaged rodctl metadata ({e})") from None
    have = pf.schema_arrow.names
    if names is not None:
        missing = [c for c in names if c not in have]
        if missing:
            raise InputError(f"{path}: no column {missing[0]}")
    meta["columns"] = {f.name: {k.decode(): v.decode() for k, v in (f.metadata or {}).items()}
                       for f in pf.schema_arrow}
    try:
        table = pf.read(columns=names, use_threads=threaded_read(path))  # csvlog.py says why not always
    except (pa.ArrowInvalid, OSError) as e:
        raise InputError(f"{path}: damaged Parquet data ({str(e).strip().splitlines()[0]})") from None
    meta["incomplete_rows"] = "0"
    return meta, table, events
