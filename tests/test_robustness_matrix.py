"""The firmware judged on the faithful plant, every case of the robustness matrix, both tasks (issues 8, 31).

The whole matrix runs once per session (module fixture, ~60 s CPU). The pass rules are
rodctl.sim.matrix.criterion(task) (nominal: the stricter goals). With the gearbox's play the rod rests
on one flank of the gap 2 to 2.8 deg off upright (docs/control.md), near the 3 deg band: the in-range
runs are held to a pass share, the known failures are listed with their reasons, and no run may fault.
"""

import pytest

from rodgains.buckling import greenhill_length
from rodgains.params import load_params
from rodctl.sim import matrix

KNOWN_FAILURES = matrix.KNOWN_FAILURES
RUNS = [(c.name, t) for t in matrix.TASKS for c in matrix.cases_for(t)]
IDEAL = load_params().with_overrides(*matrix.IDEAL_GEARBOX)


@pytest.fixture(scope="module")
def results():
    p = load_params()
    return {(r["case"], r["task"]): r for r in matrix.run_matrix(p)}


def test_no_run_of_the_matrix_faults(results):
    faulted = {k: r["fault_reason"] for k, r in results.items() if r["fault_reason"]}
    assert not faulted


def test_the_in_range_runs_pass_as_often_as_measured(results):
    in_range = [k for k in RUNS if k not in KNOWN_FAILURES]
    passed = [k for k in in_range if results[k]["passed"]]
    assert len(passed) >= matrix.MIN_PASS_SHARE * len(in_range), sorted(set(in_range) - set(passed))


def test_every_known_failure_is_a_listed_case_with_its_reason():
    assert set(KNOWN_FAILURES) <= set(RUNS)
    assert all(len(why) > 20 for why in KNOWN_FAILURES.values())


def test_the_nominal_rig_with_play_holds_the_rod_within_the_matrix_band(results):
    """Issue 31's nominal rig (1 deg of play, the boot zero half a count off): caught at once and held
    within the 3 deg band, not within the 1 deg goal (docs/control.md "What the matrix shows")."""
    b, s = results[("nominal", "balance")], results[("nominal", "swingup")]
    assert b["final_dev_deg"] < 3.5 and s["final_dev_deg"] < 3.5, (b, s)
    assert s["caught_at_s"] <= matrix.SWINGUP_CATCH_GOAL_S and s["base_turns_max"] <= matrix.SWINGUP_TURNS_GOAL


def test_on_a_rig_with_play_the_balanced_rod_stays_on_its_flank_instead_of_hunting():
    """The set-point trim reads the whole torque, friction compensation included: the rod rests on one
    flank. Reading the torque net of the compensation, it crossed the gap every 5 to 15 s with the tip
    swinging out 12 to 13 deg (docs/control.md "Finding upright")."""
    r = matrix.run_case(load_params(), matrix.CASES["nominal"], "balance", seconds=40.0, keep_log=True)
    log = r["log"]
    late = log["time"] >= 10.0
    dev = matrix._deviation_deg(log["theta"][late]).max(axis=1)
    assert dev.max() <= 3.0 and dev.mean() <= 2.8, (dev.max(), dev.mean())


NO_DRY_FRICTION = ("motor.coulomb_friction=0.0", "lqr.friction_compensation=0.0")


@pytest.mark.parametrize("coulomb_mNm, band_mNm", [(5.0, 0.5), (2.5, 0.5), (1.75, 1.25), (1.0, 1.5), (0.0, 1.5)])
def test_the_trims_band_takes_what_the_motors_dry_friction_does_not_hold(coulomb_mNm, band_mNm):
    """trim.flank_hold (3 mN m) less the rig's dry friction, within trim.band and trim.band_max: the steady torque
    the firmware's trim leaves alone (rod_gains.h's ROD_TRIM_BAND_NM)."""
    from rodgains.design import design
    from rodgains.trim import trim_gains

    p = load_params().with_overrides(f"motor.coulomb_friction={coulomb_mNm * 1e-3!r}")
    assert trim_gains(design(p)).band == pytest.approx(band_mNm * 1e-3)


def test_on_a_rig_without_dry_friction_its_own_band_stops_the_hunt_across_the_gap():
    """Nothing but the trim's band keeps the rod's foot on one flank when the motor has no dry friction. The
    rig's own design (band 1.5 mN m) holds the swing-up within 3 deg where the 0.5 mN m band of a rig with
    friction lets the rod cross the gap, the tip swinging out 6 to 9 deg (whole matrix: 61 and 22 of 78 runs;
    docs/control.md "The band follows the rig's dry friction")."""
    rig = load_params().with_overrides(*NO_DRY_FRICTION)
    cases = [matrix.CASES[n] for n in ("J+30", "J-30", "gear20", "der40")]
    passed = {bm: sum(matrix.run_case(rig.with_overrides(f"trim.band_max={bm!r}"), c, "swingup")["passed"] for c in cases)
              for bm in (0.0015, 0.0005)}
    assert passed[0.0015] == len(cases) and passed[0.0005] == 0, passed


def test_with_an_ideal_gearbox_the_nominal_meets_the_goals_of_issue_8():
    b = matrix.run_case(IDEAL, matrix.CASES["nominal"], "balance")
    s = matrix.run_case(IDEAL, matrix.CASES["nominal"], "swingup")
    assert b["settle_s"] <= matrix.BALANCE_SETTLE_GOAL_S and b["fault_reason"] == 0
    assert s["caught_at_s"] <= matrix.SWINGUP_CATCH_GOAL_S
    assert s["settle_s"] <= matrix.SWINGUP_SETTLE_GOAL_S
    assert s["base_turns_max"] <= matrix.SWINGUP_TURNS_GOAL


def test_every_case_of_the_issue_is_in_the_matrix():
    wanted = {"E+15", "E-15", "rho+15", "rho-15", "damping*0.1", "damping*10", "viscous*3", "coulomb*0",
              "coulomb*2", "J+30", "J-30", "kt+15", "kt-15", "L+3", "L-3", "supply11", "supply13", "delay+1",
              "dist+", "dist-", "inext10", "inext20", "inext40", "der10", "der20", "der40",
              # issue 31: what a real rig adds between the encoder and the rod
              "backlash0", "backlash0.5", "backlash2", "backlash3", "gear20", "gear200", "zero+0.5", "zero-0.5",
              "curved", "lag0.75", "E-15,coulomb*0", "rho+15,coulomb*0"}
    assert wanted <= set(matrix.CASES)
    assert set(matrix.CASE_SETS["matrix"]) == set(matrix.CASES)
    assert {c.name for c in matrix.cases_for("swingup")} == set(matrix.CASES) - {"dist+", "dist-"}


def _stop_at_simulate(monkeypatch) -> dict:
    """Make matrix.simulate record the design and plant parameters it is given, then raise."""
    seen = {}

    def fake(design_p, plant_p, task, **kw):
        seen["design"], seen["plant"] = design_p, plant_p
        raise RuntimeError("stop")

    monkeypatch.setattr(matrix, "simulate", fake)
    return seen


def test_a_plant_override_never_reaches_the_design(monkeypatch):
    """The design is built from params + design_overrides only; the plant gets the case's overrides."""
    seen = _stop_at_simulate(monkeypatch)
    p = load_params()
    with pytest.raises(RuntimeError):
        matrix.run_case(p, matrix.CASES["E+15"], "balance")
    assert seen["design"]["rod"]["youngs_modulus"] == p["rod"]["youngs_modulus"]
    assert seen["plant"]["rod"]["youngs_modulus"] == pytest.approx(1.15 * p["rod"]["youngs_modulus"])


def test_plant_params_replace_the_plant_and_the_case_scales_them(monkeypatch):
    """run_case(plant_params=hidden): the design stays params', the plant is the hidden rod (its [plant]
    table too) and a relative case override scales the hidden value (rodctl robustness --plant)."""
    seen = _stop_at_simulate(monkeypatch)
    p = load_params()
    hidden = p.with_overrides("motor.rotor_inertia=6.0e-7", 'plant.model="inextensible"', "plant.edges=12")
    with pytest.raises(RuntimeError):
        matrix.run_case(p, matrix.CASES["J+30"], "balance", plant_params=hidden)
    assert seen["design"] is p
    assert seen["plant"]["motor"]["rotor_inertia"] == pytest.approx(1.3 * 6.0e-7)
    assert (seen["plant"]["plant"]["model"], seen["plant"]["plant"]["edges"]) == ("inextensible", 12)


def test_result_is_json_serializable(results):
    import json

    rows = list(results.values())
    assert json.loads(json.dumps(rows, allow_nan=False)) == rows  # strict JSON: NaN and inf are null already


def test_longest_rod_tries_the_design_variants_in_order(monkeypatch):
    """The design is redone per rod: a length counts as held when the first variant that holds it
    (design-only overrides) does; later variants are not run."""
    calls = []

    def fake(params, case, task, *, start_deg, **kw):
        calls.append(case.design_overrides)
        held = case.design_overrides == ("observer.process_noise_torque=0.0",)
        return {"fault_reason": 0, "final_dev_deg": 0.4 if held else 5.0}

    monkeypatch.setattr(matrix, "run_case", fake)
    variants = ((), ("observer.process_noise_torque=0.0",), ("rod.edges=6",))
    assert matrix.balances(load_params(), 0.16, designs=variants) == ("observer.process_noise_torque=0.0",)
    assert calls == [(), ("observer.process_noise_torque=0.0",)]
    monkeypatch.setattr(matrix, "run_case", lambda *a, **k: {"fault_reason": 2, "final_dev_deg": 180.0})
    assert matrix.balances(load_params(), 0.16, designs=variants) is None


def test_longest_rod_is_the_longest_without_a_gap_below_it(monkeypatch):
    """Pass/fail is not monotone near the limit (measured: 1.10 holds, 1.11 to 1.15 fail, 1.16 holds),
    so the measure walks up in steps and stops at the first length nothing holds."""
    p = load_params()
    lc = greenhill_length(p)
    holds = {1.0, 1.01, 1.02, 1.03, 1.05}  # 1.04 is a gap

    monkeypatch.setattr(matrix, "balances",
                        lambda params, length, designs=((),), band_deg=1.0: () if round(length / lc, 2) in holds else None)
    r = matrix.longest_balanced(p, lo=1.0, hi=1.2, step=0.01)
    assert r["ratio"] == pytest.approx(1.03)
    assert r["first_failure"] == pytest.approx(1.04)
    assert r["length_m"] == pytest.approx(1.03 * lc)


def test_pumping_past_the_rigid_upright_energy_catches_a_short_stiff_rod():
    """Hidden rig C of test_identify (0.94 x its critical length) with viscous friction x3: a pump that stops at
    the rigid pendulum's upright energy (swing_up.energy_target = 1.0, the stall watch off) holds theta_1 in a
    steady swing that peaks just outside the catch window, so it is never caught; the stall watch lifts that
    swing after a few half-swings, and the default target (1.05) catches it on the first approach
    (docs/scenarios.md, "Swing-up: energy pumping")."""
    from hidden_rigs import hidden_params

    rig = hidden_params("C").with_overrides(*matrix.IDEAL_GEARBOX)
    assert rig["swing_up"]["energy_target"] == 1.05
    rigid = matrix.run_case(rig.with_overrides("swing_up.energy_target=1.0", "swing_up.stall_steps=0"),
                            matrix.CASES["viscous*3"], "swingup")
    assert rigid["caught_at_s"] is None and not rigid["passed"], rigid
    watched = matrix.run_case(rig.with_overrides("swing_up.energy_target=1.0"), matrix.CASES["viscous*3"], "swingup")
    # measured 2.38 s
    assert watched["passed"] and 1.5 < watched["caught_at_s"] < 4.0, watched
    r = matrix.run_case(rig, matrix.CASES["viscous*3"], "swingup")
    # measured 1.09 s: the first approach (the next one, on the other side, comes half a swing later)
    assert r["passed"] and r["caught_at_s"] < 1.3 and r["base_turns_max"] < 0.6, r


def test_a_supply_below_the_designs_stalls_the_swing_until_the_watch_raises_the_pump():
    """The firmware made for 12 V on a 10 V supply: the back-EMF leaves the pump short, and Table I's rod settles
    into a steady swing whose theta_1 turns back at 147 deg, 1 deg short of the catch window. The stall watch
    (rod_swingup.h) raises the pump and the target until it is caught (measured 3.22 s) and held."""
    p = load_params()
    ten_volts = ("driver.supply_voltage=10.0",)
    off = matrix.run_case(p.with_overrides("swing_up.stall_steps=0"), matrix.CASES["nominal"], "swingup",
                          extra_plant_overrides=ten_volts, seconds=8.0)
    assert off["caught_at_s"] is None and off["fault_reason"] == 0, off
    on = matrix.run_case(p, matrix.CASES["nominal"], "swingup", extra_plant_overrides=ten_volts, seconds=12.0)
    # measured: held within 2.6 deg from 9 s on, the play's lean (docs/control.md)
    assert 2.0 < on["caught_at_s"] < 5.0 and on["fault_reason"] == 0 and on["final_dev_deg"] < 3.0, on


def test_past_its_clamped_buckling_length_the_rod_ends_bent_and_the_table_says_why():
    """Table I's design on its own plant with an ideal gearbox, E scaled. At x0.85 the rod above the hub
    is 0.994 x its clamped buckling length and the 30 deg release holds (measured 1.03 deg); at x0.79
    it is 1.018 x and the rod ends bent over a shaft held upright (measured 44.6 deg). The table marks
    such a case."""
    from rodctl.cli.robustness import table_lines

    p = IDEAL
    rows = [matrix.run_case(p, matrix.Case(f"E*{f}", "E scaled", (f"rod.youngs_modulus*={f}",)), "balance")
            for f in (0.85, 0.79)]
    held, bent = rows
    assert held["buckling_ratio"] == pytest.approx(0.994, abs=1e-3) and held["passed"], held
    assert bent["buckling_ratio"] == pytest.approx(1.018, abs=1e-3), bent
    assert not bent["passed"] and bent["fault_reason"] == 0 and bent["final_dev_deg"] > 20, bent
    lines = table_lines(rows)
    assert [x.split("|")[0].strip() for x in lines[2:4]] == ["E*0.85", "E*0.79 ^"]
    assert "past the buckling length" in lines[-1] and "(E*0.79 1.018 x)" in lines[-1]


def test_the_matrix_cases_past_the_buckling_length_of_a_rig():
    """Table I's rod keeps every case short of it (E -15 %: 0.994 x); hidden rig B (E 5.2e5 Pa, 0.983 x)
    is pushed past it by three cases (docs/identification.md)."""
    from hidden_rigs import hidden_params

    assert matrix.buckled_cases(load_params()) == {}
    past = matrix.buckled_cases(hidden_params("B"))
    assert set(past) == {"E-15", "rho+15", "L+3", "E-15,coulomb*0", "rho+15,coulomb*0"}
    assert past["E-15"] == pytest.approx(1.038, abs=1e-3) and past["L+3"] == pytest.approx(1.015, abs=1e-3)


def test_the_table_keeps_its_columns_for_the_longest_case_name():
    from rodctl.cli.robustness import table_lines

    def row(case, task, passed):
        return {"case": case, "task": task, "passed": passed, "settle_s": None, "final_dev_deg": 2.5}

    rows = [row(c, t, c == "nominal") for c in ("nominal", "rho+15,coulomb*0") for t in matrix.TASKS]
    lines = table_lines(rows)
    table = [x for x in lines if "|" in x]  # the footnotes below it are lines of text
    bars = {tuple(i for i, ch in enumerate(x) if ch == "|") for x in table}
    assert len(bars) == 1 and len(next(iter(bars))) == len(matrix.TASKS)  # every '|' in the same column
    assert len(table) == 4 and lines[3].split("|")[0].strip() == "rho+15,coulomb*0"
    # the nominal row is held to other goals than the rest: marked, and its rule said
    assert lines[2].split("|")[0].strip() == "nominal *" and lines[4].startswith("  * held to the nominal goals")
