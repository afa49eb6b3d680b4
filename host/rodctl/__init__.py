"""rodctl: the host tool for the soft-rod testbed (gains, firmware build, simulator, telemetry).

    import rodctl
    with rodctl.Session("sim://") as s:          # a board, or the virtual one (sim:// is registered
        s.arm(rodctl.P.ArmMode.BALANCE)          # with pyserial by importing rodctl)
    meta, data = rodctl.read_log("run.csv")     # any log: CSV, Parquet, MCAP (numpy structured array)
    outcome = rodctl.run_scenario("swingup")    # a simulated experiment (rodctl sim --list)

Session, read_log, LogWriter, run_scenario and P (the protocol) load on first use, so
`import rodctl` stays fast.
"""

__version__ = "0.1.0"

_LAZY = {
    "Session": ("rodctl.link.session", "Session"),
    "read_log": ("rodctl.logs.reader", "read_log"),
    "LogWriter": ("rodctl.logs.writer", "LogWriter"),
    "run_scenario": ("rodctl.sim.scenarios", "run_scenario"),
    "P": ("rodctl.link.protocol", None),
}

__all__ = ["LogWriter", "P", "Session", "__version__", "read_log", "run_scenario"]


def __getattr__(name):
    if name not in _LAZY:
        raise AttributeError(f"module 'rodctl' has no attribute {name!r}")
    import importlib

    mod, attr = _LAZY[name]
    m = importlib.import_module(mod)
    value = m if attr is None else getattr(m, attr)
    globals()[name] = value
    return value


def _register_sim_url() -> None:
    """Make serial.serial_for_url("sim://...") open the virtual board (when pyserial is installed)."""
    try:
        from rodctl.link.urlhandler import register
    except ImportError:  # pragma: no cover - pyserial is a dependency
        return
    try:
        register()
    except ImportError:
        pass


_register_sim_url()
