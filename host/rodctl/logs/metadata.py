"""A log's metadata: who recorded it, from which firmware and parameters (a dict of strings).

Written beside a CSV (PATH.json), in the Parquet file metadata and in the MCAP metadata record;
the trailer (counters at a clean close) is added under the same keys.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import time

from rodgains.errors import UserError

from rodctl import __version__, paths
from rodctl.link import protocol as P
from rodctl.link.session import hello_counts_per_rev
from rodctl.logs.schema import FORMAT_VERSION


def utc_now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def _settings_json(hello) -> str:
    return json.dumps({
        "swing_amplitude_Nm": float(hello.swing_amplitude),
        "swing_angle_rad": float(hello.swing_angle),
        "catch_angle_rad": float(hello.catch_angle),
        "heartbeat_timeout_s": float(hello.heartbeat_timeout),
        "torque_max_Nm": float(hello.torque_max),
        "counts_per_rev": hello_counts_per_rev(hello),
    }, sort_keys=True)


def identify_params(header_sha256: str, candidates=()):
    """The parameters the firmware's gains were designed from: (Params, source) or (None, "unknown").

    Matches the device's header SHA-256 (HELLO) against Params.sha256() of the candidates
    (iterable of (Params or path, label)), the committed firmware/include/rod_gains.toml and the
    default parameter file.
    """
    from rodgains.params import DEFAULT_PARAMS, load_params

    tried = list(candidates) + [(paths.COMMITTED_PARAMS, paths.shown(paths.COMMITTED_PARAMS)),
                                (DEFAULT_PARAMS, paths.shown(DEFAULT_PARAMS))]
    for cand, label in tried:
        try:
            p = cand if hasattr(cand, "sha256") else load_params(cand)
        except (UserError, OSError):
            continue
        if p.sha256() == header_sha256:
            return p, label
    return None, "unknown"


def overrides_of(params) -> list[str]:
    """`section.key=value` for every value of `params` that differs from the default parameter file."""
    if params is None:
        return []
    from rodgains.params import load_params

    base = load_params()
    out = []
    for section, values in params.values.items():
        for key, v in values.items():
            if base.values.get(section, {}).get(key) != v:
                out.append(f"{section}.{key}={v:g}" if isinstance(v, float) else f"{section}.{key}={v}")
    return out


def device_metadata(hello, *, port: str, params=None, params_source: str = "unknown",
                    start_unix: float | None = None) -> dict[str, str]:
    """Metadata of a log recorded from a device that sent `hello`."""
    meta = {
        "rodctl-log": FORMAT_VERSION,
        "created_utc": utc_now(),
        "rodctl_version": __version__,
        "source": "device",
        "port": port,
        "protocol_version": str(P.VERSION),
        "firmware_version": f"{hello.fw_major}.{hello.fw_minor}.{hello.fw_patch}",
        "gains_schema": str(hello.gains_schema),
        "header_sha256": bytes(hello.header_sha256).hex(),
        "params_source": params_source if params is not None else "unknown",
        "params_sha256": params.sha256() if params is not None else "unknown",
        "overrides": " ".join(overrides_of(params)),
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
        "counts_per_rev": float(params.counts_per_rev),
    }
    return {
        "rodctl-log": FORMAT_VERSION,
        "created_utc": utc_now(),
        "rodctl_version": __version__,
        "source": source,
        "port": "",
        "protocol_version": str(P.VERSION),
        "firmware_version": firmware_version,
        "gains_schema": "",
        "header_sha256": header_sha256 or params.sha256(),
        "params_source": "simulator",
        "params_sha256": params.sha256(),
        "overrides": " ".join(overrides_of(params)),
        "n_edges": str(n if n is not None else params.N),
        "period_us": str(period_us if period_us is not None else int(round(params.dt * 1e6))),
        "decimation": str(decimation),
        "settings": json.dumps(s, sort_keys=True),
        "host_start_unix_s": f"{time.time():.6f}",
        "params_json": params.canonical_json(),
    }


def counts_per_rev_of(meta: dict, params=None) -> float | None:
    """Encoder counts per output turn the board reduced the log's counts with: its run-time setting (the
    HELLO in the metadata), else the parameters' (None when neither is known)."""
    try:
        value = json.loads(meta.get("settings") or "{}").get("counts_per_rev")
    except (ValueError, AttributeError):
        value = None
    if value:
        return float(value)
    return float(params.counts_per_rev) if params is not None else None


def params_of(meta: dict):
    """The Params recorded in a log's metadata, or None when the log says "unknown"."""
    text = meta.get("params_json")
    if not text:
        return None
    from rodgains.params import Params, validate

    try:
        return Params(validate(json.loads(text), source="log"), source="log")
    except (UserError, ValueError, TypeError):
        return None


def edge_length(meta: dict, n: int) -> tuple[float, str]:
    """(l [m], note): rod length / n from the log's parameters (the default rod when the log has none)."""
    p = params_of(meta)
    if p is not None:
        return p["rod"]["length"] / n, ""
    from rodgains.params import load_params

    return load_params()["rod"]["length"] / n, " (parameters unknown: default rod length assumed)"
