"""How fast the host reads and plots long logs, and with how much memory.

    python3 -m rodctl.bench.logs

A 1,000,000-frame N=5 CSV log (16.7 min at 1 kHz, a swing-up-like trace) is made once in
the build folder (rodctl.paths.BUILD), bench-log-1M.csv. Measured: read_log of the plot's columns [frames/s], `rodctl plot LOG --out
PNG` as a separate process [log MB per wall second] and that process's peak resident memory [MB],
and the vectorized telemetry decoder (link/batch.py) [frames/s].
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from rodctl import paths

FRAMES = 1_000_000


def make_log(path: Path, frames: int = FRAMES, n: int = 5) -> Path:
    """A CSV log (with sidecar and events) of `frames` telemetry rows, written with pyarrow (fast)."""
    import pyarrow as pa
    import pyarrow.csv as pc
    from rodgains.params import load_params

    from rodctl.logs import csvlog, schema
    from rodctl.logs.metadata import simulator_metadata

    if path.exists() and csvlog.sidecar_path(path).exists():
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(1)
    k = np.arange(frames)
    t = k * 1e-3
    swing = np.minimum(t / 5.0, 1.0) * np.pi
    cols = {}
    for name, d, _, _ in schema.columns(n):
        if name == "time_s":
            v = t
        elif name == "host_time_s":
            v = t + 0.003
        elif name in ("seq_count",):
            v = k
        elif name == "device_time_us":
            v = (k * 1000) % (1 << 32)
        elif name == "mode_code":
            v = np.where(t < 5, 2, 1)
        elif name == "mode_name":
            v = np.where(t < 5, "SWING_UP", "BALANCE")
        elif name == "reason_name":
            v = np.full(frames, "NONE")
        elif name.startswith("theta_hat_"):
            v = (swing * (1 + 0.5 * np.sin(2 * t)) + 0.01 * rng.standard_normal(frames)).astype(np.float32)
        elif d == "i8":
            v = np.zeros(frames, dtype=np.int64)
        else:
            v = (0.1 * rng.standard_normal(frames)).astype(np.float32)
        cols[name] = pa.array(v)
    pc.write_csv(pa.table(cols), path, write_options=pc.WriteOptions(quoting_style="none"))
    meta = simulator_metadata(load_params(), n=n, source="rodctl bench (synthetic)")
    csvlog.sidecar_path(path).write_text(json.dumps({"metadata": meta, "trailer": {"rows": str(frames)},
                                                     "columns": schema.units(n)}))
    csvlog.events_path(path).write_text(",".join(c[0] for c in schema.EVENT_COLUMNS) + "\n")
    return path


def read_rate(path: Path, frames: int, runs: int = 3) -> float:
    from rodctl.logs.plots import PLOT_COLUMNS
    from rodctl.logs.reader import read_log

    rates = []
    for _ in range(runs):
        t0 = time.perf_counter()
        log = read_log(path, columns=PLOT_COLUMNS)
        rates.append(len(log.data) / (time.perf_counter() - t0))
        assert len(log.data) == frames
        del log
    return statistics.median(rates)


def plot_process(path: Path, runs: int = 3) -> tuple[float, float]:
    """(log MB per wall second, peak RSS MB) of `rodctl plot LOG --out PNG`, medians."""
    out = path.with_suffix(".png")
    mb = path.stat().st_size / 1e6
    speeds, peaks = [], []
    env = dict(os.environ, MPLBACKEND="Agg")
    for _ in range(runs):
        t0 = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-m", "rodctl.cli", "plot", str(path), "--out", str(out), "--force"],
                                stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        proc.returncode = os.waitstatus_to_exitcode(status)
        if proc.returncode != 0:
            raise RuntimeError(f"rodctl plot failed: {proc.stderr.read().decode().strip()}")
        speeds.append(mb / wall)
        peaks.append(usage.ru_maxrss / 1024.0)  # kB on Linux
    return statistics.median(speeds), statistics.median(peaks)


def decode_rate(seconds: float = 2.0, n: int = 5) -> float:
    """Median frames/s of the vectorized decoder over 200,000-frame buffers."""
    from rodctl.bench.protocol import telemetry_stream
    from rodctl.link.batch import decode_telemetry

    blob = telemetry_stream(2000, n) * 100
    decode_telemetry(blob, n)
    rates = []
    t_end = time.perf_counter() + seconds
    while time.perf_counter() < t_end or len(rates) < 3:
        t0 = time.perf_counter()
        _, c = decode_telemetry(blob, n)
        rates.append(c["frames"] / (time.perf_counter() - t0))
    return statistics.median(rates)


def measure(quick: bool = False, build: Path = paths.BUILD) -> dict[str, float]:
    frames = 200_000 if quick else FRAMES
    path = make_log(build / f"bench-log-{frames // 1000}k.csv", frames)
    speed, peak = plot_process(path, runs=1 if quick else 3)
    return {
        "host_decode_frames_per_s": round(decode_rate(0.5 if quick else 2.0)),
        "host_log_read_frames_per_s": round(read_rate(path, frames, runs=1 if quick else 3)),
        "plot_log_mb_per_s": round(speed, 1),
        "plot_peak_memory_mb": round(peak),
    }


if __name__ == "__main__":
    print(json.dumps(measure(quick="--quick" in sys.argv), indent=1))
