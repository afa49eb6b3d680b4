"""What the rig of a parameter file should do under the check's torque pulses: the firmware's own
IDENTIFY (SIL) against the faithful plant of those parameters, gearbox included."""

from __future__ import annotations

import numpy as np

from rodctl.ident.experiments import Experiment
from rodctl.link import protocol as P

PULSE_HOLD_S = 0.15  # each level of +A, 0, -A, 0 [s]
PULSE_PEAK_DEG = 20.0  # the model's largest excursion the pulses aim for [deg]
PULSE_MIN_NM, PULSE_MAX_SHARE = 0.005, 0.5  # amplitude floor [N m]; ceiling as a share of the torque limit


def pulse(amplitude: float) -> Experiment:
    """+A, 0, -A, 0, each PULSE_HOLD_S: the motor step's excitation [N m]."""
    return Experiment("check-pulse", int(P.Excitation.STEPS), float(amplitude), 4 * PULSE_HOLD_S, PULSE_HOLD_S)


def _predict(params, amplitude: float) -> np.ndarray:
    from rodctl.build.sil_build import build_sil
    from rodctl.ident.experiments import run_sil
    from rodctl.sim.plant import SilController, faithful_plant

    rec = run_sil(pulse(amplitude), SilController(build_sil(params)), faithful_plant(params, input_mode="duty"))
    return rec.count.astype(float) - float(rec.count[0])


_PLANNED: dict[str, tuple[float, np.ndarray]] = {}


def _planned(params) -> tuple[float, np.ndarray]:
    key = params.sha256()
    if key not in _PLANNED:
        _PLANNED[key] = _plan(params)
    return _PLANNED[key]


def _plan(params) -> tuple[float, np.ndarray]:
    probe = 0.02
    counts = _predict(params, probe)
    peak_deg = float(np.max(np.abs(counts))) * 360.0 / float(params.counts_per_rev)
    limit = float(params["safety"]["torque_limit"])
    amp = probe * PULSE_PEAK_DEG / peak_deg if peak_deg > 0 else probe
    amp = round(float(np.clip(amp, PULSE_MIN_NM, PULSE_MAX_SHARE * limit)), 4)  # whole 0.1 mN m
    return amp, (counts if amp == probe else _predict(params, amp))


def planned_pulse(params) -> tuple[Experiment, np.ndarray]:
    """The pulse for this rig (sized for a PULSE_PEAK_DEG excursion on its model) and the model's count
    trace under it, one entry per control period, relative to the first."""
    amp, counts = _planned(params)
    return pulse(amp), counts
