"""The faithful-rod control goals of issue 8, measured (deterministic simulations, not speeds):
nominal balance and swing-up on the faithful plant, the robustness matrix's pass count, and the
longest rod balanced from 10 deg as a ratio to the continuum critical length."""

from __future__ import annotations


def measure(quick: bool = False) -> dict[str, float]:
    from rodgains.params import load_params

    from rodctl.sim import matrix as M

    p = load_params()
    bal = M.run_case(p, M.CASES["nominal"], "balance")
    swing = M.run_case(p, M.CASES["nominal"], "swingup")
    inf = float("inf")
    out = {
        "nominal_balance_settle_s": round(bal["settle_s"] if bal["settle_s"] is not None else inf, 3),
        "nominal_swingup_catch_s": round(swing["caught_at_s"] if swing["caught_at_s"] is not None else inf, 3),
        "nominal_swingup_settle_s": round(swing["settle_s"] if swing["settle_s"] is not None else inf, 3),
    }
    if not quick:  # the whole matrix (52 runs) and the longest-rod walk: about a minute
        rows = M.run_matrix(p)
        out["matrix_runs_passing"] = sum(1 for r in rows if r["passed"])
        r = M.longest_balanced(p, designs=M.LONG_ROD_DESIGNS)
        out["longest_rod_ratio"] = r["ratio"] if r["ratio"] is not None else 0.0
    return out
