"""The rod's static shapes upright (rodctl.sim.statics): how near upright any controller at the base can hold a
rod curved at rest, and the matrix's curved case labelled by it (docs/control.md, "A rod curved at rest")."""

import math

import numpy as np
import pytest
from rodgains.params import load_params

from rodctl.sim import matrix, statics
from rodctl.sim.plant import faithful_plant

P = load_params()
CURVED = P.with_overrides(f"rod.rest_curvature={matrix.CURVED_REST_CURVATURE}")


def test_a_straight_rod_stands_straight_with_no_torque():
    z = statics.zero_moment_shape(P)
    assert abs(z.hub_deg) < 1e-9 and abs(z.torque_Nm) < 1e-12 and z.largest_deviation_deg < 1e-9
    assert statics.straightest_shape(P) == (0.0, 0.0, 0.0)
    assert matrix.straightest_deg(P) == 0.0


def test_the_matrix_curved_rod_has_no_shape_within_the_band():
    """Its zero-moment shape leans 6.07 deg; tilting the hub 3.2 deg against the bend with 2.1 mN m brings the
    worst edge down to 3.22 deg and no further: the hub and the tip then lean as far, opposite ways."""
    z, s = statics.zero_moment_shape(CURVED), statics.straightest_shape(CURVED)
    assert z.largest_deviation_deg == pytest.approx(6.07, abs=0.02) and abs(z.torque_Nm) < 1e-9
    assert s.largest_deviation_deg == pytest.approx(3.22, abs=0.02) and s.largest_deviation_deg > matrix.ROBUST_BAND_DEG
    assert s.torque_Nm == pytest.approx(2.12e-3, abs=0.02e-3) and s.hub_deg == pytest.approx(-3.22, abs=0.02)
    fam = statics._Family(CURVED)
    for step in (-0.05, 0.05):  # a minimum: either way is worse
        assert fam.shape(s.hub_deg + step).largest_deviation_deg > s.largest_deviation_deg
    mirrored = statics.straightest_shape(P.with_overrides(f"rod.rest_curvature={-matrix.CURVED_REST_CURVATURE}"))
    assert mirrored.hub_deg == pytest.approx(-s.hub_deg, abs=1e-6) and mirrored.torque_Nm == pytest.approx(-s.torque_Nm)


def test_the_zero_moment_shape_is_where_the_plant_rests():
    """Set into the zero-moment shape with the hub held and no torque, the simulated rod stays there."""
    z = statics.zero_moment_shape(CURVED)
    fam = statics._Family(CURVED)
    fam.shape(z.hub_deg)
    pl = faithful_plant(CURVED.with_overrides("rod.damping=0.02"), input_mode="torque", gear=None, J=1e3, coulomb=0.0)
    pl.set_raw_state(np.concatenate([[fam.origin + math.radians(z.hub_deg)], fam.x[:-1]]), np.zeros(pl.n))
    before, _ = pl.state()
    for _ in range(20):
        pl.advance(0.0, 0.01)
    after, _ = pl.state()
    assert np.degrees(np.abs(after - before)).max() < 0.01
    assert np.degrees(np.abs(np.mod(after, 2 * math.pi) - math.pi)).max() == pytest.approx(6.07, abs=0.02)


def test_the_known_failure_says_the_numbers_the_statics_give():
    why = matrix.KNOWN_FAILURES[("curved", "balance")]
    s, z = statics.straightest_shape(CURVED), statics.zero_moment_shape(CURVED)
    assert f"{s.largest_deviation_deg:.2f} deg off" in why and f"({1e3 * s.torque_Nm:.1f} mN m)" in why
    assert f"{z.largest_deviation_deg:.2f} deg" in why


def test_the_matrix_labels_the_curved_case_on_every_rig_by_its_own_rod():
    from hidden_rigs import hidden_params

    assert set(matrix.past_band_cases(P)) == {"curved"}
    assert matrix.past_band_cases(P)["curved"] == pytest.approx(3.22, abs=0.02)
    # a file's own curvature is the plant's in every case but "curved" (which sets 0.82): 0.4 1/m has a shape
    # inside the band, so only that case is labelled
    assert matrix.past_band_cases(P.with_overrides("rod.rest_curvature=0.4")).keys() == {"curved"}
    assert matrix.straightest_deg(P.with_overrides("rod.rest_curvature=0.4")) == pytest.approx(1.57, abs=0.02)
    assert "curved" in matrix.past_band_cases(hidden_params("B"))


def test_the_robustness_table_and_the_verdict_treat_a_bent_rod_apart():
    from rodctl.cli.robustness import table_lines
    from rodctl.ident import verdict as V

    def row(case, task, passed, straightest=0.0):
        return {"case": case, "task": task, "passed": passed, "settle_s": None, "final_dev_deg": 5.9,
                "fault": False, "fault_reason": 0, "caught_at_s": 1.0, "buckling_ratio": 0.9,
                "straightest_deg": straightest}

    rows = [row(c, t, c == "nominal", 3.22 if c == "bent" else 0.0) for c in ("nominal", "bent") for t in matrix.TASKS]
    lines = table_lines(rows)
    assert lines[3].split("|")[0].strip() == "bent ~"
    assert lines[-1].startswith("  ~ no shape within 3 deg of upright") and "(bent 3.22 deg)" in lines[-1]
    v = V.from_rows(rows, P, "matrix")
    assert (v.in_range_runs, v.in_range_passed) == (2, 2) and not v.failed


def test_the_report_gives_the_floor_and_what_the_trim_holds():
    from rodgains.design import design

    from rodctl.sim.linear_check import _curvature_lines

    from rodgains.trim import trim_gains

    d = design(P.with_overrides("rod.rest_curvature=0.4"))
    lines = _curvature_lines(d, trim_gains(d))
    assert lines[1].startswith("  this rod (0.4 1/m, hanging tip +2.4 mm with the hub vertical): zero-moment 2.96 deg; "
                               "straightest 1.57 deg, held by +1.03 mN m")
    assert lines[2].endswith("straightest 3.22 deg, held by +2.12 mN m  (past the 3 deg band: the matrix labels it)")
    assert lines[3].startswith("  the trim holds this rod's straightest shape: +1.02 mN m, starting at -1.62 deg")
    assert len(_curvature_lines(design(P), trim_gains(design(P)))) == 2  # a straight rod: the matrix's curved case
    d = design(P.with_overrides("rod.rest_curvature=0.4", "trim.time_constant=0"))
    assert _curvature_lines(d, trim_gains(d))[3] == ("  the set-point is this rod's straightest shape's hub, -1.62 deg "
                                                     "(the trim is off: it seeks no torque)")


def test_the_hanging_tip_says_the_curvature():
    """rod.rest_curvature is the rod's shape hanging with its hub vertical: the matrix's 0.82 1/m puts the tip 5.0 mm
    to the side, as the simulated rod settles (tests/test_plant_gearbox.py)."""
    assert statics.hanging_tip_offset_m(CURVED) == pytest.approx(matrix.CURVED_TIP_M, abs=5e-5)
    assert statics.hanging_tip_offset_m(P.with_overrides("rod.rest_curvature=-0.4")) == pytest.approx(-2.45e-3, abs=5e-5)


@pytest.mark.parametrize("kappa", [0.82, -0.4])
def test_the_design_finds_the_straightest_shape_the_plant_has(kappa):
    """The trim's aim, from linear statics of the file's rod (gains/rodgains/trim.py), against the faithful plant's
    nonlinear statics: the torque within 0.05 mN m, the hub within 0.15 deg (0.09 measured: the design's first
    edge is a piece of the rod, the plant's a rigid hub)."""
    from rodgains.trim import straightest_shape

    q = P.with_overrides(f"rod.rest_curvature={kappa}")
    aim, plant = straightest_shape(q), statics.straightest_shape(q)
    assert aim.torque == pytest.approx(plant.torque_Nm, abs=0.05e-3)
    assert math.degrees(aim.hub) == pytest.approx(plant.hub_deg, abs=0.15)
    assert straightest_shape(P) == (0.0, 0.0)


def test_the_header_carries_the_trims_aim_and_a_straight_rod_leaves_it_at_zero():
    from rodgains.codegen import header_text
    from rodgains.design import design
    from rodgains.trim import straightest_shape

    def macro(text, name):
        line = next(ln for ln in text.splitlines() if ln.startswith(f"#define {name} "))
        return float(line.split()[2].rstrip("f"))

    straight = header_text(design(P), "test")
    assert macro(straight, "ROD_TRIM_TARGET_NM") == 0.0 and macro(straight, "ROD_TRIM_START_RAD") == 0.0
    aim = straightest_shape(CURVED)
    curved = header_text(design(CURVED), "test")
    assert macro(curved, "ROD_TRIM_TARGET_NM") == pytest.approx(aim.torque, rel=1e-6)
    assert macro(curved, "ROD_TRIM_START_RAD") == pytest.approx(aim.hub, rel=1e-6)
    off = header_text(design(CURVED.with_overrides("trim.time_constant=0")), "test")  # a trim that does not walk
    assert macro(off, "ROD_TRIM_TARGET_NM") == 0.0 and macro(off, "ROD_TRIM_START_RAD") == pytest.approx(aim.hub, rel=1e-6)


def test_a_rod_too_curved_for_the_trims_range_is_refused_naming_the_key():
    from rodgains.design import design
    from rodgains.errors import ParamError
    from rodgains.trim import trim_gains

    with pytest.raises(ParamError, match=r"^rod.rest_curvature: 3 1/m puts the straightest upright shape's hub "
                                         r"-12.1 deg off upright, past trim.limit_deg 5 \(raise it"):
        trim_gains(design(P.with_overrides("rod.rest_curvature=3")))
    assert trim_gains(design(P.with_overrides("rod.rest_curvature=3", "trim.limit_deg=15"))).rate > 0


def test_a_curved_rod_whose_file_says_so_is_held_near_its_straightest_shape():
    """The firmware's own C: released 30 deg off, the matrix's curved rod with the file's straight design rests on
    its zero-moment shape, 5.9 deg off; with a file that gives its curvature, the trim starts at and holds the
    straightest shape's torque: 3.35 deg, against the 3.22 deg no controller at the base can beat. The end states
    only: the simulated time it takes is `rodctl bench --only control`'s (curved_own_design_within_4deg_s)."""
    case = matrix.CASES["curved"]
    straight = matrix.run_case(P, case, "balance")
    own = matrix.run_case(P, matrix.own_design(case), "balance")
    assert straight["final_dev_deg"] > 5.5 and not straight["fault"]
    assert own["straightest_deg"] < own["final_dev_deg"] < 3.6 and not own["fault"]  # where it ends, not when


def test_the_trim_is_off_where_its_band_spans_its_whole_range():
    """A 4 cm rod: a zero error of 5.6 deg makes only the band's 0.5 mN m, so the trim walked to its 5 deg limit on
    the friction's torque and the rod ended 5.9 deg off (0.7 without it). Table I's rod: 0.08 deg."""
    from rodgains.design import design
    from rodgains.trim import trim_gains

    from rodctl.sim.linear_check import report_lines

    short = trim_gains(design(P.with_overrides("rod.length=0.04")))
    assert short.rate == 0.0 and math.degrees(short.band / short.torque_per_offset) == pytest.approx(5.58, abs=0.02)
    assert trim_gains(design(P.with_overrides("rod.length=0.05"))).rate > 0  # 3.5 deg: within its range
    table_i = trim_gains(design(P))
    assert table_i.rate > 0 and math.degrees(table_i.band / table_i.torque_per_offset) == pytest.approx(0.08, abs=0.01)
    line = next(x for x in report_lines(design(P.with_overrides("rod.length=0.04"))) if x.startswith("Set-point trim"))
    assert "off: its 0.5 mN m band is 5.6 deg of zero error on this rod" in line


def test_the_firmware_starts_its_trim_at_the_straightest_hub():
    """The firmware's own C at power-on: the trim is ROD_TRIM_START_RAD (the curved file's straightest hub), 0 for a
    straight rod, read through the SIL's rod_sil_balance."""
    import ctypes

    from rodgains.trim import straightest_shape

    from rodctl.build.sil_build import build_sil

    def trim_at_reset(p):
        lib = ctypes.CDLL(str(build_sil(p)))
        lib.rod_sil_reset()
        trim, hold, w = ctypes.c_float(), ctypes.c_float(), ctypes.c_float()
        lib.rod_sil_balance(ctypes.byref(trim), ctypes.byref(hold), ctypes.byref(w))
        return trim.value

    assert trim_at_reset(CURVED) == pytest.approx(straightest_shape(CURVED).hub, rel=1e-6)
    assert trim_at_reset(P) == 0.0
