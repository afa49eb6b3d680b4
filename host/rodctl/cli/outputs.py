"""Where a command's output files go: checked, or their folder made, before any design work, run or
experiment, so that a bad path costs the user nothing and leaves nothing half-written.

A single named result (`--out`, `--json`, `--plot`, `--screenshot`) must go into a folder that exists
and can be written (a typo or a read-only folder is caught rather than made), must not be a folder, must not replace
an existing file unless the command has `--force`, and a figure must have an extension matplotlib
writes. Collections of files (a simulation's figure and logs, an identification's logs, the header)
make their folder, the way a run directory is made, and the folder must then be writable too; so does a
log (`log`/`arm --out`, `scope --record`, `log-convert --out`), which is a run's record. docs/host.md says which.
Every refusal is an InputError: one line naming the option, exit 2.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

from rodgains.errors import InputError

# What matplotlib's savefig writes (matplotlib.backend_bases.FigureCanvasBase.get_supported_filetypes()),
# listed here so that checking a name does not import matplotlib; figure_extensions() asks matplotlib
# when it is already loaded.
_FIGURE_EXTENSIONS = ("eps", "jpeg", "jpg", "pdf", "pgf", "png", "ps", "raw", "rgba", "svg", "svgz", "tif", "tiff",
                      "webp")


def figure_extensions() -> tuple[str, ...]:
    try:
        from matplotlib.backend_bases import FigureCanvasBase

        return tuple(sorted(FigureCanvasBase.get_supported_filetypes()))
    except Exception:  # noqa: BLE001 - matplotlib missing or changed: the list above
        return _FIGURE_EXTENSIONS


def _not_writable(folder: Path) -> str | None:
    """Why files cannot be made in `folder` (None when they can). os.access alone is not enough: root
    passes every permission check, but not a read-only mount, so a file is made and removed too."""
    if not os.access(folder, os.W_OK | os.X_OK):
        return "Read-only file system" if _read_only_mount(folder) else "Permission denied"
    try:
        fd, probe = tempfile.mkstemp(prefix=".rodctl-write-check-", dir=folder)
    except OSError as e:
        return e.strerror or str(e)
    os.close(fd)
    try:
        os.unlink(probe)
    except OSError:
        pass
    return None


def _read_only_mount(folder: Path) -> bool:
    try:
        return bool(os.statvfs(folder).f_flag & os.ST_RDONLY)
    except (OSError, AttributeError):
        return False


def check_folder_writable(folder: str | Path, what: str) -> None:
    """InputError unless files can be made in `folder` (an existing folder)."""
    why = _not_writable(Path(folder))
    if why is not None:
        raise InputError(f"{what}: cannot write into folder {folder} ({why})")


def check_figure_name(path: str | Path, what: str) -> None:
    """InputError unless the name ends in an extension matplotlib writes (it says the file's format;
    without one, matplotlib would write NAME.png instead of NAME)."""
    ext = Path(str(path)).suffix.lower().lstrip(".")
    known = figure_extensions()
    if not ext:
        raise InputError(f"{what} {path}: a figure's name needs an extension: {', '.join(known)}")
    if ext not in known:
        raise InputError(f"{what} {path}: matplotlib cannot write .{ext} figures; use one of: {', '.join(known)}")
    if ext == "pgf":
        # matplotlib draws .pgf text through LaTeX and finds it missing only once the figure is drawn, after
        # a command's other files are written
        import shutil

        import matplotlib

        tex = matplotlib.rcParams["pgf.texsystem"]
        if shutil.which(tex) is None:
            raise InputError(f"{what} {path}: a .pgf figure needs {tex} (LaTeX), which is not installed; "
                             "use .pdf or .svg")


def check_name(path: str | Path, what: str, *, figure: bool = False) -> Path:
    """InputError unless `path` names a file (not empty, not a folder) and, for a figure, one matplotlib
    writes; the path itself is not touched."""
    text = str(path)
    if not text.strip():
        raise InputError(f"{what}: empty file name")
    p = Path(text)
    if p.is_dir() or text.endswith(("/", os.sep)) or p.name in ("", ".", ".."):
        raise InputError(f"{what} {path}: is a folder")
    if figure:
        check_figure_name(p, what)
    return p


def check_output(path: str | Path, what: str, *, force: bool | None = None, figure: bool = False,
                 make_parent: bool = False) -> None:
    """InputError unless `path` can be written: not empty, not a folder, a figure's extension matplotlib
    writes (figure=True), its folder exists and is writable; with `force` given (the command has
    --force), an existing file also needs force=True. make_parent: the writer makes a missing folder
    (a log), so the nearest existing one must be a writable folder."""
    p = check_name(path, what, figure=figure)
    parent = p.resolve().parent
    if make_parent:
        while not parent.exists() and parent != parent.parent:
            parent = parent.parent
    if not parent.is_dir():
        if parent.exists():
            raise InputError(f"{what} {path}: {parent} is a file, not a folder")
        raise InputError(f"{what} {path}: folder {parent} does not exist (a result named alone is not given a "
                         "folder of its own: make it first)")
    if force is not None and (p.exists() or p.is_symlink()) and not force:
        raise InputError(f"{what} {path} exists; pass --force to overwrite")
    check_folder_writable(parent, f"{what} {path}")


def check_apart(path: str | Path | None, what: str, other: str | Path | None, other_what: str) -> None:
    """InputError when two outputs of one command name one file (None or '' entries skipped): the one written
    last would replace the other."""
    if path and other and Path(path).resolve() == Path(other).resolve():
        raise InputError(f"{what} {path} is also the {other_what}: one would replace the other; name them apart")


GENERATED_MARK = "DO NOT EDIT"


def check_not_input(path: str | Path, what: str, inputs) -> None:
    """InputError when `path` is one of `inputs` (None entries skipped): a command never writes over what it reads,
    --force or not."""
    p = Path(path)
    for src in inputs:
        if src is not None and p.exists() and p.resolve() == Path(src).resolve():
            raise InputError(f"{what}: would write {path}, which is an input of this command; choose another name")


def check_regenerable(path: str | Path, what: str, *, force: bool, inputs=()) -> None:
    """InputError unless `path` may be written as a generated file: it is none of `inputs` (check_not_input),
    not a folder, and if it exists it is a file rodctl generated (GENERATED_MARK in its first lines, so a
    regenerate command runs again as it is) or `force` is set."""
    check_not_input(path, what, inputs)
    p = check_name(path, what)  # a folder in the way: --force cannot replace it, so the write would fail half-way
    if force or not (p.exists() or p.is_symlink()):
        return
    try:
        with open(p, "rb") as f:
            head = f.read(512)
    except OSError:
        head = b""
    if GENERATED_MARK.encode() not in head:
        raise InputError(f"{what} {path} exists and is not a file rodctl generated; pass --force to overwrite")


def check_output_folder(folder: str | Path, what: str) -> None:
    """InputError (said as make_folder says it) unless `folder` is a writable folder, or can be made: the
    nearest existing folder above it is writable. Nothing is made here."""
    text = str(folder)
    if not text.strip():
        raise InputError(f"{what}: empty folder name")
    p = Path(text).resolve()
    while not p.exists() and p != p.parent:
        p = p.parent
    if not p.is_dir():
        raise InputError(f"{what}: cannot make folder {folder}: a file is in the way")
    check_folder_writable(p, what)


def make_folder(folder: str | Path, what: str) -> Path:
    """Make `folder` and its parents for `what`'s files; InputError (one line) when a file is in the
    way, the folder cannot be made, or it cannot be written."""
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise InputError(f"{what}: cannot make folder {folder}: a file is in the way") from None
    except OSError as e:
        raise InputError(f"{what}: cannot make folder {folder}: {e.strerror or e}") from None
    check_folder_writable(folder, what)
    return folder
