"""The layering docs/architecture.md promises: the packages the commands call never reach back into the
CLI, and building the command line loads nothing a display, a video or a cluster would need."""

from __future__ import annotations

import ast
import subprocess
import sys

from rodctl import paths

HOST = paths.PACKAGE
# the only modules outside cli/ that may import it, and why
CLI_IMPORT_ALLOWED = {
    "docsgen/cli_ref.py": "it writes docs/reference/cli.md from the command parsers",
    "sim/friction_study.py": "its `python -m` entry point refuses bad options in one line, as rodctl does",
}


def _imports(path) -> set[str]:
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
    return out


def test_the_packages_the_commands_call_never_import_the_cli():
    offenders = []
    for f in sorted(HOST.rglob("*.py")):
        rel = f.relative_to(HOST).as_posix()
        if rel.startswith("cli/") or rel in CLI_IMPORT_ALLOWED:
            continue
        if any(m == "rodctl.cli" or m.startswith("rodctl.cli.") for m in _imports(f)):
            offenders.append(rel)
    assert offenders == [], f"import rodctl.cli from a domain package: {offenders}"
    for rel in CLI_IMPORT_ALLOWED:  # the exceptions are real, not stale
        assert any(m.startswith("rodctl.cli") for m in _imports(HOST / rel)), rel


def test_building_the_command_line_loads_no_plotting_video_gui_or_cluster_library():
    """`rodctl --help` (and every command before it needs them) starts without a display, OpenCV,
    Optuna or Dask installed and working."""
    heavy = ("matplotlib", "tkinter", "cv2", "optuna", "dask", "distributed", "pyarrow", "polars", "mcap")
    code = ("import sys; from rodctl.cli import build_parser; build_parser().format_help(); "
            f"print(','.join(m for m in {heavy!r} if m in sys.modules))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip() == ""
