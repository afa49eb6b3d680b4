"""The tip IMU on the hanging rod (`rodctl identify --imu`): the gyro's bias, the accelerometer's axes
against gravity, its mounting tilt, and the gyro's sign against the encoder under a hand's turn.

Hanging still, the rod's frame (x along the rod to the tip, y toward increasing theta) reads
accel = (-g, 0) and gyro = its bias. A part mounted at a tilt a in the swing plane reads
(-g cos a, g sin a): the tilt is atan2(accel_y, -accel_x), and it matters: the estimator takes the
accelerometer's y for the tip's lean from gravity, so an uncorrected 1 deg tilt holds the tip 1 deg off
upright (sensors.imu_tilt_deg removes it). A rod that is not straight at rest hangs with its tip edge
off vertical; that shows up here as tilt too (docs/sensors.md).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

G = 9.80665
GRAVITY_TOLERANCE = 0.1  # |accel| hanging within 10 % of g, or the part or its scale is wrong [-]
TILT_LIMIT_DEG = 10.0  # beyond this the part is mounted across the rod, not tilted on it
BIAS_LIMIT_RAD_S = 0.0175  # 1 dps: twice the ICM-42688-P's +-0.5 dps zero-rate output (the default part's sibling)
STILL_RMS_RAD_S = 0.02  # the gyro's spread at rest above this: the rod was moving, or the part is noisy


@dataclass
class ImuCalibration:
    gyro_bias_rad_s: float
    gyro_noise_rad_s: float
    gravity_m_s2: float
    tilt_deg: float  # the part's tilt on the rod: what the firmware turns back plus what is left [deg]
    gyro_gain: float | None = None  # the gyro's angle over the encoder's during the hand's turn (None: not measured)
    firmware_tilt_deg: float | None = 0.0  # what the firmware already turns back (None: its parameters unknown)
    problems: list[str] = field(default_factory=list)  # one line each: what is wrong and the fix

    @property
    def ok(self) -> bool:
        return not self.problems

    def lines(self) -> list[str]:
        fw = self.firmware_tilt_deg
        if fw is None:
            tilt = (f"mounting tilt {self.tilt_deg:+.2f} deg beyond what the firmware turns back (its parameters are "
                    "not known here: pass --params FILE to be told the value to set)")
        elif abs(self.tilt_deg) > TILT_LIMIT_DEG:
            tilt = f"mounting tilt {self.tilt_deg:+.2f} deg"
        else:
            tilt = (f"mounting tilt {self.tilt_deg:+.2f} deg"
                    + (f" ({self.tilt_deg - fw:+.2f} left after the firmware's {fw:+.2f})" if fw else "")
                    + f" (set sensors.imu_tilt_deg = {self.tilt_deg:.2f})")
        out = [f"gyro bias {math.degrees(self.gyro_bias_rad_s):+.3f} dps ({self.gyro_bias_rad_s * 1e3:+.2f} mrad/s), "
               f"noise {self.gyro_noise_rad_s * 1e3:.2f} mrad/s RMS at rest",
               f"gravity {self.gravity_m_s2:.3f} m/s^2, {tilt}"]
        if self.gyro_gain is not None:
            out.append(f"during the hand's turn the gyro's angle is {self.gyro_gain:+.2f} x the encoder's "
                       "(the same sense; a soft rod's tip droops behind its hub)")
        else:
            out.append("gyro sign: not checked (no hand to turn the rod)")
        out += [f"FAIL: {p}" for p in self.problems]
        return out


def calibrate(still: dict, turn: dict | None = None, firmware_tilt_deg: float | None = 0.0) -> ImuCalibration:
    """still: arrays gyro, accel_x, accel_y (rod frame, as the firmware gives them: its sensors.imu_tilt_deg,
    firmware_tilt_deg [deg], already turned back; None: not known) with the rod hanging at rest; turn: arrays gyro
    and base_rate (the encoder's) while a hand turns the rod slowly, or None."""
    g, ax, ay = (np.asarray(still[k], float) for k in ("gyro", "accel_x", "accel_y"))
    if g.size < 50:
        raise ValueError(f"only {g.size} IMU samples at rest: is the firmware built with sensors.tip_imu?")
    bias, noise = float(np.mean(g)), float(np.std(g))
    mx, my = float(np.mean(ax)), float(np.mean(ay))
    grav = math.hypot(mx, my)
    tilt = math.degrees(math.atan2(my, -mx)) + (firmware_tilt_deg or 0.0)
    cal = ImuCalibration(bias, noise, grav, tilt, firmware_tilt_deg=firmware_tilt_deg)
    p = cal.problems
    if abs(grav - G) > GRAVITY_TOLERANCE * G:
        p.append(f"the accelerometer reads {grav:.2f} m/s^2 hanging, not {G:.2f}: check its full scale "
                 "(board_imu.cpp ACCEL_M_S2_PER_LSB) and that it is the part on the rod")
    elif abs(my) > abs(mx):
        p.append("gravity falls on the accelerometer's y axis: x and y are swapped; exchange BOARD_IMU_X_AXIS and "
                 "BOARD_IMU_Y_AXIS in board_pins.h")
    elif mx > 0:
        p.append("gravity reads +x hanging (it must be -x: x points along the rod to the tip); flip BOARD_IMU_X_SIGN "
                 "and BOARD_IMU_Y_SIGN in board_pins.h (the part is mounted pointing to the hub)")
    elif abs(tilt) > TILT_LIMIT_DEG:
        p.append(f"the part is tilted {tilt:+.1f} deg on the rod (more than {TILT_LIMIT_DEG:g}): mount it along the rod")
    if abs(bias) > BIAS_LIMIT_RAD_S:
        p.append(f"gyro bias {math.degrees(bias):+.2f} dps is beyond 1 dps, twice the part family's zero-rate output: was the rod still?")
    if noise > STILL_RMS_RAD_S:
        p.append(f"the gyro moved {noise * 1e3:.1f} mrad/s RMS at rest: let the rod hang still and run again")
    if turn is not None:
        r, w = np.asarray(turn["gyro"], float) - bias, np.asarray(turn["base_rate"], float)
        # the angles turned (sums of the rates): the tip swings about the hub as the hand moves it, and a soft
        # rod droops under gravity (on the default rod the tip turns about half the hub's 90 deg), so only the
        # sense is checked, and that the gyro sees a turn at all
        a_tip, a_hub = np.cumsum(r), np.cumsum(w)
        if np.abs(w).max(initial=0.0) < 0.2 or np.abs(a_hub).max() < 10 * np.abs(w).max():
            p.append("the rod hardly turned: turn it about a quarter turn by hand, slowly, and back")
        else:
            gain = float(np.dot(a_tip, a_hub) / np.dot(a_hub, a_hub))
            cal.gyro_gain = gain
            if gain < 0:
                p.append("the gyro turns against the encoder: flip BOARD_IMU_Z_SIGN in board_pins.h (or the "
                         "encoder's sign is wrong: run rodctl check first)")
            elif gain < 0.1:
                p.append(f"the gyro saw {gain:.2f} of the hub's turn: check that BOARD_IMU_Z_AXIS is the axis out of "
                         "the swing plane, and its full scale (board_imu.cpp GYRO_RAD_S_PER_LSB)")
    return cal


STILL_S = 3.0  # hanging still [s]
TURN_S = 4.0  # the hand's quarter turn and back [s]


def measure(session, user, say) -> tuple[dict, dict | None]:
    """Record the IMU with the rod hanging still, then under a hand's turn if `user` has a hand
    (rodctl.check.user); say(text) tells the person what to do. Returns (still, turn or None) for calibrate."""
    from rodctl.link import protocol as P

    samples: list[tuple] = []
    rate = [0.0]

    def listen(frame, t):
        if frame.type == P.MsgType.TELEMETRY:
            rate[0] = float(frame.msg.base_rate)
        elif frame.type == P.MsgType.IMU and frame.msg.status & P.ImuFlag.FRESH:
            m = frame.msg
            samples.append((m.gyro, m.accel_x, m.accel_y, rate[0]))

    def record(seconds: float) -> dict:
        del samples[:]
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            session.check()
            time.sleep(0.02)
        cols = list(zip(*samples)) if samples else [(), (), (), ()]
        return dict(zip(("gyro", "accel_x", "accel_y", "base_rate"), cols))

    session.add_listener(listen, replay=False)
    try:
        say(f"Step 1: the rod hangs still for {STILL_S:g} s (let it settle first)")
        still = record(STILL_S)
        if not user.has_hand:
            say("Step 2 skipped: --yes, and the gyro's sign needs a hand to turn the rod")
            return still, None
        say("Step 2: turn the rod by hand, slowly, about a quarter turn counter-clockwise (seen from the front) "
            f"and back, within {TURN_S:g} s")
        if not user.do("turn", session):
            return still, None
        return still, record(TURN_S)
    finally:
        session.remove_listener(listen)
