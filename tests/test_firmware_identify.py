"""IDENTIFY mode: each excitation's torque profile as the firmware plays it (SIL), its end, its
refusals and its safety limits."""

from __future__ import annotations

import math

import numpy as np
import pytest

from firmware_sil import ACK, MODE, REASON, Dev, Sil, count_of
from rodctl.link import protocol as P

CHIRP, PRBS, STEPS, RELEASE, SETTLE = 1, 2, 3, 4, 5
DT = 1e-3


def play(sil: Sil, count: int = 0, limit: int = 100000) -> tuple[np.ndarray, list[int], list[int]]:
    """Step at a fixed count until IDENTIFY ends: torques, driver enables, modes (one per period)."""
    u, en, modes = [], [], []
    for _ in range(limit):
        u.append(sil.step(count))
        en.append(sil.enable)
        modes.append(sil.mode)
        if sil.mode != MODE["IDENTIFY"]:
            break
    return np.array(u), en, modes


def started(**kw) -> Sil:
    sil = Sil()
    assert sil.identify(**kw) == ACK["OK"]
    assert sil.mode == MODE["IDENTIFY"]
    return sil


def test_chirp_is_a_linear_sweep_from_f0_to_f1_and_ends_disarmed():
    amp, dur, f0, f1 = 0.02, 2.0, 1.0, 20.0
    u, en, modes = play(started(excitation=CHIRP, amplitude=amp, duration=dur, shape1=f0, shape2=f1))
    n = round(dur / DT)
    assert len(u) == n + 1 and modes[-1] == MODE["DISARMED"] and u[-1] == 0.0 and en[-1] == 0
    t = np.arange(n) * DT
    expect = amp * np.sin(2 * np.pi * (f0 * t + (f1 - f0) * t ** 2 / (2 * dur)))
    assert np.max(np.abs(u[:n] - expect)) < 0.002 * amp  # float phase, wrapped every period
    assert np.max(np.abs(u[:n])) == pytest.approx(amp, rel=1e-3)
    assert all(en[:n])


def test_prbs_is_the_lfsr_sequence_held_one_bit_time():
    amp, bit, seed = 0.015, 0.02, 0xACE1
    u, en, _ = play(started(excitation=PRBS, amplitude=amp, duration=1.0, shape1=bit, seed=seed))
    bits, lfsr = [], seed
    for _ in range(50):  # Galois LFSR x^16 + x^14 + x^13 + x^11 + 1
        lsb = lfsr & 1
        lfsr = (lfsr >> 1) ^ (0xB400 if lsb else 0)
        bits.append(amp if lsb else -amp)
    expect = np.repeat(bits, round(bit / DT))
    np.testing.assert_allclose(u[:1000], np.float32(expect), rtol=1e-6)
    assert len(set(np.round(u[:1000], 6))) == 2 and all(en[:1000])


def test_steps_hold_plus_zero_minus_zero():
    amp, hold = 0.01, 0.05
    u, _, _ = play(started(excitation=STEPS, amplitude=amp, duration=0.4, shape1=hold))
    levels = u[:400].reshape(8, 50)
    assert np.all(levels == levels[:, :1])  # each level held for the whole hold time
    np.testing.assert_allclose(levels[:, 0], np.float32(amp) * np.array([1, 0, -1, 0, 1, 0, -1, 0]))


def test_release_is_a_pulse_then_zero_torque_with_the_driver_still_enabled():
    amp, pulse = 0.03, 0.1
    u, en, modes = play(started(excitation=RELEASE, amplitude=amp, duration=0.5, shape1=pulse))
    np.testing.assert_allclose(u[:100], np.float32(amp))
    assert np.all(u[100:500] == 0.0)
    assert all(en[:500]), "the free swing keeps the driver enabled (back-EMF compensated zero current)"
    assert modes[499] == MODE["IDENTIFY"] and modes[500] == MODE["DISARMED"] and en[500] == 0


def test_settle_is_a_sine_fading_linearly_to_nothing():
    """The move between experiments: its strokes shrink each cycle, so the last ones are too weak to
    move the rod against the dry friction."""
    amp, dur, f = 0.01, 4.0, 0.5
    u, en, modes = play(started(excitation=SETTLE, amplitude=amp, duration=dur, shape1=f))
    n = round(dur / DT)
    assert len(u) == n + 1 and modes[-1] == MODE["DISARMED"] and u[-1] == 0.0 and all(en[:n])
    t = np.arange(n) * DT
    expect = amp * (1 - t / dur) * np.sin(2 * np.pi * f * t)
    assert np.max(np.abs(u[:n] - expect)) < 1e-3 * amp
    peaks = [np.max(np.abs(u[k:k + 1000])) for k in range(0, n, 1000)]  # each half cycle's stroke [N m]
    assert peaks[0] > 0.85 * amp and all(np.diff(peaks) < -0.2 * amp) and peaks[-1] < 0.15 * amp


def test_zero_torque_while_moving_drives_the_back_emf_not_a_short():
    sil = started(excitation=RELEASE, amplitude=0.01, duration=1.0, shape1=0.001)
    for k in range(200):
        sil.step(k // 4)  # theta_1 rising steadily: a positive base rate
    shaft_rad_s = sil.rate  # the firmware's estimate of the simulated shaft's angular rate, not a wall-clock speed
    assert sil.mode == MODE["IDENTIFY"] and shaft_rad_s > 1.0
    assert sil.duty > 0.0  # the duty cancels the back-EMF so no braking current flows


@pytest.mark.parametrize("kw", [
    dict(excitation=CHIRP, amplitude=0.3, duration=1.0, shape1=1.0, shape2=2.0),     # above the torque limit
    dict(excitation=CHIRP, amplitude=0.0, duration=1.0, shape1=1.0, shape2=2.0),
    dict(excitation=CHIRP, amplitude=0.01, duration=1.0, shape1=2.0, shape2=1.0),    # f1 < f0
    dict(excitation=CHIRP, amplitude=0.01, duration=1.0, shape1=1.0, shape2=600.0),  # beyond Nyquist
    dict(excitation=PRBS, amplitude=0.01, duration=1.0, shape1=0.0),
    dict(excitation=STEPS, amplitude=0.01, duration=1.0, shape1=2.0),               # hold longer than the run
    dict(excitation=RELEASE, amplitude=0.01, duration=1.0, shape1=1.0),             # no free swing left
    dict(excitation=RELEASE, amplitude=0.01, duration=float("nan"), shape1=0.1),
    dict(excitation=SETTLE, amplitude=0.01, duration=1.0, shape1=0.0),             # no frequency
    dict(excitation=SETTLE, amplitude=0.01, duration=1.0, shape1=501.0),           # beyond Nyquist
    dict(excitation=CHIRP, amplitude=0.01, duration=700.0, shape1=1.0, shape2=2.0),
    dict(excitation=9, amplitude=0.01, duration=1.0, shape1=0.1),
])
def test_out_of_range_requests_are_refused_and_change_nothing(kw):
    sil = Sil()
    assert sil.identify(**kw) == ACK["BAD_VALUE"]
    assert sil.mode == MODE["DISARMED"] and sil.step(0) == 0.0 and sil.enable == 0


def test_refused_while_armed_or_faulted():
    sil = Sil()
    assert sil.arm(2) == ACK["OK"]
    assert sil.identify(excitation=RELEASE, amplitude=0.01, duration=1.0, shape1=0.1) == ACK["BAD_STATE"]
    assert sil.mode == MODE["SWING_UP"]
    sil = started(excitation=RELEASE, amplitude=0.01, duration=1.0, shape1=0.1)
    sil.step(count_of(math.radians(90)))
    assert sil.mode == MODE["FAULT"]
    assert sil.identify(excitation=RELEASE, amplitude=0.01, duration=1.0, shape1=0.1) == ACK["BAD_STATE"]


def test_angle_limit_is_measured_from_hanging():
    sil = started(excitation=RELEASE, amplitude=0.01, duration=5.0, shape1=0.1)
    limit = sil.p["safety"]["angle_limit_deg"]
    for deg in np.linspace(0, limit - 1, 50):
        sil.step(count_of(math.radians(deg)))
    assert sil.mode == MODE["IDENTIFY"]
    u = sil.step(count_of(math.radians(limit + 1)))
    assert (sil.mode, sil.reason, sil.enable, u) == (MODE["FAULT"], REASON["ANGLE_LIMIT"], 0, 0.0)


def test_speed_limit_trips_identify():
    sil = started(excitation=CHIRP, amplitude=0.01, duration=5.0, shape1=1.0, shape2=2.0)
    speed = sil.p["safety"]["speed_limit"] * 1.5
    for k in range(40):
        sil.step(count_of(math.radians(-10) + speed * DT * k))
        if sil.mode == MODE["FAULT"]:
            break
    assert (sil.mode, sil.reason, sil.enable) == (MODE["FAULT"], REASON["SPEED_LIMIT"], 0)


def test_identify_over_the_protocol_needs_heartbeats():
    dev = Dev()
    dev.run(2)
    seq = dev.send(P.encode_identify, P.Excitation.CHIRP, 0, 0.01, 10.0, 1.0, 5.0)
    dev.step()
    acks = [f.msg for f in dev.frames() if f.type == P.MsgType.ACK]
    assert [(a.command_seq, a.result, a.mode) for a in acks] == [(seq, P.AckResult.OK, P.Mode.IDENTIFY)]
    timeout = dev.p["safety"]["heartbeat_timeout"]
    dev.run(round(timeout / DT) + 5)
    assert (dev.mode, dev.reason, dev.enable) == (MODE["FAULT"], REASON["HEARTBEAT"], 0)


def test_identify_telemetry_reports_mode_and_torque():
    dev = Dev()
    dev.send(P.encode_identify, P.Excitation.RELEASE, 0, 0.02, 0.05, 0.02, 0.0)
    for _ in range(60):
        dev.step()
        dev.send(P.encode_heartbeat)
    tlm = [f.msg for f in dev.frames() if f.type == P.MsgType.TELEMETRY]
    modes = [t.mode for t in tlm]
    assert P.Mode.IDENTIFY in modes and modes[-1] == P.Mode.DISARMED and tlm[-1].reason == P.Reason.NONE
    torques = [t.torque for t in tlm if t.mode == P.Mode.IDENTIFY]
    assert torques[:20] == [pytest.approx(0.02)] * 20 and torques[-1] == 0.0
