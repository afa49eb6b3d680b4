"""Build the SIL library: the firmware core + a generated rod_gains.h as a host shared library.

    from rodctl.build.sil_build import build_sil
    lib = build_sil(load_params(None, ["rod.edges=8"]))   # Path to librodsil-<hash>.so

The header goes into build/sil/<parameters hash>/ (the committed firmware/include/rod_gains.h
is never touched) and is searched first, so the library runs exactly the gains designed for
those parameters. The same firmware/src/core sources as the Teensy build are compiled, never a
copy, with the firmware's warning set. Builds are cached by content (rodctl.build.native).
"""

from __future__ import annotations

from pathlib import Path

from rodgains.atomic_file import atomic_write
from rodgains.errors import UserError

from rodctl import paths
from rodctl.build import native

SIL_DIR = paths.SIL_SRC
LIB_NAME = "rodsil"


def sil_sources() -> list[Path]:
    paths.require_firmware_sources()
    return [SIL_DIR / "rod_sil.c", *sorted(paths.CORE_SRC.glob("*.c"))]


def write_header(params, command: str | None = None, out_root: Path | None = None) -> Path:
    """Design gains for `params` and write their rod_gains.h under build/sil/; returns its folder."""
    from rodgains.codegen import header_text
    from rodgains.design import design

    from rodctl.build.header import regenerate_command

    if command is None:
        command = regenerate_command(None, [], None)
    text = header_text(design(params), command)
    folder = Path(out_root or paths.BUILD / "sil") / params.sha256()[:16]
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UserError(f"cannot create the build folder {folder}: {e.strerror or e} "
                        "(set RODCTL_BUILD_DIR to a writable folder)") from None
    header = folder / "rod_gains.h"
    if not header.exists() or header.read_text() != text:
        atomic_write(header, text)  # a concurrent build never sees half a header
    return folder


# (parameters hash, command, out_dir) -> library: a process (a pool or Dask worker running many runs
# of one design) designs and hashes the sources once per distinct parameter set, not once per run.
_BUILT: dict[tuple, Path] = {}


def build_sil(params=None, command: str | None = None, out_dir: Path | None = None) -> Path:
    """Path of the SIL shared library for `params` (default parameters when None)."""
    if params is None:
        from rodgains.params import load_params

        params = load_params()
    memo = (params.sha256(), command, str(out_dir))
    lib = _BUILT.get(memo)
    if lib is not None and lib.exists():
        return lib
    header_dir = write_header(params, command)
    lib = native.compile_shared(
        LIB_NAME,
        sil_sources(),
        include_dirs=[header_dir, paths.CORE_SRC, SIL_DIR],
        flags=("-O2",) + native.FIRMWARE_WARNINGS,
        out_dir=out_dir,
    )
    _BUILT[memo] = lib
    return lib
