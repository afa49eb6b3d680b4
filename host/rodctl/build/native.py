"""Compile C into host shared libraries with gcc, cached by the content of everything that goes in.

Two caches: the library, keyed by every source and header; on a miss, each translation unit's object,
keyed by its preprocessed text. A new design changes the generated rod_gains.h, which every core
file includes, yet most of them use none of the values that moved: their preprocessed text is the
same, and their objects are reused (the protocol's encoders, half a build's time, never depend on
the gains). A rebuild for a new design then compiles only the files that read the changed values.
"""

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
    sources = [Path(s).resolve() for s in sources]
    include_dirs = [Path(d).resolve() for d in include_dirs]  # objects compile in a folder of their own
    cflags = ["-std=c11", "-fPIC", *flags] + [f"-I{d}" for d in include_dirs]
    parts = [cc.encode(), " ".join(["-shared", *cflags]).encode()]
    for f in sources + _headers(include_dirs):
        parts += [str(f.name).encode(), f.read_bytes()]
    out_dir = Path(out_dir or paths.BUILD / "native")
    try:
        (out_dir / "obj").mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise UserError(f"cannot create the build folder {out_dir}: {e.strerror or e} "
                        "(set RODCTL_BUILD_DIR to a writable folder)") from None
    lib = out_dir / f"lib{name}-{_digest(parts)}.so"
    if lib.exists():
        return lib
    objects = _objects(name, cc, cflags, len(include_dirs), sources, out_dir / "obj")
    tmp = _unique(lib)
    _run(name, [cc, "-shared", *map(str, objects), "-o", str(tmp), "-lm"], tmp)
    os.replace(tmp, lib)  # atomic: concurrent builds of the same inputs are harmless
    return lib


def _unique(path: Path) -> Path:
    """A temporary name beside `path`, unique per process, thread and host (shared build dirs)."""
    return path.with_suffix(f".{uuid.uuid4().hex}.tmp")


def _run(name: str, cmd: list[str], tmp: Path, cwd: Path | None = None) -> None:
    result = subprocess.run(cmd, capture_output=True, text=True, cwd=cwd)
    if result.returncode != 0:
        if tmp.is_file():
            tmp.unlink()
        raise UserError(f"compiling {name} failed: {first_error(result.stderr)}")


def _objects(name: str, cc: str, cflags: list[str], n_include: int, sources: list[Path], obj_dir: Path) -> list[Path]:
    """Each source's object in obj_dir, compiled only when no object of the same preprocessed text exists.
    The key is the text without line markers (-P) and the flags but the include folders (the last
    n_include of cflags), so a header with the same content in another folder is no change. The object
    is compiled from the source itself, so warnings and errors point at its lines."""
    if len({s.stem for s in sources}) < len(sources):
        raise ValueError(f"{name}: two sources with one name: {sorted(s.name for s in sources)}")
    objects = []
    for src in sources:
        pre = subprocess.run([cc, *cflags, "-E", "-P", str(src)], capture_output=True)
        if pre.returncode != 0:
            raise UserError(f"compiling {name} failed: {first_error(pre.stderr.decode(errors='replace'))}")
        flags = " ".join(cflags[:len(cflags) - n_include])
        key = _digest([cc.encode(), flags.encode(), src.name.encode(), pre.stdout])
        objects.append(obj_dir / f"{src.stem}-{key}.o")
    missing = [(src, obj) for src, obj in zip(sources, objects) if not obj.exists()]
    if missing:  # one compiler run for all of them: gcc -c writes each X.c's X.o into its working folder
        tmp = _unique(obj_dir / name)
        tmp.mkdir()
        try:
            _run(name, [cc, *cflags, "-c", *(str(src) for src, _ in missing)], tmp, cwd=tmp)
            for src, obj in missing:
                os.replace(tmp / f"{src.stem}.o", obj)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    return objects
