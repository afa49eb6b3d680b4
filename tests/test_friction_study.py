"""python -m rodctl.sim.friction_study: the friction compensation's window (docs/control.md). The default
design holds the nominal rig on its file's friction and hunts across the play on a rig without any."""

from __future__ import annotations

import subprocess
import sys

import pytest


def test_the_default_holds_its_files_friction_and_hunts_without_friction(monkeypatch):
    from rodctl.sim import friction_study as F

    monkeypatch.setattr(F, "ZERO_ERRORS_DEG", (0.18,))  # the file's own rig: half a count off, 1 deg of play
    monkeypatch.setattr(F, "BACKLASH_DEG", (1.0,))
    table = F.window(frictions=(1.0, 0.0), seconds=20.0, jobs=2)
    held, bare = table[1.0], table[0.0]
    assert held["runs"] == bare["runs"] == 2
    # measured: peaks 2.49 / 2.02 deg (balance / swing-up) on its friction, 12.4 / 12.4 without any
    assert held["max_peak_deg"] < 3.0 and 1.0 < held["median_mean_deg"] < 3.0, held  # the lean on a flank
    assert bare["max_peak_deg"] > 6.0, bare  # the rod crosses the gap and swings out


@pytest.mark.parametrize("argv, says", [
    (["--frictions", "x"], "friction_study: --frictions x: distinct finite multiples >= 0"),
    (["--frictions", "nan"], "friction_study: --frictions nan: distinct finite multiples >= 0"),
    (["--frictions", "1,1"], "friction_study: --frictions 1,1: distinct"),
    (["--frictions", "1e9"], "friction_study: motor.coulomb_friction = 5e+06 N m is not a testbed's"),
    (["--seconds", "5"], "friction_study: --seconds 5: more than 10"),
    (["--seconds", "abc"], "argument --seconds: invalid float value: 'abc'"),
    (["--set", "lqr.nope=1"], "friction_study: --set lqr.nope: unknown key")])
def test_bad_input_is_one_line_and_exit_2(argv, says):
    r = subprocess.run([sys.executable, "-m", "rodctl.sim.friction_study", *argv], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 2 and r.stdout == ""
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and says in lines[0], r.stderr
