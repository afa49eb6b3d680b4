"""The scope's last act when its X display goes: the board disarmed and the recording closed before the process ends.

Xlib ends the process itself, from C, when the connection to the X server breaks (an ssh -X session dropped, the
server killed) or when an X error reaches its default handler (the scope's window destroyed under Tk): Python's
`finally` blocks never run, the session never sends DISARM, and the board stays armed until its heartbeat
watchdog trips (up to `heartbeat_timeout`, 10 s at most). Both handlers are Xlib's process-wide ones, set through
ctypes on the libX11 that Tk uses; the error handler is set before Tk opens the display, so Tk keeps handling
the errors it expects and passes on only those it would have left to Xlib's default. Only with matplotlib's Tk
backend (TkAgg, the one the scope is tested on): Qt's xcb plugin sets both handlers itself when it opens the
display, and its own exit would win; there the board's watchdog disarms it.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import os
import sys
from typing import Callable

_IO_HANDLER = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p)  # int (*)(Display *)
_ERROR_HANDLER = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p)  # int (*)(Display *, XErrorEvent *)
_KEPT: list = []  # the C callbacks must outlive every call Xlib makes to them


def _libx11():
    if sys.platform != "linux" or not os.environ.get("DISPLAY"):
        return None
    name = ctypes.util.find_library("X11") or "libX11.so.6"
    try:
        return ctypes.CDLL(name)
    except OSError:
        return None


def install(on_lost: Callable[[str], None]) -> bool:
    """Call on_lost(why) and then end the process with exit code 1 when the X display is lost or an X error
    would end it. on_lost must not raise. Returns whether the handlers are set (a machine without libX11, or a
    session without DISPLAY, has no X display to lose; another backend than TkAgg sets its own). Call it before
    the first window is made."""
    import matplotlib

    if matplotlib.get_backend().lower() != "tkagg":
        return False
    x11 = _libx11()
    if x11 is None:
        return False

    def ended(why: str) -> None:
        try:
            on_lost(why)
        finally:
            sys.stderr.flush()
            os._exit(1)  # Xlib would exit() after the handler anyway; this keeps the exit code and the one line

    io = _IO_HANDLER(lambda display: ended("the scope's X display was lost") or 0)
    err = _ERROR_HANDLER(lambda display, event: ended("the scope's window failed (an X error: was it destroyed "
                                                      "under the scope?)") or 0)
    x11.XSetIOErrorHandler.argtypes = [_IO_HANDLER]
    x11.XSetIOErrorHandler.restype = ctypes.c_void_p
    x11.XSetErrorHandler.argtypes = [_ERROR_HANDLER]
    x11.XSetErrorHandler.restype = ctypes.c_void_p
    x11.XSetIOErrorHandler(io)
    x11.XSetErrorHandler(err)
    _KEPT.extend([x11, io, err])
    return True
