"""A session with the board (or the virtual one): the port, a reader thread, heartbeats, commands.

    from rodctl.link.session import Session
    with Session("sim://") as s:              # opens, waits for the HELLO
        print(s.hello.fw_major, s.hello.n)
        s.arm(P.ArmMode.SWING_UP)              # waits for the ACK; UserError on refusal
        tlm = s.wait_telemetry()               # the next telemetry frame
    # leaving: DISARM sent (when the port still works), threads stopped, port closed

While open, a HEARTBEAT goes out every 100 ms (faster when the device's heartbeat timeout is
short), so a host that dies or hangs leaves an armed device disarming itself after its
heartbeat timeout (0.5 s by default) with FAULT reason HEARTBEAT. With liveness_s [s] (the
commands' sessions: rodctl.cli.common.session_for), heartbeats go out only while the code that
holds the session has called check() (every wait of the session does) within liveness_s: the
heartbeat thread alone is not someone in control, and a main thread stuck elsewhere (a terminal
paused with Ctrl-S, a hung window) lets the board disarm itself.

Frames reach listeners (add_listener) in the reader thread, in arrival order, each with the host
receive time [s since the session opened]. The session's stream starts at the device's ACK of a
HELLO_REQUEST sent once the link has drained (see _handshake): frames that sat in the USB buffer
from before we connected are skipped (stale_frames), so sequence gaps count only frames lost while
connected. A listener added after
open gets every frame of the session first (replayed), so a log started right after open misses
nothing.
"""

from __future__ import annotations

import collections
import contextlib
import errno
import itertools
import math
import os
import threading
import time
from typing import Callable

from rodgains.errors import InputError, UserError

from rodctl.link import protocol as P
from rodctl.link.ports import find_port

HEARTBEAT_INTERVAL_S = 0.1
ACK_TIMEOUT_S = 1.0
HELLO_TIMEOUT_S = 3.0
REPLAY_FRAMES = 20000  # frames kept for listeners added after open (20 s at 1 kHz)

REASON_TEXT = {
    P.Reason.NONE: "no reason",
    P.Reason.HOST: "disarmed by the host",
    P.Reason.ANGLE_LIMIT: "angle limit",
    P.Reason.SPEED_LIMIT: "speed limit",
    P.Reason.DRIVER_FAULT: "motor driver fault",
    P.Reason.HEARTBEAT: "heartbeat lost",
    P.Reason.NON_FINITE: "non-finite estimate",
    P.Reason.OVERRUN: "control step overrun",
    P.Reason.NO_TIMER: "the board's control timer did not start (reset the board)",
    P.Reason.RUNAWAY: "runaway: the base accelerated against the torque (a reversed encoder or motor: run `rodctl check`)",
    P.Reason.IMU: "the tip IMU was lost (no sample, a stuck one, or one at full scale)",
    P.Reason.UPLOAD: "restarting for an upload (the driver is off until the new firmware runs)",
    P.Reason.RESET: "the board restarted while running (its watchdog, a lockup or a brown-out), not from power-on: "
                    "its encoder zero is where the rod was then (power it off and on with the rod hanging still)",
}

# the board's own faults (rod_device_board_fault): CLEAR_FAULT cannot leave them, only a restart
HELD_UNTIL_RESET = (P.Reason.NO_TIMER, P.Reason.UPLOAD, P.Reason.RESET)
ARMED_MODES = (P.Mode.BALANCE, P.Mode.SWING_UP, P.Mode.CATCH, P.Mode.IDENTIFY)


def name_of(enum_cls, value) -> str:
    try:
        return enum_cls(int(value)).name
    except ValueError:
        return f"{int(value)}?"


def reason_text(reason) -> str:
    try:
        return REASON_TEXT[P.Reason(int(reason))]
    except ValueError:
        return f"reason {int(reason)}"


CLEAR_FAULT = "run `rodctl clear-fault`"  # what leaves a FAULT, said the same way wherever a FAULT is shown


def fault_text(reason) -> str:
    """The board is in FAULT for `reason`: why, and what leaves it (clear-fault, or for the board's own faults
    the restart their words name)."""
    return f"device is in {mode_text(P.Mode.FAULT, reason)}"


def cleared_text(before, ack) -> str:
    """What a CLEAR_FAULT did, as every tool says it: the fault it cleared (from `before`, the telemetry or hello
    just before it), or that there was none; then the mode after (`ack`)."""
    after = name_of(P.Mode, ack.mode)
    if before is not None and int(before.mode) == P.Mode.FAULT:
        return f"fault cleared ({reason_text(before.reason)}): mode {after}"
    return f"no fault to clear: mode {after}"


def mode_text(mode, reason, clear: str = CLEAR_FAULT) -> str:
    """The mode in words; a FAULT with its reason and what leaves it (`clear`: how this tool says clear-fault)."""
    m = name_of(P.Mode, mode)
    if int(mode) == P.Mode.FAULT:
        if int(reason) in HELD_UNTIL_RESET:  # clear-fault cannot leave these: the text says what does
            return f"{m} ({reason_text(reason)})"
        return f"{m} ({reason_text(reason)}): {clear}"
    if int(reason) != P.Reason.NONE:
        return f"{m} (last: {reason_text(reason)})"
    return m


# ---- run-time settings (SET) -------------------------------------------------------------------

class Setting:
    """One `rodctl set NAME=VALUE` name: its device parameter, unit conversion and physical range.

    The range is the one in firmware/protocol/rodlink.toml (codes.param min / max / design_max),
    which the firmware's rod_control_set checks too, converted to this setting's unit.
    """

    def __init__(self, name: str, param, unit: str, hello_field: str, scale: float = 1.0, integer: bool = False):
        self.name, self.param, self.unit, self.hello_field = name, param, unit, hello_field
        self.scale = scale  # device value = user value * scale
        self.integer = integer
        code = P.PARAM_INFO[param]
        self.min = code.min / scale  # user unit
        self.max = None if code.max is None else code.max / scale
        self.design_max = code.design_max

    def parse(self, text: str) -> float:
        """The value in the user's unit; UserError unless a finite number inside the fixed range."""
        try:
            v = float(text)
        except ValueError:
            raise InputError(f"{self.name}: {text!r} is not a number") from None
        if not math.isfinite(v):
            raise InputError(f"{self.name}: {text!r} is not a finite number")
        self.check(v)
        return v

    def ceiling(self, hello=None, design_params=None) -> float | None:
        """Upper bound [user unit] including the design's (None: not known here)."""
        hi = self.max
        d = None
        if self.design_max == "ROD_TORQUE_MAX_NM" and hello is not None:
            d = float(hello.torque_max)
        elif self.design_max == "ROD_ANGLE_LIMIT_RAD" and design_params is not None:
            d = math.radians(design_params["safety"]["angle_limit_deg"])
        elif self.design_max is not None:
            return hi  # the design's bound is not known here: the device may still refuse below hi
        if d is not None:
            d /= self.scale
            hi = d if hi is None else min(hi, d)
        return hi

    def check(self, v: float, hello=None, design_params=None) -> None:
        """UserError when the device would refuse v [user unit] (as far as the host can tell)."""
        hi = self.ceiling(hello, design_params)
        # float32 rounding on the device: compare with a relative slack of 1e-6
        bad = v < self.min * (1 - 1e-6) or (hi is not None and v > hi * (1 + 1e-6))
        if self.integer and v != math.floor(v):
            bad = True
        if bad:
            raise InputError(f"{self.name}={v:g} out of range: allowed {self.allowed(hello, design_params)}")

    def to_device(self, v: float) -> float:
        return v * self.scale

    def from_device(self, v: float) -> float:
        return v / self.scale

    def format(self, v: float) -> str:
        if self.integer:
            return f"{v:g}"
        return f"{v:.6g} {self.unit}".strip()

    def allowed(self, hello=None, design_params=None) -> str:
        """The range the firmware accepts, in this setting's unit."""
        n = self.name
        lo = f"{'integer ' if self.integer else ''}{self.min:.6g} <= {n} <= "
        hi = self.ceiling(hello, design_params)
        names = {"ROD_TORQUE_MAX_NM": "the firmware's torque ceiling",
                 "ROD_ANGLE_LIMIT_RAD": "the balance angle limit"}
        what = names.get(self.design_max, self.design_max)
        if self.design_max is None:
            return f"{lo}{hi:.6g} {self.unit}".rstrip()
        known = (self.design_max == "ROD_TORQUE_MAX_NM" and hello is not None) or \
                (self.design_max == "ROD_ANGLE_LIMIT_RAD" and design_params is not None)
        if known:
            return f"{lo}{hi:.6g} {self.unit} ({what}{f', at most {self.max:.6g} {self.unit}' if self.max else ''})"
        bound = f"min({self.max:.6g}, {what})" if self.max is not None else what
        where = {"ROD_TORQUE_MAX_NM": "rodctl status gives the ceiling",
                 "ROD_ANGLE_LIMIT_RAD": "--params names the design's safety.angle_limit_deg"}.get(self.design_max, "")
        return f"{lo}{bound}, in {self.unit}" + (f" ({where})" if where else "")


    def value_of(self, hello) -> float:
        """This setting's value in a HELLO [user unit]."""
        return self.from_device(getattr(hello, self.hello_field))


class SignSetting(Setting):
    """A wiring sign (+1 or -1): set while disarmed, reported in HELLO's rig bits, kept by SAVE_RIG."""

    def __init__(self, name: str, param, flag):
        super().__init__(name, param, "", "rig", integer=True)
        self.flag = flag

    def check(self, v: float, hello=None, design_params=None) -> None:
        if v not in (1.0, -1.0):
            raise InputError(f"{self.name}={v:g} out of range: allowed {self.allowed()}")

    def allowed(self, hello=None, design_params=None) -> str:
        return f"{self.name} = 1 or -1"

    def value_of(self, hello) -> float:
        return -1.0 if int(hello.rig) & int(self.flag) else 1.0


class CountsSetting(Setting):
    """Encoder counts per output turn: set while disarmed, reported in HELLO as counts_num / counts_den,
    kept by SAVE_RIG. The board holds the simplest fraction with a denominator up to 1000 within 1e-4
    count of the value."""

    def __init__(self):
        super().__init__("counts_per_rev", P.Param.COUNTS_PER_REV, "counts/turn", "rig")

    def value_of(self, hello) -> float:
        counts = hello_counts_per_rev(hello)
        return float("nan") if counts is None else counts


def hello_counts_per_rev(hello) -> float | None:
    """Encoder counts per output turn a HELLO reports (counts_num / counts_den); None when it says none."""
    den = int(hello.counts_den)
    return int(hello.counts_num) / den if den else None


_DEG = math.pi / 180.0
SETTINGS = {s.name: s for s in (
    Setting("swing_amplitude", P.Param.SWING_AMPLITUDE, "N m", "swing_amplitude"),
    Setting("swing_angle_deg", P.Param.SWING_ANGLE, "deg", "swing_angle", scale=_DEG),
    Setting("catch_angle_deg", P.Param.CATCH_ANGLE, "deg", "catch_angle", scale=_DEG),
    Setting("telemetry_decimation", P.Param.TELEMETRY_DECIMATION, "", "decimation", integer=True),
    Setting("heartbeat_timeout", P.Param.HEARTBEAT_TIMEOUT, "s", "heartbeat_timeout"),
    SignSetting("encoder_sign", P.Param.ENCODER_SIGN, P.RigFlag.ENCODER_REVERSED),
    SignSetting("motor_sign", P.Param.MOTOR_SIGN, P.RigFlag.MOTOR_REVERSED),
    CountsSetting(),
)}


def rig_source(hello) -> str:
    """Whether the rig settings in use are the ones stored on the board (HELLO rig bits)."""
    rig = int(hello.rig)
    if rig & int(P.RigFlag.STORE_CORRUPT):
        return "not stored on the board: the stored settings were unreadable"
    if rig & int(P.RigFlag.STORED):
        return "stored on the board"
    return "not stored on the board"  # the compiled defaults, or a SET since power-on


def parse_assignment(text: str) -> tuple[Setting, float]:
    """'NAME=VALUE' -> (Setting, value in the user's unit); UserError on a bad name, number or range."""
    if "=" not in text:
        raise InputError(f"expected NAME=VALUE, got {text!r} (names: {', '.join(SETTINGS)})")
    name, value = (x.strip() for x in text.split("=", 1))
    s = SETTINGS.get(name)
    if s is None:
        raise InputError(f"unknown setting {name!r}: choose one of {', '.join(SETTINGS)}")
    return s, s.parse(value)


def hello_settings(hello) -> dict[str, float]:
    """The settings of a HELLO in the user's units (the names of `rodctl set`)."""
    return {s.name: s.value_of(hello) for s in SETTINGS.values()}


# ---- opening ports -------------------------------------------------------------------------------

def open_serial(port: str, timeout: float = 0.05):
    """pyserial port for a device path, any pyserial URL or sim://; UserError when it cannot open."""
    import serial

    from rodctl.link.urlhandler import register
    from rodctl.link.urlhandler.protocol_sim import BadURL

    register()
    is_url = "://" in port
    try:
        if is_url:
            return serial.serial_for_url(port, baudrate=115200, timeout=timeout, write_timeout=2.0)
        return serial.Serial(port, baudrate=115200, timeout=timeout, write_timeout=2.0, exclusive=True)
    except serial.SerialException as e:
        msg = str(e).strip()
        if "exclusively lock" in msg or "Resource temporarily unavailable" in msg or e.errno == errno.EBUSY:
            raise UserError(f"{port} is in use by another program (another rodctl?)") from None
        if e.errno == errno.EACCES and not is_url:
            raise UserError(f"cannot open {port}: permission denied (on Linux: `sudo usermod -aG dialout $USER`, "
                            "then log in again; and PJRC's udev rules, 00-teensy.rules)") from None
        if not is_url and (isinstance(e.__cause__ or e.__context__, FileNotFoundError) or "No such file" in msg):
            raise UserError(f"cannot open {port}: no such port (is the board plugged in? "
                            "`--port sim://` runs the simulated rod)") from None
        kind = InputError if isinstance(e, BadURL) else UserError  # a bad sim:// URL is bad input
        if msg.startswith("sim://: "):  # the virtual board's own one-line reason (e.g. a missing params= file)
            raise kind(msg) from None
        if ("Could not configure port" in msg and "Inappropriate ioctl" in msg) or e.errno == errno.EISDIR:
            raise InputError(f"cannot open {port}: not a serial port") from None  # a file or folder, no terminal
        raise kind(f"cannot open {port}: {msg}") from None
    except ValueError as e:  # pyserial's "invalid URL, protocol 'x' not known" and the like: the name is wrong
        raise InputError(f"cannot open {port}: {e}") from None
    except OSError as e:
        raise UserError(f"cannot open {port}: {e}") from None


class Session:
    """An open connection to the firmware (see the module doc)."""

    def __init__(self, port: str | None = None, *, hello_timeout: float = HELLO_TIMEOUT_S,
                 heartbeat_interval: float = HEARTBEAT_INTERVAL_S, disarm_on_close: bool = True,
                 liveness_s: float | None = None):
        self.port = find_port(port)
        self.hello_timeout = hello_timeout
        self.heartbeat_interval = heartbeat_interval
        self.liveness_s = liveness_s  # heartbeats only within this of the last check() [s]; None: always
        self._checked = time.monotonic()
        self.disarm_on_close = disarm_on_close
        self.ser = None
        self.decoder = P.Decoder()
        self.hello = None  # latest HELLO message
        self.hello_seen = 0  # HELLO frames received
        self.telemetry = None  # latest TELEMETRY message
        self.telemetry_frame = None
        self.telemetry_seen = 0
        self.dropped_at_connect = None  # the device's frames_dropped in the first telemetry
        self.frames = 0  # valid frames received (= frames dispatched to listeners)
        self.sync_bytes = 0  # bytes dropped before the first frame boundary
        self.disconnected: str | None = None  # why the link ended, when it did
        self.listener_error: Exception | None = None  # first exception a listener raised
        self.t0 = time.perf_counter()
        self.open_unix = time.time()
        self._seq = itertools.count(1)
        self._write_lock = threading.Lock()
        self._lock = threading.RLock()  # frame dispatch and listener changes
        self._cond = threading.Condition(self._lock)
        self._pending: dict[int, list] = {}  # host seq -> [Event, Ack]
        self._listeners: list[Callable] = []
        self._recent: collections.deque = collections.deque(maxlen=REPLAY_FRAMES)
        self._stop = threading.Event()
        self._hb_paused = 0
        self._reader = None
        self._heart = None
        self._synced = False
        self._sync_buf = b""
        self._started = False  # frames count from the ACK of our first HELLO_REQUEST on
        self._start_seqs: set[int] = set()
        self._probe_seqs: set[int] = set()
        self._probe_acked = False
        self._last_seq: int | None = None
        self.stale_frames = 0  # frames that were queued before we connected (skipped)
        self.seq_gaps = 0  # device frames missing since the session started
        self.seq_restarts = 0
        self._err_base = (0, 0)
        self.closed = False
        self.disarm_acked = False  # close() sent DISARM and the device acknowledged it
        self.reader_error: str | None = None  # why the reader thread stopped on its own, if it did
        self.disarm_sent = False  # a DISARM went out without waiting for its ACK (reader stopped)

    # --- life cycle -------------------------------------------------------------------------
    def open(self) -> "Session":
        self.ser = open_serial(self.port)
        try:
            self.ser.reset_input_buffer()
        except Exception:  # noqa: BLE001 - not every URL handler supports it
            pass
        self.t0 = time.perf_counter()
        self.open_unix = time.time()
        self._reader = threading.Thread(target=self._read_loop, name="rodctl-reader", daemon=True)
        self._reader.start()
        self._heart = threading.Thread(target=self._heartbeat_loop, name="rodctl-heartbeat", daemon=True)
        self._heart.start()
        try:
            self._handshake(self.hello_timeout)
        except BaseException:
            self.close(disarm=False)
            raise
        return self

    def _handshake(self, timeout: float) -> None:
        """Two HELLO_REQUESTs: the first one's ACK ends what was queued before we connected (a USB
        buffer that filled while no host read it, and the frames the device dropped while it drained);
        the second one's ACK is where this session's frames begin, from a drained link.

        Frames before it are skipped (stale_frames), so the stream seen by listeners and the gap
        count start clean.
        """
        deadline = time.monotonic() + timeout
        for phase, seqs in (("probe", self._probe_seqs), ("start", self._start_seqs)):
            while True:
                seq = next(self._seq) & 0xFFFFFFFF
                with self._lock:
                    seqs.add(seq)
                self._send(P.HelloRequest(), seq)
                with self._cond:
                    end = min(deadline, time.monotonic() + 0.5)
                    done = (lambda: self._probe_acked) if phase == "probe" else (
                        lambda: self._started and self.hello_seen > 0)
                    while not done():
                        self.check()
                        left = end - time.monotonic()
                        if left <= 0:
                            break
                        self._cond.wait(min(left, 0.05))
                    if done():
                        break
                if time.monotonic() >= deadline:
                    if self.decoder.frames == 0:
                        raise self._no_frames(timeout)
                    raise UserError(f"{self.port}: the device does not answer HELLO_REQUEST "
                                    f"(rodctl speaks rodlink v{P.VERSION})")

    def _no_frames(self, timeout: float) -> UserError:
        """Why no frame came: the board speaks another protocol version (its frames arrive whole, and
        are not ours to read), or it is not the rod firmware at all."""
        if self.decoder.version_errors:
            return UserError(f"{self.port}: the board's firmware speaks another rodlink version than this rodctl "
                             f"(v{P.VERSION}; {self.decoder.version_errors} frames not read): flash this "
                             "checkout's firmware (`rodctl flash`), or use the rodctl it was built with")
        return UserError(f"{self.port}: no rodlink frames within {timeout:g} s: is the board "
                         "running the rod firmware (flash it with `rodctl flash`)?")

    def __enter__(self) -> "Session":
        if self.ser is None:
            self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self, disarm: bool | None = None) -> None:
        """DISARM (when the port still works), stop the threads, close the port. Idempotent."""
        if self.closed:
            return
        self.closed = True
        if disarm is None:
            disarm = self.disarm_on_close
        self._hb_paused += 1  # the DISARM (any command) is the last sign of life
        try:
            if disarm and self.ser is not None and self.disconnected is None:
                try:
                    self.command(P.Disarm(), timeout=0.5, what="disarm")
                    self.disarm_acked = True
                except (UserError, OSError):
                    pass
        finally:
            self._stop.set()
            if self.ser is not None:
                try:
                    self.ser.cancel_read()
                except Exception:  # noqa: BLE001
                    pass
            for t in (self._heart, self._reader):
                if t is not None and t is not threading.current_thread():
                    t.join(timeout=2)
            if self.ser is not None:
                try:
                    self.ser.close()
                except Exception:  # noqa: BLE001
                    pass

    @property
    def alive(self) -> bool:
        return not self.closed and self.disconnected is None

    def check(self) -> None:
        """Raise UserError when the link has ended (unplugged board, stopped virtual device). Also the
        holder's sign of life that keeps the heartbeats going (liveness_s)."""
        self._checked = time.monotonic()
        self._check_link()

    def _check_link(self) -> None:
        if self.reader_error is not None:
            raise UserError(f"{self.port}: {self.disconnected}")
        if self.disconnected is not None:
            raise UserError(f"{self.port}: device disconnected ({self.disconnected})")

    def elapsed(self) -> float:
        return time.perf_counter() - self.t0

    # --- listeners --------------------------------------------------------------------------
    def add_listener(self, fn: Callable, replay: bool = True) -> None:
        """fn(frame, host_time_s) for every frame, in the reader thread; replay: frames so far first."""
        with self._lock:
            if replay:
                for frame, t in list(self._recent):
                    fn(frame, t)
            self._listeners.append(fn)

    def remove_listener(self, fn: Callable) -> None:
        with self._lock:
            if fn in self._listeners:
                self._listeners.remove(fn)

    # --- threads ----------------------------------------------------------------------------
    def _sync(self, data: bytes) -> bytes:
        """Drop bytes before the first frame boundary (a port opened mid-frame), keep a whole frame."""
        buf = self._sync_buf + data
        i = buf.find(b"\0")
        if i < 0:
            self._sync_buf = buf[-P.MAX_FRAME:]
            return b""
        self._synced = True
        self._sync_buf = b""
        head = buf[:i + 1]
        try:
            P.decode_frame(head)
            return buf
        except P.ProtocolError:
            self.sync_bytes += len(head)
            return buf[i + 1:]

    def _read_loop(self) -> None:
        try:
            self._read_frames()
        except BaseException as e:  # noqa: BLE001 - a reader that stops must not leave the board armed
            if not self._stop.is_set():
                self._reader_died(f"{type(e).__name__}: {e}")

    def _reader_died(self, why: str) -> None:
        """Nobody reads the link any more: stop the heartbeats (the board then disarms itself after its
        heartbeat timeout even if the DISARM below is lost), send DISARM, and end the session so the
        command's next check() fails and it exits non-zero."""
        self.reader_error = why
        self._hb_paused += 1
        try:
            wire = P.encode(P.Disarm(), next(self._seq) & 0xFFFFFFFF, int(time.monotonic() * 1e6) & 0xFFFFFFFF)
            with self._write_lock:
                self.ser.write(wire)  # no ACK can be read now: best effort, and the heartbeat stops anyway
            self.disarm_sent = True
        except Exception:  # noqa: BLE001
            pass
        self._lost(f"the host stopped reading the link ({why}); heartbeats stopped, DISARM sent")

    def _read_frames(self) -> None:
        import serial

        ser = self.ser
        feed = self.decoder.feed
        while not self._stop.is_set():
            try:
                n = ser.in_waiting
                data = ser.read(n if n > 0 else 1)
            except (serial.SerialException, OSError, TypeError, AttributeError) as e:
                if not self._stop.is_set():
                    self._lost(str(e) or type(e).__name__)
                return
            if not data:
                continue
            t = time.perf_counter() - self.t0
            if not self._synced:
                data = self._sync(data)
                if not data:
                    continue
            frames = feed(data)
            if frames:
                self._dispatch(frames, t)

    def _dispatch(self, frames, t: float) -> None:
        with self._cond:
            for f in frames:
                ft = f.type
                if not self._started:
                    if ft == P.MsgType.ACK and f.msg.command_seq in self._start_seqs:
                        self._started = True
                        self._err_base = (self.decoder.crc_errors, self.decoder.errors)
                    else:
                        if ft == P.MsgType.ACK and f.msg.command_seq in self._probe_seqs:
                            self._probe_acked = True
                        self.stale_frames += 1
                        continue
                last = self._last_seq
                if last is not None:
                    gap = (f.seq - last - 1) & 0xFFFFFFFF
                    if gap < 0x80000000:
                        self.seq_gaps += gap
                    else:
                        self.seq_restarts += 1
                self._last_seq = f.seq
                if ft == P.MsgType.TELEMETRY:
                    self.telemetry = f.msg
                    self.telemetry_frame = f
                    self.telemetry_seen += 1
                    if self.dropped_at_connect is None:
                        self.dropped_at_connect = f.msg.frames_dropped
                elif ft == P.MsgType.ACK:
                    waiter = self._pending.get(f.msg.command_seq)
                    if waiter is not None:
                        waiter[1] = f.msg
                        waiter[0].set()
                elif ft == P.MsgType.HELLO:
                    self.hello = f.msg
                    self.hello_seen += 1
                self.frames += 1
                self._recent.append((f, t))
                for fn in self._listeners:
                    try:
                        fn(f, t)
                    except Exception as e:  # noqa: BLE001 - e.g. disk full: the main thread reports it
                        if self.listener_error is None:
                            self.listener_error = e
            self._cond.notify_all()

    def _lost(self, why: str) -> None:
        with self._cond:
            self.disconnected = why
            for waiter in self._pending.values():
                waiter[0].set()
            self._cond.notify_all()

    def _interval(self) -> float:
        iv = self.heartbeat_interval
        h = self.hello
        if h is not None and h.heartbeat_timeout > 0:
            iv = min(iv, max(0.01, h.heartbeat_timeout / 4))
        return iv

    def _heartbeat_loop(self) -> None:
        while not self._stop.wait(self._interval()):
            if self._hb_paused or self.disconnected is not None:
                continue
            if self.liveness_s is not None and time.monotonic() - self._checked > self.liveness_s:
                continue  # the holder has not looked at the link: nobody is in control
            try:
                self._send(P.Heartbeat())
            except UserError:
                return

    @contextlib.contextmanager
    def heartbeat_paused(self):
        """Send no heartbeat inside the block (the host falls silent, as a hung host would)."""
        self._hb_paused += 1
        try:
            yield
        finally:
            self._hb_paused -= 1

    # --- sending ----------------------------------------------------------------------------
    def _send(self, msg, seq: int | None = None) -> int:
        import serial

        self._check_link()  # not check(): the heartbeat thread sends too, and is no sign of the holder's life
        if seq is None:
            seq = next(self._seq) & 0xFFFFFFFF
        wire = P.encode(msg, seq, int(time.monotonic() * 1e6) & 0xFFFFFFFF)
        try:
            with self._write_lock:
                self.ser.write(wire)
        except (serial.SerialException, OSError) as e:
            self._lost(str(e) or type(e).__name__)
            self._check_link()
        return seq

    def command(self, msg, timeout: float = ACK_TIMEOUT_S, what: str | None = None):
        """Send one command and wait for its ACK; returns the Ack, raises UserError on refusal."""
        what = what or P.MsgType(msg.TYPE).name.lower()
        for attempt in range(4):
            ev = threading.Event()
            waiter = [ev, None]
            with self._lock:
                self._pending[seq := next(self._seq) & 0xFFFFFFFF] = waiter
            try:
                self._send(msg, seq)
                ok = ev.wait(timeout)
                self.check()
                if not ok:
                    raise UserError(f"{self.port}: no answer to {what} within {timeout:g} s "
                                    "(is the board running the rod firmware?)")
            finally:
                with self._lock:
                    self._pending.pop(seq, None)
            ack = waiter[1]
            if ack.result == P.AckResult.BUSY and attempt < 3:
                time.sleep(0.01)
                continue
            if ack.result != P.AckResult.OK:
                raise UserError(self._refusal(msg, ack, what))
            return ack
        raise AssertionError("unreachable")

    def _refusal(self, msg, ack, what: str) -> str:
        result = name_of(P.AckResult, ack.result)
        if ack.result == P.AckResult.BAD_STATE:
            if ack.mode == P.Mode.FAULT:
                return fault_text(self.current_reason())
            hint = "" if ack.mode == P.Mode.DISARMED else ": disarm first (rodctl disarm)"
            return f"device refused {what} in mode {name_of(P.Mode, ack.mode)}{hint}"
        if ack.result == P.AckResult.BAD_VALUE:
            return f"device refused {what}: value out of range"
        if ack.result == P.AckResult.BUSY:
            return f"device refused {what}: busy (its command queue full, or storing the rig settings), try again"
        return (f"device refused {what} ({result}): the firmware and this rodctl speak different "
                f"protocol versions? (rodctl protocol v{P.VERSION})")

    def current_reason(self):
        """The device's reason code from its latest telemetry or hello."""
        latest = self.telemetry if self.telemetry is not None else self.hello
        if latest is not None and latest.mode == P.Mode.FAULT:
            return latest.reason
        try:
            return self.request_hello(timeout=0.5).reason
        except UserError:
            return latest.reason if latest is not None else P.Reason.NONE

    # --- commands ---------------------------------------------------------------------------
    def request_hello(self, timeout: float = 1.0):
        """Ask for a HELLO and return it (the first one received after the request)."""
        with self._cond:
            before = self.hello_seen
        deadline = time.monotonic() + timeout
        self._send(P.HelloRequest())
        with self._cond:
            while self.hello_seen == before:
                left = deadline - time.monotonic()
                self.check()
                if left <= 0:
                    if self.decoder.frames == 0:
                        raise self._no_frames(timeout)
                    raise UserError(f"{self.port}: no HELLO within {timeout:g} s")
                self._cond.wait(min(left, 0.1))
            return self.hello

    def wait_telemetry(self, timeout: float = 1.0, newer_than: int | None = None):
        """The next telemetry message (after `newer_than` telemetry frames seen, default: now)."""
        deadline = time.monotonic() + timeout
        with self._cond:
            start = self.telemetry_seen if newer_than is None else newer_than
            while self.telemetry_seen <= start:
                self.check()
                left = deadline - time.monotonic()
                if left <= 0:
                    raise UserError(f"{self.port}: no telemetry within {timeout:g} s")
                self._cond.wait(min(left, 0.1))
            return self.telemetry

    def arm(self, mode) -> object:
        mode = P.ArmMode(mode)
        return self.command(P.Arm(mode), what=f"arm {mode.name.lower().replace('_', '-')}")

    def disarm(self):
        return self.command(P.Disarm(), what="disarm")

    def clear_fault(self):
        """CLEAR_FAULT; UserError when the board keeps the fault (its own: only a restart leaves it)."""
        ack = self.command(P.ClearFault(), what="clear-fault")
        if ack.mode == P.Mode.FAULT:
            raise UserError(f"not cleared: {fault_text(self.current_reason())}")
        return ack

    def set(self, setting: Setting | str, value: float, design_params=None):
        """Set one run-time setting (value in the setting's user unit); returns the ack."""
        if isinstance(setting, str):
            setting = SETTINGS[setting]
        setting.check(value, self.hello, design_params)
        try:
            return self.command(P.Set(setting.param, setting.to_device(value)),
                                what=f"{setting.name}={value:g}")
        except UserError as e:
            if "out of range" in str(e):
                raise UserError(f"device refused {setting.name}={value:g}: allowed "
                                f"{setting.allowed(self.hello, design_params)}") from None
            raise

    def save_rig(self) -> dict[str, float]:
        """SAVE_RIG: store the rig settings in use (signs, counts per turn) on the board for every
        power-on; returns the settings its HELLO reports afterwards (user units)."""
        self.command(P.SaveRig(), what="save-rig")
        # the board writes its EEPROM in its main loop, after the ACK: HELLO flags STORED once it reads back
        deadline = time.monotonic() + 2.0
        while not (hello := self.request_hello()).rig & P.RigFlag.STORED:
            if time.monotonic() > deadline:
                raise UserError(f"{self.port}: the board did not report the rig settings stored within 2 s")
            time.sleep(0.02)
        return hello_settings(hello)

    def set_all(self, pairs: list[tuple[Setting, float]], design_params=None) -> dict[str, float]:
        """Apply every (setting, value) or none; returns the device's settings afterwards (user units).

        Every value is range-checked before the first SET goes out. Should the device still refuse
        one (a bound the host could not know), the ones already applied are set back to the values
        the device reported just before, and the refusal is raised.
        """
        for setting, value in pairs:
            setting.check(value, self.hello, design_params)
        before = hello_settings(self.request_hello())
        done: list[Setting] = []
        try:
            for setting, value in pairs:
                self.set(setting, value, design_params)
                done.append(setting)
        except BaseException:
            for setting in reversed(done):
                with contextlib.suppress(UserError):
                    self.command(P.Set(setting.param, setting.to_device(before[setting.name])),
                                 what=f"restore {setting.name}")
            raise
        return hello_settings(self.request_hello())

    # --- status -----------------------------------------------------------------------------
    def log_trailer(self, ended: str) -> dict:
        """What a log's trailer records of the link when it closes: how it ended ("end", "Ctrl-C",
        "duration", "error", "scope"), the frames, and every loss the host or the board counted."""
        c = self.counters()
        trailer = {"end": ended, "frames": c["frames"], "seq_gaps": c["seq_gaps"], "crc_errors": c["crc_errors"],
                   "decode_errors": c["errors"], "device_frames_dropped": c["device_dropped"],
                   "device_frames_dropped_since_boot": c["device_dropped_boot"], "sync_bytes": self.sync_bytes}
        if self.disconnected:
            trailer["disconnected"] = self.disconnected
        return trailer

    def counters(self) -> dict[str, int]:
        d = self.decoder
        t = self.telemetry
        return {
            "frames": self.frames,
            "crc_errors": d.crc_errors - self._err_base[0],
            "errors": d.errors - self._err_base[1],
            "seq_gaps": self.seq_gaps,
            "seq_restarts": self.seq_restarts,
            # frames the device dropped while this session was connected (and since its boot)
            "device_dropped": int(t.frames_dropped - self.dropped_at_connect) if t is not None else 0,
            "device_dropped_boot": int(t.frames_dropped) if t is not None else 0,
            "device_rx_errors": int(t.rx_errors) if t is not None else 0,
            "overruns": int(t.overruns) if t is not None else 0,
        }


def is_tty(stream) -> bool:
    try:
        return stream.isatty() and os.environ.get("TERM") != "dumb"
    except (AttributeError, ValueError):
        return False
