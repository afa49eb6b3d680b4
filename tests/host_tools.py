"""Helpers for the host tests: run rodctl as a user would, start `rodctl sim-device --pty`, watch a port, find
the build tools (one policy for a missing one: see tool()).

Not a test module. No mocks: every helper runs the real rodctl code against the virtual board
(sim:// in-process or `rodctl sim-device` in another process on a pseudo-terminal).
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from contextlib import contextmanager

import pytest

from rodctl.link import protocol as P

RODCTL = [sys.executable, "-m", "rodctl.cli"]


def rodctl_env(**extra) -> dict:
    """The environment of a rodctl the test starts: this one's, with no window and no debug tracebacks unless the
    test asks for them in `extra`. A user's MPLBACKEND or desktop session (DISPLAY, WAYLAND_DISPLAY) would
    otherwise decide whether a plot opens a window or writes a file."""
    env = dict(os.environ)
    for k in ("RODCTL_DEBUG", "DISPLAY", "WAYLAND_DISPLAY"):
        env.pop(k, None)
    env["MPLBACKEND"] = "Agg"
    env.update(extra)
    return env


# Build tools. .ci/run installs every one of them, so in CI none is missing. On a machine without one, a test
# that needs it skips naming it (pytest's -ra summary lists it), with two exceptions that fail instead: the host
# C compiler, which the SIL library and so the virtual board are built with (host_compiler), and the ARM tools
# of the generated header's M4F build check in test_gains_design (tool(..., required=True)), which exists to
# prove that header builds for the target.

def tool(name: str, required: bool = False) -> str:
    """Full path of build tool `name`; when missing the test skips naming it, or fails if `required`."""
    path = shutil.which(name)
    if path is None:
        why = f"{name} not installed (bash .ci/run installs it)"
        if required:
            pytest.fail(why)
        pytest.skip(why)
    return path


def needs_tools(*names: str) -> pytest.MarkDecorator:
    """Skip mark for tests that need `names` but call them through rodctl (target_build), not by path."""
    missing = [n for n in names if shutil.which(n) is None]
    return pytest.mark.skipif(bool(missing), reason=f"{', '.join(missing)} not installed (bash .ci/run installs it)")


def host_compiler() -> str:
    """Full path of the host C compiler the SIL library is built with (rodctl.build.native: $CC, else gcc);
    its absence fails the test: .ci/run installs it."""
    from rodctl.build import native
    from rodgains.errors import UserError

    try:
        return shutil.which(native.compiler())
    except UserError as e:
        pytest.fail(f"no host C compiler for the SIL build: {e}")


def host_cxx() -> str:
    """Full path of g++, the host C++ compiler the board layer's headers are checked with; the test skips naming
    it when it is missing."""
    return tool("g++")


@contextmanager
def refusing_port():
    """A localhost port that refuses connections for as long as it is held: bound, so no other program can
    take it meanwhile, and not listening."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        yield s.getsockname()[1]


def until(condition, timeout: float = 30.0) -> bool:
    """Poll `condition` until it holds or `timeout` [s] passes; its last value. A loaded machine runs the
    virtual board and the windows late, never differently: wait for what is checked, not a fixed time."""
    t0 = time.monotonic()
    while not condition() and time.monotonic() - t0 < timeout:
        time.sleep(0.02)
    return bool(condition())


def run_rodctl(*args, timeout: float = 120, env: dict | None = None, input: str | None = None, cwd=None):
    """Run `rodctl ARGS` in a subprocess (in folder cwd); returns CompletedProcess (text)."""
    return subprocess.run([*RODCTL, *args], capture_output=True, text=True, timeout=timeout,
                          env=env or rodctl_env(), input=input, cwd=cwd)


def ctrl_c_as_at_a_terminal() -> None:
    """Popen preexec_fn: a shell starts background jobs (nohup, `cmd &` in a script, so possibly this test run)
    with SIGINT ignored, and a child would inherit that and never see a test's Ctrl-C: give it the
    disposition a terminal gives."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def start_rodctl(*args, env: dict | None = None, **kw) -> subprocess.Popen:
    kw.setdefault("preexec_fn", ctrl_c_as_at_a_terminal)
    return subprocess.Popen([*RODCTL, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=env or rodctl_env(), **kw)


class BoardSaid:
    """What a `rodctl sim-device` process has said on its stderr so far (its mode changes, "A -> B"),
    read without blocking: call it for the text."""

    def __init__(self, proc: subprocess.Popen):
        self._fd = proc.stderr.fileno()
        self._said = bytearray()

    def __call__(self) -> str:
        import select

        while select.select([self._fd], [], [], 0)[0]:
            chunk = os.read(self._fd, 65536)
            if not chunk:
                break
            self._said.extend(chunk)
        return self._said.decode(errors="replace")


@contextmanager
def sim_device(*args, startup_timeout: float = 60):
    """`rodctl sim-device --pty ARGS` in another process; yields (Popen, /dev/pts path)."""
    proc = start_rodctl("sim-device", "--pty", *args)
    try:
        lines = []
        deadline = time.monotonic() + startup_timeout
        while time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            lines.append(line.strip())
            if line.startswith("/dev/"):
                break
        if not lines or not lines[-1].startswith("/dev/"):
            proc.kill()
            raise RuntimeError(f"sim-device did not start: {lines} {proc.stderr.read()}")
        yield proc, lines[-1]
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        for s in (proc.stdout, proc.stderr):
            if s:
                s.close()


class Listener:
    """A passive observer on a serial port: reads and decodes, never writes (sends no heartbeat)."""

    def __init__(self, port: str):
        import serial

        self.ser = serial.Serial(port, 115200, timeout=0.05)
        self.ser.reset_input_buffer()
        self.dec = P.Decoder()
        self.synced = False

    def frames(self, seconds: float):
        """Frames received over `seconds` (the first partial frame skipped), with their arrival time."""
        out = []
        end = time.monotonic() + seconds
        buf = b""
        while time.monotonic() < end:
            data = self.ser.read(self.ser.in_waiting or 1)
            now = time.monotonic()
            if not self.synced:
                buf += data
                i = buf.find(b"\0")
                if i < 0:
                    continue
                data, self.synced = buf[i + 1:], True
            out += [(now, f) for f in self.dec.feed(data)]
        return out

    def wait_for(self, predicate, timeout: float):
        """(arrival time, frame) of the first frame satisfying predicate, or None."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            for now, f in self.frames(0.02):
                if predicate(f):
                    return now, f
        return None

    def close(self):
        self.ser.close()
