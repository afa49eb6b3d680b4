"""First power-on: `rodctl check` proves the wiring, the signs and the loop before the first arm.

    from rodctl.check import run_check
    report = run_check(session, params, label, user)   # each step: PASS, FAIL or SKIP, with the fix

The steps (rodctl.check.steps) never arm balance or swing-up: the motor only moves in short
IDENTIFY pulses, under every safety of that mode (angle and speed limits, heartbeat).
"""

from rodctl.check.results import Report, Result
from rodctl.check.runner import run_check

__all__ = ["Report", "Result", "run_check"]
