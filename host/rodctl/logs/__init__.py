"""Telemetry logs: writing (writer), reading (reader), the formats (csvlog, parquetlog, mcaplog), plots.

    from rodctl.logs import LogWriter, read_log
Layout and units: schema.py; metadata (firmware, parameters): metadata.py.
"""

from rodctl.logs.metadata import (device_metadata, edge_length, identify_params, overrides_of, params_of,
                                  simulator_metadata)
from rodctl.logs.reader import Log, convert_log, device_time_s, n_edges, read_log, telemetry, theta_hat
from rodctl.logs.schema import columns, from_upright
from rodctl.logs.writer import LogWriter, check_new, log_format, require_format, require_pyarrow

__all__ = ["Log", "LogWriter", "check_new", "columns", "convert_log", "device_metadata", "device_time_s",
           "edge_length", "from_upright", "identify_params", "log_format", "n_edges", "overrides_of", "params_of",
           "read_log", "require_format", "require_pyarrow", "simulator_metadata", "telemetry", "theta_hat"]
