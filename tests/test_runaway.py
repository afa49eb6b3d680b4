"""RUNAWAY: a reversed encoder or motor trips within 0.3 s of the first drive, before the angle limit,
for balance and for swing-up (the firmware's own rod_dev path against the faithful plant, sim:// faults);
a rig wired right is never tripped."""

from __future__ import annotations

import math

import pytest

from rodctl.link import protocol as P
from rodctl.sim.device import VirtualDevice

TRIP_WITHIN_S = 0.3


def run(faults: dict, arm: P.ArmMode, theta0_deg: float, seconds: float) -> dict:
    """Arm after 50 ms at rest with heartbeats every 0.1 s; until FAULT or `seconds`."""
    dev = VirtualDevice.from_options(theta0_deg=str(theta0_deg), **faults)
    try:
        for _ in range(50):
            dev.step()
        dev.write(P.encode(P.Arm(arm), 1, 0))
        driving_since = None
        start_deg = None
        for k in range(int(seconds / dev.period)):
            if k % 100 == 0:
                dev.write(P.encode(P.Heartbeat(), 2 + k, 0))
            dev.step()
            dev.read()
            if driving_since is None and dev.lib.rod_dev_enable():
                driving_since = dev.time
                start_deg = math.degrees(dev.plant.state()[0][0])
            if dev.mode == P.Mode.FAULT:
                break
        theta = math.degrees(dev.plant.state()[0][0])
        return {"mode": P.Mode(dev.mode), "reason": P.Reason(dev.reason),
                "after_s": dev.time - driving_since if driving_since is not None else None,
                "moved_deg": abs(theta - start_deg) if start_deg is not None else 0.0, "theta_deg": theta}
    finally:
        dev.close()


CASES = [(P.ArmMode.BALANCE, 175.0), (P.ArmMode.BALANCE, 165.0), (P.ArmMode.SWING_UP, 0.0),
         (P.ArmMode.SWING_UP, 20.0)]


@pytest.mark.parametrize("fault", [{"encoder_sign": "-1"}, {"motor_sign": "-1"}], ids=["encoder", "motor"])
@pytest.mark.parametrize("arm, theta0", CASES, ids=["balance175", "balance165", "swing0", "swing20"])
def test_a_reversed_sign_trips_runaway_fast(fault, arm, theta0):
    r = run(fault, arm, theta0, 2.0)
    assert (r["mode"], r["reason"]) == (P.Mode.FAULT, P.Reason.RUNAWAY), r
    assert r["after_s"] <= TRIP_WITHIN_S, r
    assert r["moved_deg"] < 30.0, r  # half the 60 deg angle limit: caught long before it


@pytest.mark.parametrize("arm, theta0", CASES, ids=["balance175", "balance165", "swing0", "swing20"])
def test_a_rig_wired_right_is_not_tripped(arm, theta0):
    r = run({}, arm, theta0, 6.0 if arm == P.ArmMode.SWING_UP else 3.0)
    assert r["mode"] == P.Mode.BALANCE, r
    assert abs(abs(r["theta_deg"]) - 180.0) < 5.0, r
