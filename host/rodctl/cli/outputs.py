"""Where a command's output files go: checked, or their folder made, before any design work, run or
experiment, so that a bad path costs the user nothing and leaves nothing half-written.

A single named result (`--out`, `--json`) must go into a folder that exists: a typo there is caught.
Collections of files (a simulation's figure and logs, an identification's logs, the header) make
their folder, the way a run directory is made."""

from __future__ import annotations

from pathlib import Path

from rodgains.errors import InputError


def check_output(path: str | Path, what: str, *, force: bool | None = None) -> None:
    """InputError unless `path` can be written: its folder exists and it is not a folder; with `force`
    given, an existing file also needs force=True."""
    if force is not None and Path(path).exists() and not force:
        raise InputError(f"{path} exists; pass --force to overwrite")
    parent = Path(path).resolve().parent
    if not parent.is_dir():
        raise InputError(f"{what} {path}: folder {parent} does not exist")
    if Path(path).is_dir():
        raise InputError(f"{what} {path}: is a folder")


def make_folder(folder: str | Path, what: str) -> Path:
    """Make `folder` and its parents for `what`'s files; InputError (one line) when a file is in the
    way or the folder cannot be made."""
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise InputError(f"{what}: cannot make folder {folder}: a file is in the way") from None
    except OSError as e:
        raise InputError(f"{what}: cannot make folder {folder}: {e.strerror or e}") from None
    return folder
