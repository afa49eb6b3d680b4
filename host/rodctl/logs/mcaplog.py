"""MCAP logs (the `mcap` library): opens in Foxglove and PlotJuggler.

Channels, all JSON with a JSON Schema (Foxglove plots any numeric field, e.g. /telemetry.theta_hat_1_rad):
    /telemetry   one message per TELEMETRY frame, the telemetry columns of the CSV log as fields
    /events      HELLO, ACK, mode changes and notes (the columns of PATH.events.csv)
    /rod_shape   the estimated rod every 20 ms of device time: x_m, y_m (node coordinates, node 0
                 on the motor axis) and points [{x, y}]; in Foxglove's Plot panel choose the x axis
                 "path (current)" = /rod_shape.x_m[:] and plot /rod_shape.y_m[:]
Message log times are host_start_unix_s + time_s (device clock). The log's metadata is the MCAP
metadata record "rodctl", the trailer "rodctl_trailer" (written at close). Chunks of 256 kB
(about 0.4 s at 1 kHz) are written as they fill, so a killed logger loses only the last chunk.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from rodgains.errors import InputError

from rodctl.logs import schema
from rodctl.logs.schema import TRAILER_KEY
from rodctl.logs.metadata import edge_length

MAGIC = b"\x89MCAP0\r\n"
SHAPE_INTERVAL_S = 0.02
CHUNK_BYTES = 256 * 1024


def _json_type(dtype: str) -> str:
    return "integer" if dtype == "i8" else "string" if dtype.startswith("U") else "number"


def json_schema(cols, title: str) -> bytes:
    props = {c: {"type": [_json_type(d), "null"] if d == "f8" else _json_type(d), "description": f"{w} [{u}]"}
             for c, d, u, w in cols}
    return json.dumps({"title": title, "type": "object", "properties": props}).encode()


SHAPE_SCHEMA = json.dumps({
    "title": "rodctl.RodShape", "type": "object",
    "properties": {
        "time_s": {"type": "number", "description": "device time [s]"},
        "x_m": {"type": "array", "items": {"type": "number"}, "description": "node x [m], node 0 on the axis"},
        "y_m": {"type": "array", "items": {"type": "number"}, "description": "node y [m], up positive"},
        "points": {"type": "array", "items": {"type": "object", "properties": {"x": {"type": "number"},
                                                                              "y": {"type": "number"}}}},
    }}).encode()


def _clean(v):
    return None if isinstance(v, float) and not math.isfinite(v) else v  # JSON has no NaN or Infinity


class McapSink:
    files = ("log",)

    def __init__(self, path: Path, meta: dict, n: int):
        from mcap.writer import Writer

        self.path = path
        self.n = n
        self.cols = schema.columns(n)
        self.names = [c[0] for c in self.cols]
        self.enames = [c[0] for c in schema.EVENT_COLUMNS]
        self.t0_ns = int(float(meta.get("host_start_unix_s", "0") or 0) * 1e9)
        self.l, _ = edge_length(meta, n) if n else (0.0, "")
        self._f = open(path, "wb")
        w = self._w = Writer(self._f, chunk_size=CHUNK_BYTES)
        w.start(profile="", library="rodctl")
        tid = w.register_schema("rodctl.Telemetry", "jsonschema", json_schema(self.cols, "rodctl.Telemetry"))
        eid = w.register_schema("rodctl.Event", "jsonschema", json_schema(schema.EVENT_COLUMNS, "rodctl.Event"))
        sid = w.register_schema("rodctl.RodShape", "jsonschema", SHAPE_SCHEMA)
        self.ch_t = w.register_channel("/telemetry", "json", tid)
        self.ch_e = w.register_channel("/events", "json", eid)
        self.ch_s = w.register_channel("/rod_shape", "json", sid)
        w.add_metadata("rodctl", {k: str(v) for k, v in meta.items()})
        self._next_shape = 0.0
        self._seq = 0

    def _ns(self, t: float) -> int:
        return self.t0_ns + int(round(t * 1e9))

    def write_rows(self, rows) -> None:
        w, names, n, l = self._w, self.names, self.n, self.l
        th0 = len(schema.BASE_COLUMNS)
        for r in rows:
            t = r[0]
            ns = self._ns(t)
            self._seq += 1
            w.add_message(self.ch_t, log_time=ns, publish_time=ns, sequence=self._seq,
                          data=json.dumps(dict(zip(names, map(_clean, r)))).encode())
            if t >= self._next_shape and n:
                th = np.asarray(r[th0:th0 + n], dtype=float)
                if np.all(np.isfinite(th)):
                    x = np.concatenate([[0.0], np.cumsum(l * np.sin(th))]).round(6).tolist()
                    y = np.concatenate([[0.0], -np.cumsum(l * np.cos(th))]).round(6).tolist()
                    w.add_message(self.ch_s, log_time=ns, publish_time=ns, sequence=self._seq, data=json.dumps(
                        {"time_s": t, "x_m": x, "y_m": y, "points": [{"x": a, "y": b} for a, b in zip(x, y)]}).encode())
                self._next_shape = t + SHAPE_INTERVAL_S
        self._f.flush()

    def write_events(self, rows) -> None:
        for r in rows:
            ns = self._ns(r[0] if not math.isnan(r[0]) else 0.0)
            self._w.add_message(self.ch_e, log_time=ns, publish_time=ns, sequence=0,
                                data=json.dumps(dict(zip(self.enames, map(_clean, r)))).encode())

    def abandon(self) -> None:
        """After a refused write: the file as it is, its chunks so far readable, no summary."""
        try:
            self._f.close()
        except OSError:
            pass

    def close(self, trailer: dict) -> None:
        self._w.add_metadata("rodctl_trailer", {k: str(v) for k, v in trailer.items()})
        self._w.finish()
        self._f.close()


def read(path: Path, names: list[str] | None):
    """(meta, dict of telemetry column lists, list of event dicts); reads a cut file up to its last chunk."""
    from mcap.records import Channel, Message, Metadata
    from mcap.stream_reader import StreamReader

    with open(path, "rb") as f:
        if f.read(len(MAGIC)) != MAGIC:
            raise InputError(f"{path}: not an MCAP file")
        f.seek(0)
        meta: dict = {}
        trailer: dict | None = None
        channels: dict[int, str] = {}
        tl: list[dict] = []
        events: list[dict] = []
        cut = 0
        try:
            for rec in StreamReader(f, skip_magic=False).records:
                if isinstance(rec, Message):
                    topic = channels.get(rec.channel_id)
                    if topic == "/telemetry":
                        tl.append(json.loads(rec.data))
                    elif topic == "/events":
                        events.append(json.loads(rec.data))
                elif isinstance(rec, Channel):
                    channels[rec.id] = rec.topic
                elif isinstance(rec, Metadata) and rec.name in ("rodctl", "rodctl_trailer"):
                    meta.update(rec.metadata)
                    if rec.name == "rodctl_trailer":
                        trailer = {**(trailer or {}), **rec.metadata}
        except Exception as e:  # noqa: BLE001 - the mcap library raises many kinds on a cut or damaged file
            cut = 1
            if not tl:
                raise InputError(f"{path}: damaged or cut MCAP file ({type(e).__name__}: {e})") from None
    if "rodctl-log" not in meta and not tl:
        raise InputError(f"{path}: an MCAP file, but not a rodctl log (no /telemetry channel)")
    have = list(tl[0]) if tl else [c[0] for c in schema.columns(int(meta.get("n_edges", 0) or 0))]
    want = have if names is None else names
    missing = [c for c in want if c not in have]
    if missing:
        raise InputError(f"{path}: no column {missing[0]}")
    cols = {c: [m.get(c) for m in tl] for c in want}
    meta["incomplete_rows"] = str(cut)
    meta[TRAILER_KEY] = dict(trailer or {})
    return meta, cols, events
