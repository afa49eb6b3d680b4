"""rodctl log-convert: any log (CSV, Parquet, MCAP) to any other format."""

from __future__ import annotations

import sys
from pathlib import Path


def run_log_convert(args) -> int:
    from rodctl.cli.outputs import check_name, check_output
    from rodctl.logs.reader import convert_log
    from rodctl.logs.writer import log_format

    src = Path(args.log)
    if args.out is not None:
        check_name(args.out, "--out")  # an empty name is refused, not taken for the default
    fmt = log_format(args.out, args.format) if args.out else (args.format or "parquet")
    out = Path(args.out) if args.out else src.with_suffix("." + fmt)
    check_output(out, "--out", make_parent=True)  # before reading the log: the folder can be written
    convert_log(src, out, fmt=fmt, overwrite=args.force,
                warn=lambda line: print(f"warning: {line}", file=sys.stderr),
                say=lambda line: print(f"{line} ...", file=sys.stderr, flush=True))
    print(f"wrote {out}")
    return 0


def register(sub) -> None:
    p = sub.add_parser("log-convert", help="convert a log between CSV, Parquet and MCAP",
                       description="Read a log in any format (CSV with its sidecar, Parquet, MCAP) and write it in "
                                   "another: every telemetry row, the events and the metadata.")
    p.add_argument("log", metavar="LOG")
    p.add_argument("--out", metavar="PATH", help="the new log (default: LOG with the format's extension)")
    p.add_argument("--format", choices=("csv", "parquet", "mcap"),
                   help="format (default: from --out's extension, else parquet)")
    p.add_argument("--force", action="store_true", help="replace an existing --out")
    p.set_defaults(func=run_log_convert)
