"""Output files of the robustness commands: written whole or not at all (temporary name, then rename)."""

from __future__ import annotations

import json
from pathlib import Path

from rodgains.atomic_file import atomic_write, replacing


def write_json(path: str | Path, obj) -> Path:
    # allow_nan=False: non-finite numbers are None (null) in every row, so the file is strict JSON
    return atomic_write(path, json.dumps(obj, indent=1, allow_nan=False) + "\n")


# A run's row (rodctl.robust.execute.run_unit over rodctl.sim.matrix.run_case): every column with its type, so
# that two files of one command read together (pl.read_parquet([a, b])) whatever their runs did: a column
# no run filled (no catch in a balance sweep, every point refused) is a typed column of nulls, not a `null`
# column or none at all.
RUN_COLUMN_TYPES = {
    "case": "string", "task": "string", "refused": "bool", "reason": "string", "params_sha256": "string",
    "settle_s": "float64", "final_dev_deg": "float64", "held_fraction": "float64", "max_dev_deg": "float64",
    "peak_torque_Nm": "float64", "caught_at_s": "float64", "fault": "bool", "fault_reason": "int64",
    "base_turns_max": "float64", "est_rms_deg": "float64", "simulated_s": "float64", "passed": "bool",
    "title": "string", "criterion": "string", "plant": "string", "buckling_ratio": "float64",
    "straightest_deg": "float64", "plant_sha256": "string", "kind": "string", "draw": "int64", "point": "int64",
}


def write_parquet(path: str | Path, rows: list[dict], meta: dict, types: dict[str, str] | None = None) -> Path:
    """One row per run; columns are the union of the rows' keys and of `types` (name -> Arrow type name), typed
    as `types` says; another column that no row filled is a float64 of nulls (a number no run produced)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    types = types or {}
    names = list(dict.fromkeys([*(k for r in rows for k in r), *types]))
    fields = []
    for k in names:
        if k in types:
            fields.append(pa.field(k, pa.type_for_alias(types[k])))
            continue
        t = pa.array([r.get(k) for r in rows]).type
        fields.append(pa.field(k, pa.float64() if pa.types.is_null(t) else t))
    table = pa.Table.from_pylist([{k: r.get(k) for k in names} for r in rows], schema=pa.schema(fields))
    table = table.replace_schema_metadata({"rodctl": json.dumps(meta)})
    with replacing(path) as tmp:
        pq.write_table(table, tmp)
    return Path(path)
