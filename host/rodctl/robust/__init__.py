"""Robustness score, automatic tuning and design sweeps over SIL runs (rodctl robustness / tune / sweep).

uncertainty: seeded Monte Carlo plants; score: the runs of a score, the fraction passing and its
tie-break margin; execute: the work-unit runner (local process pool, or a Dask cluster); tune: the
Optuna search; sweep: grids and their runs; figures: the heatmap and the frontier; output:
whole-or-nothing files.
Bad input raises rodgains.errors.InputError (one line, exit 2).
"""
