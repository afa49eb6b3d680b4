"""The control step fits the Teensy's budget: instruction counts on a Cortex-M4F (QEMU)."""

import pytest

from rodctl.bench import m4 as bench_m4

# The counter script belongs to the workplace, not this repository; QEMU and the cross compiler are
# installed by .ci/run, so their absence is a failure, not a skip.
pytestmark = pytest.mark.skipif(not bench_m4.ICOUNT.is_file(), reason="m4-icount.sh is not on this machine")


def test_step_plus_telemetry_encode_meets_the_instruction_goals():
    from rodctl.bench.suite import GOALS

    result = bench_m4.measure()
    for key in bench_m4.M4_GOAL_KEYS:
        assert 0 < result[key] <= GOALS[key][0], (key, result[key])
    assert result["m4_step_instructions_n20"] > result["m4_step_instructions_n5"]
    assert result["m4_core_flash_bytes"] > 0 and result["m4_core_ram_bytes"] > 0
