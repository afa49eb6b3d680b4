"""On-disk cache of the robust refinement, the only part of a design that takes seconds.

Why: `design.method = "robust"` refines the LQG gains over a family of rods and releases them
from the catch angle (robust_design.py, large_signal.py): about 25 s. Every `rodctl` command that
needs gains (sim, log --port sim://, the SIL build, the header check) would pay that again in
each new process. The result depends only on its inputs, so it is stored once per input.

Key: SHA-256 over the refinement's exact inputs (parameters' canonical JSON, the sampling period,
the estimator and LQG matrices as float64 bytes, whether the disturbance state is on) and over the
code that computes it (every rodgains module's source, numpy's and scipy's versions). A changed
parameter, a changed line of design code or another LAPACK result gives a new key; nothing is
ever served stale. Values are stored as JSON, whose float repr round-trips float64 exactly, so a
cached design is bit-identical to a fresh one.

Where: $RODGAINS_CACHE_DIR, else $XDG_CACHE_HOME/rodgains, else ~/.cache/rodgains. An unreadable,
corrupt or unwritable cache is ignored (the design is computed); it never fails a design.
"""

from __future__ import annotations

import hashlib
import json
import os
from functools import lru_cache
from pathlib import Path

import numpy as np
import scipy

from .atomic_file import atomic_write

PACKAGE = Path(__file__).resolve().parent
FORMAT = 1  # bump when the stored layout changes


def user_cache_home() -> Path:
    """The user's cache folder by the XDG rule: $XDG_CACHE_HOME, else ~/.cache (rodctl's too)."""
    return Path(os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"))


def directory() -> Path:
    if os.environ.get("RODGAINS_CACHE_DIR"):
        return Path(os.environ["RODGAINS_CACHE_DIR"])
    return user_cache_home() / "rodgains"


@lru_cache(maxsize=1)
def code_hash() -> str:
    """SHA-256 of the design code: every module of this package, and numpy's and scipy's versions."""
    h = hashlib.sha256(f"format {FORMAT} numpy {np.__version__} scipy {scipy.__version__}\n".encode())
    for src in sorted(PACKAGE.glob("*.py")):
        h.update(src.name.encode() + b"\0" + src.read_bytes() + b"\0")
    return h.hexdigest()


def key(params_sha256: str, scalars: tuple, arrays: tuple) -> str:
    h = hashlib.sha256(f"{code_hash()}\n{params_sha256}\n{scalars!r}\n".encode())
    for a in arrays:
        a = np.ascontiguousarray(a, dtype=np.float64)
        h.update(repr(a.shape).encode() + a.tobytes())
    return h.hexdigest()


def load(k: str) -> dict | None:
    """The stored record for key `k`, or None (absent, unreadable or not this key's)."""
    try:
        record = json.loads((directory() / f"{k}.json").read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(record, dict) or record.get("key") != k:
        return None
    return record


def store(k: str, record: dict) -> None:
    """Write atomically (a concurrent reader sees the whole record or none); errors are ignored."""
    try:
        atomic_write(directory() / f"{k}.json", json.dumps(dict(record, key=k)))
    except OSError:
        pass
