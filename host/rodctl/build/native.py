"""Compile C into host shared libraries with gcc, cached by the content of everything that goes in."""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import uuid
from pathlib import Path

from rodgains.errors import UserError

from rodctl import paths

# The firmware's own warning set: the SIL library is the target code, so it must be as clean here.
FIRMWARE_WARNINGS = ("-Wall", "-Wextra", "-Wdouble-promotion", "-Werror")


def compiler() -> str:
    cc = os.environ.get("CC", "gcc")
    if shutil.which(cc) is None:
        raise UserError(f"C compiler {cc!r} not found: install gcc (Debian: apt-get install gcc)")
    return cc


def _digest(parts: list[bytes]) -> str:
    h = hashlib.sha256()
    for part in parts:
        h.update(len(part).to_bytes(8, "little"))
        h.update(part)
    return h.hexdigest()[:16]


def _headers(include_dirs: list[Path]) -> list[Path]:
    out = []
    for d in include_dirs:
        out += sorted(Path(d).glob("*.h"))
    return out


def first_error(stderr: str) -> str:
    """The compiler's first `error:` line (not the "In file included from" chain before it)."""
    lines = [x.strip() for x in stderr.strip().splitlines() if x.strip()]
    for x in lines:
        if "error:" in x:
            return x
    return lines[0] if lines else "(no output)"


def compile_shared(
    name: str,
    sources: list[Path],
    include_dirs: list[Path] = (),
    flags: tuple[str, ...] = ("-O2",),
    out_dir: Path | None = None,
) -> Path:
    """Build lib<name>-<hash>.so from `sources`; reuse it when sources, headers and flags are unchanged.

    Include directories are searched in order, so a build folder placed first overrides the
    committed generated header without touching it.
    """
    cc = compiler()
    sources = [Path(s) for s in sources]
    include_dirs = [Path(d) for d in include_dirs]
    argv_flags = ["-std=c11", "-fPIC", "-shared", *flags] + [f"-I{d}" for d in include_dirs]
    parts = [cc.encode(), " ".join(argv_flags).encode()]
    for f in sources + _headers(include_dirs):
        parts += [str(f.name).encode(), f.read_bytes()]
    out_dir = Path(out_dir or paths.BUILD / "native")
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UserError(f"cannot create the build folder {out_dir}: {e.strerror or e} "
                        "(set RODCTL_BUILD_DIR to a writable folder)") from None
    lib = out_dir / f"lib{name}-{_digest(parts)}.so"
    if lib.exists():
        return lib
    tmp = lib.with_suffix(f".{uuid.uuid4().hex}.tmp")  # unique per process, thread and host (shared build dirs)
    cmd = [cc, *argv_flags, *map(str, sources), "-o", str(tmp), "-lm"]
    result = subprocess.run(cmd, capture_output=True, text=True)
    if result.returncode != 0:
        tmp.unlink(missing_ok=True)
        raise UserError(f"compiling {name} failed: {first_error(result.stderr)}")
    os.replace(tmp, lib)  # atomic: concurrent builds of the same inputs are harmless
    return lib
