"""rodctl build / rodctl flash: regenerate the gains header when the parameters changed, then PlatformIO.

    rodctl build [--env teensy35] [--params F] [--set S.K=V]      pio run -e teensy35
    rodctl flash [--env teensy35] [--port P | --upload-port P]    pio run -e teensy35 -t upload

Before anything is written or built: PlatformIO must be there (`pio`, `platformio`, or
`python3 -m platformio`), platformio.ini must define the environment, the platform must be
installed or the PlatformIO registry reachable, and for flash a Teensy must be on USB. Each
missing piece is one line and a non-zero exit. PlatformIO's whole output goes to
build/pio-<env>.log (or to the terminal with --verbose); a failure is summarized in one line.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from rodgains.atomic_file import atomic_write
from rodgains.errors import InputError, UserError

from rodctl import paths
from rodctl.build import header as gains_header
from rodctl.build import platformio
from rodctl.cli.outputs import check_regenerable
from rodctl.link.session import is_tty


BACK_ON_USB_S = 10.0  # how long a flashed board may take to come back on USB [s]


def project_header(project: Path) -> Path:
    """The gains header a PlatformIO project builds from (its platformio.ini's include folder)."""
    return project / "firmware" / "include" / "rod_gains.h"


def check_upload_port(port: str) -> None:
    """InputError unless `port` can be a Teensy's serial port: an existing device, not a URL (the virtual board runs
    this checkout's core and takes no firmware)."""
    if "://" in port:
        raise InputError(f"--port {port}: flash uploads to a Teensy on USB; the virtual board (sim://) needs no "
                         "firmware: it runs this checkout's core with the parameters it is given")
    if port.startswith("/") and not Path(port).exists():  # a device path (COM3 is not a file on Windows)
        raise InputError(f"--port {port}: no such serial port (a Teensy shows as /dev/ttyACM0 on Linux; without "
                         "--port, flash finds the one on USB)")


def ensure_header(args, project: Path) -> None:
    """Regenerate the project's firmware/include/rod_gains.h (+ .toml) when the parameters changed: the one PlatformIO
    builds (--project-dir's, not this checkout's)."""
    from rodctl.cli.gains import robust_progress

    print("checking the gains header against the parameters (designing) ...", file=sys.stderr, flush=True)
    t = time.monotonic()
    header = project_header(project)
    d, files = gains_header.generated_files(args.params, args.overrides,
                                            None if header.resolve() == paths.COMMITTED_HEADER.resolve() else str(header),
                                            progress=robust_progress)
    stale = gains_header.stale(files)  # as `gains --check` judges it: a path spelled otherwise is no change
    for f in stale:
        atomic_write(f, files[f])
    if stale:
        shown = ", ".join(paths.shown(f) for f in stale)
        print(f"parameters changed: regenerated {shown} (N={d.N}, {1 / d.dt:g} Hz) in {time.monotonic() - t:.1f} s",
              file=sys.stderr, flush=True)
    else:
        print(f"gains header up to date (N={d.N}, {1 / d.dt:g} Hz)", file=sys.stderr, flush=True)


class _Progress:
    """PlatformIO's latest line: rewritten in place on a terminal, every 10 s otherwise."""

    def __init__(self) -> None:
        self.tty = is_tty(sys.stderr)
        self.next_plain = 10.0  # seconds since the start

    def line(self, seconds: float, last_line: str) -> None:
        if self.tty:
            sys.stderr.write(f"\r\x1b[K  {seconds:5.0f} s  {last_line[:100]}")
            sys.stderr.flush()
        elif seconds >= self.next_plain:
            print(f"  {seconds:5.0f} s  {last_line[:100]}", file=sys.stderr, flush=True)
            self.next_plain = seconds + 10

    def end(self) -> None:
        if self.tty:
            sys.stderr.write("\r\x1b[K")
            sys.stderr.flush()


def run_pio_reporting(cmd: list[str], project: Path, env: str, what: str, platform: str, verbose: bool) -> None:
    log = platformio.pio_log(env)
    shown = " ".join(Path(c).name if i == 0 else c for i, c in enumerate(cmd))
    print(f"{what}: {shown}", file=sys.stderr, flush=True)
    if verbose:
        platformio.run_pio(cmd, project, log, what, platform, verbose)
        return
    progress = _Progress()
    seconds = platformio.run_pio(cmd, project, log, what, platform, verbose, progress.line, progress.end)
    print(f"{what}: done in {seconds:.0f} s (output in {log})", file=sys.stderr, flush=True)


def run(args, upload: bool) -> int:
    from rodgains.params import load_params

    what = "flash" if upload else "build"
    if args.project_dir is None:
        paths.require_checkout(f"rodctl {what}")
    elif not args.project_dir.strip():  # an unset shell variable is not this checkout
        raise InputError("--project-dir: empty folder name")
    load_params(args.params, args.overrides)  # the user's inputs first: a bad file is named, exit 2
    project = Path(args.project_dir) if args.project_dir is not None else paths.REPO
    if upload and args.port is not None:
        check_upload_port(args.port)
    header = project_header(project)
    for f in (header, header.with_suffix(".toml")):  # a hand-written header is the user's, as for rodctl gains
        check_regenerable(f, "the project's", force=args.force, inputs=(args.params,))
    platform = platformio.env_platform(project, args.env)
    pio = platformio.find_platformio()
    name = platformio.platform_name(platform)
    if not platformio.platform_installed(name) and not platformio.registry_reachable():
        raise UserError(f"PlatformIO could not install platform {name} (no internet?): it is not in "
                        f"{platformio.platforms_dir()} and {platformio.REGISTRY_HOST} cannot be reached; "
                        f"install it once on a connected machine with `pio pkg install -g -p {name}`")
    upload_port = None
    if upload:
        from rodctl.link.ports import find_port

        upload_port = args.upload_port or args.port
        if upload_port is None and not args.no_port_check:
            find_port(None, simulated=False)  # one clear line when no (or more than one) Teensy is on USB
    ensure_header(args, project)
    cmd = [*pio, "run", "-e", args.env]
    if upload:
        cmd += ["-t", "upload"]
        if upload_port:
            cmd += ["--upload-port", upload_port]
    run_pio_reporting(cmd, project, args.env, what, name, args.verbose)
    if upload:
        from rodctl.link.ports import wait_for_board

        # PlatformIO returns while the board restarts: a `rodctl status` at once would find no Teensy
        back = None if args.no_port_check else wait_for_board(upload_port, BACK_ON_USB_S)
        if back is not None:
            print(f"flashed: the board is back on {back}, DISARMED; check it with `rodctl status`")
        elif args.no_port_check:
            print("flashed: the board restarts DISARMED; check it with `rodctl status`")
        else:
            print(f"flashed, but the board is not back on USB after {BACK_ON_USB_S:g} s: unplug it and plug it in "
                  "again, then `rodctl status`")
    return 0


def register(sub) -> None:
    for name, upload in (("build", False), ("flash", True)):
        desc = ("Regenerate firmware/include/rod_gains.h when the parameters changed, then "
                + ("build and upload the firmware with PlatformIO (pio run -e ENV -t upload)." if upload
                   else "build the firmware with PlatformIO (pio run -e ENV) without uploading."))
        p = sub.add_parser(name, help=("build and upload the firmware (PlatformIO)" if upload
                                       else "build the firmware without uploading (PlatformIO)"),
                           description=desc)
        p.add_argument("--env", default="teensy35", help="PlatformIO environment (default teensy35)")
        p.add_argument("--params", metavar="FILE", help="parameter file (TOML); default: gains/rodgains/default.toml")
        p.add_argument("--set", metavar="SECTION.KEY=VALUE", action="append", default=[], dest="overrides",
                       help="override one parameter (repeatable)")
        p.add_argument("--project-dir", metavar="DIR", help="PlatformIO project (default: the repository root); its "
                                                           "firmware/include/rod_gains.h is the header regenerated")
        p.add_argument("--verbose", "-v", action="store_true", help="show PlatformIO's output as it runs")
        p.add_argument("--force", action="store_true", help="regenerate the project's rod_gains.h (and .toml) even "
                                                            "when they are not files rodctl generated")
        if upload:
            p.add_argument("--port", metavar="PORT", help="the board's serial port (default: the one Teensy on USB)")
            p.add_argument("--upload-port", metavar="PORT", help="passed to PlatformIO as --upload-port")
            p.add_argument("--no-port-check", action="store_true",
                           help="upload even when no Teensy serial port is seen (e.g. a board in its bootloader), "
                                "and do not wait for it to come back on USB after")
        p.set_defaults(func=lambda a, up=upload: run(a, up))
