"""Wiring faults of a virtual board (sim:// options), for `rodctl check` and its tests.

Each one is a first-hour mistake on a real rig, reproduced between the simulated rod and the
firmware's host build, where the board layer would see it:

    encoder_sign=-1      the encoder counts the wrong way (BOARD_ENCODER_SIGN)
    ab_swapped           encoder channels A and B swapped (the same effect, another fix)
    encoder=dead         the encoder is not connected: the count stays 0
    counts_per_rev=X     the encoder gives X counts per output turn (another gear ratio or encoder)
    motor_sign=-1        a positive duty turns the motor the wrong way (BOARD_MOTOR_DIR_SIGN, motor leads)
    supply=off           the motor supply (VM) is off: the driver runs, the motor gets nothing
    nfault=low           the driver's nFAULT line is held low
    boot_angle_deg=X     the rod was held X deg counter-clockwise of hanging when the board booted,
                         so its zero is there: hanging reads -X
    header=stale         the firmware was built from another design than the parameter file's
    hand=none            nobody stands by the virtual rod (steps that need a hand wait for a human)
    imu_tilt_deg=X       the tip IMU sits X deg more tilted on the rod than sensors.imu_tilt_deg says
    restart=watchdog     the board started after its watchdog (or restart=lockup) rather than a power-on:
                         its zero is wherever the rod was, and it holds FAULT (reason RESET)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from rodgains.errors import InputError

FAULT_OPTIONS = ("encoder_sign", "motor_sign", "encoder", "ab_swapped", "counts_per_rev", "nfault", "supply",
                 "boot_angle_deg", "header", "hand", "imu_tilt_deg", "restart")

# header=stale: the board's firmware was designed for a rod 20 % stiffer than the parameter file says
STALE_OVERRIDE_KEY = "rod.youngs_modulus"
STALE_FACTOR = 1.2


def _choice(key: str, value: str, allowed: dict[str, object]):
    if value not in allowed:
        raise InputError(f"{key}={value}: choose one of {', '.join(a for a in allowed if a)}")
    return allowed[value]


@dataclass(frozen=True)
class Faults:
    encoder_sign: int = 1
    motor_sign: int = 1
    encoder_dead: bool = False
    ab_swapped: bool = False
    counts_per_rev: float | None = None  # counts per output turn the encoder really gives [-]
    nfault_low: bool = False
    supply_off: bool = False
    boot_angle_deg: float = 0.0
    header_stale: bool = False
    hand: bool = True  # a virtual hand can turn the rod (VirtualDevice.hand_turn)
    imu_tilt_deg: float = 0.0  # the tip IMU's mounting tilt beyond the design's [deg]
    restart_reason: int = 0  # the board's own fault at start-up (protocol reason RESET), 0 after a power-on

    @classmethod
    def from_options(cls, opts: dict[str, str]) -> "Faults":
        """Faults from sim:// option strings; InputError (one line) on a bad value."""
        kw: dict[str, object] = {}
        sign = {"1": 1, "+1": 1, "-1": -1}
        if "encoder_sign" in opts:
            kw["encoder_sign"] = _choice("encoder_sign", opts["encoder_sign"], sign)
        if "motor_sign" in opts:
            kw["motor_sign"] = _choice("motor_sign", opts["motor_sign"], sign)
        if "encoder" in opts:
            kw["encoder_dead"] = _choice("encoder", opts["encoder"], {"ok": False, "dead": True})
        if "ab_swapped" in opts:
            kw["ab_swapped"] = _choice("ab_swapped", opts["ab_swapped"], {"": True, "1": True, "0": False})
        if "nfault" in opts:
            kw["nfault_low"] = _choice("nfault", opts["nfault"], {"high": False, "low": True})
        if "supply" in opts:
            kw["supply_off"] = _choice("supply", opts["supply"], {"on": False, "off": True})
        if "header" in opts:
            kw["header_stale"] = _choice("header", opts["header"], {"current": False, "stale": True})
        if "hand" in opts:
            kw["hand"] = _choice("hand", opts["hand"], {"virtual": True, "none": False})
        if "restart" in opts:
            from rodctl.link.protocol import Reason

            kw["restart_reason"] = _choice("restart", opts["restart"], {"power-on": 0, "watchdog": int(Reason.RESET),
                                                                        "lockup": int(Reason.RESET)})
        if "counts_per_rev" in opts:
            kw["counts_per_rev"] = _number("counts_per_rev", opts["counts_per_rev"], 1.0, 1e7, "counts per output turn")
        if "imu_tilt_deg" in opts:
            kw["imu_tilt_deg"] = _number("imu_tilt_deg", opts["imu_tilt_deg"], -90.0, 90.0, "deg")
        if "boot_angle_deg" in opts:
            kw["boot_angle_deg"] = _number("boot_angle_deg", opts["boot_angle_deg"], -180.0, 180.0, "deg")
        return cls(**kw)

    @property
    def count_sign(self) -> int:
        """The sign the wiring puts on the count (A and B swapped reverse it just as the sign does)."""
        return self.encoder_sign * (-1 if self.ab_swapped else 1)

    @property
    def any(self) -> bool:
        return self != Faults(hand=self.hand)

    def describe(self) -> str:
        parts = []
        if self.encoder_sign < 0:
            parts.append("encoder counting backwards")
        if self.ab_swapped:
            parts.append("encoder A/B swapped")
        if self.encoder_dead:
            parts.append("encoder not connected")
        if self.counts_per_rev is not None:
            parts.append(f"{self.counts_per_rev:g} counts per output turn")
        if self.motor_sign < 0:
            parts.append("motor reversed")
        if self.supply_off:
            parts.append("motor supply off")
        if self.nfault_low:
            parts.append("nFAULT held low")
        if self.boot_angle_deg:
            parts.append(f"booted with the rod at {self.boot_angle_deg:g} deg")
        if self.header_stale:
            parts.append("firmware of another design")
        if self.imu_tilt_deg:
            parts.append(f"tip IMU tilted {self.imu_tilt_deg:g} deg more than designed")
        if self.restart_reason:
            parts.append("started by its watchdog, not a power-on")
        return ", ".join(parts)


def _number(key: str, text: str, lo: float, hi: float, unit: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise InputError(f"{key} must be a number [{unit}], got {text!r}") from None
    if not (math.isfinite(v) and lo <= v <= hi):
        raise InputError(f"{key} must be within {lo:g}..{hi:g} [{unit}], got {text!r}")
    return v


class Hand:
    """A hand on the virtual rod's hub: a stiff spring-damper on the shaft pulling theta_1 along a
    smooth turn out to `peak_deg` and back over `seconds`, then letting go."""

    STIFFNESS = 2.0  # [N m/rad]: holds the Table I rod within ~2 deg of where the hand is
    DAMPING = 0.06  # [N m s/rad]: about critically damped with the rod and the reflected rotor

    def __init__(self, peak_deg: float, seconds: float):
        self.peak = math.radians(peak_deg)
        self.seconds = seconds
        self.t0: float | None = None
        self.origin = 0.0

    def torque(self, t: float, theta1: float, rate1: float) -> float | None:
        """External torque on the shaft at device time t [s] (None once the hand has let go)."""
        if self.t0 is None:
            self.t0, self.origin = t, theta1
        s = (t - self.t0) / self.seconds
        if s >= 1.0:
            return None
        target = self.origin + self.peak * math.sin(math.pi * s) ** 2
        return self.STIFFNESS * (target - theta1) - self.DAMPING * rate1
