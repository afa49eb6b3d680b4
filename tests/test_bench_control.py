"""`rodctl bench --only control`: issue 8's control goals as bench numbers with verdicts (the
simulations are replaced by fixed rows here; the real numbers are the README's scenario table)."""

from __future__ import annotations

import json

from rodctl.cli import main
from rodctl.sim import matrix as M


def test_control_goals_are_reported_with_verdicts_and_a_miss_exits_1(monkeypatch, tmp_path, capsys):
    def run_case(params, case, task, **kw):
        return {"settle_s": 0.7 if task == "balance" else 1.55, "caught_at_s": 0.93 if task == "swingup" else None}

    monkeypatch.setattr(M, "run_case", run_case)
    monkeypatch.setattr(M, "run_matrix", lambda p, **kw: [{"passed": True}] * 50 + [{"passed": False}] * 2)
    monkeypatch.setattr(M, "longest_balanced", lambda p, designs=((),): {"ratio": 1.10})
    out = tmp_path / "bench.json"
    assert main(["bench", "--only", "control", "--json", str(out)]) == 1  # two goals missed
    got = json.loads(out.read_text())
    assert got == {"nominal_balance_settle_s": 0.7, "nominal_swingup_catch_s": 0.93, "nominal_swingup_settle_s": 1.55,
                   "matrix_runs_passing": 50, "longest_rod_ratio": 1.1}
    lines = {line.split()[0]: line for line in capsys.readouterr().out.splitlines() if line.strip()}
    assert " ok " in lines["nominal_balance_settle_s"] and "MISSED" in lines["longest_rod_ratio"]
    assert "MISSED" in lines["matrix_runs_passing"] and "(goal >= 1.3 x L_crit)" in lines["longest_rod_ratio"]


def test_control_quick_skips_the_matrix_and_the_longest_rod(monkeypatch):
    from rodctl.bench import control

    monkeypatch.setattr(M, "run_case", lambda params, case, task, **kw: {"settle_s": None, "caught_at_s": None})
    got = control.measure(quick=True)
    assert set(got) == {"nominal_balance_settle_s", "nominal_swingup_catch_s", "nominal_swingup_settle_s"}
    assert got["nominal_balance_settle_s"] == float("inf")  # never settled reads as a miss, not a crash
