"""The project's performance goals and how each is measured (`rodctl bench`): instruction counts,
real-time factors, rates. Scratch files (a long log, a rendered clip) go under rodctl.paths.BUILD."""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from rodgains.errors import UserError

# key: (goal, "<=" or ">=", unit, what)
GOALS = {
    "gains_seconds_n5": (3.0, "<=", "s", "`rodctl gains` for N = 5, wall time with interpreter start"),
    "gains_seconds_n20": (10.0, "<=", "s", "`rodctl gains` for N = 20, wall time with interpreter start"),
    "m4_step_instructions_n5": (2000, "<=", "instr", "one control step + its telemetry frame, Cortex-M4F, N = 5"),
    "m4_step_instructions_n20": (15000, "<=", "instr", "the same, N = 20"),
    "m4_step_instructions_default": (None, "", "instr", "the same, the committed header's N (rod.edges)"),
    "m4_step_instructions_imu": (30000, "<=", "instr", "the same with the tip IMU (sensors.tip_imu), default N: "
                                 "a quarter of the 1 ms period at 120 MHz"),
    "m4_core_flash_bytes": (None, "", "B", "portable core flash (text + data), the committed header"),
    "m4_core_ram_bytes": (None, "", "B", "portable core RAM (data + bss), the committed header"),
    "sil_realtime_factor_n5": (1000, ">=", "x", "SIL firmware + N = 5 inextensible plant at 1 kHz"),
    "sil_realtime_factor_n20": (50, ">=", "x", "SIL firmware (N = 20) + N = 20 inextensible plant at 1 kHz"),
    "sil_realtime_factor_der20": (50, ">=", "x", "SIL firmware (N = 20) + N = 20 extensible (DER) plant"),
    "host_decode_frames_per_s": (1e6, ">=", "frames/s", "vectorized decoder (link/batch.py), N = 5 telemetry"),
    "host_stream_decode_frames_per_s": (100000, ">=", "frames/s", "streaming protocol.Decoder, N = 5 telemetry"),
    "host_log_read_frames_per_s": (1e6, ">=", "frames/s", "read_log of a 1,000,000-frame CSV log (200,000 with --quick), the plot's columns"),
    "plot_log_mb_per_s": (None, "", "MB/s", "`rodctl plot` of that log (210 MB) to PNG, log MB per wall second (a process)"),
    "plot_peak_memory_mb": (1000, "<=", "MB", "peak resident memory of that `rodctl plot` process"),
    "robustness_runs_per_s_per_core": (None, "", "runs/s", "matrix runs (both tasks) on one local worker"),
    "robustness_scaling_1_to_2_workers": (1.7, ">=", "x", "matrix runs/s with 2 local workers / with 1"),
    "robust_design_seconds": (None, "", "s", "`rodctl gains --set design.method=robust` from an empty design cache, "
                              "wall time with interpreter start (the refinement and its large-signal guard)"),
    "nominal_balance_settle_s": (1.5, "<=", "s", "faithful plant (1 deg of play), from 30 deg, every link within 1 deg"),
    "nominal_balance_final_deg": (1.0, "<=", "deg", "its largest link deviation over the last 0.5 s"),
    "nominal_swingup_catch_s": (5.0, "<=", "s", "faithful plant, swing-up from rest to the catch"),
    "low_supply_swingup_catch_s": (5.0, "<=", "s", "the same on a 10 V supply, the firmware made for 12 V: the stall "
                                   "watch lifts the swing past the steady 147 deg it stalls at (docs/control.md)"),
    "nominal_swingup_settle_s": (2.0, "<=", "s", "faithful plant, every link within 1 deg after the catch"),
    "nominal_swingup_final_deg": (1.0, "<=", "deg", "its largest link deviation over the last 0.5 s"),
    "balanced_torque_rms_mNm": (20.0, "<=", "mN m", "RMS torque over the last 4 s of the nominal swing-up (docs/control.md)"),
    "matrix_runs_passing": (None, "", "runs", "robustness matrix on the faithful plant (docs/control.md)"),
    "matrix_runs": (None, "", "runs", "runs in the robustness matrix"),
    "backlash3_final_deg": (3.0, "<=", "deg", "3 deg of gearbox play: the larger final deviation of the two tasks"),
    "zero_place_worst_final_deg": (3.0, "<=", "deg", "the boot zero at six places within its count (0 to 0.27 deg), "
                                   "1 deg of play: the largest final deviation of the nominal balance and swing-up"),
    "track_720p_frames_per_s": (120.0, ">=", "frames/s", "`rodctl track`'s pass over a 720p video (decode, markers, repeats)"),
    "longest_rod_ratio": (1.3, ">=", "x L_crit", "longest rod held within 3 deg from 10 deg on the faithful plant, design redone per length"),
    "longest_rod_ratio_imu": (1.3, ">=", "x L_crit", "the same with the tip IMU (issue 35)"),
    "longest_rod_ratio_imu_no_play": (1.3, ">=", "x L_crit", "the same with the tip IMU, no play in the gearbox, held upright"),
    "imu_own_design_e_minus15_final_deg": (3.0, "<=", "deg", "Young's modulus -15 % (1.013 x L_crit with the IMU's mass), the tip IMU and a design "
                                           "for that rod: the larger final deviation of the two tasks"),
    "imu_own_design_rho_plus15_final_deg": (3.0, "<=", "deg", "the same for density +15 %"),
    "curved_own_design_within_4deg_s": (5.0, "<=", "s", "the matrix's curved rod (0.82 1/m), released 30 deg off, a "
                                        "file that gives its curvature: simulated time from which it stays within 4 deg"),
}
GROUPS = ("gains", "m4", "sil", "host", "robust", "control", "track")


def _gains_seconds(edges: int, repeats: int = 3) -> float:
    return statistics.median(_gains_wall(["--set", f"rod.edges={edges}"], f"gains-n{edges}-{i}") for i in range(repeats))


def _robust_design_seconds() -> float:
    """One robust refinement of the default file from an empty design cache (design_cache.py)."""
    with tempfile.TemporaryDirectory(prefix="rodctl-bench-cache-") as cache:
        return _gains_wall(["--set", "design.method=robust"], "gains-robust", {"RODGAINS_CACHE_DIR": cache})


def _gains_wall(args: list[str], name: str, env: dict[str, str] | None = None) -> float:
    """Wall time [s] of `rodctl gains ARGS --json` in a new interpreter, its JSON in a scratch folder."""
    with tempfile.TemporaryDirectory(prefix="rodctl-bench-") as tmp:
        t0 = time.perf_counter()
        r = subprocess.run([sys.executable, "-m", "rodctl.cli", "gains", *args, "--json", str(Path(tmp) / f"{name}.json")],
                           capture_output=True, text=True, env=None if env is None else {**os.environ, **env})
        wall = time.perf_counter() - t0
    if r.returncode != 0:
        raise UserError(f"rodctl gains failed: {r.stderr.strip()}")
    return wall


def _sil_factor(edges: int, kind: str, seconds: float) -> float:
    from rodgains.params import load_params

    from rodctl.build.sil_build import build_sil
    from rodctl.sim.plant import Plant, measure_realtime_factor

    p = load_params(overrides=[f"rod.edges={edges}"])
    plant = Plant(p, kind=kind, edges=edges, input_mode="duty")
    return float(measure_realtime_factor(plant, build_sil(p), seconds=seconds, repeats=5, arm_mode=2)["factor"])


def measure(groups: set[str], quick: bool = False) -> dict:
    out: dict[str, float] = {}
    if "gains" in groups:
        out["gains_seconds_n5"] = round(_gains_seconds(5), 3)
        out["gains_seconds_n20"] = round(_gains_seconds(20), 3)
    if "m4" in groups:
        from rodctl.bench import m4 as bench_m4

        out.update(bench_m4.measure())
    if "sil" in groups:
        secs = 2.0 if quick else 10.0
        out["sil_realtime_factor_n5"] = round(_sil_factor(5, "inextensible", secs), 1)
        out["sil_realtime_factor_n20"] = round(_sil_factor(20, "inextensible", secs), 1)
        out["sil_realtime_factor_der20"] = round(_sil_factor(20, "der", secs), 1)
    if "robust" in groups:
        from rodctl.bench import robust as bench_robust

        out.update(bench_robust.measure(quick=quick))
        out["robust_design_seconds"] = round(_robust_design_seconds(), 1)
    if "control" in groups:
        from rodctl.bench import control as bench_control

        out.update(bench_control.measure(quick=quick, say=lambda text: print(f"  control: {text}", file=sys.stderr,
                                                                             flush=True)))
    if "track" in groups:
        from rodctl.bench import track as bench_track

        out.update(bench_track.measure(quick=quick))
    if "host" in groups:
        from rodctl.bench.protocol import measure_decode_rate

        from rodctl.bench import logs as bench_logs

        out["host_stream_decode_frames_per_s"] = round(measure_decode_rate(seconds=0.5 if quick else 2.0))
        out.update(bench_logs.measure(quick=quick))
    return out


def verdict(key: str, value: float) -> str:
    goal, op, _, _ = GOALS[key]
    if goal is None:
        return ""
    ok = value <= goal if op == "<=" else value >= goal
    return "ok" if ok else "MISSED"
