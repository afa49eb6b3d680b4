"""One scenario run of `rodctl sim`: the simulation, its figure, and its logs in the device log format
with the simulator's true angles beside each (LOG.truth.csv)."""

from __future__ import annotations

import re
import time
from pathlib import Path
from typing import Callable

import numpy as np

from rodgains.errors import UserError
from rodgains.params import Params


def truth_name(log: Path) -> Path:
    """The simulator's true angles beside a log: LOG.truth.csv."""
    return log.with_name(log.stem + ".truth.csv")


def check_new_log(log: Path) -> None:
    """InputError when writing the log `log` would replace a file: the log's own files or its truth file."""
    from rodctl.logs.writer import check_new

    check_new(log, also=(truth_name(log),))


_NAN = float("nan")


def write_log(o, trace, path: Path) -> tuple[Path, Path]:
    """The trace in the device log format (rodctl.logs.LogWriter), plus the true state beside it. With the tip IMU
    its columns hold the sample each step read; the estimator's gyro bias and encoder offset are NaN (a virtual
    board's log, `rodctl log --port sim://?params=...`, has them)."""
    from rodctl import logs as logfile
    from rodctl.logs.writer import LogWriteFailed, files_of
    from rodctl.link import protocol as P

    p = o.params
    firmware = trace.est is not None
    n = trace.est.shape[1] // 2 if firmware else trace.theta.shape[1]
    meta = logfile.simulator_metadata(p, n=n, source=f"simulator: rodctl sim --scenario {o.name} ({trace.label}"
                                      + ("" if firmware else "; state feedback, theta_hat is the true state") + ")")
    period_us = int(round(p.dt * 1e6))
    w = logfile.LogWriter(path, meta, n=n, overwrite=True)  # the caller has checked the log against --force
    written = files_of(path)
    try:
        est = trace.est if firmware else np.hstack([trace.theta, np.zeros_like(trace.theta)])
        mode = trace.mode if trace.mode is not None else np.full(len(trace.t), 1)
        duty = trace.duty if trace.duty is not None else np.zeros(len(trace.t))
        count = trace.count if trace.count is not None else np.zeros(len(trace.t), int)
        # the firmware's command, as a board's telemetry carries it (the torque the rod received is the metrics')
        torque = trace.torque_cmd if trace.torque_cmd is not None else trace.torque
        # the board's f32, as its telemetry carries them: every log format then holds the same values
        est, duty, torque = (np.asarray(a, np.float32).astype(float) for a in (est, duty, torque))
        imu = None if trace.imu is None else np.asarray(trace.imu, np.float32).astype(float)
        step = 1 if imu is None else 2  # a board with the IMU sends an IMU frame after each telemetry frame
        for k in range(len(trace.t)):
            m = int(mode[k])
            reason = trace.reason if m == 3 else 0
            enabled = m in (1, 2)
            msg = P.Telemetry(m, reason, (1 if enabled else 0) | 4, n, int(count[k]), float(est[k, n]),
                              float(torque[k]), float(duty[k]), 0, 0, 0, 0,
                              tuple(est[k, :n].tolist()), tuple(est[k, n:].tolist()))
            time_us = (k * period_us) & 0xFFFFFFFF
            w.write_telemetry(msg, seq=step * k, time_us=time_us, host_time_s=float(trace.t[k]))
            if imu is not None:  # the sample the step read; the estimator's bias and offset are the board's alone
                fresh = bool(np.isfinite(imu[k]).all())
                w.write_imu(P.Imu(*imu[k].tolist(), _NAN, _NAN, int(P.ImuFlag.FRESH) if fresh else 0,
                                  0 if fresh else 1), seq=step * k + 1, time_us=time_us, host_time_s=float(trace.t[k]))
        w.close()
        truth = truth_name(path)
        written.append(truth)
        N = trace.theta.shape[1]
        header = "time_s," + ",".join(f"theta_{i + 1}_rad" for i in range(N))
        np.savetxt(truth, np.column_stack([trace.t, trace.theta]), delimiter=",", header=header, comments="",
                   fmt="%.9g")
    except BaseException as e:  # a run can be run again: its log is all or nothing, not a live log's first rows
        w.discard()
        for f in written:
            f.unlink(missing_ok=True)
        if isinstance(e, LogWriteFailed) and w.failure is not None:
            raise w.failure from None  # the system's refusal, not the live log's "keeps its first rows"
        raise
    return path, truth


def run_and_write(name: str, params: Params, *, plot: Path | None, log: Path | None, keep_log: bool = False,
                  duration: float | None = None, progress: Callable[[str, float], None] | None = None,
                  finished: Callable[[], None] = lambda: None):
    """Run the scenario `name`, then write its figure `plot` and its log `log` (None: not written).

    The caller has checked both paths before the run. keep_log: an existing log is never replaced (an
    explicit --log without --force); a run of several traces writes a log for each, LOG-LABEL.EXT, and
    checks them once their names are known. duration: simulated time [s] (None: the scenario's).
    progress(label, fraction) during the run; finished() when it ends, before anything is written.
    Returns (outcome, wall time [s], the files written).
    """
    from rodctl.sim.scenarios import Options, SCENARIOS

    scen = SCENARIOS[name]
    t0 = time.monotonic()
    try:
        o = scen.run(Options(params, progress=progress, duration=duration))
    finally:
        finished()
    wall = time.monotonic() - t0
    logs = []  # (trace, path): a run of several traces writes a log for each, named by its label
    if log is not None:
        traces = o.traces
        logs = [(traces[0], log)] if len(traces) == 1 else [
            (tr, log.with_name(f"{log.stem}-{re.sub(r'[^A-Za-z0-9.]+', '-', tr.label).strip('-')}{log.suffix}"))
            for tr in traces]
        if len(traces) > 1 and keep_log:  # known once run; checked before anything is written
            for _, path in logs:
                check_new_log(path)
    written = []
    try:
        if plot is not None:
            from rodctl.sim.figures import save

            written.append(str(plot))
            save(o, plot)
        for tr, path in logs:
            written += [str(f) for f in write_log(o, tr, path)]
    except BaseException as e:  # all or nothing: no figure left beside a log that is not there
        for f in written:
            Path(f).unlink(missing_ok=True)
        if isinstance(e, OSError):
            from rodctl.logs.writer import refused_text

            names = ([str(plot)] if plot is not None else []) + [str(path) for _, path in logs]
            raise UserError(f"{refused_text(e)}: the run's files were not written ({', '.join(names)}); "
                            "free space or choose another folder, and run it again") from None
        raise
    return o, wall, written
