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
    assert held["past_band"] == 0 and 1.0 < held["median_mean_deg"] < 3.0, held  # the lean on a flank
    assert bare["past_band"] >= 1, bare  # the rod crosses the gap and swings out


@pytest.mark.parametrize("argv, says", [(["--frictions", "x"], "--frictions must be multiples >= 0"),
                                        (["--seconds", "5"], "--seconds more than 10"),
                                        (["--set", "lqr.nope=1"], "--set lqr.nope: unknown key")])
def test_bad_input_is_one_line_and_exit_2(argv, says):
    r = subprocess.run([sys.executable, "-m", "rodctl.sim.friction_study", *argv], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 2 and r.stdout == ""
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and says in lines[0], r.stderr
