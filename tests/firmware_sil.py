"""ctypes access to the SIL library (firmware core on the host) for the firmware tests.

Not a test module: tests import Sil / Dev from here. The library is built once per parameter
set by rodctl.build.sil_build.build_sil (cached by content) and loaded once per process; every test
resets the device it uses.
"""

from __future__ import annotations

import ctypes as C
import math
from functools import lru_cache

from rodgains.params import load_params

from rodctl.link import protocol as P
from rodctl.build.sil_build import build_sil, write_header

MODE = {"DISARMED": 0, "BALANCE": 1, "SWING_UP": 2, "FAULT": 3, "CATCH": 4, "IDENTIFY": 5}
REASON = {"NONE": 0, "HOST": 1, "ANGLE_LIMIT": 2, "SPEED_LIMIT": 3, "DRIVER_FAULT": 4, "HEARTBEAT": 5,
          "NON_FINITE": 6, "OVERRUN": 7}
ACK = {"OK": 0, "BAD_VALUE": 1, "BAD_STATE": 2}
PARAM = {"SWING_AMPLITUDE": 1, "SWING_ANGLE": 2, "CATCH_ANGLE": 3, "TELEMETRY_DECIMATION": 4,
         "HEARTBEAT_TIMEOUT": 5, "ENCODER_SIGN": 6, "MOTOR_SIGN": 7, "COUNTS_PER_REV": 8}

COUNTS_PER_REV = 4896 / 5  # 979.2
RAD_PER_COUNT = 2 * math.pi / COUNTS_PER_REV
UPRIGHT = COUNTS_PER_REV / 2  # 489.6


def count_of(theta: float) -> int:
    """Encoder count nearest theta_1 [rad] (0 hanging)."""
    return int(math.floor(theta / RAD_PER_COUNT + 0.5))


@lru_cache(maxsize=None)
def params(overrides: tuple[str, ...] = ()):
    return load_params(None, list(overrides))


@lru_cache(maxsize=None)
def library(overrides: tuple[str, ...] = ()) -> C.CDLL:
    lib = C.CDLL(str(build_sil(params(overrides))))
    f, i, u32, i32, sz = C.c_float, C.c_int, C.c_uint32, C.c_int32, C.c_size_t
    fp = C.POINTER(C.c_float)
    protos = {
        "rod_sil_abi_version": (i, []), "rod_sil_reset": (None, []), "rod_sil_period": (f, []),
        "rod_sil_edges": (i, []), "rod_sil_arm": (None, [i]), "rod_sil_arm_result": (i, [i]),
        "rod_sil_step": (f, [i32]), "rod_sil_status": (i, [fp, i]), "rod_sil_duty": (f, []),
        "rod_sil_enable": (i, []), "rod_sil_reason": (i, []), "rod_sil_rate": (f, []),
        "rod_sil_set": (i, [i, f]), "rod_sil_identify": (i, [i, f, f, f, f, i]), "rod_sil_clear_fault": (i, []), "rod_sil_inject_nan": (None, []),
        "rod_dev_reset": (None, [sz]), "rod_dev_step": (f, [i32, u32, u32, i]), "rod_dev_duty": (f, []),
        "rod_dev_enable": (i, []), "rod_dev_reason": (i, []), "rod_dev_status": (i, [fp, i]),
        "rod_dev_write": (sz, [C.c_char_p, sz]), "rod_dev_read": (sz, [C.c_char_p, sz]),
    }
    for name, (res, args) in protos.items():
        fn = getattr(lib, name)
        fn.restype = res
        fn.argtypes = args
    return lib


def header_path(overrides: tuple[str, ...] = ()):
    return write_header(params(overrides)) / "rod_gains.h"


class Sil:
    """The rod_sil_* controller: live heartbeat, one period of virtual time per step."""

    def __init__(self, overrides: tuple[str, ...] = ()):
        self.lib = library(overrides)
        self.p = params(overrides)
        self.n = self.lib.rod_sil_edges()
        self.lib.rod_sil_reset()

    def step(self, count: int) -> float:
        return self.lib.rod_sil_step(count)

    def arm(self, mode: int) -> int:
        return self.lib.rod_sil_arm_result(mode)

    def past_runaway_watch(self, count: int = 0) -> None:
        """A second at rest at `count`: the runaway watch (rod_runaway.h) of the mode just armed ends.
        For tests that then impose a motion no torque made (a real base would answer the torque)."""
        for _ in range(int(round(1.05 / self.p.dt))):
            self.step(count)

    def status(self) -> tuple[int, list[float], list[float]]:
        buf = (C.c_float * (2 * self.n))()
        mode = self.lib.rod_sil_status(buf, 2 * self.n)
        return mode, list(buf[: self.n]), list(buf[self.n:])

    @property
    def mode(self) -> int:
        return self.lib.rod_sil_status(None, 0)

    @property
    def duty(self) -> float:
        return self.lib.rod_sil_duty()

    @property
    def enable(self) -> int:
        return self.lib.rod_sil_enable()

    @property
    def reason(self) -> int:
        return self.lib.rod_sil_reason()

    @property
    def rate(self) -> float:
        return self.lib.rod_sil_rate()

    def set(self, param: str, value: float) -> int:
        return self.lib.rod_sil_set(PARAM[param], value)

    def identify(self, excitation: int, amplitude: float, duration: float, shape1: float, shape2: float = 0.0,
                 seed: int = 0) -> int:
        """IDENTIFY (excitation 1 chirp, 2 PRBS, 3 steps, 4 release); the ack code."""
        return self.lib.rod_sil_identify(excitation, amplitude, duration, shape1, shape2, seed)

    def clear_fault(self) -> int:
        return self.lib.rod_sil_clear_fault()

    def hold(self, count: int, steps: int) -> float:
        u = 0.0
        for _ in range(steps):
            u = self.step(count)
        return u

    def catch_at(self, count: int) -> float:
        """Arm balance at rest on `count` (inside the catch angle); returns the catch step's torque."""
        assert self.arm(1) == ACK["OK"]
        u = self.step(count)
        assert self.mode == MODE["BALANCE"]
        return u


class Dev:
    """The rod_dev_* virtual device: explicit time, real protocol, no implicit heartbeat."""

    def __init__(self, overrides: tuple[str, ...] = (), tx_capacity: int = 0):
        self.lib = library(overrides)
        self.p = params(overrides)
        self.n = self.lib.rod_sil_edges()
        self.period_us = round(self.p.dt * 1e6)
        self.lib.rod_dev_reset(tx_capacity)
        self.now = 0
        self.count = 0
        self.host_seq = 0
        self.decoder = P.Decoder()
        self.reading = True  # a live host drains the device's bytes after every step
        self._pending = bytearray()

    def step(self, count: int | None = None, fault: bool = False, last_step_us: int = 0, dt_us: int | None = None) -> float:
        if count is not None:
            self.count = count
        u = self.lib.rod_dev_step(self.count, self.now & 0xFFFFFFFF, last_step_us, 1 if fault else 0)
        self.now += self.period_us if dt_us is None else dt_us
        if self.reading:
            self._pending += self.read_bytes()
        return u

    def run(self, steps: int, **kw) -> None:
        for _ in range(steps):
            self.step(**kw)

    def send(self, encoder, *args, **fields) -> int:
        self.host_seq += 1
        wire = encoder(*args, seq=self.host_seq, **fields)
        assert self.lib.rod_dev_write(wire, len(wire)) == len(wire)
        return self.host_seq

    def write_raw(self, data: bytes) -> int:
        return self.lib.rod_dev_write(data, len(data))

    def read_bytes(self) -> bytes:
        out = bytearray()
        buf = C.create_string_buffer(8192)
        while True:
            n = self.lib.rod_dev_read(buf, len(buf))
            if n == 0:
                return bytes(out)
            out += buf.raw[:n]

    def frames(self) -> list:
        """Every frame the host received since the last call."""
        data = bytes(self._pending) + self.read_bytes()
        self._pending.clear()
        return self.decoder.feed(data)

    def status(self) -> tuple[int, list[float], list[float]]:
        buf = (C.c_float * (2 * self.n))()
        mode = self.lib.rod_dev_status(buf, 2 * self.n)
        return mode, list(buf[: self.n]), list(buf[self.n:])

    @property
    def mode(self) -> int:
        return self.lib.rod_dev_status(None, 0)

    @property
    def duty(self) -> float:
        return self.lib.rod_dev_duty()

    @property
    def enable(self) -> int:
        return self.lib.rod_dev_enable()

    @property
    def reason(self) -> int:
        return self.lib.rod_dev_reason()

    def acks(self, frames) -> list:
        return [f.msg for f in frames if f.type == P.MsgType.ACK]
