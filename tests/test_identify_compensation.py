"""rodctl identify chooses the dry-friction compensation for the identified rig by the robustness matrix:
the ranking, the file it writes, and rig A, whose nominal balance the nominal file's 7.4 mN m misses."""

from __future__ import annotations

import math

import pytest
from rodgains.params import load_params

from host_tools import run_rodctl
from rodctl.ident import compensation as C
from test_identify import _identified, hidden_params


def _row(case, task, passed, settle=None):
    return {"case": case, "task": task, "passed": passed, "settle_s": settle}


def test_ranking_takes_the_most_passes_then_the_widest_nominal_margin_then_the_default_ratio():
    good = [_row("nominal", "balance", True, 0.9), _row("nominal", "swingup", True, 1.2), _row("E-15", "balance", True)]
    slow = [_row("nominal", "balance", True, 1.4), _row("nominal", "swingup", True, 1.2), _row("E-15", "balance", True)]
    miss = [_row("nominal", "balance", False, None), _row("nominal", "swingup", True, 0.5), _row("E-15", "balance", True)]
    cands = [C.candidate(1.2, 1e-3, miss), C.candidate(1.3, 1e-3, slow), C.candidate(2.0, 1e-3, good),
             C.candidate(1.4, 1e-3, good)]
    assert [c.passed for c in cands] == [2, 3, 3, 3]
    assert cands[0].margin_s == -math.inf and cands[0].failed == ("nominal/balance",)
    assert cands[1].margin_s == pytest.approx(0.1)  # 1.5 s goal - 1.4 s
    assert cands[2].margin_s == pytest.approx(0.6)  # min(1.5 - 0.9, 2.0 - 1.2)
    best = max(cands, key=C.rank_key)
    assert best.ratio == 1.4  # ties with 2.0 on passes and margin; nearer the default 1.5 x


def test_no_dry_friction_leaves_nothing_to_choose():
    assert C.choose(load_params(None, ["motor.coulomb_friction=0.0"]), cases="nominal", jobs=1, progress=False) is None


def test_rig_a_meets_the_nominal_goals_with_the_chosen_compensation(tmp_path):
    """Rig A (T_c 4 mN m): the identified file with the nominal 7.4 mN m settles balance in 1.64 s (goal 1.5 s).
    The compensation chosen on the identified rig meets both nominal goals on the hidden plant."""
    from rodctl.sim.matrix import BALANCE_SETTLE_GOAL_S, CASES, SWINGUP_SETTLE_GOAL_S, run_case

    mine, hidden = _identified("A", tmp_path), hidden_params("A")
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


def test_identify_refuses_an_unknown_case_set_before_anything_runs(tmp_path):
    r = run_rodctl("identify", "--port", "sim://", "--yes", "--out", str(tmp_path / "o.toml"),
                   "--log-dir", str(tmp_path), "--compensation-cases", "bogus")
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [r.stderr.strip()]
    assert "--compensation-cases bogus: unknown case set; one of matrix, nominal, quick, plants, none" in r.stderr
    assert not list(tmp_path.iterdir())


def check_written_compensation(out, stdout: str) -> None:
    """The file `rodctl identify` wrote carries ratio x its identified Coulomb friction, and every candidate's
    measured result (used by test_identify's run over sim://)."""
    p = load_params(out)
    text = out.read_text()
    chosen = [ln for ln in text.splitlines() if ln.startswith("# ^ rodctl identify: chosen by the robustness matrix")]
    assert len(chosen) == 1
    ratio = float(chosen[0].split(" on the identified rig, ")[1].split(" x ")[0])
    fc, tc = p["lqr"]["friction_compensation"], p["motor"]["coulomb_friction"]
    nominal = load_params()["lqr"]["friction_compensation"]
    assert f"{fc / tc:.3g}" == f"{ratio:.3g}"  # the comment states the ratio to 3 digits
    assert fc == pytest.approx(nominal) or any(fc == pytest.approx(r * tc, rel=1e-9) for r in C.RATIOS)
    lines = [ln for ln in text.splitlines() if ln.startswith("# ^   ") and " passed" in ln]
    assert len(lines) == len(C.RATIOS) + 1  # and the nominal file's own value
    assert sum("(the nominal file's)" in ln for ln in lines) == 1
    assert f"({ratio:.3g} x)" in stdout
