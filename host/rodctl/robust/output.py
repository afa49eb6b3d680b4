"""Output files of the robustness commands: written whole or not at all (temporary name, then rename)."""

from __future__ import annotations

import json
from pathlib import Path

from rodgains.atomic_file import atomic_write, replacing


def write_json(path: str | Path, obj) -> Path:
    # allow_nan=False: non-finite numbers are None (null) in every row, so the file is strict JSON
    return atomic_write(path, json.dumps(obj, indent=1, allow_nan=False) + "\n")


def write_parquet(path: str | Path, rows: list[dict], meta: dict) -> Path:
    """One row per run; columns are the union of the rows' keys; lists stay lists."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    names = list(dict.fromkeys(k for r in rows for k in r))
    table = pa.Table.from_pylist([{k: r.get(k) for k in names} for r in rows])
    table = table.replace_schema_metadata({"rodctl": json.dumps(meta)})
    with replacing(path) as tmp:
        pq.write_table(table, tmp)
    return Path(path)
