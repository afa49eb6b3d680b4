"""pyserial URL handler for sim://: a virtual board in this process, as a serial port.

    import serial, rodctl.link.urlhandler
    rodctl.link.urlhandler.register()
    port = serial.serial_for_url("sim://?plant=der&edges=20&params=my_rod.toml", timeout=0.1)

Opening the port powers the virtual board on (rodctl.sim.device: the firmware's host build, the
rod_dev_* path with the real protocol, against the simulated rod hanging at rest) and starts it
in real time; closing powers it off. Options in the query:
    plant=inextensible|der   simulated rod model (default: the parameters' [plant] model)
    plant=HIDDEN.toml        the rod the board drives comes from this parameter file (its [plant] table,
                             motor, friction), while the firmware is built from params= (system
                             identification: the host is not told the plant)
    edges=N                  plant edges (default: the parameters' plant.edges)
    params=PATH              parameter file for both the firmware build and the plant (default
                             gains/rodgains/default.toml)
    set=SECTION.KEY=VALUE    override one parameter of both (repeatable; `--set` of device commands)
    theta0_deg=DEG           every edge's angle at power-on (0 hanging, 180 upright; default 0)
    eeprom=PATH              the board's EEPROM as a file: the rig settings SAVE_RIG stored, read at power-on
                             (default: blank at every power-on)
    encoder_sign=-1, motor_sign=-1, encoder=dead, ab_swapped, counts_per_rev=X, nfault=low, supply=off,
    boot_angle_deg=DEG, header=stale, hand=none
                             wiring faults of a first power-on (rodctl.sim.faults), for `rodctl check`
Writes go to the board's RX buffer, reads return what its USB would send. Baud rate and line
settings are accepted and ignored, as by the Teensy's USB serial.
"""

from __future__ import annotations

import threading
import time
import urllib.parse as urlparse

from serial.serialutil import PortNotOpenError, SerialBase, SerialException, to_bytes

from rodctl.sim.faults import FAULT_OPTIONS

OPTIONS = ("plant", "edges", "params", "set", "theta0_deg", "eeprom", *FAULT_OPTIONS)
REPEATABLE = ("set",)


class BadURL(SerialException):
    """A sim:// URL or a file it names that cannot be used: the user's input (rodctl exits 2), not a board
    fault."""


def parse_url(url: str) -> dict[str, str]:
    """Options of a sim:// URL; raises BadURL on a malformed one."""
    parts = urlparse.urlsplit(url)
    if parts.scheme != "sim":
        raise BadURL(f"expected a URL like sim://?plant=der&edges=20&params=FILE, got {url!r}")
    if parts.netloc or parts.path not in ("", "/"):
        raise BadURL(f"sim:// takes options only after '?', e.g. sim://?edges=20 (got {url!r})")
    opts: dict[str, str] = {}
    for key, values in urlparse.parse_qs(parts.query, keep_blank_values=True).items():
        if key not in OPTIONS:
            raise BadURL(f"unknown sim:// option {key!r}: options are {', '.join(OPTIONS)}")
        opts[key] = values if key in REPEATABLE else values[-1]
    return opts


class Serial(SerialBase):
    """A virtual board behind the pyserial API (in-process, real time)."""

    MAX_BACKLOG = 1 << 20  # unread device bytes before the board sees a full USB buffer

    def __init__(self, *args, **kwargs):
        self.device = None
        self._runner = None
        self._rx = bytearray()  # device -> host, not yet read
        self._tx = bytearray()  # host -> device, not yet taken
        self._cond = threading.Condition()
        self._cancel = False
        super().__init__(*args, **kwargs)

    # --- life cycle -------------------------------------------------------------------------
    def open(self):
        if self.is_open:
            raise SerialException("Port is already open.")
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        from rodgains.errors import UserError

        from rodctl.sim.device import RealTimeRunner, VirtualDevice

        opts = parse_url(self.portstr)
        try:
            self.device = VirtualDevice.from_options(**opts)
        except UserError as e:
            kind = BadURL if e.exit_code == 2 else SerialException  # a missing params= file, not a failed compile
            raise kind(f"sim://: {e}") from None
        self._rx.clear()
        self._tx.clear()
        self._runner = RealTimeRunner(self.device, take_input=self._take_input, deliver=self._deliver,
                                      backlog=lambda: len(self._rx), max_backlog=self.MAX_BACKLOG,
                                      name="sim://").start()
        self.is_open = True

    def close(self):
        if self._runner is not None:
            self._runner.stop()
            self._runner = None
        if self.device is not None:
            self.device.close()
        self.is_open = False
        with self._cond:
            self._cond.notify_all()

    def _reconfigure_port(self):
        pass

    # --- the runner's side --------------------------------------------------------------------
    def _take_input(self) -> bytes:
        if not self._tx:
            return b""
        with self._cond:
            data = bytes(self._tx)
            self._tx.clear()
        return data

    def _deliver(self, data: bytes) -> None:
        with self._cond:
            self._rx += data
            self._cond.notify_all()

    def _check(self):
        if not self.is_open:
            raise PortNotOpenError()
        r = self._runner
        if r is not None and r.error is not None:
            raise SerialException(f"virtual board stopped: {type(r.error).__name__}: {r.error}")

    # --- pyserial API -----------------------------------------------------------------------
    @property
    def in_waiting(self):
        self._check()
        return len(self._rx)

    @property
    def out_waiting(self):
        self._check()
        return len(self._tx)

    def read(self, size=1):
        self._check()
        deadline = None if self._timeout is None else time.monotonic() + self._timeout
        with self._cond:
            self._cancel = False
            while len(self._rx) < size and self.is_open and not self._cancel:
                if self._runner is not None and self._runner.error is not None:
                    break
                if deadline is None:
                    self._cond.wait(0.5)
                else:
                    left = deadline - time.monotonic()
                    if left <= 0:
                        break
                    self._cond.wait(left)
            data = bytes(self._rx[:size])
            del self._rx[:size]
        if not data:
            self._check()
        return data

    def write(self, data):
        self._check()
        data = to_bytes(data)
        with self._cond:
            self._tx += data
        return len(data)

    def cancel_read(self):
        with self._cond:
            self._cancel = True
            self._cond.notify_all()

    def cancel_write(self):
        pass

    def reset_input_buffer(self):
        self._check()
        with self._cond:
            self._rx.clear()

    def reset_output_buffer(self):
        self._check()
        with self._cond:
            self._tx.clear()

    def flush(self):
        # like a serial port's drain: wait until the board took what was written
        end = time.monotonic() + 1.0
        while self._tx and self.is_open and time.monotonic() < end:
            time.sleep(0.001)

    def _update_break_state(self):
        pass

    def _update_rts_state(self):
        pass

    def _update_dtr_state(self):
        pass

    @property
    def cts(self):
        return True

    @property
    def dsr(self):
        return True

    @property
    def ri(self):
        return False

    @property
    def cd(self):
        return True
