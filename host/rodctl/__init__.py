"""rodctl: the host tool for the soft-rod testbed (gains, firmware build, simulator, telemetry)."""

__version__ = "0.1.0"
