"""A scripted board on a pseudo-terminal: answers the handshake and commands, streams telemetry,
and sends what a test asks for (e.g. a CRC-valid TELEMETRY frame with a 0-1 byte payload).

Not a test module. Unlike `rodctl sim-device` it runs no firmware: it lets a test send frames the
firmware never would, and records every frame the host sent, with its arrival time.
"""

from __future__ import annotations

import collections
import os
import threading
import time
import tty

from rodctl.link import protocol as P


class FakeBoard:
    def __init__(self, telemetry_period_s: float = 0.01):
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)
        self.period = telemetry_period_s
        self.received: list[tuple[float, P.Frame]] = []  # (monotonic time, frame from the host)
        self.mode = P.Mode.DISARMED
        self.inject: list[bytes] = []  # raw wire frames to send before the next telemetry
        self.before_arm_ack: list[bytes] = []  # raw wire frames to send just before the next ARM's ACK
        self.telemetry_sent = 0
        self.telemetry_by_mode: collections.Counter = collections.Counter()  # telemetry sent, by the mode it reported
        self._seq = 0
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._send_lock = threading.Lock()
        self._threads = [threading.Thread(target=self._rx, daemon=True), threading.Thread(target=self._tx, daemon=True)]

    # --- what the test uses ---
    def __enter__(self) -> "FakeBoard":
        for t in self._threads:
            t.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(timeout=5)
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass

    def short_telemetry(self, payload: bytes) -> bytes:
        """A CRC-valid TELEMETRY frame whose payload is `payload` (too short to hold a telemetry)."""
        return P.encode_packet(P.MsgType.TELEMETRY, self._next_seq(), 0, payload)

    def times_of(self, msg_type) -> list[float]:
        with self._lock:
            return [t for t, f in self.received if f.type == msg_type]

    # --- the board ---
    def _next_seq(self) -> int:
        self._seq += 1
        return self._seq

    def _write(self, data: bytes) -> None:
        try:
            os.write(self.master, data)
        except OSError:
            self._stop.set()

    def _send(self, msg) -> None:
        # the ACKs (receive thread) and the telemetry (send thread) share one sequence: numbered and written as
        # one, or the host may see 10, 12, 11 and count a gap the board never made
        with self._send_lock:
            self._write(P.encode(msg, self._next_seq(), int(time.monotonic() * 1e6) & 0xFFFFFFFF))

    def _hello(self):
        return P.Hello(fw_major=0, fw_minor=1, fw_patch=0, gains_schema=1, n=2, mode=self.mode, reason=0, rig=0,
                       period_us=1000, decimation=10, swing_amplitude=0.05, swing_angle=0.5, catch_angle=0.5,
                       heartbeat_timeout=0.5, torque_max=0.2, header_sha256=bytes(32), counts_num=4896, counts_den=5)

    def _rx(self) -> None:
        dec = P.Decoder()
        while not self._stop.is_set():
            try:
                data = os.read(self.master, 4096)
            except OSError:
                return
            for f in dec.feed(data):
                with self._lock:
                    self.received.append((time.monotonic(), f))
                if f.type in (P.MsgType.HEARTBEAT,):
                    continue
                if f.type == P.MsgType.ARM:
                    self.mode = P.Mode.SWING_UP
                    while self.before_arm_ack:
                        self._write(self.before_arm_ack.pop(0))
                elif f.type == P.MsgType.DISARM:
                    self.mode = P.Mode.DISARMED
                self._send(P.Ack(command=f.type, result=P.AckResult.OK, command_seq=f.seq, mode=self.mode))
                if f.type == P.MsgType.HELLO_REQUEST:
                    self._send(self._hello())

    def _tx(self) -> None:
        while not self._stop.wait(self.period):
            while self.inject:
                self._write(self.inject.pop(0))
            mode = self.mode
            self._send(P.Telemetry(mode=mode, reason=0, flags=4, n=2, encoder_count=0, base_rate=0.0,
                                   torque=0.0, duty=0.0, step_us=50, overruns=0, frames_dropped=0, rx_errors=0,
                                   theta_hat=(0.0, 0.0), rate_hat=(0.0, 0.0)))
            self.telemetry_sent += 1
            self.telemetry_by_mode[mode] += 1
