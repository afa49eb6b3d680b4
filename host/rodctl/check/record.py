"""Telemetry of a window of time, as arrays: what every check step measures from."""

from __future__ import annotations

import threading
import time

import numpy as np

from rodctl.link import protocol as P


class Recording:
    """Collects every TELEMETRY frame while open (a Session listener); `arrays()` after."""

    FIELDS = ("time_us", "mode", "reason", "flags", "count", "step_us", "overruns", "frames_dropped", "rx_errors",
              "torque")

    def __init__(self, session):
        self.session = session
        self.rows: list[tuple] = []
        self._lock = threading.Lock()
        self.first_seq: int | None = None
        self.last_seq: int | None = None

    def _on(self, frame, t) -> None:
        if frame.type != P.MsgType.TELEMETRY:
            return
        m = frame.msg
        with self._lock:
            if self.first_seq is None:
                self.first_seq = frame.seq
            self.last_seq = frame.seq
            self.rows.append((frame.time_us, m.mode, m.reason, m.flags, m.encoder_count, m.step_us, m.overruns,
                              m.frames_dropped, m.rx_errors, m.torque))

    def __enter__(self) -> "Recording":
        self.session.add_listener(self._on, replay=False)
        return self

    def __exit__(self, *exc) -> None:
        self.session.remove_listener(self._on)

    def wait(self, seconds: float, until=None) -> None:
        """Record `seconds` (host time), or until until(rows) is true; the link is checked meanwhile."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.session.check()
            if until is not None:
                with self._lock:
                    if until(self.rows):
                        return
            time.sleep(0.02)

    def arrays(self) -> dict[str, np.ndarray]:
        with self._lock:
            rows = list(self.rows)
        if not rows:
            return {k: np.zeros(0) for k in self.FIELDS}
        cols = list(zip(*rows))
        out = {k: np.asarray(v) for k, v in zip(self.FIELDS, cols)}
        # the device clock wraps every 71 min: unwrap relative to the first frame
        out["t_s"] = ((out["time_us"].astype(np.int64) - int(out["time_us"][0])) % (1 << 32)) * 1e-6
        return out
