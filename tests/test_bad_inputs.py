"""Inputs a user can get wrong end in one line naming the problem, never "internal error"."""

from __future__ import annotations

import pytest

from host_tools import rodctl_env, run_rodctl


def _one_line(r) -> str:
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    return lines[0]


def test_binary_params_file_is_named(tmp_path):
    f = tmp_path / "rod.toml"
    f.write_bytes(b"\x00\xff\xfe\x89PNG\r\n")
    r = run_rodctl("gains", "--params", str(f), "--header", str(tmp_path / "h" / "rod_gains.h"))
    assert r.returncode == 2
    assert _one_line(r) == f"rodctl: {f}: not a parameter file (not UTF-8 text; expected TOML)"
    assert not (tmp_path / "h").exists()


def test_gains_json_into_a_missing_folder_writes_nothing(tmp_path):
    header = tmp_path / "rod_gains.h"
    r = run_rodctl("gains", "--json", "/nonexistent/d.json", "--header", str(header))
    assert r.returncode == 2
    assert _one_line(r) == "rodctl: --json /nonexistent/d.json: folder /nonexistent does not exist"
    assert not header.exists()  # checked before anything was designed or written


def test_gains_json_onto_a_folder(tmp_path):
    r = run_rodctl("gains", "--json", str(tmp_path))
    assert r.returncode == 2
    assert _one_line(r) == f"rodctl: --json {tmp_path}: is a folder"


@pytest.mark.parametrize("value", ["1e42", "1e-40", "nan", "inf", "-3"])
def test_set_out_of_range_before_opening_the_port(value):
    """Checked before the port is opened: no board is needed to be told."""
    r = run_rodctl("set", f"catch_angle_deg={value}", "--port", "/dev/ttyNOPE0")
    assert r.returncode == 2
    line = _one_line(r)
    assert line.startswith("rodctl: catch_angle_deg")
    assert "2 <= catch_angle_deg" in line or "not a finite number" in line


def test_missing_params_file_of_a_sim_url_is_named():
    r = run_rodctl("status", "--port", "sim://?params=missing.toml")
    assert r.returncode == 2
    assert _one_line(r) == "rodctl: sim://: missing.toml: cannot read parameter file (No such file or directory)"


@pytest.mark.parametrize("url, says", [
    ("sim://?bogus=1", "unknown sim:// option 'bogus'"),
    ("sim://x", "sim:// takes options only after '?'"),
    ("sim://?edges=abc", "edges must be an integer, got 'abc'"),
    ("sim://?plant=foo", "unknown plant 'foo'"),
    ("sim://?plant=missing.toml", "missing.toml: cannot read parameter file"),
    ("sim://?set=rod.nope=1", "--set rod.nope: unknown key"),
])
def test_a_bad_sim_url_is_bad_input_not_a_board_fault(url, says):
    """The virtual board's URL is the user's own input: exit 2, as for a bad --params (a board that is not
    plugged in is exit 1)."""
    r = run_rodctl("status", "--port", url)
    assert r.returncode == 2, r.stderr
    line = _one_line(r)
    assert line.startswith("rodctl: ") and says in line


@pytest.mark.parametrize("argv", [["log", "--duration", "0", "--port", "/dev/ttyNOPE0", "--out"],
                                  ["arm", "--balance", "--duration", "nan", "--port", "/dev/ttyNOPE0", "--out"],
                                  ["sim-device", "--pty", "--duration", "-1", "--link"]])
def test_a_non_positive_duration_is_refused_before_the_board_or_the_file(argv, tmp_path):
    out = tmp_path / "run.csv"  # the log, or the sim-device's link
    r = run_rodctl(*argv, str(out))
    assert r.returncode == 2, r.stderr
    assert _one_line(r).endswith(": must be > 0 s") and not out.exists()


@pytest.mark.parametrize("argv, what, folder", [
    (["sim", "--duration", "0.2", "--no-log", "--plot", "{blocked}/x.png"], "--plot", "{blocked}"),
    (["sim", "--duration", "0.2", "--no-plot", "--log", "{blocked}/x.csv"], "--log", "{blocked}"),
    (["gains", "--header", "{blocked}/rod_gains.h"], "--header", "{blocked}"),
    (["identify", "--port", "sim://", "--yes", "--experiment", "release", "--log-dir", "{blocked}/logs",
      "--out", "{tmp}/o.toml"], "--log-dir", "{blocked}/logs"),
])
def test_an_output_folder_with_a_file_in_the_way_is_one_line_before_any_work(argv, what, folder, tmp_path):
    """These outputs make their folder; a file where the folder should be is bad input (exit 2), said
    before the simulation, the design or the experiment (not an internal error after it)."""
    blocked = tmp_path / "a_file"
    blocked.write_text("not a folder\n")
    r = run_rodctl(*(a.format(blocked=blocked, tmp=tmp_path) for a in argv), timeout=120)
    assert r.returncode == 2, r.stderr
    line = _one_line(r)
    assert line.startswith(f"rodctl: {what} {blocked}/")
    assert line.endswith(f": cannot make folder {folder.format(blocked=blocked)}: a file is in the way")
    assert "simulated" not in r.stdout and "release:" not in r.stderr  # nothing ran
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]


def test_sim_compile_failure_is_one_clear_line(tmp_path):
    """The compiler's first `error:` line, not the "In file included from" chain before it."""
    cc = tmp_path / "cc"
    cc.write_text("#!/bin/sh\necho 'In file included from rod_control.c:1:' >&2\n"
                  "echo 'rod_config.h:97:1: error: static assertion failed' >&2\nexit 1\n")
    cc.chmod(0o755)
    env = rodctl_env(CC=str(cc), RODCTL_BUILD_DIR=str(tmp_path / "build"))
    r = run_rodctl("sim", "--duration", "0.2", "--no-plot", "--no-log", env=env)
    assert r.returncode != 0
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr
    assert r.stderr.strip().splitlines()[-1] == ("rodctl: compiling rodsil failed: "
                                                 "rod_config.h:97:1: error: static assertion failed")


@pytest.mark.parametrize("override, line", [
    ("rod.length=155", "rodctl: rod.length = 155 m is not a testbed's (plausible: 0.02 to 2 m): did you mean 0.155 m?"),
    ("rod.youngs_modulus=593",
     "rodctl: rod.youngs_modulus = 593 Pa is not a testbed's (plausible: 1000 to 2e+11 Pa): did you mean 593000 Pa?"),
])
def test_a_unit_slip_is_refused_with_the_reading_that_fits(override, line, tmp_path):
    from host_tools import run_rodctl

    r = run_rodctl("gains", "--set", override, "--header", str(tmp_path / "h.h"))
    assert r.returncode == 2 and r.stderr.strip() == line
    assert not (tmp_path / "h.h").exists()
