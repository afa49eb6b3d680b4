"""rodctl sim-device: the virtual board on a pseudo-terminal, for any serial tool."""

from __future__ import annotations

import contextlib
import os
import sys
import time
from pathlib import Path

from rodgains.errors import InputError, UserError
from rodctl.cli.common import check_duration, mode_text, stop_signals


def run_sim_device(args) -> int:
    import tty as _tty

    from rodctl.sim.device import RealTimeRunner, VirtualDevice

    check_duration(args.duration)
    if args.link is not None:  # an empty name is refused, not taken for no link
        check_link(args.link)
    if not hasattr(os, "openpty"):
        raise UserError("sim-device --pty needs a POSIX system (pseudo-terminals)")
    dev = VirtualDevice.from_options(plant=args.plant, edges=args.edges, params=args.params, set=args.overrides,
                                     theta0_deg=args.theta0_deg)
    master, slave = os.openpty()
    _tty.setraw(slave)  # bytes pass untouched, no echo, for any tool that opens it
    name = os.ttyname(slave)
    os.set_blocking(master, False)
    out_pending = bytearray()

    def take_input() -> bytes:
        chunks = []
        while True:
            try:
                b = os.read(master, 65536)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:
                break
            if not b:
                break
            chunks.append(b)
        return b"".join(chunks)

    def push() -> None:
        while out_pending:
            try:
                k = os.write(master, out_pending)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:
                out_pending.clear()
                return
            del out_pending[:k]

    def deliver(data: bytes) -> None:
        out_pending.extend(data)
        push()

    def backlog() -> int:
        push()
        return len(out_pending)

    last = [dev.mode, dev.reason]

    def watch() -> None:
        m, r = dev.mode, dev.reason
        if [m, r] != last:
            print(f"sim-device: t={dev.time:.3f} s: {mode_text(last[0], last[1])} -> {mode_text(m, r)}",
                  file=sys.stderr, flush=True)
            last[:] = [m, r]

    link = None
    if args.link:
        link = Path(args.link)
        try:
            if link.is_symlink():  # an earlier sim-device's link: replaced
                link.unlink()
            link.symlink_to(name)
        except OSError as e:
            for fd in (master, slave):
                with contextlib.suppress(OSError):
                    os.close(fd)
            dev.close()
            raise InputError(f"--link {link}: cannot make the link: {e.strerror or e}") from None
    # What the USB link and the host's serial driver hold unread (like a CDC-ACM port's 64 kB): beyond
    # it the board's own TX buffer fills and it drops frames, counted in telemetry.frames_dropped.
    runner = RealTimeRunner(dev, take_input=take_input, deliver=deliver, backlog=backlog, max_backlog=65536,
                            on_batch=watch, name="sim-device")
    print(f"virtual board: {dev.describe()}", flush=True)
    print(f"connect with: rodctl status --port {link or name}   (Ctrl-C stops the board)", flush=True)
    print(name, flush=True)
    runner.start()
    t_end = None if args.duration is None else time.monotonic() + args.duration
    try:
        with stop_signals():
            warned = False
            while runner.alive and (t_end is None or time.monotonic() < t_end):
                time.sleep(0.1)
                if runner.skipped_steps and not warned:  # a client would see the rod in slow motion
                    warned = True
                    print("sim-device: warning: the board cannot keep up with real time on this machine "
                          f"({dev.describe()}); its clock skips ahead where it fell behind: fewer edges or "
                          "the inextensible plant keep up", file=sys.stderr, flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        runner.stop()
        dev.close()
        for fd in (master, slave):
            with contextlib.suppress(OSError):
                os.close(fd)
        if link is not None:
            with contextlib.suppress(OSError):
                link.unlink()
    if runner.error is not None:
        raise UserError(f"virtual board stopped: {type(runner.error).__name__}: {runner.error}")
    behind = (f" ({runner.skipped_steps * dev.period:.1f} s skipped: it ran behind real time)"
              if runner.skipped_steps else "")
    print(f"sim-device: stopped after {dev.time:.1f} s of device time{behind}", file=sys.stderr)
    return 0


def check_link(path: str) -> None:
    """--link PATH, before the board starts: a symlink there is replaced; anything else is refused, and
    its folder must exist and be writable (InputError, exit 2)."""
    from rodctl.cli.outputs import check_name, check_output

    if not path.strip():
        check_name(path, "--link")  # an empty name, not the current folder
    link = Path(path)
    if link.exists() and not link.is_symlink():
        raise InputError(f"--link {link} exists and is not a symlink; name another path")
    if link.is_symlink():  # an earlier board's link: the folder it sits in is what must be writable, not its target's
        from rodctl.cli.outputs import check_folder_writable

        check_folder_writable(Path(os.path.abspath(link)).parent, f"--link {link}")
        return
    check_output(link, "--link")


def register(sub) -> None:
    p = sub.add_parser("sim-device", help="run the virtual board on a pseudo-terminal for any serial tool",
                       description="Run the firmware's host build against the simulated rod in real time on a "
                                   "pseudo-terminal; prints the /dev/pts path as its last line and runs until "
                                   "Ctrl-C. Any tool, including another rodctl (--port PATH), can then talk to a "
                                   "virtual board over a real serial device. Mode changes are reported on stderr.")
    p.add_argument("--pty", action="store_true", default=True, help="serve on a pseudo-terminal (the default)")
    p.add_argument("--params", metavar="FILE", help="parameter file for the firmware build and the plant")
    p.add_argument("--set", metavar="SECTION.KEY=VALUE", action="append", default=[], dest="overrides",
                   help="override one parameter of --params, for the firmware build and the plant (repeatable)")
    p.add_argument("--theta0-deg", type=float, default=0.0, metavar="DEG",
                   help="every edge's angle at power-on (0 hanging, 180 upright)")
    # None: the file's [plant] table, as sim:// and `rodctl sim` do; the board drives the faithful rod
    p.add_argument("--plant", choices=("inextensible", "der"),
                   help="simulated rod model (default: the parameter file's plant.model, as sim://)")
    p.add_argument("--edges", type=int, help="flexible edges of the simulated rod beyond its hub (default: the "
                                               "parameter file's plant.edges)")
    p.add_argument("--link", metavar="PATH", help="also make PATH a symlink to the pseudo-terminal")
    p.add_argument("--duration", type=float, metavar="S",
                   help="stop after S seconds of wall time [s] (the end says how far the device's clock got)")
    p.set_defaults(func=run_sim_device)
