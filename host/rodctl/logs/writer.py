"""LogWriter: writes a log as frames arrive (a Session listener), in CSV, Parquet or MCAP.

    w = LogWriter("run.csv", device_metadata(hello, port=...), n=hello.n)   # fmt from the extension
    session.add_listener(w)          # or w.write_telemetry(P.Telemetry(...), seq, time_us) (simulator)
    w.close({"frames": 1234})        # the trailer: counters of the session

One row per TELEMETRY frame (schema.columns); HELLO and ACK frames, mode changes and notes go to
the events. time_s is the device clock unwrapped (schema.DeviceClock). An existing log is never
replaced unless overwrite=True (`--force`).
"""

from __future__ import annotations

import datetime as _dt
import errno
import threading
import time
from pathlib import Path

from rodgains.errors import InputError, UserError

from rodctl.link import protocol as P
from rodctl.logs import schema
from rodctl.logs.metadata import utc_now

FORMATS = ("csv", "parquet", "mcap")
FLUSH_INTERVAL_S = {"csv": 0.25, "parquet": 5.0, "mcap": 0.25}
_NAN = float("nan")


def _host_us(host_time_s: float) -> float:
    """The host's receive time to the microsecond [s], as a CSV cell spells it: every format then holds the same
    value (a USB batch's arrival is known to far less)."""
    return round(float(host_time_s), 6)


EXTENSIONS = {".csv": "csv", ".parquet": "parquet", ".pq": "parquet", ".mcap": "mcap"}


class LogWriteFailed(UserError):
    """The system refused a write to a log (a full disk, a removed drive): the log stops there, as one line says."""


def refused_text(e: OSError) -> str:
    """What the system refused, in a few words ("the disk is full")."""
    if e.errno in (errno.ENOSPC, errno.EDQUOT):
        return "the disk is full"
    if e.errno == errno.EFBIG:  # a FAT32 stick's 4 GB, or `ulimit -f`
        return "the file reached the largest size its disk or the system allows"
    return f"writing failed ({e.strerror or e})"


def log_format(path: str | Path, fmt: str | None = None) -> str:
    """The format to write a log path in: the extension's (.csv, .parquet, .mcap), or fmt, which must
    agree with it; a name with no extension takes fmt, else csv. An unknown extension (run.xlsx) or one
    that contradicts fmt is refused (one line) rather than written in a format its name misstates."""
    if fmt and fmt not in FORMATS:
        raise InputError(f"unknown log format {fmt!r}: {', '.join(FORMATS)}")
    ext = Path(str(path)).suffix.lower()
    if not ext:
        return fmt or "csv"
    if ext not in EXTENSIONS:
        raise InputError(f"{path}: a log is .csv, .parquet or .mcap, not {ext} (a spreadsheet opens the .csv; "
                         "rodctl log-convert turns one into another)")
    if fmt and EXTENSIONS[ext] != fmt:
        raise InputError(f"{path}: --format {fmt} but the name says {EXTENSIONS[ext]}; name it .{fmt} or drop --format")
    return EXTENSIONS[ext]


def default_log_name(fmt: str, folder: str | Path = ".") -> str:
    """rod-YYYYMMDD-HHMMSS.EXT, with -2, -3, ... when a log of that second is already in `folder`: the user did
    not choose the name, so it never collides with the last run's."""
    stamp = _dt.datetime.now().strftime("%Y%m%d-%H%M%S")
    ext = fmt if fmt in ("parquet", "mcap") else "csv"
    name, k = f"rod-{stamp}.{ext}", 1
    while (Path(folder) / name).exists() or (Path(folder) / f"{name}.partial").exists():
        k += 1
        name = f"rod-{stamp}-{k}.{ext}"
    return name


def require_format(fmt: str) -> None:
    """UserError when the library a format needs is missing."""
    lib = {"parquet": "pyarrow", "mcap": "mcap"}.get(fmt)
    if lib is None:
        return
    try:
        __import__(lib)
    except ImportError:
        raise UserError(f"--format {fmt} needs {lib}: pip install {lib}, or log as CSV (--format csv)") from None


def require_pyarrow() -> None:
    require_format("parquet")


def files_of(path: str | Path, fmt: str | None = None) -> list[Path]:
    """Every file a log at `path` writes (a CSV log has a sidecar and an events file)."""
    from rodctl.logs import csvlog

    path = Path(path)
    if log_format(path, fmt) == "csv":
        return [path, csvlog.sidecar_path(path), csvlog.events_path(path)]
    return [path]


def check_new(path: str | Path, fmt: str | None = None, overwrite: bool = False, also=()) -> None:
    """UserError when the log would replace an existing file and overwrite is not set (before any work);
    `also`: files the caller writes beside the log (the simulator's truth file)."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path} is a directory; name a log file")
    if not overwrite:
        for f in [*files_of(path, fmt), *map(Path, also)]:
            if f.exists():
                raise InputError(f"{f} exists: choose another file name, or --force to replace it")


_MODE_NAMES = {int(m): m.name for m in P.Mode}
_REASON_NAMES = {int(r): r.name for r in P.Reason}


def _name(table, v) -> str:
    v = int(v)
    return table.get(v, str(v))


class LogWriter:
    """Writes a log as frames arrive (thread-safe); see the module doc.

    path: the log. metadata: device_metadata(...) or simulator_metadata(...). n: edges (default
    metadata n_edges). fmt: "csv" | "parquet" | "mcap" (default from the extension).
    """

    def __init__(self, path: str | Path, metadata: dict, *, n: int | None = None, fmt: str | None = None,
                 flush_interval: float | None = None, overwrite: bool = False):
        from rodctl.logs import csvlog, mcaplog, parquetlog

        self.path = Path(path)
        self.format = log_format(path, fmt)
        require_format(self.format)
        check_new(self.path, self.format, overwrite)
        self.metadata = dict(metadata)
        self.n = int(n if n is not None else metadata.get("n_edges", 0))
        self.flush_interval = FLUSH_INTERVAL_S[self.format] if flush_interval is None else flush_interval
        self.rows = 0  # telemetry rows
        self.failure: OSError | None = None  # the write the system refused; nothing is written after it
        self.events = 0
        self.heartbeat_acks = 0  # OK acks of heartbeats: counted in the trailer, not written as events
        self.clock = schema.DeviceClock()
        self._last_mode: tuple[int, int] | None = None
        self._buf: list[tuple] = []
        self._held: tuple | None = None  # the latest telemetry row, waiting for its IMU frame
        self.imu_unmatched = 0  # IMU frames that followed no telemetry row
        self._ebuf: list[tuple] = []
        self._lock = threading.Lock()
        self._last_flush = time.monotonic()
        self._pad = (_NAN,) * self.n
        sink = {"csv": csvlog.CsvSink, "parquet": parquetlog.ParquetSink, "mcap": mcaplog.McapSink}[self.format]
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._sink = sink(self.path, self.metadata, self.n)
        except OSError as e:  # the header's own write refused: nothing of this log stays (a re-run is not "exists")
            for f in files_of(self.path, self.format):
                if f.is_file():
                    f.unlink(missing_ok=True)
            if e.errno in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
                raise LogWriteFailed(f"{refused_text(e)}: {self.path} was not written") from None
            raise InputError(f"cannot write {self.path}: {e.strerror or e}") from None
        self.closed = False
        self._kept: tuple[int, float] | None = None  # after a refused write: (rows, seconds) a reader finds

    @property
    def telemetry_rows(self) -> int:
        return self.rows

    # --- rows -------------------------------------------------------------------------------
    def _added(self) -> None:
        if self.failure is not None:  # the file is closed: what is received goes nowhere
            return
        if time.monotonic() - self._last_flush >= self.flush_interval or len(self._buf) >= 20000:
            self._flush_locked()

    def write_telemetry(self, msg, seq: int, time_us: int, host_time_s: float = _NAN) -> None:
        """One telemetry row from a protocol.Telemetry tuple (also the simulator's entry point)."""
        n = self.n
        th, rt = tuple(msg.theta_hat[:n]), tuple(msg.rate_hat[:n])
        if len(th) < n:
            th, rt = (th + self._pad)[:n], (rt + self._pad)[:n]
        mode, reason = int(msg.mode), int(msg.reason)
        with self._lock:
            t = self.clock(time_us)
            if self.failure is not None:
                return
            row = (t, _host_us(host_time_s), int(seq), int(time_us), mode, _name(_MODE_NAMES, mode), reason,
                   _name(_REASON_NAMES, reason), int(msg.flags), int(msg.encoder_count), float(msg.base_rate),
                   float(msg.torque), float(msg.duty), int(msg.step_us), int(msg.overruns),
                   int(msg.frames_dropped), int(msg.rx_errors)) + th + rt
            self._release_held()
            self._held = row + schema.NO_IMU
            self.rows += 1
            if (mode, reason) != self._last_mode:
                what = ("start in " if self._last_mode is None else f"{_name(_MODE_NAMES, self._last_mode[0])} -> ")
                self._event_locked(t, host_time_s, seq, "MODE", mode, reason,
                                   what + _name(_MODE_NAMES, mode) + (f" ({_name(_REASON_NAMES, reason)})"
                                                                      if reason else ""))
                self._last_mode = (mode, reason)
            self._added()

    def _release_held(self) -> None:
        """The held row goes out as it is, its IMU columns empty (lock held)."""
        if self._held is not None:
            self._buf.append(self._held)
            self._held = None

    def _event_locked(self, t, host_time_s, seq, kind, mode, reason, info) -> None:
        if self.failure is not None:
            return
        self._ebuf.append((t, _host_us(host_time_s), int(seq), kind, int(mode), _name(_MODE_NAMES, mode),
                           -1 if reason is None else int(reason),
                           "" if reason is None else _name(_REASON_NAMES, reason), info))
        self.events += 1

    def _event(self, time_us, host_time_s, seq, kind, mode, reason, info) -> None:
        with self._lock:
            t = self.clock(time_us) if time_us is not None else self.clock.us / 1e6
            self._event_locked(t, host_time_s, seq, kind, mode, reason, info)
            self._added()

    def write_hello(self, msg, seq: int, time_us: int, host_time_s: float = _NAN) -> None:
        info = (f"HELLO fw {msg.fw_major}.{msg.fw_minor}.{msg.fw_patch} schema {msg.gains_schema} n {msg.n} "
                f"period_us {msg.period_us} decimation {msg.decimation} swing_amplitude_Nm {msg.swing_amplitude:.6g} "
                f"swing_angle_rad {msg.swing_angle:.6g} catch_angle_rad {msg.catch_angle:.6g} "
                f"heartbeat_timeout_s {msg.heartbeat_timeout:.6g} torque_max_Nm {msg.torque_max:.6g} "
                f"header_sha256 {bytes(msg.header_sha256).hex()}")
        self._event(time_us, host_time_s, seq, "HELLO", msg.mode, msg.reason, info)

    def write_ack(self, msg, seq: int, time_us: int, host_time_s: float = _NAN) -> None:
        if msg.command == P.MsgType.HEARTBEAT and msg.result == P.AckResult.OK:
            with self._lock:  # ten a second, and they say nothing: counted, the clock moves
                self.clock(time_us)
                self.heartbeat_acks += 1
            return
        info = f"ACK {_name({int(t): t.name for t in P.MsgType}, msg.command)} command_seq {msg.command_seq} " \
               f"{_name({int(r): r.name for r in P.AckResult}, msg.result)}"
        self._event(time_us, host_time_s, seq, "ACK", msg.mode, None, info)

    def write_imu(self, msg, seq: int, time_us: int, host_time_s: float = _NAN) -> None:
        """The IMU frame that follows a telemetry frame (seq + 1): its columns join that row."""
        with self._lock:
            self.clock(time_us)
            held = self._held
            if self.failure is not None:
                return
            if held is None or held[2] != int(seq) - 1:
                self.imu_unmatched += 1
                return
            imu = (float(msg.gyro), float(msg.accel_x), float(msg.accel_y), float(msg.gyro_bias),
                   float(msg.encoder_offset), int(msg.status), int(msg.bad_run))
            self._buf.append(held[:-len(imu)] + imu)
            self._held = None
            self._added()

    def note(self, text: str, host_time_s: float = _NAN) -> None:
        """A host event (e.g. "recording started"), at the device time of the latest frame."""
        mode, reason = self._last_mode or (0, 0)
        self._event(None, host_time_s, -1, "NOTE", mode, reason, text)

    def write_frame(self, frame, host_time_s: float = _NAN) -> None:
        """One decoded frame (protocol.Frame): a telemetry row or an event."""
        t = frame.type
        if t == P.MsgType.TELEMETRY:
            self.write_telemetry(frame.msg, frame.seq, frame.time_us, host_time_s)
        elif t == P.MsgType.HELLO:
            self.write_hello(frame.msg, frame.seq, frame.time_us, host_time_s)
        elif t == P.MsgType.ACK:
            self.write_ack(frame.msg, frame.seq, frame.time_us, host_time_s)
        elif t == P.MsgType.IMU:
            self.write_imu(frame.msg, frame.seq, frame.time_us, host_time_s)
        else:  # a host->device type from a device: still recorded
            self._event(frame.time_us, host_time_s, frame.seq, "NOTE", 0, None, f"unexpected {t!r}: {frame.msg!r}")

    __call__ = write_frame  # a Session listener: fn(frame, host_time_s)

    # --- file -------------------------------------------------------------------------------
    def _flush_locked(self) -> None:
        if self.failure is not None:
            raise LogWriteFailed(self._refused())
        try:
            if self._buf:
                rows, self._buf = self._buf, []
                self._sink.write_rows(rows)
            if self._ebuf:
                ev, self._ebuf = self._ebuf, []
                self._sink.write_events(ev)
        except OSError as e:
            self._failed(e)
        self._last_flush = time.monotonic()

    def _failed(self, e: OSError) -> None:
        """Stop at the first refused write (lock held; on the thread that receives the frames, under the session's
        lock): nothing more is written. Only the sink is closed here; what the file keeps is read later, on the
        main thread once the board is disarmed (failure_text): a long log takes seconds to read."""
        self._buf, self._ebuf, self._held = [], [], None
        self.closed = True
        self._sink.abandon()
        self.failure = e  # last: whoever sees it finds the sink closed
        raise LogWriteFailed(self._refused()) from None

    def _refused(self) -> str:
        return f"{refused_text(self.failure)} writing {self.path}"

    def _readable(self) -> tuple[int, float]:
        """(rows, their span [s]) a reader finds in what the failed write left: the rows the file holds, not the
        ones sent to it (an MCAP chunk still in memory, or a CSV line cut, is not in it)."""
        import contextlib
        import io

        from rodctl.logs.reader import device_time_s, read_log

        try:
            with contextlib.redirect_stderr(io.StringIO()):  # its "cut short" warning: failure_text says it
                t = device_time_s(read_log(self.path, ["time_s"]).data)
        except (UserError, OSError, ValueError):
            return 0, 0.0
        return (len(t), float(t[-1])) if len(t) else (0, 0.0)

    def failure_text(self) -> str:
        """One line: what the system refused, and what is left of the log. It reads the file (once), and removes a
        log that holds no row: call it once the board is disarmed."""
        if self._kept is None:
            self._kept = self._readable()
            if not self._kept[0]:
                for f in files_of(self.path, self.format):
                    f.unlink(missing_ok=True)
        rows, span_s = self._kept
        what = refused_text(self.failure)
        if rows:
            left = f"{self.path} keeps its first {rows} rows ({span_s:.1f} s), cut short (plot and log-convert read it)"
        elif self.format == "parquet":
            left = (f"nothing was kept of {self.path} (a Parquet file cannot be read before its end; "
                    "CSV and MCAP logs keep what was written)")
        else:
            left = f"nothing was kept of {self.path}"
        return f"{what}: {left}"

    def append_rows(self, rows: list[tuple], events: list[tuple]) -> None:
        """Write rows already in this log's column order and events (another log's, as log-convert copies them),
        counted as received. LogWriteFailed when the system refuses a write."""
        with self._lock:
            if self.failure is not None:
                raise LogWriteFailed(self._refused())
            self.rows += len(rows)
            self.events += len(events)
            try:
                for k in range(0, len(rows), 50000):  # a long log in slices: the sinks build each in memory
                    self._sink.write_rows(rows[k:k + 50000])
                self._sink.write_events(events)
            except OSError as e:
                self._failed(e)

    def discard(self) -> None:
        """Close and remove every file of this log (a copy that could not be finished: all or nothing)."""
        with self._lock:
            self.closed = True
            self._sink.abandon()
            for f in files_of(self.path, self.format):
                f.unlink(missing_ok=True)

    def flush(self) -> None:
        """Write everything received so far (the latest row too, without waiting for its IMU frame)."""
        with self._lock:
            if self.failure is not None:
                raise LogWriteFailed(self._refused())
            if not self.closed:
                self._release_held()
                self._flush_locked()

    def maybe_flush(self) -> None:
        """The periodic write: the latest row stays back for its IMU frame. LogWriteFailed once a write was refused
        (here or on the thread that receives the frames)."""
        if self.failure is not None:  # the short line: the caller disarms first, then asks failure_text()
            raise LogWriteFailed(self._refused())
        if time.monotonic() - self._last_flush >= self.flush_interval:
            with self._lock:
                if not self.closed:
                    self._flush_locked()

    def close(self, trailer: dict | None = None, *, verbatim: bool = False) -> Path:
        """Write what is left and the trailer (counters). Returns the log path. verbatim: `trailer` is the
        whole trailer, as is (a converted log's; {} or None: none, so the log still reads as cut short),
        without this writer's close time and counts. LogWriteFailed when a write was refused, then or before
        (failure_text: read once the frames' thread is off this writer, as the session's listener removed)."""
        if not self._close_locked(trailer, verbatim):
            raise LogWriteFailed(self.failure_text())  # outside the lock: it reads the file
        return self.path

    def _close_locked(self, trailer: dict | None, verbatim: bool) -> bool:
        """close() under the lock; False when a write was refused."""
        with self._lock:
            if self.failure is not None:
                return False
            if self.closed:
                return True
            try:
                self._release_held()
                self._flush_locked()
            except LogWriteFailed:
                return False
            if verbatim:
                tr = {k: str(v) for k, v in (trailer or {}).items()}
            else:
                tr = {"closed_utc": utc_now(), "rows": str(self.rows), "events": str(self.events),
                      "heartbeat_acks": str(self.heartbeat_acks)}
                if self.imu_unmatched:
                    tr["imu_unmatched"] = str(self.imu_unmatched)
                tr.update({k: str(v) for k, v in (trailer or {}).items()})
            try:
                self._sink.close(tr)
            except Exception as e:  # noqa: BLE001 - pyarrow raises its own kinds on a closing write too
                try:
                    self._failed(e if isinstance(e, OSError) else OSError(errno.EIO, str(e)))
                except LogWriteFailed:
                    return False
            self.closed = True
            return True


def attach_device_log(session, path: str | Path, *, params=None, params_source: str = "unknown", fmt: str | None = None,
                      overwrite: bool = False, replay: bool = False) -> LogWriter:
    """A LogWriter for an open Session's board (device_metadata of its HELLO, its edges), added as its listener.
    replay: also write the frames the session has received so far."""
    from rodctl.logs.metadata import device_metadata

    meta = device_metadata(session.hello, port=session.port, params=params, params_source=params_source,
                           start_unix=session.open_unix)
    writer = LogWriter(path, meta, n=session.hello.n, fmt=fmt, overwrite=overwrite)
    session.add_listener(writer, replay=replay)
    return writer
