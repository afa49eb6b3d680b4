"""rodctl identify's fit: it recovers hidden plants from firmware (SIL) experiments, refuses data that cannot
identify anything, flags non-physical values, and its file designs gains that hold the hidden rig. The live
runs over sim:// are in test_identify_runs.py."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from rodgains.params import load_params

from hidden_rigs import TOLERANCE, TOLERANCE_DEG, fitted, hidden_params, identified, records, sil, truth
from host_tools import run_rodctl
from rodctl.ident import compensation as C
from rodctl.ident import experiments as E
from rodctl.ident import fit as F
from rodctl.ident import report as R
from rodctl.sim.plant import faithful_plant


@pytest.mark.parametrize("name", ["A", "B", "C", "D", "F", "G", "H"])
def test_fit_recovers_a_hidden_rig(name):
    recs = list(records(name))
    assert all(r.ended_in == 0 and r.end_reason == 0 for r in recs), "every experiment plays to its end"
    res = fitted(name)
    true = truth(name)
    for p, tol in TOLERANCE.items():
        err = res.values[p] / true[p] - 1
        if p == "damping" and not res.identifiable[p]:
            continue  # allowed: reported as not identifiable
        assert abs(err) < tol, f"{p}: {res.values[p]:.4g} vs true {true[p]:.4g} ({100 * err:+.1f} %)"
        assert res.identifiable[p], (p, res.why[p])
    for p, tol in TOLERANCE_DEG.items():
        assert abs(res.values[p] - true[p]) < tol, f"{p}: {res.values[p]:.3f} vs true {true[p]:.3f} deg"
        assert res.identifiable[p], (p, res.why[p])
    assert res.validation_fit_pct > 95
    assert not res.out_of_range
    assert F.model_miss_text(res.rms_counts) is None, res.rms_counts  # the model is the rig: no warning


@pytest.mark.parametrize("enc_deg, rod_deg", [(0.3, 0.0), (-0.9, 0.0), (1.5, 0.5), (-2.0, -1.0),
                                              (361.5, 360.5)])  # a turn from the boot zero (after a swing-up)
def test_a_record_starts_with_the_rod_hanging_as_far_as_the_play_lets_it(enc_deg, rod_deg):
    """2 deg of play: the rod hangs straight down while the gap around the motor side reaches it, else
    it rests on the nearer flank; the motor side is where the encoder says."""
    plant = faithful_plant(load_params().with_overrides("gearbox.backlash_deg=2.0"), input_mode="duty")
    plant.start_hanging(math.radians(enc_deg))
    th, dth = plant.state()
    assert np.allclose(np.degrees(th), rod_deg, atol=1e-9) and not dth.any()
    assert math.degrees(plant.motor_state()[0]) == pytest.approx(enc_deg)
    out = faithful_plant(load_params().with_overrides('encoder.location="output"'), input_mode="duty")
    out.start_hanging(math.radians(1.5))
    assert np.allclose(np.degrees(out.state()[0]), 1.5), "an output-shaft encoder reads the rod itself"


def test_the_polish_on_the_files_plant_removes_the_fast_rods_bias():
    """The starts search on the inextensible N = 20 rod; the rig is a DER N = 30 rod. On rig D that
    mismatch alone puts the viscous friction more than 5 % off; the polish on the file's plant recovers it."""
    b = truth("D")["viscous_friction"]
    fast = F.fit(list(records("D")), load_params(), starts=1, polish=False)
    assert fast.model and abs(fast.values["viscous_friction"] / b - 1) > 0.05, fast.values
    res = fitted("D")
    assert res.model == () and "polish" in res.starts[-1]
    fast_err, err = abs(fast.values["viscous_friction"] / b - 1), abs(res.values["viscous_friction"] / b - 1)
    assert err < 0.05 and err < fast_err / 2, (fast_err, err)


def _record(duty, torque, count, name="x"):
    n = len(duty)
    return E.Record(name, 1e-3, np.asarray(count, np.int64), np.asarray(duty, float), np.asarray(torque, float),
                    np.zeros(n))


@pytest.mark.parametrize("rec, why", [
    (_record(np.zeros(3000), np.zeros(3000), np.zeros(3000)), "no excitation: the torque command"),
    (_record(np.full(3000, 0.01), np.full(3000, 0.01), np.zeros(3000)), "no excitation: theta_1 moved only 0"),
    (_record(np.full(500, 0.1), np.full(500, 0.02), np.arange(500) // 10), "too short: 0.50 s"),
    (_record(np.where(np.arange(3000) % 2, 1.0, -1.0), np.full(3000, 0.2), np.arange(3000) // 10),
     "saturated: the duty or torque is at its limit in 100 %"),
])
def test_refuses_data_that_cannot_identify(rec, why):
    with pytest.raises(F.NotIdentifiable, match="not identifiable: " + why):
        F.fit([rec], load_params())


def test_refuses_logs_without_identify_data():
    with pytest.raises(F.NotIdentifiable, match="no IDENTIFY data"):
        F.fit([], load_params())


def test_cli_refuses_a_log_without_excitation(tmp_path):
    from rodctl.link import protocol as P
    from rodctl.logs import LogWriter, simulator_metadata

    p = load_params()
    log = tmp_path / "quiet.csv"
    w = LogWriter(log, simulator_metadata(p), n=p.N)
    for k in range(3000):  # IDENTIFY with zero torque: the rod never moves
        w.write_telemetry(P.Telemetry(int(P.Mode.IDENTIFY), 0, 5, p.N, 0, 0.0, 0.0, 0.0, 10, 0, 0, 0,
                                      (0.0,) * p.N, (0.0,) * p.N), k, k * 1000)
    w.close({})
    r = run_rodctl("identify", str(log), "--out", str(tmp_path / "out.toml"))
    assert r.returncode == 2, r.stderr
    assert r.stderr.strip().splitlines()[-1].startswith("rodctl: not identifiable: no excitation")
    assert not (tmp_path / "out.toml").exists()


def test_an_experiment_that_trips_stops_the_motor_with_its_reason():
    hidden = hidden_params("A")
    strong = E.EXPERIMENTS["steps"].scaled(torque=3.0)
    rec = E.run_sil(strong, sil(), faithful_plant(hidden, input_mode="duty"))
    assert (rec.ended_in, rec.end_reason) == (3, 2)  # FAULT, ANGLE_LIMIT (60 deg from hanging)
    assert rec.seconds < strong.duration


def test_a_value_outside_its_physical_range_is_flagged_not_written():
    recs = list(records("A"))
    res = F.fit(recs, load_params(), starts=1, max_nfev=3, polish=False)
    bad = dataclasses.replace(res, values={**res.values, "rotor_inertia": 5e-5},
                              out_of_range={"rotor_inertia": "5e-05 kg m^2 is outside the physical range"})
    values, notes = R.written_values(bad)
    assert values["rotor_inertia"] == res.nominal["rotor_inertia"]
    assert notes["rotor_inertia"].startswith("NOT WRITTEN")
    text = R.parameter_file(load_params(), bad, [("a.csv", "0" * 64)])
    assert "rotor_inertia = 5e-07" in text and "NOT WRITTEN" in text and "0" * 64 in text


def test_written_file_is_complete_and_loads(tmp_path):
    res = F.fit(list(records("A")), load_params(), starts=1, max_nfev=3, polish=False)
    f = tmp_path / "my_rod.toml"
    f.write_text(R.parameter_file(load_params(), res, [("a.csv", "ab" * 32)]))
    p = load_params(f)
    assert p["motor"]["rotor_inertia"] == pytest.approx(res.values["rotor_inertia"])
    assert "ab" * 32 in f.read_text()
    lines = {ln.split("=")[0].strip(): ln for ln in f.read_text().splitlines() if "=" in ln and not ln.startswith("#")}
    # every value identify set names it as the source, not the default file's (Table I, the tuning)
    assert lines["youngs_modulus"].endswith("# E [Pa]   [rodctl identify]"), lines["youngs_modulus"]
    assert "[T1]" not in lines["youngs_modulus"] and "[E]" not in lines["rotor_inertia"]
    assert lines["backlash_deg"].endswith("[rodctl identify]")
    assert lines["length"].endswith("[T1]")  # a value it did not touch keeps its source


def test_the_design_for_the_identified_rig_passes_on_the_hidden_plant(tmp_path):
    """Issue 10: design from the identified file, judge it on the hidden rig (`rodctl robustness --plant`),
    here on the quick case set (docs/identification.md: the whole matrix on rigs A, B, C)."""
    from rodctl.sim.matrix import CASE_SETS, CASES, IDEAL_GEARBOX, TASKS, run_case

    # judged with an ideal gearbox: what the identified rod and motor change, without the play's hunting
    mine = identified("C", tmp_path).with_overrides(*IDEAL_GEARBOX)
    hidden = hidden_params("C").with_overrides(*IDEAL_GEARBOX)
    for task in TASKS:
        for name in CASE_SETS["quick"]:
            r = run_case(mine, CASES[name], task, plant_params=hidden)
            assert r["passed"], r


def test_a_case_the_default_design_drops_on_a_hidden_rig_holds_with_the_identified_design(tmp_path):
    """Rig C (a stiffer rod, E = 7.2e5 Pa) ten times more damped: the default design, which assumes Table I's
    rod, trips the angle limit; the design for the identified rig holds the rod."""
    from rodctl.sim.matrix import CASES, IDEAL_GEARBOX, SETTLE_DEG, run_case

    hidden = hidden_params("C").with_overrides(*IDEAL_GEARBOX)
    default = run_case(load_params().with_overrides(*IDEAL_GEARBOX), CASES["damping*10"], "balance", plant_params=hidden)
    mine = run_case(identified("C", tmp_path).with_overrides(*IDEAL_GEARBOX), CASES["damping*10"], "balance",
                    plant_params=hidden)
    assert default["fault_reason"] != 0 and not default["passed"], default
    assert mine["passed"] and mine["fault_reason"] == 0 and mine["final_dev_deg"] < SETTLE_DEG, mine


def test_identify_says_how_far_the_identified_rod_is_from_buckling(tmp_path):
    """Rig B's rod above the hub is 0.98 x its clamped buckling length; rig A's 0.91 x, and no matrix case
    takes A past it."""
    from rodctl.ident.fit_logs import buckling_line

    b = buckling_line(identified("B", tmp_path)).splitlines()
    assert b[0].startswith("buckling: the rod above the hub is 0.98") and "it reaches 1 at E -" in b[0]
    assert "past it in the robustness matrix: E-15 1.03" in b[1] and "rho+15" in b[1] and "L+3" in b[1]
    a = buckling_line(identified("A", tmp_path)).splitlines()
    assert len(a) == 1 and a[0].startswith("buckling: the rod above the hub is 0.91")


# with the compensation's other tests it would fit rig A again: .ci/run gives each test file to one worker
def test_rig_a_meets_the_nominal_goals_with_the_chosen_compensation(tmp_path):
    """Rig A (T_c 4 mN m) with an ideal gearbox: the identified file with the nominal 7.4 mN m settles balance
    in 1.64 s (goal 1.5 s). The compensation chosen on the identified rig meets both nominal goals on the
    hidden plant."""
    from rodctl.sim.matrix import BALANCE_SETTLE_GOAL_S, CASES, IDEAL_GEARBOX, SWINGUP_SETTLE_GOAL_S, run_case

    mine = identified("A", tmp_path).with_overrides(*IDEAL_GEARBOX)
    hidden = hidden_params("A").with_overrides(*IDEAL_GEARBOX)
    before = run_case(mine, CASES["nominal"], "balance", plant_params=hidden)
    assert not before["passed"] and before["settle_s"] > BALANCE_SETTLE_GOAL_S, before
    choice = C.choose(mine, cases="nominal", jobs=2, progress=False)
    tc = mine["motor"]["coulomb_friction"]
    assert choice.best.torque_nm == pytest.approx(choice.best.ratio * tc)
    assert choice.best.passed == choice.best.runs == 2
    own = [c for c in choice.candidates if c.nominal]
    assert len(own) == 1 and own[0].torque_nm == pytest.approx(mine["lqr"]["friction_compensation"])
    assert own[0].failed == ("nominal/balance",) and choice.best is not own[0]
    assert choice.params["lqr"]["friction_compensation"] == pytest.approx(choice.best.torque_nm)
    for task, goal in (("balance", BALANCE_SETTLE_GOAL_S), ("swingup", SWINGUP_SETTLE_GOAL_S)):
        r = run_case(choice.params, CASES["nominal"], task, plant_params=hidden)
        assert r["passed"] and r["settle_s"] < goal, r


def test_held_out_data_that_holds_still_is_said_so_not_nan():
    from rodctl.ident.fit import percent_fit, validation_text

    still = np.full(200, 0.3)
    assert math.isnan(percent_fit(still, still + 0.01))
    assert validation_text(percent_fit(still, still)) == "none: the held-out data does not move"
    moving = np.sin(np.linspace(0, 6, 200))
    assert validation_text(percent_fit(moving, 0.99 * moving)) == "99.0 % fit"


def test_the_polish_simulates_the_files_plant_where_the_search_left_off():
    """The polish starts where the search on the fast rod ended: its first residual must be the file's plant's,
    not the fast rod's last one handed back by the residual's cache."""
    p = load_params()
    problem = F.FitProblem(list(records("A")), p, F.NAMES, F.fit_model(p))
    x = problem.start_points()[0]
    fast = problem.residual(x)
    problem.model = ()
    own = problem.residual(x)
    assert problem.evaluations == 2
    assert np.abs(own - fast).max() > 0.1  # quantization noise units: the two plants differ


def test_a_rig_without_play_and_an_exact_zero_is_written_as_measured(tmp_path):
    """Rig G: the file says no play and no zero error (it kept the nominal 1 deg and 0.18 deg, their intervals being
    "+-190 %" and "+-700 %" of values near 0), so the design and the verdict are for the rig measured."""
    p = identified("G", tmp_path)
    assert abs(p["gearbox"]["backlash_deg"]) < TOLERANCE_DEG["backlash"]
    assert abs(p["encoder"]["zero_error_deg"]) < TOLERANCE_DEG["zero_error"]


def test_a_fit_that_leaves_far_more_than_the_encoder_s_rounding_says_the_model_misses_the_rig():
    """A rod 0.17 m long fitted as the file's 0.155 m: 1.28 counts RMS, every value written wrong (b +304 %) and the
    held-out fit still 96 %, without a word. The hidden rigs leave 0.29 to 0.36 (the rounding alone: 0.289)."""
    assert F.model_miss_text(0.29) is None and F.model_miss_text(0.57) is None
    text = F.model_miss_text(1.28)
    assert text.startswith("the fit leaves 1.28 counts RMS, 4.4 x the encoder's rounding alone: the model misses")
    assert "the rod's length, width, thickness and density" in text
