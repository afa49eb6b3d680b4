"""Every run-time setting has a physical range, defined once (rodlink.toml codes.param min / max /
design_max) and read by the firmware (generated ROD_PARAM_*_MIN / _MAX), the host (`rodctl set`)
and the parameter checks."""

from __future__ import annotations

import math
import re
import struct

import pytest

from rodctl import paths
from rodctl.link import protocol as P
from rodctl.link.protocol_spec import SpecError, load_spec
from rodctl.link.session import SETTINGS


def f32(x: float) -> float:
    return struct.unpack("<f", struct.pack("<f", x))[0]


def test_every_setting_has_a_range():
    for c in P.SPEC.codes["param"].values:
        assert c.min is not None and (c.max is not None or c.design_max), c.name
        if c.name in ("ENCODER_SIGN", "MOTOR_SIGN"):  # +1 or -1 and nothing between (the firmware refuses 0)
            assert (c.min, c.max, c.integer) == (-1, 1, True), c.name
            continue
        assert c.min > 0 or c.name == "TELEMETRY_DECIMATION" and c.min >= 1, c.name  # nothing down to denormals


def test_catch_angle_is_at_least_2_deg():
    c = P.SPEC.codes["param"].by_name("CATCH_ANGLE")
    assert math.degrees(c.min) == pytest.approx(2.0)
    assert SETTINGS["catch_angle_deg"].min == pytest.approx(2.0)


def test_generated_c_bounds_are_the_spec_values():
    h = (paths.CORE_SRC / "rod_protocol_defs.h").read_text()
    for c in P.SPEC.codes["param"].values:
        lo = re.search(rf"#define ROD_PARAM_{c.name}_MIN\s+(\S+)f\b", h).group(1)
        assert f32(float(lo)) == f32(c.min), c.name
        hi = re.search(rf"#define ROD_PARAM_{c.name}_MAX\s+(.+?)\s+/\*", h).group(1)
        if c.max is not None:
            assert f"{float(re.search(r'[0-9.e+-]+', hi).group(0)):.6g}" == f"{f32(c.max):.6g}", c.name
        if c.design_max:
            assert c.design_max in hi, c.name


def test_host_ranges_are_the_spec_values_in_user_units():
    for s in SETTINGS.values():
        c = P.PARAM_INFO[s.param]
        assert s.min == pytest.approx(c.min / s.scale)
        assert (s.max is None) == (c.max is None)
        if s.max is not None:
            assert s.max == pytest.approx(c.max / s.scale)


@pytest.mark.parametrize("entry, problem", [
    ('min = 2.0, max = 1.0', "min < max"),
    ('min = 1.0', "min and max"),
    ('max = 1.0', "min and max"),
    ('min = "a", max = 1.0', "finite number"),
    ('min = 0.1, design_max = "lower case"', "rod_gains.h macro"),
])
def test_malformed_ranges_are_refused(tmp_path, entry, problem):
    text = (paths.SPEC).read_text()
    new = re.sub(r'(\{ name = "SWING_ANGLE", value = 2, unit = "rad", )min = [^,]+, max = [^,]+, ', rf"\g<1>{entry}, ",
                 text)
    assert new != text
    bad = tmp_path / "rodlink.toml"
    bad.write_text(new)
    with pytest.raises(SpecError, match=re.escape(problem)):
        load_spec(bad)
