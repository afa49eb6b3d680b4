"""lqr.r_torque_rate: the LQR that weighs the torque's change per period, designed in Python and run by the
firmware's own estimator step (u = -K z - w - Ku (u_prev + w))."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
from firmware_sil import MODE, RAD_PER_COUNT, Sil

from rodgains.design import design

# the trim and the friction compensation off: the command is then the estimator's alone
PLAIN = ("lqr.friction_compensation=0", "trim.time_constant=0")
WEIGHT = "lqr.r_torque_rate=1e-5"  # the closed-loop buzz 14.2 mN m RMS against 19.1 (docs/control.md)
COUNTS = [489, 489, 490, 490, 491, 490, 489, 488, 488, 489, 490, 490, 490, 489, 489, 488, 487, 488, 489, 490] * 3


def _python_torques(d, z0: np.ndarray, counts: list[int]) -> list[float]:
    """The design's estimator and feedback (Design.estimator()) from the catch's estimate z0 on."""
    Ao, Bo, Co, Ko, Lo = d.estimator()
    x = np.zeros(Ao.shape[0])
    x[: z0.size] = z0
    u = float(-(Ko @ x)[0])
    out = [u]
    for c in counts:
        xp = Ao @ x + Bo[:, 0] * u
        y = c * RAD_PER_COUNT - math.pi
        x = xp + Lo[:, 0] * (y - (Co @ xp)[0])
        u = float(-(Ko @ x)[0])
        out.append(u)
    return out


@pytest.mark.parametrize("weight", [(), (WEIGHT,)], ids=["no weight", "torque-rate weight"])
def test_the_firmware_runs_the_torque_rate_law_the_design_made(weight):
    sil = Sil(PLAIN + weight)
    d = design(sil.p)
    assert (d.Ku != 0.0) == bool(weight)
    u_catch = sil.catch_at(489)
    _, theta, rate = sil.status()
    z0 = np.array([t - math.pi for t in theta] + rate)
    want = _python_torques(d, z0, COUNTS)
    got = [u_catch] + [sil.step(c) for c in COUNTS]
    assert sil.mode == MODE["BALANCE"]
    assert max(abs(w) for w in want) > 0.02  # torques the law shapes, well inside the 0.2 N m clamp
    assert np.allclose(got, want, rtol=0, atol=2e-5)  # float32 against float64: 0.02 mN m


def test_the_weight_is_refused_where_it_is_not_built(tmp_path):
    out = subprocess.run([sys.executable, "-m", "rodctl.cli", "gains", "--header", str(tmp_path / "g.h"), "--set", WEIGHT,
                          "--set", "sensors.tip_imu=true"], capture_output=True, text=True)
    assert out.returncode == 2
    assert out.stderr.count("\n") == 1 and "lqr.r_torque_rate" in out.stderr
    assert not (tmp_path / "g.h").exists()
