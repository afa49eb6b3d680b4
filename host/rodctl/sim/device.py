"""The virtual board: the firmware's host build (rod_dev_*) against the simulated rod, in real time.

    dev = VirtualDevice.from_options(plant="inextensible", edges=None, params=None)
    runner = RealTimeRunner(dev, take_input=..., deliver=..., can_deliver=...)
    runner.start(); ...; runner.stop()

One virtual step (period P, from the firmware's own rod_sil_period()):
    count = plant.encoder()
    rod_dev_step(count, now_us = k * P_us, last_step_us = 0, driver_fault = 0)
    plant.advance(duty if rod_dev_enable() else 0, P)       # duty held for one period
    device bytes <- rod_dev_read()                           # what the board's USB would send
Host bytes go in through rod_dev_write before a step (the board's main loop takes them between
timer interrupts). The device's clock is virtual (exactly one period per step), so jitter of the
host scheduler never shows as an overrun; the runner keeps that clock on the wall clock's pace
(time.perf_counter) by running the steps that are due in small batches and sleeping between
batches, never per step, catching up when it was late.

The SIL library holds one device per loaded copy (rod_sil.h), so every VirtualDevice loads a
private copy of it: two sim:// ports in one process are two independent boards. Copies are
pooled and reused after close.

Flow control is the USB's: while the host side does not take the bytes (its buffer above
`backlog`), the runner stops reading the device, whose TX buffer then fills and drops frames,
counted in telemetry.frames_dropped, exactly like the board when nobody reads its serial port.
"""

from __future__ import annotations

import ctypes
import math
import os
import shutil
import tempfile
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import Callable

from rodctl.sim.faults import STALE_OVERRIDE_KEY, STALE_FACTOR, Faults, Hand

PLANT_KINDS = ("inextensible", "der")
RIG_STORE_BYTES = 16  # rod_rig.h ROD_RIG_STORE_SIZE: what SAVE_RIG writes to the EEPROM

_POOL_LOCK = threading.Lock()
_POOL: dict[str, list[ctypes.CDLL]] = {}


def _eeprom_file(eeprom: str | None) -> Path | None:
    """eeprom=PATH of a sim:// URL: a file, or one that can be made in an existing folder (InputError)."""
    if not eeprom:
        return None
    from rodgains.errors import InputError

    path = Path(eeprom)
    if path.is_dir():
        raise InputError(f"eeprom={eeprom}: is a folder; name the EEPROM's file")
    if not path.parent.is_dir():
        raise InputError(f"eeprom={eeprom}: folder {path.parent} does not exist")
    if path.exists() and not os.access(path, os.R_OK):
        raise InputError(f"eeprom={eeprom}: cannot read it")
    if path.is_file() and not _looks_like_eeprom(path):  # SAVE_RIG would write over someone's own file
        raise InputError(f"eeprom={eeprom}: not an EEPROM image (the board's rig record starts with 'RG'); "
                         f"name a new file")
    return path


EEPROM_BYTES = 4096  # the Teensy 3.5's EEPROM


def _looks_like_eeprom(path: Path) -> bool:
    """Empty, erased (every byte 0xFF or 0x00), or a rig record however damaged (rod_rig.h: 'R' 'G' ...)."""
    if path.stat().st_size > EEPROM_BYTES:
        return False
    data = path.read_bytes()
    return data[:2] == b"RG" or not data.strip(b"\xff\x00")


def _prototype(lib: ctypes.CDLL) -> ctypes.CDLL:
    f, i, u32, i32, sz = ctypes.c_float, ctypes.c_int, ctypes.c_uint32, ctypes.c_int32, ctypes.c_size_t
    protos = {
        "rod_sil_period": (f, []),
        "rod_sil_edges": (i, []),
        "rod_dev_reset": (None, [sz]),
        "rod_dev_step": (f, [i32, u32, u32, i]),
        "rod_dev_duty": (f, []),
        "rod_dev_enable": (i, []),
        "rod_dev_reason": (i, []),
        "rod_dev_status": (i, [ctypes.POINTER(ctypes.c_float), i]),
        "rod_dev_write": (sz, [ctypes.c_char_p, sz]),
        "rod_dev_read": (sz, [ctypes.c_void_p, sz]),
        "rod_dev_load_rig": (None, [ctypes.c_char_p, sz]),
        "rod_dev_take_save": (sz, [ctypes.c_void_p, sz]),
        "rod_dev_board_fault": (None, [i]),
        "rod_dev_imu": (None, [f, f, f, i]),
    }
    for name, (res, args) in protos.items():
        fn = getattr(lib, name)
        fn.restype = res
        fn.argtypes = args
    return lib


def _take_library(path: Path) -> ctypes.CDLL:
    """A private copy of the SIL library (its own rod_dev device), from the pool when one is free."""
    key = str(path)
    with _POOL_LOCK:
        free = _POOL.get(key)
        if free:
            return free.pop()
    tmp = tempfile.mkdtemp(prefix="rodsim-")
    try:
        copy = os.path.join(tmp, path.name)
        shutil.copyfile(path, copy)
        lib = ctypes.CDLL(copy)  # another file: the dynamic loader maps a separate instance
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    lib._rod_key = key
    return _prototype(lib)


def _give_back(lib: ctypes.CDLL) -> None:
    with _POOL_LOCK:
        _POOL.setdefault(lib._rod_key, []).append(lib)


class VirtualDevice:
    """One virtual board: firmware (rod_dev_*) + Plant in duty mode, stepped explicitly.

    Not thread-safe: one thread (the runner) makes every call.
    """

    def __init__(self, params=None, *, plant: str | None = None, edges: int | None = None,
                 params_path: str | None = None, tx_capacity: int = 0, overrides=(), theta0_deg: float = 0.0,
                 plant_params=None, faults=None, eeprom: str | None = None):
        from rodgains.params import load_params

        from rodctl.build.sil_build import build_sil
        from rodctl.sim.plant import faithful_plant

        if plant is not None and plant not in PLANT_KINDS and plant_params is None:
            from rodgains.errors import InputError

            raise InputError(f"unknown plant {plant!r}: choose one of {', '.join(PLANT_KINDS)}")
        eeprom_path = _eeprom_file(eeprom)  # before the build: a SAVE_RIG must not stop the board later
        # The same parameters build the firmware and the plant: `--params/--set` describe this rod.
        self.params = params if params is not None else load_params(params_path, list(overrides))
        # plant= and edges= are shorthands for the [plant] table, as `rodctl sim --plant/--edges` are.
        shorthand = (([f"plant.model={plant}"] if plant else [])
                     + ([f"plant.edges={edges}"] if edges is not None else []))
        self.params_path = params_path
        self.overrides = list(overrides)
        self.theta0_deg = float(theta0_deg)
        self.faults = faults if faults is not None else Faults()
        # header=stale: the board runs firmware designed from other parameters than these
        built = self.params
        if self.faults.header_stale:
            section, key = STALE_OVERRIDE_KEY.split(".")
            stale = float(self.params[section][key]) * STALE_FACTOR
            built = self.params.with_overrides(f"{STALE_OVERRIDE_KEY}={stale!r}")
        self.lib_path = build_sil(built)
        # plant_params (sim://?plant=FILE.toml): the rod the board really drives, which the firmware's
        # parameters only estimate (what `rodctl identify` must recover). Its [plant] table is the model.
        self.plant_params = plant_params
        if plant_params is not None:
            self.plant = faithful_plant(plant_params, input_mode="duty")
            plant = f"{plant_params['plant']['model']} from {plant_params.source}"
        else:
            # The board drives the faithful rod of the parameter file, never the controller's own model.
            rod = self.params.with_overrides(*shorthand) if shorthand else self.params
            self.plant = faithful_plant(rod, input_mode="duty")
            plant = rod["plant"]["model"]
        imu = self.plant.config.imu
        if self.faults.imu_tilt_deg and imu is not None:
            self.plant = self.plant.twin(imu=replace(imu, tilt=imu.tilt + math.radians(self.faults.imu_tilt_deg)))
        if self.theta0_deg:
            self.plant.set_state(math.radians(self.theta0_deg))
        self.kind = plant
        self.lib = _take_library(self.lib_path)
        self.period = float(self.lib.rod_sil_period())
        self.period_us = int(round(self.period * 1e6))
        self.edges = int(self.lib.rod_sil_edges())
        self._buf = ctypes.create_string_buffer(65536)
        self._buf_addr = ctypes.addressof(self._buf)
        self.lib.rod_dev_reset(tx_capacity)
        # The board's EEPROM: what SAVE_RIG stored, read back at power-on (a file with eeprom=PATH,
        # else blank at every power-on and kept in memory while the board runs).
        self.eeprom_path = eeprom_path
        self.eeprom = self.eeprom_path.read_bytes() if self.eeprom_path and self.eeprom_path.is_file() else b""
        self.lib.rod_dev_load_rig(self.eeprom or None, len(self.eeprom))
        if self.faults.restart_reason:  # started by its watchdog or a lockup, not powered on (main.cpp setup)
            self.lib.rod_dev_board_fault(self.faults.restart_reason)
        self._save_buf = ctypes.create_string_buffer(RIG_STORE_BYTES)
        self.steps = 0
        self._closed = False
        f = self.faults
        # the encoder's own counts per output turn, and where the board took its zero at boot
        rig = self.plant_params if self.plant_params is not None else self.params
        self._nominal_cpr = float(rig.counts_per_rev)
        self._count_scale = (f.counts_per_rev / self._nominal_cpr) if f.counts_per_rev else 1.0
        self._boot_offset = 0
        if f.boot_angle_deg:
            cpr = f.counts_per_rev or self._nominal_cpr
            self._boot_offset = int(round(f.boot_angle_deg / 360.0 * cpr))
        self._hand: Hand | None = None

    @classmethod
    def from_options(cls, *, plant: str | None = None, edges: int | str | None = None,
                     params: str | None = None, set=(), theta0_deg: float | str | None = None,
                     eeprom: str | None = None, **faults: str) -> "VirtualDevice":
        """A board from sim:// URL options (strings): plant, edges, params (file), set (list of
        section.key=value overrides), theta0_deg (every edge's angle at power-on, 0 hanging, 180 upright),
        eeprom (a file that keeps the board's stored rig settings across power-ons), and wiring faults (rodctl.sim.faults: encoder_sign=-1, motor_sign=-1, encoder=dead, ...)."""
        from rodgains.errors import InputError

        if isinstance(set, str):
            set = [set]
        try:
            theta0 = float(theta0_deg) if theta0_deg not in (None, "") else 0.0
        except ValueError:
            raise InputError(f"theta0_deg must be a number [deg], got {theta0_deg!r}") from None
        if not math.isfinite(theta0) or abs(theta0) > 360:
            raise InputError(f"theta0_deg must be within -360..360 deg, got {theta0_deg!r}")

        if edges is not None:
            try:
                edges = int(edges)
            except ValueError:
                raise InputError(f"edges must be an integer, got {edges!r}") from None
        plant_params = None
        if plant is not None and plant.endswith(".toml"):
            from rodgains.params import load_params

            plant_params, plant = load_params(plant), None
        return cls(plant=plant or None, edges=edges, params_path=params, overrides=list(set),
                   theta0_deg=theta0, plant_params=plant_params, faults=Faults.from_options(faults),
                   eeprom=eeprom or None)

    # --- one thread drives all of these ----------------------------------------------------
    @property
    def time(self) -> float:
        """Device time [s] (steps done x period)."""
        return self.steps * self.period

    def write(self, data: bytes) -> int:
        """Host bytes into the board's RX buffer; returns how many it took (the rest: offer later)."""
        return self.lib.rod_dev_write(data, len(data))

    def hand_turn(self, peak_deg: float, seconds: float = 2.0) -> None:
        """A hand turns the rod by its hub `peak_deg` counter-clockwise (seen from the front) and back
        over `seconds`, then lets go. Safe to call from another thread: the runner picks it up."""
        self._hand = Hand(peak_deg, seconds)

    def _encoder_count(self) -> int:
        """The count the board's quadrature decoder holds, faults included."""
        f = self.faults
        if f.encoder_dead:
            return 0
        raw = self.plant.encoder()
        if self._count_scale != 1.0:
            raw = int(round(raw * self._count_scale))
        return f.count_sign * (raw - self._boot_offset)

    def step(self) -> None:
        lib, plant, f = self.lib, self.plant, self.faults
        hand = self._hand
        if hand is not None:
            th, dth = plant.state()
            tq = hand.torque(self.time, float(th[0]), float(dth[0]))
            if tq is None:
                self._hand = None
                tq = 0.0
            plant.external_torque = tq
        count = self._encoder_count()
        if plant.config.imu is not None:
            sample = plant.imu_read(self.period)
            lib.rod_dev_imu(*(sample or (0.0, 0.0, 0.0)), 1 if sample else 0)
        lib.rod_dev_step(count, (self.steps * self.period_us) & 0xFFFFFFFF, 0, 1 if f.nfault_low else 0)
        duty = lib.rod_dev_duty() if lib.rod_dev_enable() else 0.0
        if not math.isfinite(duty) or f.supply_off:
            duty = 0.0
        plant.advance(duty * f.motor_sign, self.period)
        self.steps += 1
        n = lib.rod_dev_take_save(self._save_buf, RIG_STORE_BYTES)
        if n:
            self._store(self._save_buf.raw[:n])

    def _store(self, data: bytes) -> None:
        """SAVE_RIG: the bytes the board writes to its EEPROM (the file whole, or as it was)."""
        from rodgains.atomic_file import atomic_write

        self.eeprom = data
        if self.eeprom_path is not None:
            atomic_write(self.eeprom_path, data)

    def read(self) -> bytes:
        """Device bytes the board's USB would send now (whole frames)."""
        n = self.lib.rod_dev_read(self._buf_addr, len(self._buf))
        return ctypes.string_at(self._buf_addr, n) if n else b""

    @property
    def mode(self) -> int:
        return self.lib.rod_dev_status(None, 0)

    @property
    def reason(self) -> int:
        return self.lib.rod_dev_reason()

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            _give_back(self.lib)

    def describe(self) -> str:
        start = "hanging at rest" if not self.theta0_deg else f"at rest at {self.theta0_deg:g} deg"
        over = f" with --set {' '.join(self.overrides)}" if self.overrides else ""
        if self.faults.any:
            start += f"; wiring faults: {self.faults.describe()}"
        return (f"firmware N={self.edges} at {1 / self.period:g} Hz (parameters {self.params.sha256()[:16]}{over}), "
                f"plant {self.kind} with {self._plant_edges_text()}, duty input, {start}")

    def _plant_edges_text(self) -> str:
        """The faithful rod's flexible edges and its hub (one more coordinate), as --edges and plant.edges count."""
        if self.plant.hub is None:
            return f"{self.plant.N} edges"
        return f"{self.plant.N - 1} edges + a {self.plant.hub * 1e3:g} mm hub"


class RealTimeRunner:
    """Runs a VirtualDevice on the wall clock in a thread.

    take_input() -> bytes: host bytes that arrived (called once per batch).
    deliver(bytes): device bytes for the host (called once per batch with what the steps made).
    backlog() -> int: bytes the host side has not taken yet; above `max_backlog` the device is
    not read (its TX buffer fills and it drops frames, as on the board).
    on_batch(): optional hook after each batch (mode watching).
    """

    BATCH_S = 0.002  # wake-up interval: a few steps per batch at 1 kHz
    # Later than this (a loaded machine starved the thread, or the process was stopped): skip ahead instead.
    # A stall's backlog runs in one burst with only the host bytes that were waiting before it, so a burst
    # longer than the board's heartbeat timeout (0.5 s) would fault HEARTBEAT while the host kept sending;
    # a fifth of it keeps the virtual board's heartbeat what the host's own pace makes it [s].
    MAX_CATCH_UP_S = 0.1

    def __init__(self, device: VirtualDevice, *, take_input: Callable[[], bytes], deliver: Callable[[bytes], None],
                 backlog: Callable[[], int] = lambda: 0, max_backlog: int = 65536,
                 on_batch: Callable[[], None] | None = None, name: str = "rodsim"):
        self.device = device
        self._take_input = take_input
        self._deliver = deliver
        self._backlog = backlog
        self.max_backlog = max_backlog
        self._on_batch = on_batch
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self.error: BaseException | None = None
        self.skipped_steps = 0  # steps skipped after a stall longer than MAX_CATCH_UP_S
        self.max_lateness = 0.0  # worst lag behind the wall clock [s]

    def start(self) -> "RealTimeRunner":
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(timeout=5)

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    def _run(self) -> None:
        dev = self.device
        period = dev.period
        pending = b""
        t0 = time.perf_counter()
        done = 0  # steps run since t0
        try:
            while not self._stop.is_set():
                now = time.perf_counter()
                due = int((now - t0) / period) + 1
                late = (due - done - 1) * period
                if late > self.max_lateness:
                    self.max_lateness = late
                if late > self.MAX_CATCH_UP_S:
                    skip = due - done - 1
                    self.skipped_steps += skip
                    t0 += skip * period
                    due -= skip
                new = self._take_input()
                if new:
                    pending += new
                out = []
                read = self._backlog() < self.max_backlog
                while done < due:
                    if pending:
                        taken = dev.write(pending)
                        pending = pending[taken:]
                    dev.step()
                    if read:
                        b = dev.read()
                        if b:
                            out.append(b)
                    done += 1
                if out:
                    self._deliver(b"".join(out))
                if self._on_batch is not None:
                    self._on_batch()
                wait = t0 + done * period + self.BATCH_S - time.perf_counter()
                if wait > 0:
                    self._stop.wait(wait)
        except BaseException as e:  # noqa: BLE001 - reported to the port's reader as a disconnect
            self.error = e
