"""What a log holds: its columns (name, type, unit), its events, the device clock, angles from upright.

Every format (CSV + sidecar, Parquet, MCAP) carries the same telemetry columns, one row per
TELEMETRY frame, and the same events (HELLO, ACK, mode changes, notes), so `read_log` gives the
same arrays whatever the file.
"""

from __future__ import annotations

import math

import numpy as np

from rodctl.link import protocol as P

# The format readers hand read_log the trailer (the counters written at a clean close) under this key, beside
# its values merged into the metadata; read_log takes it out as Log.trailer (log-convert carries it over).
TRAILER_KEY = "\0trailer"
FORMAT_VERSION = "3"  # 3: the tip IMU's columns; 2: without them; 1: CSV with '#' metadata lines (no longer written)

# (name, numpy dtype, unit, meaning). "i8" columns are never empty; "f8" columns are f32 values from the device.
BASE_COLUMNS = [
    ("time_s", "f8", "s", "device clock since the log's first frame, unwrapped (monotonic)"),
    ("host_time_s", "f8", "s", "host receive time since the session opened (arrives in USB batches)"),
    ("seq_count", "i8", "1", "device sequence number (contiguous unless frames were lost)"),
    ("device_time_us", "i8", "us", "raw device clock (u32, wraps after 71.6 min)"),
    ("mode_code", "i8", "1", ", ".join(f"{int(m)} {m.name}" for m in P.Mode)),
    ("mode_name", "U8", "", "mode as text"),
    ("reason_code", "i8", "1", "last disarm/fault reason (docs/architecture.md)"),
    ("reason_name", "U12", "", "reason as text"),
    ("flags_bits", "i8", "1", ", ".join(f"{f.name} {int(f)}" for f in P.TelemetryFlag)),
    ("encoder_count", "i8", "count", "raw encoder count (979.2 per output turn, 0 hanging at power-on)"),
    ("base_rate_rad_s", "f8", "rad/s", "base rate from the encoder tracking filter"),
    ("torque_Nm", "f8", "N m", "commanded torque at the output shaft"),
    ("duty_frac", "f8", "1", "signed PWM duty, -1..1"),
    ("step_time_us", "i8", "us", "control step execution time"),
    ("overruns_count", "i8", "1", "control steps that missed their deadline, since boot"),
    ("frames_dropped_count", "i8", "1", "device frames dropped (TX full), since boot"),
    ("rx_errors_count", "i8", "1", "bad frames the device received, since boot"),
]

# The tip IMU (IMU frames, right after each TELEMETRY of a firmware with sensors.tip_imu); NaN / -1 without one.
IMU_COLUMNS = [
    ("imu_gyro_rad_s", "f8", "rad/s", "tip IMU: rate about z (its edge), as the step read it"),
    ("imu_accel_x_m_s2", "f8", "m/s^2", "tip IMU: specific force along the rod, toward the tip"),
    ("imu_accel_y_m_s2", "f8", "m/s^2", "tip IMU: specific force across the rod, toward increasing theta"),
    ("imu_gyro_bias_rad_s", "f8", "rad/s", "gyro bias: the estimator's in BALANCE, else the mean at rest"),
    ("imu_encoder_offset_rad", "f8", "rad", "the estimator's encoder offset from the rod's base (BALANCE)"),
    ("imu_status_bits", "i8", "1", "FRESH 1, GOOD 2, BIAS_KNOWN 4; -1: no IMU frame"),
    ("imu_bad_run_count", "i8", "1", "unusable IMU samples in a row; -1: no IMU frame"),
]
NO_IMU = (math.nan,) * 5 + (-1, -1)

EVENT_COLUMNS = [
    ("time_s", "f8", "s", "device clock on the telemetry's time axis"),
    ("host_time_s", "f8", "s", "host receive time"),
    ("seq_count", "i8", "1", "device sequence number (-1: an event of the host)"),
    ("event_name", "U8", "", "HELLO | ACK | MODE | NOTE"),
    ("mode_code", "i8", "1", "mode after the event"),
    ("mode_name", "U8", "", "mode as text"),
    ("reason_code", "i8", "1", "reason after the event (-1 on ACK: not carried)"),
    ("reason_name", "U12", "", "reason as text"),
    ("info_text", "U400", "", "one-line summary"),
]


def columns(n: int) -> list[tuple[str, str, str, str]]:
    """(name, dtype, unit, meaning) of every telemetry column of an n-edge estimate."""
    return (BASE_COLUMNS
            + [(f"theta_hat_{i}_rad", "f8", "rad", f"estimated absolute angle of edge {i} (0 hanging, pi upright)")
               for i in range(1, n + 1)]
            + [(f"rate_hat_{i}_rad_s", "f8", "rad/s", f"estimated rate of edge {i}") for i in range(1, n + 1)]
            + IMU_COLUMNS)


def column_names(n: int) -> list[str]:
    return [c[0] for c in columns(n)]


def dtype_of(name: str) -> str:
    for c in BASE_COLUMNS + IMU_COLUMNS + EVENT_COLUMNS:
        if c[0] == name:
            return c[1]
    return "f8"


def is_device_f32(name: str) -> bool:
    """A telemetry column whose values are the device's f32 (every f8 column but the two clocks)."""
    return dtype_of(name) == "f8" and not name.endswith("time_s")


def units(n: int) -> dict[str, dict[str, str]]:
    """{column: {"unit", "meaning"}}, as written to the sidecar, the Parquet schema and the MCAP schema."""
    return {name: {"unit": unit, "meaning": what} for name, _, unit, what in columns(n)}


def n_edges_of(names) -> int:
    return sum(1 for c in names if c.startswith("theta_hat_"))


class DeviceClock:
    """Unwraps the device's u32 microsecond clock into seconds since the first frame, never decreasing.

    A step backwards (a device reset) holds the time instead of jumping back, so time_s stays monotonic.
    """

    def __init__(self):
        self.last: int | None = None
        self.us = 0

    def __call__(self, time_us: int) -> float:
        t = int(time_us) & 0xFFFFFFFF
        if self.last is not None:
            d = (t - self.last) & 0xFFFFFFFF
            if d < 0x80000000:
                self.us += d
        self.last = t
        return self.us / 1e6  # correctly rounded: the CSV's 6 decimals read back to the same double


def unwrap_us(time_us) -> np.ndarray:
    """Seconds since the first sample of a u32 microsecond clock (vectorized DeviceClock)."""
    t = np.asarray(time_us, dtype=np.int64)
    if t.size == 0:
        return np.zeros(0)
    d = np.diff(t) % (1 << 32)
    d = np.where(d >= (1 << 31), 0, d)
    return np.concatenate([[0], np.cumsum(d)]) / 1e6


def from_upright(theta_rad):
    """Angle from the nearest upright [rad] in [-pi, pi): 0 upright whichever way the rod came over (NaN where the
    log's cell is not finite)."""
    with np.errstate(invalid="ignore"):  # a damaged cell stays a gap, without a warning per call
        return np.mod(np.asarray(theta_rad, dtype=float), 2 * math.pi) - math.pi


def from_upright_deg(theta_rad) -> float:
    """A scalar angle from the nearest upright [deg], for status lines."""
    return math.degrees(float(from_upright(theta_rad)))
