"""rodctl identify: the fit recovers hidden plants from firmware (SIL) experiments, refuses data that
cannot identify anything, flags non-physical values, and runs over sim:// with a hidden plant."""

from __future__ import annotations

import dataclasses
import math
import time
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest
from rodgains.params import DEFAULT_PARAMS, load_params

from host_tools import run_rodctl
from rodctl.build.sil_build import build_sil
from rodctl.ident import compensation as C
from rodctl.ident import experiments as E
from rodctl.ident import fit as F
from rodctl.ident import report as R
from rodctl.sim.plant import SilController, faithful_plant

# Rigs the identifier is not told: motor, friction and rod off the nominal file by up to 30 %, and the
# gearbox's play and the boot zero (issue 31) anywhere a 25D gearmotor puts them.
HIDDEN = {
    "A": {"motor.rotor_inertia": 6.0e-7, "motor.viscous_friction": 7e-4, "motor.coulomb_friction": 0.004,
          "kt_scale": 1.05, "rod.youngs_modulus": 6.5e5, "rod.damping": 0.0013},
    "B": {"motor.rotor_inertia": 4.2e-7, "motor.viscous_friction": 3.5e-4, "motor.coulomb_friction": 0.007,
          "kt_scale": 0.92, "rod.youngs_modulus": 5.2e5, "rod.damping": 0.0008,
          "gearbox.backlash_deg": 2.2, "encoder.zero_error_deg": -0.3},
    "C": {"motor.rotor_inertia": 5.6e-7, "motor.viscous_friction": 9e-4, "motor.coulomb_friction": 0.0025,
          "kt_scale": 1.12, "rod.youngs_modulus": 7.2e5, "rod.damping": 0.002,
          "gearbox.backlash_deg": 0.6, "encoder.zero_error_deg": 0.1},
    # a random draw within +-30 % on which the fast fit rod alone misses the viscous friction by 8 %
    "D": {"motor.rotor_inertia": 6.05e-7, "motor.viscous_friction": 4.01e-4, "motor.coulomb_friction": 0.00497,
          "kt_scale": 1.034, "rod.youngs_modulus": 6.4e5, "rod.damping": 0.000933,
          "gearbox.backlash_deg": 1.5, "encoder.zero_error_deg": -0.12},
    # the gearbox at the ends of its range: the widest play and the softest gear train (the fit's own is 60 N m/rad)
    "F": {"motor.rotor_inertia": 4.6e-7, "motor.viscous_friction": 6.1e-4, "motor.coulomb_friction": 0.0038,
          "kt_scale": 1.07, "rod.youngs_modulus": 6.9e5, "rod.damping": 0.0016,
          "gearbox.backlash_deg": 3.0, "gearbox.stiffness": 20.0, "encoder.zero_error_deg": 0.35},
    # played on one plant, one experiment after another (test_experiments_played_one_after_another_on_one_rig)
    "E": {"motor.rotor_inertia": 6.0e-7, "motor.viscous_friction": 4e-4, "motor.coulomb_friction": 0.006,
          "kt_scale": 1.0, "rod.youngs_modulus": 5.5e5, "rod.damping": 0.0013,
          "gearbox.backlash_deg": 2.0, "encoder.zero_error_deg": -0.3},
}
TOLERANCE = {"rotor_inertia": 0.05, "viscous_friction": 0.05, "coulomb_friction": 0.10, "youngs_modulus": 0.05,
             "torque_constant_scale": 0.05, "damping": 0.25}
# between the encoder and the rod, absolute [deg]: issue 31 asks the backlash within 0.2 deg
TOLERANCE_DEG = {"backlash": 0.2, "zero_error": 0.1}


def hidden_params(name: str):
    nom = load_params()
    h = dict(HIDDEN[name])
    s = h.pop("kt_scale")
    m = nom["motor"]
    sets = [f"{k}={v!r}" for k, v in h.items()]
    sets += [f"motor.torque_constant={m['torque_constant'] * s!r}", f"motor.back_emf_constant={m['back_emf_constant'] * s!r}"]
    return nom.with_overrides(*sets)


def truth(name: str) -> dict[str, float]:
    h = HIDDEN[name]
    nom = load_params()
    return {"rotor_inertia": h["motor.rotor_inertia"], "viscous_friction": h["motor.viscous_friction"],
            "coulomb_friction": h["motor.coulomb_friction"], "torque_constant_scale": h["kt_scale"],
            "youngs_modulus": h["rod.youngs_modulus"], "damping": h["rod.damping"],
            "backlash": h.get("gearbox.backlash_deg", nom["gearbox"]["backlash_deg"]),
            "zero_error": h.get("encoder.zero_error_deg", nom["encoder"]["zero_error_deg"])}


@lru_cache(maxsize=None)
def sil() -> SilController:
    return SilController(build_sil(load_params()))  # the firmware of the nominal (user's) parameters


@lru_cache(maxsize=None)
def records(name: str) -> tuple:
    hidden = hidden_params(name)
    return tuple(E.run_sil(e, sil(), faithful_plant(hidden, input_mode="duty")) for e in E.DEFAULT_SEQUENCE)


@lru_cache(maxsize=None)
def fitted(name: str) -> F.FitResult:
    return F.fit(list(records(name)), load_params(), starts=1)


@pytest.mark.parametrize("name", ["A", "B", "C", "D", "F"])
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


def test_experiments_played_one_after_another_on_one_rig():
    """As on a board: each record starts where the last experiment left the rig, after the settle move.
    Rig E's 2 deg of play let the rod rattle unseen after the free swing, and the motor rests on a
    flank at each start: with records started mid-gap at the first count, and no settle move, its
    viscous friction came out 17.8 % low (docs/identification.md)."""
    from rodctl.ident.run import SETTLE_S

    hidden = hidden_params("E")
    plant = faithful_plant(hidden, input_mode="duty")
    cpr, zero = float(hidden.counts_per_rev), math.radians(hidden["encoder"]["zero_error_deg"])
    motor_at_start = []  # where the motor side truly was as each record began [counts]
    play = E.run_sil

    def watched(exp, sil_, plant_):
        if exp.name != "settle":
            motor_at_start.append((plant_.motor_state()[0] + zero) * cpr / (2 * math.pi))
        return play(exp, sil_, plant_)

    import unittest.mock

    with unittest.mock.patch.object(E, "run_sil", watched):
        recs = E.run_sil_sequence(E.DEFAULT_SEQUENCE, sil(), plant, load_params(), rest=SETTLE_S)
    assert [r.name for r in recs] == [e.name for e in E.DEFAULT_SEQUENCE] and all(r.end_reason == 0 for r in recs)
    res = F.fit(recs, load_params(), starts=1)
    true = truth("E")
    for p in ("rotor_inertia", "viscous_friction", "coulomb_friction", "youngs_modulus", "torque_constant_scale"):
        assert abs(res.values[p] / true[p] - 1) < TOLERANCE[p], (p, res.values[p], true[p])
    for p, tol in TOLERANCE_DEG.items():
        assert abs(res.values[p] - true[p]) < tol, (p, res.values[p], true[p])
    within = [m - r.count[0] for m, r in zip(motor_at_start, recs)]  # the start's place in its first count
    assert np.allclose(res.start_counts, within, atol=0.15), (res.start_counts, within)


@pytest.mark.parametrize("enc_deg, rod_deg", [(0.3, 0.0), (-0.9, 0.0), (1.5, 0.5), (-2.0, -1.0),
                                              (361.5, 360.5)])  # a turn from the boot zero (after a swing-up)
def test_a_record_starts_with_the_rod_hanging_as_far_as_the_play_lets_it(enc_deg, rod_deg):
    """2 deg of play: the rod hangs straight down while the gap around the motor side reaches it, else
    it rests on the nearer flank; the motor side is where the encoder says."""
    plant = faithful_plant(load_params().with_overrides("gearbox.backlash_deg=2.0"), input_mode="duty")
    F.set_start(plant, math.radians(enc_deg))
    th, dth = plant.state()
    assert np.allclose(np.degrees(th), rod_deg, atol=1e-9) and not dth.any()
    assert math.degrees(plant.motor_state()[0]) == pytest.approx(enc_deg)
    out = faithful_plant(load_params().with_overrides('encoder.location="output"'), input_mode="duty")
    F.set_start(out, math.radians(1.5))
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


def test_identify_over_sim_with_a_hidden_plant(tmp_path):
    hidden = tmp_path / "hidden.toml"
    hidden.write_text(hidden_params("B").to_toml())
    port = f"sim://?plant={hidden}"
    out = tmp_path / "my_rod.toml"
    r = run_rodctl("identify", "--port", port, "--experiment", "release", "--experiment", "prbs", "--yes",
                   "--log-dir", str(tmp_path / "logs"), "--out", str(out), "--starts", "1",
                   "--compensation-cases", "nominal", "--jobs", "2", timeout=400)
    # rig B's design misses the nominal goals on rig B's gearbox: the file is written, and the run ends
    # with a verdict that says so, in its last lines, in the file's header, and in the exit status
    assert r.returncode == 1, r.stderr
    tail = r.stdout.strip().splitlines()
    verdict = next(i for i, ln in enumerate(tail) if ln.startswith("verdict: "))
    assert tail[verdict].startswith("verdict: NOT READY: a nominal goal missed"), tail[verdict:]
    assert all(ln.startswith("  ") for ln in tail[verdict + 1:])  # nothing after the verdict but its own lines
    assert any(ln.startswith("  nominal balance: ") and ln.endswith("MISSED") for ln in tail[verdict:])
    assert any(ln.startswith("  next: ") and "encoder.location" in ln for ln in tail[verdict:])
    assert f"# {tail[verdict]}" in out.read_text()
    assert "[1/2] release: a 50 mN m push" in r.stderr and "[2/2] prbs:" in r.stderr
    assert len(list((tmp_path / "logs").glob("identify-*-release.csv"))) == 1
    p = load_params(out)
    assert p["motor"]["rotor_inertia"] == pytest.approx(HIDDEN["B"]["motor.rotor_inertia"], rel=0.05)
    assert out.with_suffix(".png").stat().st_size > 10000
    from test_identify_compensation import check_written_compensation

    check_written_compensation(out, r.stdout)


def test_identify_asks_before_moving_and_stops_without_an_answer(tmp_path):
    r = run_rodctl("identify", "--port", "sim://", "--experiment", "release", "--log-dir", str(tmp_path),
                   "--out", str(tmp_path / "o.toml"), input="", timeout=120)
    assert r.returncode == 2
    assert "release: a 50 mN m push" in r.stderr
    assert "pass --yes" in r.stderr.strip().splitlines()[-1]
    assert not list(tmp_path.glob("identify-*.csv"))


def test_the_rod_the_user_measured_is_the_nominal_whatever_the_board_was_flashed_with(tmp_path):
    """A first identify runs on a board flashed with the default gains; the user's file carries the rod
    they measured. The fit replays what the board played, so its nominal is the user's file, not the
    file the board's gains came from (which used to win, and put a 12 mm rod's fit 7 x off)."""
    measured = tmp_path / "measured.toml"
    measured.write_text(load_params().with_overrides("rod.thickness=0.012", "rod.length=0.16").to_toml())
    board = f"sim://?params={DEFAULT_PARAMS}"  # flashed with the default gains
    r = run_rodctl("identify", "--port", board, "--params", str(measured), "--experiment", "release",
                   "--log-dir", str(tmp_path), "--out", str(tmp_path / "o.toml"), input="", timeout=120)
    assert r.returncode == 2
    assert r.stderr.splitlines()[0].endswith(f"nominal parameters: {measured}"), r.stderr


def test_a_virtual_board_is_built_from_the_users_file(tmp_path):
    """--params / --set build a sim:// board's firmware and plant, as --params' help says: a rehearsal runs
    the gains the user would flash."""
    measured = tmp_path / "measured.toml"
    measured.write_text(load_params().with_overrides("rod.edges=6").to_toml())
    r = run_rodctl("identify", "--port", "sim://", "--params", str(measured), "--experiment", "release",
                   "--log-dir", str(tmp_path), "--out", str(tmp_path / "o.toml"), input="", timeout=120)
    assert r.returncode == 2
    assert "firmware N=6 at 1000 Hz" in r.stderr.splitlines()[0], r.stderr


def test_a_safety_trip_over_sim_keeps_the_log_and_names_the_limit(tmp_path):
    """With the host's soft limit off (--soft-limit 1), 75 mN m steps swing the rod into the firmware's
    own 60 deg limit: FAULT."""
    r = run_rodctl("identify", "--port", "sim://", "--experiment", "steps", "--scale", "3", "--soft-limit", "1",
                   "--yes", "--log-dir", str(tmp_path), "--out", str(tmp_path / "o.toml"), timeout=120)
    assert r.returncode == 1
    last = r.stderr.strip().splitlines()[-1]
    assert "safety limit tripped: angle limit (ANGLE_LIMIT)" in last and "log kept" in last
    assert last.endswith("for smaller swings: --scale 2.1")  # 0.7 x the scale that tripped
    logs = list(tmp_path.glob("identify-*-steps.csv"))
    assert len(logs) == 1 and str(logs[0]) in last
    assert not (tmp_path / "o.toml").exists()


def test_a_swing_past_the_soft_limit_is_stopped_and_played_again_smaller(tmp_path):
    """At 1.25 x the default rod's chirp stays within 40 deg, but its steps would swing it to about 53 deg
    (SIL: 51 deg at 1.2 x, 56 at 1.3 x), past the host's 48 deg soft limit and short of the firmware's
    60: the host stops them (no FAULT), plays them again 0.7 x smaller (21.875 mN m, about 35 deg) and
    fits the complete runs only; the stopped run's log stays on disk."""
    out = tmp_path / "o.toml"
    r = run_rodctl("identify", "--port", "sim://", "--experiment", "chirp", "--experiment", "steps",
                   "--scale", "1.25", "--settle", "2", "--yes", "--log-dir", str(tmp_path / "logs"), "--out", str(out),
                   "--starts", "1", "--compensation-cases", "none", timeout=400)
    # the file is written; the default rig misses the nominal goals on its gearbox (docs/control.md): exit 1
    assert r.returncode == 1 and "verdict: NOT READY" in r.stderr + r.stdout, r.stderr
    stopped = [ln for ln in r.stderr.splitlines() if ln.strip().startswith("stopped:")]
    assert len(stopped) == 1 and "(soft limit 48 deg)" in stopped[0] and "-steps.csv" in stopped[0]
    assert int(stopped[0].split("swung ")[1].split(" deg")[0]) >= 48
    assert "[2/2] steps: torque steps +21.875 mN m, 0, -21.875 mN m, 0" in r.stderr
    done = [ln for ln in r.stderr.splitlines() if ln.strip().startswith("done:")]
    assert len(done) == 2 and all(int(ln.split("largest swing ")[1].split(" deg")[0]) < 48 for ln in done)
    logs = sorted(p.name for p in (tmp_path / "logs").glob("identify-*.csv") if not p.name.endswith(".events.csv"))
    assert [n.split("-", 3)[3] for n in logs] == ["chirp.csv", "steps-2.csv", "steps.csv"]
    text = out.read_text()
    assert next(n for n in logs if n.endswith("steps-2.csv")) in text
    assert next(n for n in logs if n.endswith("-steps.csv")) not in text
    assert load_params(out)["motor"]["rotor_inertia"] == pytest.approx(load_params()["motor"]["rotor_inertia"], rel=0.05)


def test_a_rig_that_keeps_swinging_too_far_stops_after_three_tries(tmp_path):
    """With a 15 deg soft limit (--soft-limit 0.25), the default steps swing past it at 1, 0.7 and 0.49 x
    (SIL: 40, 28 and 20 deg): the host gives up after three stopped tries, exit 1, motor off, every log
    kept, no parameter file, and names a --scale below the last one tried."""
    out = tmp_path / "o.toml"
    r = run_rodctl("identify", "--port", "sim://", "--experiment", "steps", "--soft-limit", "0.25", "--settle", "2",
                   "--yes", "--log-dir", str(tmp_path), "--out", str(out), timeout=300)
    assert r.returncode == 1, r.stderr
    assert r.stderr.count("(soft limit 15 deg)") == 3
    last = r.stderr.strip().splitlines()[-1]
    assert last.startswith("rodctl: steps: swung") and "after 3 tries; motor stopped" in last
    assert last.endswith("for smaller swings: --scale 0.34")  # 0.7^3
    assert len([p for p in tmp_path.glob("identify-*-steps*.csv") if not p.name.endswith(".events.csv")]) == 3
    assert not out.exists()


def test_soft_limit_outside_zero_to_one_is_refused_before_anything_moves(tmp_path):
    r = run_rodctl("identify", "--port", "sim://", "--soft-limit", "1.5", "--yes", "--log-dir", str(tmp_path),
                   "--out", str(tmp_path / "o.toml"), timeout=60)
    assert r.returncode == 2
    assert r.stderr.strip() == "rodctl: --soft-limit must be in (0, 1], got 1.5"
    assert not list(tmp_path.iterdir())


def _identified(name: str, tmp_path):
    """The parameter file `rodctl identify` writes for hidden rig `name` (from the SIL records above)."""
    f = tmp_path / f"my_rod_{name}.toml"
    f.write_text(R.parameter_file(load_params(), fitted(name), [("sil", "0" * 64)]))
    return load_params(f)


def test_the_design_for_the_identified_rig_passes_on_the_hidden_plant(tmp_path):
    """Issue 10: design from the identified file, judge it on the hidden rig (`rodctl robustness --plant`),
    here on the quick case set (docs/identification.md: the whole matrix on rigs A, B, C)."""
    from rodctl.sim.matrix import CASE_SETS, CASES, IDEAL_GEARBOX, TASKS, run_case

    # judged with an ideal gearbox: what the identified rod and motor change, without the play's hunting
    mine = _identified("C", tmp_path).with_overrides(*IDEAL_GEARBOX)
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
    mine = run_case(_identified("C", tmp_path).with_overrides(*IDEAL_GEARBOX), CASES["damping*10"], "balance",
                    plant_params=hidden)
    assert default["fault_reason"] != 0 and not default["passed"], default
    assert mine["passed"] and mine["fault_reason"] == 0 and mine["final_dev_deg"] < SETTLE_DEG, mine


def test_identify_says_how_far_the_identified_rod_is_from_buckling(tmp_path):
    """Rig B's rod above the hub is 0.98 x its clamped buckling length; rig A's 0.91 x, and no matrix case
    takes A past it."""
    from rodctl.ident.fit_logs import buckling_line

    b = buckling_line(_identified("B", tmp_path)).splitlines()
    assert b[0].startswith("buckling: the rod above the hub is 0.98") and "it reaches 1 at E -" in b[0]
    assert "past it in the robustness matrix: E-15 1.03" in b[1] and "rho+15" in b[1] and "L+3" in b[1]
    a = buckling_line(_identified("A", tmp_path)).splitlines()
    assert len(a) == 1 and a[0].startswith("buckling: the rod above the hub is 0.91")


# with the compensation's other tests it would fit rig A again: .ci/run gives each test file to one worker
def test_rig_a_meets_the_nominal_goals_with_the_chosen_compensation(tmp_path):
    """Rig A (T_c 4 mN m) with an ideal gearbox: the identified file with the nominal 7.4 mN m settles balance
    in 1.64 s (goal 1.5 s). The compensation chosen on the identified rig meets both nominal goals on the
    hidden plant."""
    from rodctl.sim.matrix import BALANCE_SETTLE_GOAL_S, CASES, IDEAL_GEARBOX, SWINGUP_SETTLE_GOAL_S, run_case

    mine = _identified("A", tmp_path).with_overrides(*IDEAL_GEARBOX)
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


def _identify_interrupted(tmp_path, second: str, settle: str, until: str,
                          playing: tuple[str, int] | None = None):
    """Run `identify` on sim:// (release, then `second`) and send Ctrl-C once a stderr line starts
    with `until` (with playing = (experiment, rows): once that experiment's log holds `rows` rows in IDENTIFY
    instead, a point of the experiment on the board's clock); returns (its stderr after that line, the log
    folder). Exit 130 is asserted."""
    import signal

    from host_tools import start_rodctl

    logs = tmp_path / "logs"
    proc = start_rodctl("identify", "--port", "sim://", "--experiment", "release", "--experiment", second, "--yes",
                        "--settle", settle, "--log-dir", str(logs), "--out", str(tmp_path / "o.toml"))
    try:
        seen = []
        for line in proc.stderr:
            seen.append(line)
            if line.startswith(until):
                break
        if playing is not None:
            name, rows = playing
            while _identify_rows(logs, name) < rows and proc.poll() is None:
                time.sleep(0.02)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 130, "".join(seen) + err
    return err, logs


def _identify_rows(logs, experiment: str) -> int:
    """Rows of `experiment`'s CSV log, as far as written, in which the board plays it."""
    from rodctl.link import protocol as P

    log = next(logs.glob(f"identify-*-{experiment}.csv"), None)
    if log is None:
        return 0
    header, *rows = log.read_text().split("\n")
    if "mode_code" not in header.split(","):  # the header is not written yet
        return 0
    col = header.split(",").index("mode_code")
    # the last element is "" or a row still being appended: not counted
    return sum(int(row.split(",")[col]) == P.Mode.IDENTIFY for row in rows[:-1])


def test_ctrl_c_between_experiments_says_how_to_fit_the_logs_it_kept(tmp_path):
    # the first experiment's log is complete; the rod is settling for the second
    err, logs = _identify_interrupted(tmp_path, "prbs", "60", "  letting the rod settle")
    kept = [f for f in logs.glob("identify-*.csv") if not f.name.endswith(".events.csv")]
    assert len(kept) == 1 and kept[0].name.endswith("-release.csv")
    last = err.strip().splitlines()[-1]
    assert last.startswith("rodctl: interrupted; the motor is off; 1 experiment log kept: fit it with: rodctl identify ")
    pattern = last.split("rodctl identify ", 1)[1]
    import glob
    import shlex

    # the shell's matches are the log and its event sidecar, which identify skips (run_identify)
    matched = glob.glob(shlex.split(pattern)[0])
    assert sorted(matched) == sorted([str(kept[0]), str(kept[0]) + ".events.csv"])
    assert shlex.split(pattern)[1:] == ["--out", str(tmp_path / "o.toml")]  # the fit writes where the run would have
    assert not (tmp_path / "o.toml").exists()


def test_ctrl_c_during_the_settle_move_stops_the_motor(tmp_path):
    """On a virtual board in another process: the Ctrl-C lands while the board plays the settle move (its
    second IDENTIFY, after the release's), and the board ends disarmed by the host."""
    import json
    import signal

    from host_tools import BoardSaid, sim_device, start_rodctl, until

    logs = tmp_path / "logs"
    with sim_device() as (dev, port):
        board_said = BoardSaid(dev)
        proc = start_rodctl("identify", "--port", port, "--experiment", "release", "--experiment", "prbs", "--yes",
                            "--settle", "1", "--log-dir", str(logs), "--out", str(tmp_path / "o.toml"))
        try:
            assert until(lambda: board_said().count("-> IDENTIFY") >= 2, timeout=180), board_said()
            proc.send_signal(signal.SIGINT)
            _, err = proc.communicate(timeout=60)
        finally:
            proc.kill()
        assert proc.returncode == 130, err
        assert "  before it, settle" in err  # what was playing: the settle move
        last = err.strip().splitlines()[-1]
        assert last.startswith("rodctl: interrupted; the motor is off; 1 experiment log kept: fit it with"), last
        status = json.loads(run_rodctl("status", "--port", port, "--json", timeout=60).stdout)
        assert (status["mode"], status["reason"]) == ("DISARMED", "HOST")
        assert until(lambda: board_said().count("IDENTIFY -> DISARMED") >= 2, timeout=30), board_said()
    assert [f.name.split("-", 3)[3] for f in logs.glob("identify-*.csv") if not f.name.endswith(".events.csv")] == \
        ["release.csv"], "the settle move is not logged"


def _identify_log(path, end: str, experiment: str | None = "steps"):
    """A log as `rodctl identify` closes it, ended `end`; its rod never moves (the fit would refuse it).
    experiment None: closed as `rodctl log` closes a recording, naming no experiment."""
    from rodctl.link import protocol as P
    from rodctl.logs import LogWriter, simulator_metadata

    p = load_params()
    w = LogWriter(path, simulator_metadata(p), n=p.N)
    for k in range(500):
        w.write_telemetry(P.Telemetry(int(P.Mode.IDENTIFY), 0, 5, p.N, 0, 0.0, 0.02, 0.04, 10, 0, 0, 0,
                                      (0.0,) * p.N, (0.0,) * p.N), k, k * 1000)
    w.close({"end": end} if experiment is None else {"end": end, "experiment": experiment})
    return path


def test_fitting_logs_skips_the_runs_that_did_not_play_to_their_end(tmp_path):
    """The live run fits only complete runs; `rodctl identify logs/identify-STAMP-*.csv` (the glob a Ctrl-C
    names) also matches a run stopped at the soft limit and the one a Ctrl-C cut short: the fit skips
    them, saying so, instead of fitting their first seconds."""
    stopped = _identify_log(tmp_path / "identify-1-steps.csv", "stopped: swung 48 deg from hanging (soft limit 48 deg)")
    cut = _identify_log(tmp_path / "identify-1-chirp.csv", "error")
    r = run_rodctl("identify", str(stopped), str(cut), "--out", str(tmp_path / "o.toml"))
    assert r.returncode == 2, r.stderr
    err = r.stderr.strip().splitlines()
    assert f"fit: skipping {stopped}: the experiment did not play to its end (stopped: swung 48 deg" in err[0]
    assert err[1] == f"fit: skipping {cut}: the experiment did not play to its end (interrupted: Ctrl-C or a lost link)"
    assert err[-1] == "rodctl: no experiment log played to its end (2 skipped): nothing to fit"
    assert not (tmp_path / "o.toml").exists()


def test_a_recording_that_is_no_experiment_is_named_as_such(tmp_path):
    """A `rodctl log` recording closes with how it ended (here its duration) but names no experiment: it was
    read as an experiment that "did not play to its end (duration)"."""
    log = _identify_log(tmp_path / "run.csv", "duration", experiment=None)
    r = run_rodctl("identify", str(log), "--out", str(tmp_path / "o.toml"))
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [
        f"fit: skipping {log}: not an experiment of rodctl identify (a `rodctl log` recording?)",
        "rodctl: no experiment log played to its end (1 skipped): nothing to fit"]
    assert not (tmp_path / "o.toml").exists()


def test_fitting_logs_says_which_is_cut_short_and_fits_a_log_given_twice_once(tmp_path):
    """A log copied while it grew (its last row cut in half) is fitted for what it holds, and says so; the same
    file named twice (a glob and a name) is one experiment, not two records."""
    import shutil

    whole = _identify_log(tmp_path / "identify-1-steps.csv", "done")
    cut = tmp_path / "identify-2-steps.csv"
    for suffix in ("", ".json", ".events.csv"):
        if Path(f"{whole}{suffix}").exists():
            shutil.copy(f"{whole}{suffix}", f"{cut}{suffix}")
    data = cut.read_bytes()
    cut.write_bytes(data[: len(data) // 2 + 7])
    r = run_rodctl("identify", str(cut), str(whole), str(whole), "--out", str(tmp_path / "o.toml"))
    err = r.stderr.strip().splitlines()
    assert err[0].startswith(f"fit: warning: {cut}: cut short (1 cut row skipped; its close counted 500 rows); ") and \
        err[0].endswith(" telemetry frames readable; fitting the readable part"), err
    assert err[1] == f"fit: skipping {whole}: the same log as {whole.name}", err
    assert not any("skipping" in line for line in err[2:]), err


def test_ctrl_c_mid_experiment_disarms_and_counts_only_the_complete_runs(tmp_path):
    # 0.5 s of the board's clock into the 4 s chirp (1 kHz rows): mid-experiment however slowly this machine runs it
    err, logs = _identify_interrupted(tmp_path, "chirp", "1", "  letting the rod settle", playing=("chirp", 500))
    last = err.strip().splitlines()[-1]
    assert last.startswith("rodctl: interrupted; the motor is off; 2 experiment logs kept (1 played to the end; "
                           "the fit skips the others): fit it with: rodctl identify "), last
    assert last.endswith(f"*.csv --out {tmp_path / 'o.toml'}"), "the file asked for, not the default my_rod.toml"
    chirp = next(logs.glob("identify-*-chirp.csv"))
    from rodctl.logs import read_log

    log = read_log(chirp, columns=["mode_code"])
    assert log.trailer["end"] == "error"
    assert int(log.data["mode_code"][-1]) == 0, "the board is DISARMED in the last frame logged"
    assert not (tmp_path / "o.toml").exists() and not (tmp_path / "o.png").exists()


def test_an_existing_figure_is_kept_unless_force(tmp_path):
    """--plot (default: --out with .png) is this run's output as much as --out: checked before the fit."""
    log = _identify_log(tmp_path / "identify-1-steps.csv", "done")
    fig = tmp_path / "o.png"
    fig.write_bytes(b"another rig's figure")
    r = run_rodctl("identify", str(log), "--out", str(tmp_path / "o.toml"))
    assert r.returncode == 2
    assert r.stderr.strip() == f"rodctl: --plot {fig} exists; pass --force to overwrite"
    assert fig.read_bytes() == b"another rig's figure" and not (tmp_path / "o.toml").exists()
    r = run_rodctl("identify", str(log), "--out", str(tmp_path / "o.toml"), "--force")
    assert "exists" not in r.stderr  # --force lets it through to the fit (this log cannot identify anything)
    assert r.stderr.strip().splitlines()[-1].startswith("rodctl: not identifiable"), r.stderr


def test_an_experiment_named_twice_is_refused_before_anything_moves(tmp_path):
    """Its log is named after it: the second run used to stop on the first's log, after the motor had moved."""
    r = run_rodctl("identify", "--port", "sim://", "--experiment", "release", "--experiment", "release", "--yes",
                   "--log-dir", str(tmp_path / "logs"), "--out", str(tmp_path / "o.toml"), timeout=60)
    assert r.returncode == 2
    assert r.stderr.strip() == "rodctl: --experiment release: given twice; each experiment runs once"
    assert not tmp_path.joinpath("logs").exists() and not list(tmp_path.iterdir())


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
