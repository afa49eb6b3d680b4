"""rodctl: one command line for the testbed. Errors are one line and a non-zero exit, never a traceback."""

from __future__ import annotations

import argparse
import re
import sys

# Subcommand modules, each with register(subparsers); imported lazily-light so `rodctl gains` starts fast.
COMMAND_MODULES = ["gains", "protocol", "docs", "sil", "status", "check", "record", "console", "simdevice", "logconvert", "plot", "scope", "flash", "sim", "bench", "robustness", "tune", "sweep", "identify", "track"]


class OneLineParser(argparse.ArgumentParser):
    """argparse's refusals as every other of rodctl's: one line, exit 2 (the usage is behind --help).
    Subcommand parsers are made of the same class."""

    # a value that starts with a minus and reads as numbers is a value, not an option: argparse's own rule
    # takes only -3 and -0.5, so `--hub -10,-12` or `--value -1e-3` would be refused as options
    NEGATIVE_NUMBERS = re.compile(r"^-(\d+\.?\d*|\.\d+)(e[-+]?\d+)?(,-?(\d+\.?\d*|\.\d+)(e[-+]?\d+)?)*$", re.I)

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = self.NEGATIVE_NUMBERS

    def error(self, message):
        self.exit(2, f"{self.prog}: {message}; see {self.prog} --help\n")


def build_parser():
    import importlib

    from rodctl import __version__

    parser = OneLineParser(
        prog="rodctl",
        description="Soft-rod testbed: design gains, build and flash the Teensy, simulate, stream and log telemetry.",
    )
    parser.add_argument("--version", action="version", version=f"rodctl {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(f"rodctl.cli.{name}").register(sub)
    return parser


BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS")


def one_blas_thread() -> None:
    """One BLAS thread unless the user set otherwise, before numpy loads (the pools read it once). rodctl's
    matrices have at most a few hundred rows, too small for a BLAS pool to share out; its threads only
    spin, on the cores --jobs gives to whole runs (a robustness matrix: 20 % less CPU with one).
    Set in the environment, so the --jobs workers and a sim:// board's process start with it too."""
    import os

    for name in BLAS_THREAD_VARIABLES:
        os.environ.setdefault(name, "1")


_SIGINTS = [0]  # Ctrl-Cs seen since main() started


def interrupts() -> int:
    """How many Ctrl-Cs (SIGINT) main() has seen: a command compares it before it arms, so that a Ctrl-C a
    library swallowed (a bare `except:` around an import) still stops it."""
    return _SIGINTS[0]


def _count_and_raise(signum, frame):
    _SIGINTS[0] += 1
    raise KeyboardInterrupt


def _count_only(signum, frame):
    _SIGINTS[0] += 1


def _set_sigint(handler) -> bool:
    """Install `handler` for SIGINT when Python's own is there (not when SIGINT is ignored, as in a
    background job, nor off the main thread); True when installed."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        return False
    if signal.getsignal(signal.SIGINT) not in (signal.default_int_handler, _count_and_raise, _count_only):
        return False
    signal.signal(signal.SIGINT, handler)
    return True


def main(argv: list[str] | None = None) -> int:
    """The `rodctl` entry point. Ctrl-C anywhere, even while the modules load (before any link is open, so
    nothing can be armed), is one line and exit 130.

    While the command modules load (most of the first half second), a Ctrl-C is only noted and acted on
    once they have: raised inside an import it can be swallowed by a library's bare `except:` (the
    command would then go on, and arm) or leave the interpreter to kill itself with SIGINT at exit."""
    one_blas_thread()
    _SIGINTS[0] = 0
    deferred = False
    try:
        deferred = _set_sigint(_count_only)
        try:
            parser = build_parser()
            args = parser.parse_args(argv)
        finally:
            if deferred:
                _set_sigint(_count_and_raise)
        if _SIGINTS[0]:
            raise KeyboardInterrupt
        return _main(parser, args)
    except KeyboardInterrupt as e:
        _interrupted(e)
        return 130
    finally:
        if deferred:  # Python's own again, for a caller of main() in the same process
            _restore_sigint()


def _restore_sigint() -> None:
    import signal

    try:
        if signal.getsignal(signal.SIGINT) in (_count_and_raise, _count_only):
            signal.signal(signal.SIGINT, signal.default_int_handler)
    except (ValueError, KeyboardInterrupt):
        pass


def _interrupted(e: KeyboardInterrupt) -> None:
    name = getattr(e, "signal_name", None)  # rodctl.link.attach.Stopped, not imported: main() stays light
    try:
        print(f"rodctl: stopped by {name}" if name else "rodctl: interrupted", file=sys.stderr, flush=True)
    except (OSError, ValueError, KeyboardInterrupt):
        pass


def _stdout_reader_gone() -> bool:
    """Whether stdout is a pipe whose reader has closed it (poll says POLLERR on the write end)."""
    import select

    try:
        p = select.poll()
        p.register(sys.stdout.fileno(), select.POLLOUT)
        return any(ev & (select.POLLERR | select.POLLHUP) for _, ev in p.poll(0))
    except (OSError, ValueError, AttributeError):
        return False


def _main(parser, args) -> int:
    import os

    from rodgains.errors import UserError

    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    from rodctl.cli.common import stop_signals

    try:
        with stop_signals():  # SIGTERM / SIGHUP end any command as Ctrl-C does: 130 (a command may handle its own)
            return int(args.func(args) or 0)
    except UserError as e:
        print(f"rodctl: {e}", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt as e:
        _interrupted(e)
        return 130
    except BrokenPipeError as e:
        if _stdout_reader_gone():  # `rodctl check | head`: the work was cut short, as SIGPIPE says for other tools
            try:
                os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at the exit's flush
            except (OSError, ValueError):
                pass
            return 141
        print(f"rodctl: {e.strerror or e}", file=sys.stderr)  # another pipe (a worker's, a socket): not the reader's
        return 1
    except OSError as e:  # the system refused a file or a stream (a name too long, a full disk): not a bug of ours
        import errno

        if os.environ.get("RODCTL_DEBUG"):
            raise
        where = f"{e.filename}: " if e.filename else "writing the output: " if e.errno == errno.ENOSPC else ""
        print(f"rodctl: {where}{e.strerror or e}", file=sys.stderr)
        return 2 if e.errno in (errno.ENAMETOOLONG, errno.EINVAL, errno.EISDIR, errno.ENOTDIR) else 1
    except Exception as e:  # a bug: still one line unless asked for the traceback
        if os.environ.get("RODCTL_DEBUG"):
            raise
        if interrupts():  # a Ctrl-C that a library turned into another error (an import it cut short)
            _interrupted(KeyboardInterrupt())
            return 130
        print(f"rodctl: internal error: {type(e).__name__}: {e} (set RODCTL_DEBUG=1 for a traceback)", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
