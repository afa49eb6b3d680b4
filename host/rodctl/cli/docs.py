"""rodctl docs: regenerate the reference pages generated from the code (commands, parameters, SIL ABI)."""

from __future__ import annotations

import sys

from rodctl import paths


def run_docs(args) -> int:
    from rodctl import docsgen

    paths.require_checkout("rodctl docs")
    if args.check:
        stale = docsgen.stale_files()
        if stale:
            print(f"rodctl docs --check: {', '.join(paths.shown(p) for p in stale)} not what the code generates; "
                  f"regenerate with: {docsgen.COMMAND}", file=sys.stderr)
            return 1
        print(f"up to date: {', '.join(paths.shown(p) for p in docsgen.generated_files())}")
        return 0
    written = docsgen.write_stale()
    print(f"wrote {', '.join(paths.shown(p) for p in written)}" if written else "up to date: nothing to write")
    return 0


def register(sub) -> None:
    p = sub.add_parser("docs", help="regenerate the reference pages: commands, parameters, SIL C ABI",
                       description="Write docs/reference/cli.md (every command and option, from these parsers), "
                                   "docs/reference/params.md (every parameter key, from the schema and "
                                   "default.toml) and docs/reference/sil-abi.md (from firmware/sil/rod_sil.h). "
                                   "Needs a clone. Exit 1 with --check when a committed page is stale.")
    p.add_argument("--check", action="store_true", help="exit 1 if a committed page is not what the code generates")
    p.set_defaults(func=run_docs)
