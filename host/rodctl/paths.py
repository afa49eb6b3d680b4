"""Where things live in a checkout. rodctl runs from a clone installed with `pip install -e .`."""

from __future__ import annotations

from pathlib import Path

from rodgains.errors import UserError

REPO = Path(__file__).resolve().parents[2]
FIRMWARE = REPO / "firmware"
CORE_SRC = FIRMWARE / "src" / "core"
COMMITTED_HEADER = FIRMWARE / "include" / "rod_gains.h"
COMMITTED_PARAMS = FIRMWARE / "include" / "rod_gains.toml"
BUILD = REPO / "build"


def require_firmware_sources() -> None:
    if not CORE_SRC.is_dir():
        raise UserError(
            f"firmware sources not found at {CORE_SRC}: run rodctl from a clone installed with `pip install -e .`"
        )
