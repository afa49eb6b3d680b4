"""rodctl protocol: generate the C protocol macros and docs/protocol.md from firmware/protocol/rodlink.toml."""

from __future__ import annotations

import shlex
import sys
from pathlib import Path

from rodgains.errors import InputError

from rodctl import paths


def run_protocol(args) -> int:
    from rodctl.link import protocol_gen as gen

    if args.root is not None and not args.root.strip():  # an unset shell variable is not this checkout
        raise InputError("--root: empty folder name")
    if not args.root:
        paths.require_checkout("rodctl protocol (without --root)")
    root = Path(args.root) if args.root else paths.REPO
    if not (root / gen.TOML_REL).is_file():
        raise InputError(f"--root {root}: no protocol definition at {root / gen.TOML_REL}")
    if args.check:
        stale = gen.stale_files(root)
        if stale:
            names = ", ".join(paths.shown(p, root) for p in stale)
            print(f"rodctl protocol --check: {names} not what {gen.TOML_REL} generates; "
                  f"regenerate with: {gen.COMMAND}" + (f" --root {shlex.quote(args.root)}" if args.root else ""),
                  file=sys.stderr)
            return 1
        print(f"up to date: {', '.join(paths.shown(p, root) for p in gen.generated_files(root))}")
        return 0
    from rodctl.cli.outputs import check_output

    files = gen.generated_files(root)
    for p in files:  # every target, before the first is written
        check_output(p, "cannot write", make_parent=True)
    written = gen.write_files(root, files)
    print(f"wrote {', '.join(paths.shown(p, root) for p in written)}")
    return 0


def register(sub) -> None:
    p = sub.add_parser("protocol", help="generate rod_protocol_defs.h and docs/protocol.md from rodlink.toml",
                       description="Generate firmware/src/core/rod_protocol_defs.h (C macros) and docs/protocol.md "
                                   "(byte tables) from firmware/protocol/rodlink.toml. "
                                   "Exit 1 with --check: a generated file is stale; exit 2: the TOML is invalid.")
    p.add_argument("--check", action="store_true", help="exit 1 if a generated file is not what the TOML generates")
    p.add_argument("--root", metavar="DIR", help="checkout (or copy) to work on; default: this checkout")
    p.set_defaults(func=run_protocol)
