"""A non-editable install (wheel, pipx) carries what rodctl needs outside a clone, runs on Python
3.10, and builds nothing into site-packages. The wheel is built from a copy of the sources and
run from a folder outside any clone (its files on PYTHONPATH)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from rodctl import paths

ROOT = paths.REPO
SOURCES = ["gains", "host", "firmware", "setup.py", "pyproject.toml", "MANIFEST.in", "README.md", "platformio.ini"]


def test_every_tomllib_import_falls_back_to_tomli():
    """requires-python >= 3.10, and tomllib is 3.11+."""
    for folder in ("gains", "host", "tests"):
        for f in (ROOT / folder).rglob("*.py"):
            text = f.read_text()
            for m in re.finditer(r"^(\s*)import tomllib\b", text, flags=re.M):
                after = text[m.end():m.end() + 200]
                assert re.search(r"except (ModuleNotFoundError|ImportError):\s*#?[^\n]*\n\s*import tomli as tomllib",
                                 after), f"{f.relative_to(ROOT)}: `import tomllib` without the tomli fallback"
            assert not re.search(r"^from tomllib import", text, flags=re.M), f.name


# standard-library names that appeared after Python 3.10
NEWER_THAN_310 = re.compile(r"\b(StrEnum|ExceptionGroup|TaskGroup|file_digest|itertools\.batched)\b|"
                            r"\bdatetime\.UTC\b|from datetime import [^\n]*\bUTC\b|from typing import [^\n]*\bSelf\b")


def test_sources_are_python_310():
    import ast

    for folder in ("gains", "host"):
        for f in (ROOT / folder).rglob("*.py"):
            text = f.read_text()
            ast.parse(text, filename=str(f), feature_version=(3, 10))  # 3.10 grammar (no except*, ...)
            m = NEWER_THAN_310.search(text)
            assert m is None, f"{f.relative_to(ROOT)} uses {m.group(0)!r}, newer than Python 3.10"


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    pytest.importorskip("setuptools")
    src = tmp_path_factory.mktemp("src")
    # not "build": that name is also the package rodctl.build, which the wheel must carry
    ignore = shutil.ignore_patterns("__pycache__", "*.egg-info", "*.so", "*.o", ".pio")
    for name in SOURCES:
        p = ROOT / name
        if p.is_dir():
            shutil.copytree(p, src / name, ignore=ignore)
        else:
            shutil.copy2(p, src / name)
    out = tmp_path_factory.mktemp("wheel")
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "-w",
                        str(out), str(src)], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    (whl,) = out.glob("rodctl-*.whl")
    return whl


def test_wheel_carries_spec_sources_and_defaults_but_not_the_board(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    for must in ["rodctl/_firmware/protocol/rodlink.toml", "rodctl/_firmware/src/core/rod_control.c",
                 "rodctl/_firmware/src/core/rod_config.h", "rodctl/_firmware/src/core/rod_protocol_defs.h",
                 "rodctl/_firmware/sil/rod_sil.c", "rodctl/_firmware/include/rod_gains.toml",
                 "rodctl/sim/native/rod_plant.c", "rodctl/build/sil_build.py", "rodctl/build/platformio.py",
                 "rodgains/default.toml"]:
        assert must in names, must
    assert not any("board/teensy35" in n or n.endswith("platformio.ini") for n in names)


@pytest.fixture(scope="module")
def installed(wheel, tmp_path_factory):
    """The wheel's files as site-packages would hold them, and an environment that uses them."""
    site = tmp_path_factory.mktemp("site")
    zipfile.ZipFile(wheel).extractall(site)
    home = tmp_path_factory.mktemp("outside")
    env = dict(os.environ, PYTHONPATH=str(site), XDG_CACHE_HOME=str(home / "cache"), MPLBACKEND="Agg")
    for clone_only in ("RODCTL_BUILD_DIR", "RODCTL_DEBUG", "RODGAINS_CACHE_DIR"):  # nothing of the clone's
        env.pop(clone_only, None)
    return site, home, env


def _run(installed, *args, timeout=300):
    site, home, env = installed
    return subprocess.run([sys.executable, "-m", "rodctl.cli", *args], cwd=home, env=env, capture_output=True,
                          text=True, timeout=timeout)


def test_installed_package_knows_it_is_not_a_clone(installed):
    site, home, env = installed
    r = subprocess.run([sys.executable, "-c", "from rodctl import paths; print(paths.IN_CLONE, paths.SPEC, paths.BUILD)"],
                       cwd=home, env=env, capture_output=True, text=True)
    in_clone, spec, build = r.stdout.split()
    assert in_clone == "False"
    assert Path(spec) == site / "rodctl" / "_firmware" / "protocol" / "rodlink.toml"
    assert Path(build) == home / "cache" / "rodctl" / "build"  # a user cache, not site-packages


def test_installed_gains_json_works_outside_a_clone(installed):
    site, home, env = installed
    r = _run(installed, "gains", "--json", str(home / "d.json"))
    assert r.returncode == 0, r.stderr
    import json

    from rodgains import design
    from rodgains.params import load_params

    d, here = json.loads((home / "d.json").read_text()), design(load_params())
    assert (d["N"], d["params_sha256"]) == (here.N, load_params().sha256())  # the packaged default file
    assert d["closed_loop_spectral_radius"] == pytest.approx(here.checks["closed_loop_spectral_radius"], abs=1e-9)


def test_installed_sim_builds_its_library_in_the_user_cache(installed):
    site, home, env = installed
    r = _run(installed, "sim", "--duration", "0.3", "--no-plot", "--no-log")
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr
    assert "simulated 0.3 s" in r.stdout + r.stderr
    assert list((home / "cache" / "rodctl" / "build").rglob("librodsil-*.so"))
    assert not list(site.rglob("*.so"))


@pytest.mark.parametrize("command", [["build"], ["flash"], ["protocol"], ["gains"]])
def test_installed_firmware_commands_say_they_need_a_clone(installed, command):
    r = _run(installed, *command)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "needs a clone of this repository" in lines[0], r.stderr
