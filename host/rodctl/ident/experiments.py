"""Identification experiments: what the board plays (IDENTIFY), and the records they leave.

An experiment is one IDENTIFY command: the board computes the excitation itself, so the torque the
log shows is exactly what was played, period by period. A Record is the part of a telemetry log
(or of a SIL run) spent in mode IDENTIFY: one row per control period with the encoder count and
the duty and torque that were held over that period.

The default sequence keeps the rod near hanging (the firmware's angle limit is measured from
hanging in IDENTIFY) and gives every fitted parameter something to see:
  release  a short push, then a free swing with the driver on at zero current: the pendulum and
           bending modes and their decay (rod stiffness, damping, inertia ratio);
  chirp    a sweep through the pendulum and first bending frequencies (inertia, stiffness);
  prbs     broadband +-amplitude (inertia, viscous friction, torque constant);
  steps    +A, 0, -A, 0 levels: velocity reversals and coasting (Coulomb against viscous friction).

Before each experiment but the first the board plays `settle_move`, which is not fitted: a slow push to and fro that
fades out, so that every record starts with the rod at rest near hanging. Without it a record starts
where the last left the rig: the rod rattling in the gearbox's play, which the motor's encoder cannot
see, or held off hanging and bent by the motor's dry friction (docs/identification.md).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from rodgains.errors import InputError, UserError

from rodctl.link import protocol as P

MODE_IDENTIFY = int(P.Mode.IDENTIFY)


@dataclass(frozen=True)
class Experiment:
    name: str
    excitation: int  # P.Excitation code
    amplitude: float  # [N m] at the output shaft
    duration: float  # [s]
    shape1: float  # chirp f0 [Hz] | PRBS bit time [s] | step hold [s] | release pulse [s]
    shape2: float = 0.0  # chirp f1 [Hz]
    seed: int = 0  # PRBS LFSR start state

    def describe(self) -> str:
        """What the motor will do, in words, before it does it."""
        a = f"{self.amplitude * 1e3:g} mN m"
        e = P.Excitation(self.excitation)
        if e == P.Excitation.CHIRP:
            what = f"a torque sine of {a} sweeping {self.shape1:g} -> {self.shape2:g} Hz"
        elif e == P.Excitation.PRBS:
            what = f"a random +-{a} torque switching every {self.shape1 * 1e3:g} ms"
        elif e == P.Excitation.STEPS:
            what = f"torque steps +{a}, 0, -{a}, 0 held {self.shape1 * 1e3:g} ms each"
        elif e == P.Excitation.SETTLE:
            what = f"a {a} push to and fro at {self.shape1:g} Hz, fading out, to leave the rod at rest"
        else:
            what = f"a {a} push for {self.shape1 * 1e3:g} ms, then zero torque (driver on) while the rod swings freely"
        return f"{self.name}: {what}, {self.duration:.3g} s"

    def command(self):
        return P.MESSAGE_CLASSES[P.MsgType.IDENTIFY](excitation=self.excitation, seed=self.seed,
                                                     amplitude=self.amplitude, duration=self.duration,
                                                     shape1=self.shape1, shape2=self.shape2)

    def scaled(self, torque: float = 1.0, time: float = 1.0) -> "Experiment":
        """The same experiment with the amplitude and the duration scaled (shorter runs for tests)."""
        return replace(self, amplitude=self.amplitude * torque, duration=self.duration * time)


# Amplitudes for the Table I rod on the testbed motor: a static 60 mN m holds the 0.1 kg rod about
# 50 deg out, so every experiment stays inside the 60 deg angle limit from hanging with margin.
DEFAULT_SEQUENCE = (
    Experiment("release", int(P.Excitation.RELEASE), 0.05, 3.0, 0.12),
    Experiment("chirp", int(P.Excitation.CHIRP), 0.02, 4.0, 0.3, 8.0),
    Experiment("prbs", int(P.Excitation.PRBS), 0.025, 2.5, 0.03, 0.0, 0xACE1),
    Experiment("steps", int(P.Excitation.STEPS), 0.025, 3.0, 0.5),
)
EXPERIMENTS = {e.name: e for e in DEFAULT_SEQUENCE}


# The settle move: well below the pendulum's frequency (about 1.4 Hz for Table I's rod, the header's
# ROD_SWING_OMEGA0_RAD_S), so the rod follows the push; each stroke leaves it nearer hanging once the push no longer beats the dry
# friction, and the last strokes are too weak to move it.
SETTLE_HZ = 0.3
SETTLE_CYCLES = 5
SETTLE_FRICTION_MULTIPLE = 2.0  # its first strokes: this many times the file's dry friction ...
SETTLE_MIN_NM = 0.01  # ... and at least this much


def settle_move(params) -> Experiment:
    """The move that brings the rig to rest near hanging before an experiment, for this file's rig."""
    amp = max(SETTLE_MIN_NM, SETTLE_FRICTION_MULTIPLE * float(params["motor"]["coulomb_friction"]))
    return Experiment("settle", int(P.Excitation.SETTLE), amp, SETTLE_CYCLES / SETTLE_HZ, SETTLE_HZ)


def select(names: list[str] | None) -> list[Experiment]:
    if not names:
        return list(DEFAULT_SEQUENCE)
    out = []
    for n in names:
        if n not in EXPERIMENTS:
            raise InputError(f"--experiment {n}: unknown; choose from {', '.join(EXPERIMENTS)}")
        if EXPERIMENTS[n] in out:
            # its log is named after it: the second run would stop, motor already moved, on the first's log
            raise InputError(f"--experiment {n}: given twice; each experiment runs once")
        out.append(EXPERIMENTS[n])
    return out


@dataclass
class Record:
    """One IDENTIFY run, one row per control period k (the count read at t_k; duty and torque held
    over [t_k, t_k + period])."""

    name: str
    period: float  # [s]
    count: np.ndarray  # encoder counts (0 hanging at power-on)
    duty: np.ndarray  # signed duty [-1, 1]
    torque: np.ndarray  # commanded output torque [N m]
    rate: np.ndarray  # the firmware's base rate [rad/s]
    end_reason: int = 0  # P.Reason after the run (NONE: played to the end)
    ended_in: int = 0  # P.Mode after the run
    source_sha256: str = ""  # SHA-256 of the log file it came from (or of its arrays)
    notes: list[str] = field(default_factory=list)

    @property
    def seconds(self) -> float:
        return len(self.count) * self.period

    def digest(self) -> str:
        if not self.source_sha256:
            h = hashlib.sha256()
            for a in (self.count, self.duty, self.torque):
                h.update(np.ascontiguousarray(a).tobytes())
            self.source_sha256 = h.hexdigest()
        return self.source_sha256


def file_sha256(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def records_from_rows(rows: np.ndarray, period: float, name: str, sha256: str) -> list[Record]:
    """The IDENTIFY runs of a log's rows (read_log): telemetry rows in mode IDENTIFY, split where the
    mode leaves IDENTIFY or a frame is missing (a lost frame would shift the replayed input)."""
    tlm = rows[rows["type_name"] == "TELEMETRY"] if "type_name" in (rows.dtype.names or ()) else rows
    if len(tlm) == 0:
        return []
    mode = np.asarray(tlm["mode_code"], np.int64)
    t_us = np.asarray(tlm["device_time_us"], np.int64)
    ident = mode == MODE_IDENTIFY
    out = []
    k, n = 0, len(tlm)
    while k < n:
        if not ident[k]:
            k += 1
            continue
        j = k + 1
        while j < n and ident[j] and (t_us[j] - t_us[j - 1]) % (1 << 32) == round(period * 1e6):
            j += 1
        after = j if j < n else None
        rec = Record(f"{name}[{len(out)}]" if out or j < n and ident[j:].any() else name, period,
                     np.asarray(tlm["encoder_count"][k:j], np.int64), np.asarray(tlm["duty_frac"][k:j], float),
                     np.asarray(tlm["torque_Nm"][k:j], float), np.asarray(tlm["base_rate_rad_s"][k:j], float),
                     end_reason=int(tlm["reason_code"][after]) if after is not None else 0,
                     ended_in=int(mode[after]) if after is not None else MODE_IDENTIFY,
                     source_sha256=sha256)
        if after is not None and ident[after]:
            rec.notes.append(f"telemetry gap after {j - k} periods (decimated or lost frames): split there")
        out.append(rec)
        k = j
    return out


RECORD_COLUMNS = ["mode_code", "device_time_us", "encoder_count", "duty_frac", "torque_Nm", "base_rate_rad_s",
                  "reason_code"]  # what records_from_rows reads


def records_from_log(path: str | Path, period: float | None = None, digest: str | None = None):
    """(the log as read_log reads it, its IDENTIFY records). digest: the file's file_sha256, if known."""
    from rodctl.logs import read_log

    log = read_log(path, columns=RECORD_COLUMNS)  # a log without one is "no column X", before the fit
    if period is None:
        period = float(log.meta.get("period_us", 1000)) * 1e-6
    return log, records_from_rows(log.data, period, Path(path).stem, digest or file_sha256(path))


# ---- the same experiment through the SIL (tests, benchmarks, `rodctl identify` acceptance) ----------


def run_sil(exp: Experiment, sil, plant) -> Record:
    """Play `exp` with the firmware's SIL library (rod_sil_identify) against `plant` (duty input), from
    the plant's current state; the record ends where IDENTIFY ends (end, or a safety trip)."""
    from rodctl.sim.plant import run_closed_loop

    import ctypes

    lib = sil.lib if hasattr(sil, "lib") else sil
    lib.rod_sil_identify.restype = ctypes.c_int
    lib.rod_sil_identify.argtypes = [ctypes.c_int, ctypes.c_float, ctypes.c_float, ctypes.c_float, ctypes.c_float,
                                     ctypes.c_int]
    lib.rod_sil_reason.restype = ctypes.c_int
    lib.rod_sil_rate.restype = ctypes.c_float
    lib.rod_sil_reset()
    ack = lib.rod_sil_identify(exp.excitation, exp.amplitude, exp.duration, exp.shape1, exp.shape2, exp.seed)
    if ack != 0:
        raise UserError(f"{exp.name}: the firmware refused the excitation ({P.AckResult(ack).name})")
    periods = int(round(exp.duration / plant.params.dt)) + 1
    log = run_closed_loop(plant, sil, periods, reset=False, stop_on_mode=None)
    ident = log["mode"] == MODE_IDENTIFY
    # mode[k] is the mode after step k: the steps that played the excitation are the IDENTIFY ones.
    k_end = int(np.argmin(ident)) if not ident.all() else len(ident)
    est = log["est"]
    return Record(exp.name, float(log["period"]), log["count"][:k_end].astype(np.int64),
                  log["duty"][:k_end].astype(float), log["torque_cmd"][:k_end].astype(float),
                  est[:k_end, -1].astype(float) if est.size else np.zeros(k_end),
                  end_reason=int(lib.rod_sil_reason()), ended_in=int(log["mode"][k_end]) if k_end < len(ident) else 5)


def run_sil_sequence(exps, sil, plant, params, rest: float) -> list[Record]:
    """Play `exps` one after the other on one plant, as `rodctl identify` does on a board: before each
    but the first, the settle move and `rest` seconds with the board disarmed."""
    from rodctl.sim.plant import run_closed_loop

    out = []
    for exp in exps:
        if out:
            run_sil(settle_move(params), sil, plant)
            run_closed_loop(plant, sil, int(round(rest / plant.params.dt)), reset=False)
        out.append(run_sil(exp, sil, plant))
    return out
