"""The tracked log: Parquet (one row per frame), and MCAP for Foxglove on the telemetry's clock."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from rodgains.atomic_file import replacing


def columns(t: np.ndarray, tau: np.ndarray, theta: np.ndarray, markers_m: np.ndarray, quality: np.ndarray) -> dict:
    cols = {"time_s": t, "video_time_s": tau, "frame": np.arange(len(t)), "quality": quality.astype(np.int8)}
    for i in range(theta.shape[1]):
        cols[f"theta_{i + 1}_rad"] = theta[:, i]
    for j in range(markers_m.shape[1]):
        cols[f"marker_{j}_x_m"] = markers_m[:, j, 0]
        cols[f"marker_{j}_y_m"] = markers_m[:, j, 1]
    return cols


def rest_shape_meta(rest, note: str = "") -> dict:
    """The metadata entries of the rod's rest shape (rodctl.track.rest_shape.RestShape, or None: not measured, and
    `note` says why); the names carry their units."""
    if rest is None:
        return {"rest_curvature_per_m": "not measured", "rest_note": note}
    return {"rest_curvature_per_m": f"{rest.kappa_per_m:.4f}", "rest_tip_offset_m": f"{rest.tip_offset_m:.6f}",
            "rest_still_s": f"{rest.still_from_s:.4f},{rest.still_to_s:.4f}", "rest_frames": rest.frames,
            "rest_rms_residual_m": f"{rest.rms_residual_m:.6f}",
            "rest_note": "rod.rest_curvature: positive when the hanging tip, the hub vertical, is toward increasing "
                         "angles; from the longest still stretch, a rigid motion fitted out"}


def write_parquet(path: Path, cols: dict, meta: dict) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.table(cols).replace_schema_metadata({k: str(v) for k, v in meta.items()})
    with replacing(path) as tmp:
        pq.write_table(table, tmp)


def write_mcap(path: Path, cols: dict, meta: dict) -> None:
    """One JSON message per frame on /rod/tracked, log time = the telemetry log's clock [ns]."""
    from mcap.writer import Writer

    theta_keys = [k for k in cols if k.startswith("theta_")]
    schema = {"type": "object", "properties": {"time_s": {"type": "number"}, "quality": {"type": "integer"},
                                               "theta_rad": {"type": "array", "items": {"type": "number"}}}}

    with replacing(path) as tmp, open(tmp, "wb") as f:
        w = Writer(f)
        w.start(profile="", library="rodctl track")
        sid = w.register_schema(name="rod.Tracked", encoding="jsonschema", data=json.dumps(schema).encode())
        cid = w.register_channel(topic="/rod/tracked", message_encoding="json", schema_id=sid)
        w.add_metadata("rodctl.track", {k: str(v) for k, v in meta.items()})
        for k in range(len(cols["time_s"])):
            t = float(cols["time_s"][k])
            if not np.isfinite(t) or t < 0:
                continue
            th = [float(cols[c][k]) for c in theta_keys]
            msg = {"time_s": t, "quality": int(cols["quality"][k]),
                   "theta_rad": [v if np.isfinite(v) else None for v in th]}
            ns = int(round(t * 1e9))
            w.add_message(cid, log_time=ns, publish_time=ns, data=json.dumps(msg).encode(), sequence=k)
        w.finish()
