"""rodctl sil-lib: build the firmware core as a host shared library for given parameters."""

from __future__ import annotations

import shutil
from pathlib import Path

from rodgains.errors import InputError

from rodctl.cli.gains import add_param_args, params_from_args, regenerate_command


def run_sil_lib(args) -> int:
    from rodctl.build.sil_build import build_sil
    from rodctl.cli.outputs import check_output, check_output_folder

    params = params_from_args(args)
    into_folder = bool(args.output) and (Path(args.output).is_dir() or args.output.endswith(("/", "\\")))
    if into_folder:  # before the build; the library's own name is known once built
        check_output_folder(args.output, f"--output {args.output}")
    elif args.output is not None:  # an empty name is refused, not taken for no copy
        check_output(args.output, "--output", make_parent=True, force=args.force)
    args.header = None  # the regenerate line names the parameters, not a header path
    lib = build_sil(params, command=regenerate_command(args))
    if args.output:
        out = Path(args.output) / lib.name if into_folder else Path(args.output)
        if into_folder:
            check_output(out, "--output", make_parent=True, force=args.force)
        try:
            out.parent.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(lib, out)
        except OSError as e:
            raise InputError(f"cannot write {out}: {e.strerror}") from None
        lib = out
    print(f"SIL library for N={params.N} at {1.0 / params.dt:g} Hz (parameters {params.sha256()[:16]})")
    print(lib)
    return 0


def register(sub) -> None:
    p = sub.add_parser(
        "sil-lib",
        help="build the firmware core as a host shared library (SIL) for these parameters",
        description="Generate rod_gains.h for the parameters into build/sil/ (the committed header is not "
                    "touched), compile firmware/src/core + firmware/sil into a shared library with the stable "
                    "rod_sil_* ABI (firmware/sil/rod_sil.h), and print its path as the last line.",
    )
    add_param_args(p)
    p.add_argument("-o", "--output", metavar="PATH", help="also copy the library to PATH (a file or a folder)")
    p.add_argument("--force", action="store_true", help="overwrite an existing --output file (or the library's name in an --output folder)")
    p.set_defaults(func=run_sil_lib)
