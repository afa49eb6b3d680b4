"""rodctl gains / rodctl params: design the sampled-loop gains and write the firmware header."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from rodgains import atomic_file
from rodgains.errors import InputError
from rodgains.params import Params, load_params

from rodctl import paths
from rodctl.build import header as gains_header
from rodctl.cli.outputs import (check_name, check_not_input, check_output, check_output_folder, check_regenerable,
                                make_folder)


def add_param_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--params", metavar="FILE", help="parameter file (TOML); default: Table I rod, gains/rodgains/default.toml")
    p.add_argument("--set", metavar="SECTION.KEY=VALUE", action="append", default=[], dest="overrides",
                   help="override one parameter, e.g. --set rod.edges=8 (repeatable)")


def params_from_args(args) -> Params:
    return load_params(args.params, args.overrides)


def set_line(args) -> str:
    """The --set overrides on the parameter file as a figure title's last line ("" without any): the title names
    the design it shows, not only its file."""
    return f"\n--set {' '.join(args.overrides)}" if getattr(args, "overrides", None) else ""


def robust_progress(run: int, most: int) -> None:
    """One line per L-BFGS run of a robust refinement (design.method = robust): 1 to 3 s each, up to
    half a minute in all on a new parameter file; a cached design prints nothing."""
    if run == 1:
        print(f"rodctl: refining the gains on the robust model family (design.method = robust): up to {most} "
              "optimizer runs of 1 to 3 s each, stopping once the design most runs reach cannot change",
              file=sys.stderr, flush=True)
    end = "\r" if sys.stderr.isatty() else "\n"
    print(f"  run {run} of at most {most}", end=end, file=sys.stderr, flush=True)


def generated_files(args) -> tuple[object, dict[Path, str]]:
    """Design, then the files `rodctl gains` would write: (Design, {path: text}), the robust refinement's
    progress on stderr."""
    return gains_header.generated_files(args.params, args.overrides, args.header, progress=robust_progress)


def regenerate_command(args) -> str:
    return gains_header.regenerate_command(args.params, args.overrides, args.header)


def buckling_warning(p: Params) -> str | None:
    """One line when the rod above the hub is at or past its clamped buckling length, else None."""
    from rodgains.buckling import clamped_ratio

    ratio = clamped_ratio(p)
    if ratio < 1.0:
        return None
    return (f"the rod above the hub is {ratio:.2f} x its clamped buckling length: it bends over whenever the shaft "
            "holds still, and only a shaft that moves under it can hold it (docs/scenarios.md, longest rod); "
            "rodctl gains --report checks this design on the faithful plant")


def _write(path: Path, text: str) -> None:
    try:
        atomic_file.atomic_write(path, text)
    except OSError as e:
        raise InputError(f"writing {path} failed: {e.strerror or e}") from None


def run_gains(args) -> int:
    # `is not None`: an empty name (an unset shell variable) is refused, never taken for "not given",
    # which would write the committed header in the checkout
    if args.json is not None:
        if args.check:  # --check writes nothing: a --json beside it would be dropped without a word
            raise InputError("--check writes nothing; drop --json, or write the design without --check")
        check_output(args.json, "--json", force=args.force)
        check_not_input(args.json, "--json", (args.params,))
        if args.header is not None and args.header.strip():
            h = Path(args.header).resolve()
            if Path(args.json).resolve() in (h, h.with_suffix(".toml")):  # the second write would replace the first
                raise InputError(f"--json {args.json}: --header {args.header} writes that file too; name another")
    if args.header is not None:
        check_name(args.header, "--header")
        if Path(args.header).suffix == ".toml":  # the parameter record beside the header would be the header itself
            raise InputError(f"--header {args.header}: the header's parameter record is written beside it as "
                             f"{Path(args.header).with_suffix('.toml')}; name the header *.h")
    elif not (args.report or args.json or args.check):
        paths.require_checkout("writing the committed header (or pass --header PATH)")
    if (args.header or not (args.report or args.json)) and not args.check:  # the header will be written
        header = Path(args.header) if args.header else paths.COMMITTED_HEADER
        check_output_folder(header.parent, f"--header {header}")
        # the header and its parameter copy beside it replace earlier ones, never a user's own file
        for f in (header, header.with_suffix(".toml")):
            check_regenerable(f, "--header", force=args.force, inputs=(args.params,))
    d, files = generated_files(args)
    if args.report:  # the report ends on the faithful plant: refuse before printing half of it
        from rodctl.sim.plant import check_faithful

        check_faithful(d.params)
    warning = buckling_warning(d.params)
    if warning:
        print(f"warning: {warning}", file=sys.stderr)
    if args.report:
        from rodgains.report import report_text

        sys.stdout.write(report_text(d))
        from rodctl.sim.linear_check import report_lines

        sys.stdout.write("\n".join(report_lines(d)) + "\n")
    if args.check:
        stale = gains_header.stale(files)
        if stale:
            missing = [str(f) for f in stale if not Path(f).exists()]
            names = ", ".join(str(f) for f in stale if str(f) not in missing)
            what = "; ".join(([f"{', '.join(missing)} missing"] if missing else [])
                             + ([f"{names} not what the parameters generate"] if names else []))
            print(f"rodctl gains --check: {what}; regenerate with: {regenerate_command(args)}", file=sys.stderr)
            return 1
        print(f"up to date: {', '.join(str(f) for f in files)}")
        return 0
    if args.json:
        _write(Path(args.json), json.dumps(d.to_json(), indent=1) + "\n")
        print(f"wrote {args.json}")
    if args.header or not (args.report or args.json):
        for f, text in files.items():
            make_folder(f.parent, f"--header {f}")
            _write(f, text)
        rho = d.checks["closed_loop_spectral_radius"]
        from rodgains.report import radius_text

        print(f"wrote {', '.join(str(f) for f in files)}  (N={d.N}, {1 / d.dt:g} Hz, "
              f"closed-loop spectral radius {radius_text(rho, 5)})")  # 0.9999999991 is not "1.00000"
    return 0


def run_params(args) -> int:
    text = params_from_args(args).to_toml()
    if args.out is not None:  # an empty name (an unset shell variable) is refused, not taken for stdout
        check_output(args.out, "--out", force=args.force)
        _write(Path(args.out), text)
        print(f"wrote {args.out}")
    else:
        sys.stdout.write(text)
    return 0


def register(sub) -> None:
    g = sub.add_parser("gains", help="design the sampled-loop LQR and observer, write the firmware header",
                       description="Design gains for the sampled loop and generate firmware/include/rod_gains.h. "
                                   "Exit 2: bad parameters; exit 3: the design would not stabilize the loop.")
    add_param_args(g)
    g.add_argument("--header", metavar="PATH", help="write the header here (default firmware/include/rod_gains.h; "
                                                    "with --report or --json and no --header, none is written)")
    g.add_argument("--json", metavar="PATH", help="write the design (A, B, Ad, Bd, C, K, L, ...) as JSON")
    g.add_argument("--check", action="store_true", help="exit 1 if the header on disk is not what the parameters generate")
    g.add_argument("--report", action="store_true", help="print poles, margins, critical lengths, the paper's K sampled")
    g.add_argument("--force", action="store_true",
                   help="overwrite an existing --json, or a --header PATH (or the .toml beside it) rodctl did not generate")
    g.set_defaults(func=run_gains)

    pp = sub.add_parser("params", help="print or write a complete parameter file (defaults plus --set)")
    add_param_args(pp)
    pp.add_argument("--out", metavar="PATH", help="write to PATH instead of stdout")
    pp.add_argument("--force", action="store_true", help="overwrite --out")
    pp.set_defaults(func=run_params)
