"""rodctl console: an interactive prompt (arm, disarm, clear, set, status) with a live status line."""

from __future__ import annotations

import argparse
import contextlib
import shlex
import sys
import threading

from rodgains.errors import UserError

from rodctl.cli.common import (ARM_CHOICES, RateMeter, add_design_args, add_port_arg, mode_text,
                               session_for, status_text, stop_signals)
from rodctl.cli.status import status_report
from rodctl.link import protocol as P
from rodctl.link.design import apply_settings
from rodctl.link.session import CLEAR_FAULT, SETTINGS, Session, cleared_text, is_tty, name_of
from rodctl.logs.schema import from_upright_deg


CLEAR = "type `clear`"  # the console's words for CLEAR_FAULT


def in_console_words(text: str) -> str:
    """A message that names rodctl's commands, said as this prompt's: clear and disarm are typed here."""
    return text.replace(CLEAR_FAULT, CLEAR).replace("(rodctl disarm)", "(type `disarm`)")

# commands that take nothing after them; disarm and quit act whatever follows (a word more must not keep a motor on)
BARE_COMMANDS = ("help", "?", "clear", "clear-fault", "status")

CONSOLE_HELP = """commands:
  arm swing-up | arm balance   arm the controller (disarmed again when the console closes)
  disarm                       driver off (DISARMED, reason HOST)
  clear                        leave FAULT for DISARMED (clear-fault)
  set NAME=VALUE ...           names: """ + ", ".join(SETTINGS) + """
  status                       firmware, settings, mode, one telemetry frame
  quit                         disarm and leave (also Ctrl-D, Ctrl-C)"""


class _LiveLine(threading.Thread):
    """On a terminal: keeps the line above the prompt showing the live status."""

    def __init__(self, session: Session, stream):
        super().__init__(daemon=True, name="rodctl-console-status")
        self.session = session
        self.stream = stream
        self.meter = RateMeter(session.frames)
        self.stop = threading.Event()
        self.paused = threading.Event()

    def text(self) -> str:
        return status_text(self.session, self.meter.rate(self.session.frames))

    def run(self) -> None:
        while not self.stop.wait(0.25):
            if self.paused.is_set() or not self.session.alive:
                continue
            try:
                # save cursor, up one line, clear it, write, restore cursor
                self.stream.write("\x1b7\x1b[1A\r\x1b[2K" + self.text() + "\x1b8")
                self.stream.flush()
            except (OSError, ValueError):
                return


def run_console(args) -> int:
    tty = sys.stdin.isatty() and is_tty(sys.stdout)
    if tty:
        with contextlib.suppress(ImportError):
            import readline  # noqa: F401 - line editing and history for input()
    # the console waits at its prompt with the board armed on purpose (the user types `disarm`): always heartbeat
    with stop_signals(), session_for(args, liveness_s=None) as s:
        h = s.hello
        print(f"connected to {s.port}: firmware {h.fw_major}.{h.fw_minor}.{h.fw_patch}, N={h.n}, "
              f"{1e6 / h.period_us:g} Hz. Heartbeat on while the console is open; 'help' lists commands.")
        live = None
        if tty:
            live = _LiveLine(s, sys.stdout)
            live.start()
        try:
            while True:
                if live is not None:
                    live.paused.set()
                    print(live.text())
                    live.paused.clear()
                try:
                    line = input("rodctl> ")
                except EOFError:
                    print()
                    break
                if live is not None:
                    live.paused.set()
                try:
                    words = shlex.split(line, comments=True) if line.strip() else []
                except ValueError as e:  # an unbalanced quote: a typo, not the end of the session
                    print(f"error: {str(e)[0].lower()}{str(e)[1:]}")
                    continue
                if not words:
                    continue
                cmd, rest = words[0].lower(), words[1:]
                try:
                    s.check()
                    if rest and cmd in BARE_COMMANDS:  # `disarm now` must not look like a command that did more
                        raise UserError(f"{cmd} takes nothing after it (got {' '.join(rest)!r}); 'help' lists commands")
                    ignored = f" (ignored: {' '.join(rest)})" if rest and cmd in ("disarm", "quit", "exit", "q") else ""
                    if cmd in ("quit", "exit", "q"):
                        if ignored:
                            print(ignored.strip())
                        break
                    elif cmd in ("help", "?"):
                        print(CONSOLE_HELP)
                    elif cmd == "arm":
                        key = (rest[0].lower().lstrip("-") if rest else "")
                        if key not in ARM_CHOICES:
                            raise UserError("arm swing-up | arm balance")
                        ack = s.arm(ARM_CHOICES[key])
                        print(f"armed {key}: mode {name_of(P.Mode, ack.mode)}")
                    elif cmd == "disarm":
                        ack = s.disarm()
                        print(f"mode {name_of(P.Mode, ack.mode)}{ignored}")
                    elif cmd in ("clear", "clear-fault"):
                        # streaming: the board's mode a frame ago (none yet just after connecting: wait for one)
                        before = s.telemetry if s.telemetry is not None else s.wait_telemetry(timeout=2.0)
                        print(cleared_text(before, s.clear_fault()))
                    elif cmd == "set":
                        if not rest:
                            raise UserError(f"set NAME=VALUE (names: {', '.join(SETTINGS)})")
                        apply_settings(s, rest, args, out=print)
                    elif cmd == "status":
                        r = status_report(s, args)
                        th = ", ".join(f"{from_upright_deg(x):+.1f}" for x in r["theta_hat_rad"])
                        st = ", ".join(f"{k} {SETTINGS[k].format(v)}" for k, v in r["settings"].items())
                        print(f"mode {mode_text(P.Mode[r['mode']], P.Reason[r['reason']], CLEAR)}; theta_hat [{th}] deg from upright; "
                              f"torque {r['torque_Nm']:.3g} N m; duty {r['duty']:.3g}")
                        print(f"settings: {st}")
                        print(in_console_words(f"firmware {r['firmware_version']}, N={r['n']}, {r['rate_hz']:g} Hz, "
                                               f"parameters {r['params_source']}; "
                                               f"{status_text(s, 0).split(' | ', 2)[2]}"))
                    else:
                        raise UserError(f"unknown command {cmd!r}; 'help' lists them")
                except UserError as e:
                    if not s.alive:  # the board is gone: said once, as rodctl's last line
                        raise UserError(str(e)) from None
                    print(f"error: {in_console_words(str(e))}")
        except KeyboardInterrupt:
            print()
        finally:
            if live is not None:
                live.stop.set()
    print("disarmed and disconnected")
    return 0


def register(sub) -> None:
    p = sub.add_parser("console", help="interactive prompt: arm, disarm, clear, set, status, quit",
                       description="Interactive session with a live status line; the heartbeat runs while it is "
                                   "open and the board is disarmed when it closes.\n\n" + CONSOLE_HELP,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    add_port_arg(p)
    add_design_args(p)
    p.set_defaults(func=run_console)
