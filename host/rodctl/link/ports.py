"""Finding the board: the Teensy's USB VID:PID, or a --port the user names (pyserial URL or sim://)."""

from __future__ import annotations

from rodgains.errors import UserError

TEENSY_VID = 0x16C0
TEENSY_PID = 0x0483  # Teensyduino USB serial


def _describe(p) -> str:
    ident = f"{p.vid:04X}:{p.pid:04X}" if p.vid is not None else "no USB id"
    serial = f" serial {p.serial_number}" if getattr(p, "serial_number", None) else ""
    return f"{p.device} ({ident}{serial})"


def _is_teensy(p) -> bool:
    return p.vid == TEENSY_VID and p.pid == TEENSY_PID


def find_port(explicit: str | None = None, simulated: bool = True) -> str:
    """The port to open: `explicit` when given, else the one Teensy on USB; one clear error otherwise (naming the
    virtual board when `simulated`: a command that can talk to it)."""
    if explicit:
        return explicit
    from serial.tools import list_ports

    ports = list(list_ports.comports())
    teensies = [p for p in ports if _is_teensy(p)]
    if len(teensies) == 1:
        return teensies[0].device
    if not teensies:
        seen = ", ".join(_describe(p) for p in ports) or "none"
        raise UserError(
            f"no Teensy found (USB {TEENSY_VID:04X}:{TEENSY_PID:04X}); serial ports seen: {seen}. "
            "Plug the board in, or pass --port PORT" + (" (or --port sim:// for the simulated rod)" if simulated else "")
        )
    listed = ", ".join(_describe(p) for p in teensies)
    raise UserError(f"{len(teensies)} Teensy boards found: {listed}; choose one with --port")


def wait_for_board(port: str | None, timeout_s: float, poll_s: float = 0.2, stay_s: float = 2.0) -> str | None:
    """After an upload the Teensy restarts and comes back on USB a second or two later: the port it is back
    on (`port` when given, else the one Teensy) once it has left the list and is in it again, or has stayed
    in it stay_s [s] (it was back before the first look); None after timeout_s [s]."""
    import time

    from serial.tools import list_ports

    end = time.monotonic() + timeout_s
    gone, listed_since = False, None
    while True:
        listed = list(list_ports.comports())
        if port is not None:
            here = port if any(p.device == port for p in listed) else None
        else:
            teensies = [p.device for p in listed if _is_teensy(p)]
            here = teensies[0] if len(teensies) == 1 else None
        now = time.monotonic()
        if here is None:
            gone, listed_since = True, None
        elif gone:
            return here
        elif listed_since is None:
            listed_since = now
        elif now - listed_since >= stay_s:
            return here
        if now >= end:
            return None
        time.sleep(poll_s)
