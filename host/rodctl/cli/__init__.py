"""rodctl: one command line for the testbed. Errors are one line and a non-zero exit, never a traceback."""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from rodgains.errors import UserError

from rodctl import __version__

# Subcommand modules, each with register(subparsers); imported lazily-light so `rodctl gains` starts fast.
COMMAND_MODULES = ["gains", "protocol", "docs", "sil", "status", "check", "record", "console", "simdevice", "logconvert", "plot", "scope", "flash", "sim", "bench", "robustness", "tune", "sweep", "identify", "track"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="rodctl",
        description="Soft-rod testbed: design gains, build and flash the Teensy, simulate, stream and log telemetry.",
    )
    parser.add_argument("--version", action="version", version=f"rodctl {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        importlib.import_module(f"rodctl.cli.{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except UserError as e:
        print(f"rodctl: {e}", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:
        print("rodctl: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        return 0
    except Exception as e:  # a bug: still one line unless asked for the traceback
        if os.environ.get("RODCTL_DEBUG"):
            raise
        print(f"rodctl: internal error: {type(e).__name__}: {e} (set RODCTL_DEBUG=1 for a traceback)", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
