"""Every compile-time check in firmware/src/core/rod_config.h has a parameter check before it: a
parameter set the firmware cannot compile is refused by `rodctl gains` (one line, exit 2), never
written as a header that stops the firmware build later."""

from __future__ import annotations

import re
import subprocess

import pytest

from host_tools import host_cxx, run_rodctl
from rodgains.errors import ParamError
from rodgains.params import load_params
from rodgains.codegen import header_text
from rodgains.design import design

from rodctl import paths

# message in rod_config.h -> overrides that break it (each must be refused by load_params)
VIOLATIONS = {
    "ROD_N must be 1..64": [["rod.edges=65"]],
    "counts per revolution must be a fraction NUM / DEN of at least 16": [
        ["encoder.counts_per_motor_rev=1", "motor.gear_ratio=1"], ["encoder.counts_per_motor_rev=1", "motor.gear_ratio=15"],
        ["encoder.counts_per_motor_rev=3", "motor.gear_ratio=5.3"]],
    "counts per revolution fraction too large": [["motor.gear_ratio=20.437"]],
    "ROD_LOOP_PERIOD_US outside": [["loop.rate_hz=20000"], ["loop.rate_hz=5"]],
    "ROD_PWM_FREQUENCY_HZ outside": [["driver.pwm_frequency_hz=500"]],
    "torque ceiling must be positive": [["safety.torque_limit=0"], ["driver.current_limit=0"]],
    "duty ceiling must be in (0, 1]": [["driver.max_duty=1.5"], ["driver.max_duty=0"]],
    "motor model needs positive kt, R and supply voltage": [["motor.torque_constant=0"], ["motor.resistance=0"],
                                                            ["driver.supply_voltage=0"]],
    "back-EMF constant must not be negative": [["motor.back_emf_constant=-0.01"]],
    "angle limit must be in (0, pi]": [["safety.angle_limit_deg=200"], ["safety.angle_limit_deg=0"]],
    "speed limit must be positive": [["safety.speed_limit=0"]],
    "control period must be positive": [["loop.rate_hz=0"]],
    "default swing amplitude outside the SET range": [["driver.current_limit=0.3"], ["swing_up.amplitude=0.0005"],
                                                       ["swing_up.amplitude=0.25"]],
    "default swing angle outside the SET range": [["swing_up.angle_deg=1"], ["swing_up.angle_deg=190"]],
    "default catch angle outside the SET range": [["swing_up.catch_angle_deg=1"], ["swing_up.catch_angle_deg=1e-40"],
                                                   ["swing_up.catch_angle_deg=95"],
                                                   ["swing_up.catch_angle_deg=40", "safety.angle_limit_deg=30"]],
    "default heartbeat timeout outside the SET range": [["safety.heartbeat_timeout=20"],
                                                         ["safety.heartbeat_timeout=0.01"]],
}
# checks no parameter file can reach: the generator's own layout and the firmware's own constants
NOT_FROM_PARAMETERS = ("ROD_GAINS_SCHEMA_VERSION", "lacks a macro", "ROD_NX must be", "ring sizes", "ROD_NY must be",
                       "designed with the tip IMU but lacks")


def _config_messages() -> list[str]:
    text = (paths.CORE_SRC / "rod_config.h").read_text()
    msgs = re.findall(r'#error\s+"([^"]+)"', text)
    msgs += re.findall(r'(?:static_assert|ROD_STATIC_ASSERT)\((?:[^;]*?),\s*"([^"]+)"\)', text, flags=re.S)
    return [m for m in msgs if "msg" not in m]


def test_every_compile_time_check_has_a_parameter_check():
    msgs = _config_messages()
    assert len(msgs) >= 20
    for m in msgs:
        if any(k in m for k in NOT_FROM_PARAMETERS):
            continue
        assert any(m.startswith(k) for k in VIOLATIONS), f"rod_config.h checks {m!r}: add a params check and a row here"


@pytest.mark.parametrize("overrides", [o for group in VIOLATIONS.values() for o in group],
                         ids=lambda o: " ".join(o))
def test_parameters_the_firmware_cannot_compile_are_refused(overrides):
    with pytest.raises(ParamError):
        load_params(None, overrides)


def test_gains_with_a_low_current_limit_is_one_line_exit_2_and_writes_nothing(tmp_path):
    """The issue's case: the swing amplitude above the effective torque ceiling, not safety.torque_limit."""
    header = tmp_path / "rod_gains.h"
    r = run_rodctl("gains", "--set", "driver.current_limit=0.3", "--header", str(header))
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [
        "rodctl: swing_up.amplitude: must be in [0.001, 0.03574] N m, the firmware's torque ceiling "
        "(set by driver.current_limit 0.3 A x the motor's torque at the output, motor.gear_ratio 20.4 x "
        "torque_constant 0.01123 x gearbox_efficiency 0.52), got 0.05 (with --set driver.current_limit=0.3)"]
    assert not header.exists()


def test_values_on_the_bounds_compile(tmp_path):
    """The Python bounds and the generated f32 ones agree at the edges: these must pass both."""
    p = load_params(None, ["swing_up.catch_angle_deg=2", "swing_up.angle_deg=2", "safety.heartbeat_timeout=10"])
    torque_max = p.torque_max
    p = p.with_overrides(f"swing_up.amplitude={torque_max!r}")
    (tmp_path / "rod_gains.h").write_text(header_text(design(p), "test"))
    src = tmp_path / "uses_config.cpp"
    src.write_text('#include "rod_config.h"\nint rod_config_probe;\n')
    r = subprocess.run([host_cxx(), "-std=gnu++14", f"-I{tmp_path}", f"-I{paths.CORE_SRC}", "-c", str(src), "-o",
                        str(tmp_path / "u.o")], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
