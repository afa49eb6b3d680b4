"""design.method = "robust": the LQG gains refined on a family of rods (gains/rodgains/robust_design.py).

What a user notices: the LQG design falls over on a rod ten times more damped than its model; the
refined one, designed without ever seeing the simulated plant, balances it, and still balances the
rest of the robustness matrix's hardest cases.
"""

from __future__ import annotations

import pytest

from rodgains.design import design
from rodgains.params import load_params
from rodctl import paths
from rodctl.sim import linear_check, matrix


from host_tools import run_rodctl

ROBUST_FILE = paths.REPO / "docs/tuned/robust-damping.toml"
MATRIX_FILE = paths.REPO / "docs/tuned/robust-matrix.toml"  # + design.robust_nominal_decay = 2.5
SOFT_FILE = paths.REPO / "docs/tuned/low-ripple.toml"  # the previous default: lqr.q_shaft_angle = 0, q_angle = 4.86


def ideal(p):
    """The robust files' designs were made and measured on the rig with an ideal gearbox (no play, an
    exact zero): the refinement is about the rod, which the gearbox's play would swamp (matrix.IDEAL_GEARBOX)."""
    return p.with_overrides(*matrix.IDEAL_GEARBOX)


@pytest.fixture(scope="module")
def robust():
    return design(load_params(ROBUST_FILE))


@pytest.fixture(scope="module")
def lqg():
    return design(load_params(ROBUST_FILE, ["design.method=sampled"]))


def test_refinement_holds_every_model_of_the_family(robust):
    target = robust.params["design"]["robust_radius"]
    fam, before = robust.checks["robust_family_radii"], robust.checks["robust_family_radii_lqg"]
    # the family: two model orders x three dampings, two torque fractions, E/rho/length/J/k_t ends, delay
    assert len(fam) == 6 + 2 + 8 + 2 + 1
    assert before["N=8 damping x10"] > 1.0  # the reason for the method: LQG loses the damped rod
    assert max(fam.values()) < target + 1e-4  # a penalty, not a hard constraint: within 1e-4 of it
    assert robust.checks["closed_loop_spectral_radius"] < 1.0


def test_faithful_plant_with_ten_times_the_damping_is_linearly_stable_only_with_refinement(robust, lqg):
    """Judged on the faithful plant (DER, 30 edges + hub), which the refinement never saw."""
    q = matrix.apply_overrides(robust.params, matrix.CASES["damping*10"].plant_overrides)
    assert linear_check.loop_radius(lqg, q) > 1.003
    assert linear_check.loop_radius(robust, q) < 0.9995


@pytest.mark.parametrize("case,task", [("damping*10", "balance"), ("damping*10", "swingup"),
                                       ("damping*0.1", "balance"), ("E-15", "balance")])
def test_refined_firmware_holds_the_hard_cases_of_the_matrix(robust, case, task):
    """The firmware with the refined gains in the loop: every link within 3 deg at the end, no FAULT."""
    r = matrix.run_case(ideal(robust.params), matrix.CASES[case], task)
    assert r["passed"], r
    assert r["final_dev_deg"] < 2.0 and r["fault_reason"] == 0


def test_files_written_before_the_robust_keys_still_load(tmp_path):
    text = paths.REPO.joinpath("gains/rodgains/default.toml").read_text()
    old = "\n".join(line for line in text.splitlines() if not line.startswith("robust_"))
    f = tmp_path / "old.toml"
    f.write_text(old)
    p = load_params(f)
    assert p["design"]["robust_radius"] == 0.9996 and p["design"]["robust_gain_margin"] == 0.3


def _slowest_nominal_decay(d) -> float:
    """Decay rate [1/s] of the slowest mode of the design-order nominal model's sampled loop."""
    import math

    from rodgains import robust_design as R

    mb = next(m for m in R.family(d.params, d.dt) if m.nominal)
    return -math.log(R.radii([mb], *d.estimator())[0]) / d.dt


def test_nominal_decay_makes_every_nominal_mode_faster():
    """design.robust_nominal_decay 2.5 /s: the slowest nominal mode goes from 1.5 /s to at least
    2.5 /s (a penalty: allowed 0.1 /s short of it)."""
    fast = design(load_params(MATRIX_FILE))
    slow = design(load_params(MATRIX_FILE, ["design.robust_nominal_decay=0"]))
    assert _slowest_nominal_decay(slow) < 1.6
    assert _slowest_nominal_decay(fast) > 2.4


def test_nominal_decay_penalty_gradient_matches_finite_differences():
    """The gradient of every mode above the floor (not only the slowest) against one-sided
    differences of the summed penalty sum (|lambda| - floor)^2."""
    import math

    from rodgains import robust_design as R

    d = design(load_params(MATRIX_FILE, ["design.method=sampled"]))
    Ao, Bo, Co, Ko, Lo = d.estimator()
    mb = next(m for m in R.family(d.params, d.dt) if m.nominal)
    floor = math.exp(-15.0 * d.dt)

    def penalty(K, L):
        return sum((mag - floor) ** 2 for mag, _, _ in R.eigen_gradients(mb, Ao, Bo, Co, K, L, floor)[1])

    out = R.eigen_gradients(mb, Ao, Bo, Co, Ko, Lo, floor)[1]
    assert len(out) >= 3  # several modes, not only the slowest
    gK = sum(2 * (mag - floor) * g for mag, g, _ in out)
    gL = sum(2 * (mag - floor) * g for mag, _, g in out)
    h, base = 1e-7, penalty(Ko, Lo)
    for j in (0, 3, 9):
        K2 = Ko.copy()
        K2[0, j] += h
        assert gK[j] == pytest.approx((penalty(K2, Lo) - base) / h, rel=1e-3, abs=1e-9), ("K", j)
    for i in (0, 8):
        L2 = Lo.copy()
        L2[i, 0] += h
        assert gL[i] == pytest.approx((penalty(Ko, L2) - base) / h, rel=1e-3, abs=1e-9), ("L", i)


@pytest.mark.parametrize("case,task", [("nominal", "balance"), ("nominal", "swingup"),
                                       ("damping*10", "balance"),
                                       ("damping*10", "swingup"), ("coulomb*2", "swingup")])
def test_matrix_file_meets_the_nominal_goals_and_holds_ten_times_the_damping(case, task):
    """docs/tuned/robust-matrix.toml in the SIL on the faithful plant: nominal balance within 1 deg by
    1.5 s, swing-up settled within 2 s of the catch (the nominal cases' strict criterion), and damping
    x10 and Coulomb x2 within 3 deg at the end."""
    r = matrix.run_case(ideal(load_params(MATRIX_FILE)), matrix.CASES[case], task)
    assert r["passed"], r
    assert r["fault_reason"] == 0
    if case == "nominal" and task == "balance":
        assert r["settle_s"] < 1.3
    if case == "damping*10":
        assert r["final_dev_deg"] < 1.0


@pytest.mark.parametrize("override,needle", [("design.robust_radius=1.2", "design.robust_radius: must be between"),
                                             ("design.robust_nominal_decay=-1", "design.robust_nominal_decay: must be"),
                                             ("design.robust_gain_margin=0", "design.robust_gain_margin: must be"),
                                             ("design.robust_noise_torque=2", "design.robust_noise_torque: must be"),
                                             ("lqr.q_shaft_angle=-1", "lqr.q_shaft_angle: must be"),
                                             ("design.method=hinf", "design.method: must be one of")])
def test_bad_robust_settings_give_one_line_and_exit_2(override, needle, tmp_path):
    r = run_rodctl("gains", "--set", override, "--header", str(tmp_path / "h.h"))
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0], r.stderr
    assert not (tmp_path / "h.h").exists()


def test_analytic_radius_gradient_matches_finite_differences(lqg):
    """The refinement's gradient (first-order eigenvalue perturbation), on a plain member, a delayed one
    and a torque-scaled one, against one-sided differences of the radius itself."""
    from rodgains import robust_design as R

    Ao, Bo, Co, Ko, Lo = lqg.observer_matrices()
    members = R.family(lqg.params, lqg.dt)
    picks = [members[2], next(m for m in members if m.delay), next(m for m in members if m.gain < 0.5)]
    h = 1e-7
    for mb in picks:
        r, gK, gL = R.radius_gradient(mb, Ao, Bo, Co, Ko, Lo)
        assert r == pytest.approx(R.radii([mb], Ao, Bo, Co, Ko, Lo)[0], abs=1e-12)
        for j in (0, 3, 9):
            K2 = Ko.copy()
            K2[0, j] += h
            fd = (R.radii([mb], Ao, Bo, Co, K2, Lo)[0] - r) / h
            assert gK[j] == pytest.approx(fd, rel=1e-3, abs=1e-6), (mb.name, "K", j)
        for i in (0, 8, Lo.shape[0] - 1):
            L2 = Lo.copy()
            L2[i, 0] += h
            fd = (R.radii([mb], Ao, Bo, Co, Ko, L2)[0] - r) / h
            assert gL[i] == pytest.approx(fd, rel=1e-3, abs=1e-6), (mb.name, "L", i)


# A stiffer rig (hidden rig A of tests/test_identify.py): E 650 kPa, rotor 6e-7 kg m^2, friction and
# k_t off Table I. Redesigned for it, the refined gains of robust-matrix.toml are linearly stable on
# every model of the family and still bang the rod over from 30 deg: the large-signal guard's reason.
STIFF_RIG = ("rod.youngs_modulus=650000.0", "rod.damping=0.0013", "motor.rotor_inertia=6e-07",
             "motor.viscous_friction=0.0007", "motor.coulomb_friction=0.004",
             "motor.torque_constant=0.0117915", "motor.back_emf_constant=0.0117915")


@pytest.fixture(scope="module")
def stiff_guarded():
    return design(load_params(MATRIX_FILE, list(STIFF_RIG)))


def _restarts(monkeypatch, ends, holds, restarts, made_by=None):
    """The refinement of robust-matrix.toml, with fakes at its edges: L-BFGS run i ends at ends[i] =
    (cost, one scale for every gain entry), and the guard's call j (from 1: one per run, then the
    walk-back's) holds if holds(j). Returns (design, gain scales of the design kept, L-BFGS runs made);
    with made_by: (what made_by() returns, None, L-BFGS runs made)."""
    from types import SimpleNamespace

    import numpy as np
    from rodgains import design_cache, large_signal
    from rodgains import robust_design as R

    monkeypatch.setattr(R, "RESTARTS", restarts)
    monkeypatch.setattr(R, "_MEMO", {})
    monkeypatch.setattr(design_cache, "load", lambda key: None)
    monkeypatch.setattr(design_cache, "store", lambda key, record: None)
    made, calls = [], []

    def minimize(fun, x0, **kw):
        cost, scale = ends[len(made)]
        made.append(cost)
        return SimpleNamespace(x=np.full(x0.size, scale), fun=cost)  # cost below the LQG gains' 3.3

    def guard(p, dt, Ao, Bo, Co, K, L):
        calls.append(1)
        return {"holds": holds(len(calls)), "runs": {}}

    monkeypatch.setattr(R, "minimize", minimize)
    monkeypatch.setattr(large_signal, "guard", guard)
    if made_by is not None:
        return made_by(), None, len(made)
    d = design(load_params(MATRIX_FILE))
    lqg = design(load_params(MATRIX_FILE, ["design.method=sampled"]))
    return d, d.K[0] / lqg.K[0] - 1.0, len(made)


def test_the_design_most_restarts_reach_and_hold_is_kept(monkeypatch):
    """Which run reaches a design moves with rounding, how many runs reach it hardly: of the runs whose
    whole refinement holds the (fake) guard, three end at one design (scales 0.1 +- 1e-4) and one,
    the cheapest, elsewhere (0.2). The design three reach is kept, at the first run that reached it."""
    import numpy as np

    ends = [(0.5, 0.3), (0.9, 0.1), (0.8, 0.1 + 1e-4), (0.4, 0.2), (0.95, 0.1 - 1e-4)]
    d, scale, made = _restarts(monkeypatch, ends, lambda call: call != 1, restarts=5)
    assert made == 5 and d.checks["robust_runs"] == [3, 5]
    assert d.checks["robust_step"] == 1.0
    assert np.allclose(scale, 0.1, rtol=1e-9)
    from rodgains.report import report_text

    assert "the design 3 of 5 L-BFGS runs reached" in report_text(d)


def test_restarts_stop_once_no_later_run_can_change_the_choice(monkeypatch):
    """Three of five runs at one design that holds: the two left could only tie it, so they are not run."""
    d, scale, made = _restarts(monkeypatch, [(0.5, 0.1)] * 5, lambda call: True, restarts=5)
    assert made == 3 and d.checks["robust_runs"] == [3, 3]


def test_when_no_design_holds_the_one_most_runs_reach_is_walked_back(monkeypatch):
    """Every whole refinement fails the (fake) guard; it holds from the walk-back's third step on
    (0.8, 0.6, 0.4 of the refinement): the design two runs reach (0.1), not the cheapest run (0.3),
    is walked back, and 0.4 of it kept."""
    import numpy as np

    ends = [(0.2, 0.3), (0.5, 0.1), (0.6, 0.1 + 1e-4)]
    d, scale, made = _restarts(monkeypatch, ends, lambda call: call >= 6, restarts=3)
    assert made == 3 and d.checks["robust_runs"] == [2, 3]
    assert d.checks["robust_step"] == pytest.approx(0.4)
    assert np.allclose(scale, 0.4 * 0.1, rtol=1e-9)


def test_rounding_sized_nudges_of_every_start_keep_the_same_design(monkeypatch):
    """Another machine's rounding, as a 1e-10 nudge of every L-BFGS start (seeded): of the runs on
    robust-matrix.toml with these nudges, one stops at another design that also holds the guard
    (cost 3.08 against 3.23, measured) and others on kinks that fail it. The design kept is the same:
    gains within 1e-3, the same 61 Hz least-damped mode (its ringing is what the report warns of)."""
    import numpy as np
    from rodgains import design_cache
    from rodgains import robust_design as R
    from rodgains.report import least_damped_mode

    here = design(load_params(MATRIX_FILE))
    monkeypatch.setattr(R, "_MEMO", {})
    monkeypatch.setattr(design_cache, "load", lambda key: None)
    monkeypatch.setattr(design_cache, "store", lambda key, record: None)
    real_minimize, made = R.minimize, []

    def nudged(fun, x0, **kw):
        x0 = x0 + 1e-10 * np.random.default_rng([5, len(made)]).standard_normal(x0.size)
        made.append(1)
        return real_minimize(fun, x0, **kw)

    monkeypatch.setattr(R, "minimize", nudged)
    there = design(load_params(MATRIX_FILE))
    assert there.checks["robust_step"] == here.checks["robust_step"] == 1.0
    assert np.allclose(there.K, here.K, rtol=1e-3) and np.allclose(there.L, here.L, rtol=1e-3, atol=1e-9)
    assert least_damped_mode(there) == pytest.approx(least_damped_mode(here), rel=1e-2)


@pytest.mark.parametrize("task", ["balance", "swingup"])
def test_guarded_design_holds_the_stiffer_rig_in_the_firmware(stiff_guarded, task):
    """On the faithful plant of that rig: the unguarded gains hit the angle limit (FAULT) in both tasks."""
    p = ideal(stiff_guarded.params)
    r = matrix.run_case(p, matrix.CASES["nominal"], task)
    assert r["fault_reason"] == 0 and r["final_dev_deg"] < 1.0, r


def test_guard_keeps_the_whole_refinement_on_table_i():
    d = design(load_params(MATRIX_FILE))
    assert d.checks["robust_step"] == 1.0
    runs = d.checks["robust_release"]["runs"]
    assert list(runs) == ["nominal", "torque low, delayed, heavy rotor", "light rotor", "rod damping low"]
    assert not any(r["fell"] for r in runs.values()) and runs["nominal"]["final_deg"] < 1.0


def _ripple(p) -> tuple[float, float]:
    """(RMS [N m], spectral peak [Hz]) of the firmware's torque over 4-6 s of nominal balance in the SIL."""
    import numpy as np

    r = matrix.run_case(ideal(p), matrix.CASES["nominal"], "balance", keep_log=True, seconds=6.0)
    log = r["log"]
    u = log["torque"][log["time"] > 4.0]
    spectrum = np.abs(np.fft.rfft(u - u.mean()))
    return float(np.sqrt(np.mean(u**2))), float(np.fft.rfftfreq(u.size, log["time"][1] - log["time"][0])[
        np.argmax(spectrum)])


def test_report_warns_of_the_ringing_mode_the_firmware_then_buzzes_at():
    """`rodctl gains --report` flags a loop mode damped below 0.1; in the SIL on the faithful plant
    the balanced rod's torque then ripples at that frequency, more than 1.5 times the default's ripple
    (measured 58 against 29 mN m) and three times the previous weights' (docs/tuned/low-ripple.toml: 12)."""
    from rodgains.report import least_damped_mode, report_text

    robust = design(load_params(MATRIX_FILE))
    hz, zeta = least_damped_mode(robust)
    assert zeta < 0.1 and 50.0 < hz < 75.0
    assert f"WARNING: below 0.1, encoder quantization keeps it ringing (expect torque ripple at {hz:.3g} Hz" \
        in report_text(robust)
    default_hz, default_zeta = least_damped_mode(design(load_params()))
    assert default_zeta > 0.2

    rms, peak_hz = _ripple(load_params(MATRIX_FILE))
    default_rms, _ = _ripple(load_params())
    soft_rms, _ = _ripple(load_params(SOFT_FILE))
    assert peak_hz == pytest.approx(hz, rel=0.1)
    assert rms > 0.04 and rms > 1.5 * default_rms and rms > 3 * soft_rms  # N m RMS: 58, 29, 12 mN m


def test_noise_torque_gradient_matches_finite_differences(lqg):
    """The quantization-torque penalty's analytic gradient (two Lyapunov solutions) against central
    differences, on the nominal member with the disturbance state."""
    from rodgains import robust_design as R

    Ao, Bo, Co, Ko, Lo = lqg.estimator()
    mb = next(m for m in R.family(lqg.params, lqg.dt) if m.nominal)
    q = lqg.params.rad_per_count
    rms, gK, gL = R.noise_torque_gradient(mb, Ao, Bo, Co, Ko, Lo, q)
    assert 0.002 < rms < 0.02  # N m (3.5 mN m)
    assert R.noise_torque_rms(mb, Ao, Bo, Co, Ko, Lo, q) == rms
    for j in (0, 3, 9):
        h = 1e-6 * max(1.0, abs(Ko[0, j]))
        Kp, Km = Ko.copy(), Ko.copy()
        Kp[0, j] += h
        Km[0, j] -= h
        fd = (R.noise_torque_rms(mb, Ao, Bo, Co, Kp, Lo, q) - R.noise_torque_rms(mb, Ao, Bo, Co, Km, Lo, q)) / (2 * h)
        assert gK[j] == pytest.approx(fd, rel=1e-4, abs=1e-9), ("K", j)
    for i in (0, 5, 8):
        h = 1e-6 * max(1.0, abs(Lo[i, 0]))
        Lp, Lm = Lo.copy(), Lo.copy()
        Lp[i, 0] += h
        Lm[i, 0] -= h
        fd = (R.noise_torque_rms(mb, Ao, Bo, Co, Ko, Lp, q) - R.noise_torque_rms(mb, Ao, Bo, Co, Ko, Lm, q)) / (2 * h)
        assert gL[i] == pytest.approx(fd, rel=1e-4, abs=1e-9), ("L", i)


def test_noise_torque_limit_removes_the_buzz():
    """design.robust_noise_torque = 15 mN m on robust-matrix.toml: the report's predicted quantization
    torque drops from 23 to at most 15 mN m, the 61 Hz ring is damped past the report's 0.1 warning
    (measured 0.137, from 0.054), and the firmware's balanced torque ripple on the faithful plant
    falls (measured 41 against 58 mN m RMS: the linear bound does not see all of it). (Whether damping x10 still
    holds is a knife edge, docs/design.md; so it is not asserted.)"""
    from rodgains.report import least_damped_mode, quantization_torque, report_text

    loud = design(load_params(MATRIX_FILE))
    quiet = design(load_params(MATRIX_FILE, ["design.robust_noise_torque=0.015"]))
    assert quantization_torque(loud) > 0.02
    assert quantization_torque(quiet) < 0.0155
    assert f"encoder quantization drives {quantization_torque(quiet) * 1e3:.3g} mN m RMS" in report_text(quiet)
    assert least_damped_mode(quiet)[1] > 0.1 and "WARNING" not in report_text(quiet)
    assert _ripple(quiet.params)[0] < 0.8 * _ripple(loud.params)[0]


@pytest.mark.parametrize("task", ["balance", "swingup"])
def test_the_stiff_shaft_is_what_holds_ten_times_the_damping(task):
    """The default's stiff shaft (lqr.q_shaft_angle = 325 with q_angle = 10), plain LQG with no refinement, is
    linearly stable on the faithful plant with ten times the rod damping; the previous weights
    (docs/tuned/low-ripple.toml: no shaft weight, q_angle 4.86) are not, and the firmware drops that rod."""
    stiff, soft = ideal(load_params()), ideal(load_params(SOFT_FILE))
    assert stiff["lqr"]["q_shaft_angle"] == 325.0 and stiff["design"]["method"] == "sampled"
    assert soft["lqr"]["q_shaft_angle"] == 0.0
    damped = matrix.CASES["damping*10"]
    for p, stable in ((stiff, True), (soft, False)):
        d = design(p)
        radius = linear_check.loop_radius(d, matrix.apply_overrides(p, damped.plant_overrides))
        assert (radius < 0.9996) if stable else (radius > 1.003), (p.source, radius)  # 0.99947, 1.0039
    r = matrix.run_case(soft, damped, task)
    assert not r["passed"] and r["final_dev_deg"] > 90.0, r  # the default holds it: tests/test_robustness_matrix.py


def test_rodctl_gains_shows_each_refinement_run_and_nothing_when_cached(monkeypatch, tmp_path, capsys):
    """A robust design on a new file takes up to half a minute: each L-BFGS run is announced as it
    starts (three of at most five here: the last two could not change the choice); the same file
    again comes from the cache, at once and silent."""
    from rodctl.cli import main

    header = tmp_path / "g.h"
    argv = ["gains", "--params", str(MATRIX_FILE), "--header", str(header)]
    rc, _, made = _restarts(monkeypatch, [(0.5, 0.1)] * 5, lambda call: True, restarts=5,
                            made_by=lambda: main(argv))
    err = capsys.readouterr().err.splitlines()
    assert rc == 0 and made == 3
    assert err[0].startswith("rodctl: refining the gains on the robust model family (design.method = robust)")
    assert err[1:] == [f"  run {i} of at most 5" for i in (1, 2, 3)]
    assert main(argv) == 0 and capsys.readouterr().err == ""
