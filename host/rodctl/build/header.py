"""The generated gains header and its parameter copy, for a parameter file and its overrides.

    d, files = generated_files("my_rig.toml", ["rod.edges=8"], header=None)   # {path: text}, not written
    written = rodgains.atomic_file.write_changed(files)                         # only what differs

Both files name the command that regenerates them, spelled the same however it was typed.
"""

from __future__ import annotations

import shlex
from pathlib import Path
from typing import Callable, Sequence

from rodgains import atomic_file
from rodgains.params import DEFAULT_PARAMS, Params, load_params

from rodctl import paths


def regenerate_command(params_path: str | None, overrides: Sequence[str], header: str | None) -> str:
    """`rodctl gains ...` that regenerates the header: the default parameter file and the committed header
    are left out, other paths shown relative to the checkout."""
    parts = ["rodctl", "gains"]
    if params_path and Path(params_path).resolve() != DEFAULT_PARAMS.resolve():
        parts += ["--params", paths.shown(params_path)]
    for o in overrides:
        parts += ["--set", o]
    if header and Path(header).resolve() != paths.COMMITTED_HEADER.resolve():
        parts += ["--header", paths.shown(header)]
    return " ".join(shlex.quote(x) for x in parts)


def _comparable(text: str) -> list[str]:
    """A generated file's lines without its "Regenerate: rodctl gains ..." line: however the command was spelled
    (--params my_rod.toml from /tmp/rig or /tmp/rig/my_rod.toml from elsewhere, a copy of the default file, two
    --set in either order, a --set of the value the file already has), what the file was made from is the inputs'
    SHA-256 on the line below it, and what it holds is the rest of it."""
    return [ln for ln in text.splitlines() if "Regenerate: " not in ln]


def stale(files: dict[Path, str]) -> list[Path]:
    """Of the generated files ({path: text}), those missing or not holding their text, the regenerate command left
    out (`rodctl gains --check --params /tmp/rig/my_rod.toml` of a header made with --params my_rod.toml in /tmp/rig
    is current, and so is one made with the same values by --set)."""
    return atomic_file.stale(files, _comparable)


def params_copy_text(p: Params, command: str) -> str:
    return (
        "# rod_gains.toml -- DO NOT EDIT: the parameters rod_gains.h was generated from.\n"
        f"# Regenerate: {command}\n"
        f"# Inputs SHA-256: {p.sha256()}\n"
        + p.to_toml()
    )


def generated_files(params_path: str | None, overrides: Sequence[str], header: str | None,
                    progress: Callable[[int, int], None] | None = None) -> tuple[object, dict[Path, str]]:
    """Design, then the files `rodctl gains` would write: (Design, {path: text}). header None: the committed
    one. progress(run, most): each optimizer run of a robust refinement (design.method = robust)."""
    from rodgains.codegen import header_text
    from rodgains.design import design

    p = load_params(params_path, list(overrides))
    d = design(p, progress=progress)
    command = regenerate_command(params_path, overrides, header)
    target = Path(header) if header else paths.COMMITTED_HEADER
    return d, {target: header_text(d, command), target.with_suffix(".toml"): params_copy_text(p, command)}

