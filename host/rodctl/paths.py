"""Where things live: in a clone (pip install -e .), or in the installed package (wheel, pipx).

A clone is preferred whenever this module sits inside one (host/rodctl/ with firmware/ beside
host/). Otherwise the wheel's copy is used: setup.py copies the protocol definition, the core and
SIL C sources and the committed parameters into rodctl/_firmware/ at build time, which is enough
for `rodctl sim`, `gains` and the protocol tools; firmware builds and flashing need the clone's
PlatformIO project and say so (require_checkout). Build products never go into site-packages:
outside a clone they go to the user's cache folder.
"""

from __future__ import annotations

import os
from pathlib import Path

from rodgains.design_cache import user_cache_home
from rodgains.errors import InputError, UserError

PACKAGE = Path(__file__).resolve().parent
_CLONE = PACKAGE.parents[1]
PACKAGED_FIRMWARE = PACKAGE / "_firmware"  # written by setup.py's build_py into the wheel


def _is_clone(root: Path) -> bool:
    return (root / "firmware" / "protocol" / "rodlink.toml").is_file() and (root / "platformio.ini").is_file()


def _user_cache() -> Path:
    return user_cache_home() / "rodctl"


IN_CLONE = _is_clone(_CLONE)
REPO = _CLONE if IN_CLONE else PACKAGED_FIRMWARE.parent  # shown paths are relative to this
FIRMWARE = _CLONE / "firmware" if IN_CLONE else PACKAGED_FIRMWARE
CORE_SRC = FIRMWARE / "src" / "core"
SIL_SRC = FIRMWARE / "sil"
SPEC = FIRMWARE / "protocol" / "rodlink.toml"
COMMITTED_HEADER = FIRMWARE / "include" / "rod_gains.h"
COMMITTED_PARAMS = FIRMWARE / "include" / "rod_gains.toml"
# RODCTL_BUILD_DIR: where SIL libraries, logs of firmware builds and benches go
BUILD = Path(os.environ["RODCTL_BUILD_DIR"]) if os.environ.get("RODCTL_BUILD_DIR") else (
    _CLONE / "build" if IN_CLONE else _user_cache() / "build")


def shown(path: str | Path, root: Path | None = None) -> str:
    """A path as shown to the user and in generated text: relative to root (default: the checkout) when
    inside it, else as given."""
    try:
        return str(Path(path).resolve().relative_to((root or REPO).resolve()))
    except ValueError:
        return str(path)


def clone_around(folder: Path) -> Path | None:
    """The clone of this repository that `folder` is in (itself or a parent), if any."""
    folder = folder.resolve()
    return next((d for d in (folder, *folder.parents) if _is_clone(d)), None)


def require_checkout(what: str) -> None:
    """UserError (one line, exit 2) when rodctl runs from an installed package, not a clone, or when the current
    folder is in another clone than the one this rodctl runs from: its default files are that clone's, and writing
    them from a second clone's folder would change the first one's committed files unseen."""
    if not IN_CLONE:
        raise InputError(f"{what} needs a clone of this repository (its PlatformIO project and firmware/): "
                        f"git clone it, then `pip install -e .` inside it; this rodctl runs from {PACKAGE}")
    try:
        here = clone_around(Path.cwd())
    except OSError:  # the current folder was removed under the shell, or a parent cannot be read: no clone here
        here = None
    if here is not None and here != _CLONE.resolve():
        raise InputError(f"{what}: this rodctl is installed from the clone {_CLONE} and works on its files, but "
                         f"this folder is in another clone, {here}: run this clone's own rodctl (`pip install -e .` "
                         "in it)")


def require_firmware_sources() -> None:
    if not (CORE_SRC.is_dir() and SIL_SRC.is_dir()):
        raise UserError(f"firmware sources not found at {FIRMWARE}: reinstall rodctl, or run it from a clone "
                        f"installed with `pip install -e .`")
