"""The scope's window loop: open the figure on a session, redraw it every 100 ms until stopped, close it.

    scope = open_scope(session, args, say=say)
    run_window(scope, stop, duration_s=..., screenshot=..., failures=failures, ready=...)   # until it ends
    close_scope(scope, failures)   # the recording closed, every figure gone; failures kept, never raised

Importing this module imports matplotlib.pyplot: import it only once a display is known to be there.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path
from typing import Callable

import matplotlib.pyplot as plt

from rodgains.errors import UserError
from rodgains.params import load_params

from rodctl.link.design import design_params
from rodctl.logs.metadata import overrides_of
from rodctl.scope.window import Scope

END_GRACE_S = 3.0  # the window should be gone this long after the scope ends; else its loop is quit


def open_scope(s, args, *, say: Callable[[str], None] | None = None) -> Scope:
    """The scope's window on session `s` (not yet shown), its title naming the port, firmware and parameters."""
    params, source = design_params(s, args)
    p = params or load_params()
    over = " ".join(overrides_of(p))
    h = s.hello
    title = (f"{s.port}  firmware {h.fw_major}.{h.fw_minor}.{h.fw_patch}  N={h.n}  parameters "
             f"{source if params is not None else 'unknown (default rod drawn)'}"
             + (f"  overrides: {over}" if over else ""))
    plt.rcParams["toolbar"] = "None"  # no save or zoom dialogs beside the board's controls
    fig = plt.figure(figsize=(12, 7))
    try:
        fig.canvas.manager.set_window_title(f"rodctl scope {s.port}")
    except AttributeError:
        pass
    return Scope(s, fig, edge_length_m=p["rod"]["length"] / h.n, window_s=args.window, args=args, title=title,
                 say=say)


def _quit_window_loop(fig) -> None:
    """End the GUI's event loop even when closing the window failed (Tk: quit(); Qt: close())."""
    win = getattr(getattr(fig.canvas, "manager", None), "window", None)
    for name in ("quit", "close"):
        f = getattr(win, name, None)
        if callable(f):
            try:
                f()
            except Exception:  # noqa: BLE001 - ending: the next try, then the session's disarm
                continue
            return


def run_window(scope: Scope, stop: threading.Event, *, duration_s: float | None, screenshot: str | None,
               failures: list, ready: Callable[[], None], arm: str | None = None) -> None:
    """Show the window until it is closed, q, `stop` is set or duration_s [s] has passed; `ready` is called once the
    redraw timer runs, just before the window shows. arm: the scope's action ("swing-up", "balance") done on the
    first tick, once the window is up: the session heartbeats only while the window's ticks look at the link, and
    drawing a new window on a slow machine can outlast that. What fails in the window's callbacks, or in saving
    the screenshot [PNG] as the window last looked, is appended to `failures` and ends the scope."""
    fig = scope.fig
    t_end = None if duration_s is None else time.monotonic() + duration_s

    shot = {"tried": False}
    ending = {"since": None}
    to_arm = [arm] if arm else []

    def save_shot(*_event) -> None:
        """The screenshot, once, saved or not: before the window closes, what it showed last."""
        if screenshot and not shot["tried"]:
            shot["tried"] = True
            try:
                fig.savefig(screenshot, dpi=100)
            except Exception as e:  # noqa: BLE001 - said after the disarm
                failures.append(UserError(f"--screenshot {screenshot}: not saved: {getattr(e, 'strerror', None) or e}"))

    def tick():
        # Nothing may escape: an exception in a GUI callback is printed and the loop goes on, with the
        # heartbeat keeping the board armed. Any failure ends the scope (the session then disarms).
        try:
            if to_arm and not stop.is_set():
                scope.action(to_arm.pop())
            # q or a lost link (stop_requested), Ctrl-C (stop) or --duration
            if stop.is_set() or scope.stop_requested or (t_end is not None and time.monotonic() >= t_end):
                if ending["since"] is None:
                    ending["since"] = time.monotonic()
                save_shot()
                scope.stop_requested = True
            scope.update()
        except Exception as e:  # noqa: BLE001 - said after the disarm
            failures.append(e)
            scope.stop_requested = True
            if ending["since"] is None:
                ending["since"] = time.monotonic()
            try:
                plt.close(fig)
            except Exception:  # noqa: BLE001
                pass
        if ending["since"] is not None and time.monotonic() - ending["since"] > END_GRACE_S:
            _quit_window_loop(fig)

    fig.canvas.mpl_connect("close_event", save_shot)  # the window closed by its title bar: no tick comes after
    timer = fig.canvas.new_timer(interval=100)
    timer.add_callback(tick)
    timer.start()
    ready()
    try:
        plt.show()
    except KeyboardInterrupt:
        pass
    try:
        timer.stop()
    except Exception:  # noqa: BLE001 - the window is gone
        pass


def close_scope(scope: Scope | None, failures: list) -> None:
    """End the recording (if any) and close every figure; what fails is appended to `failures`."""
    for end in ((scope.finish,) if scope is not None else ()) + (lambda: plt.close("all"),):
        try:
            end()
        except Exception as e:  # noqa: BLE001 - the session below still disarms; said after it
            failures.append(e)


def end_on_lost_display(session, scope: Scope | None) -> str:
    """What the scope does when its display is gone (rodctl.scope.display_guard, before Xlib ends the process): the
    board disarmed first, then the recording closed (no figure call: the display is gone), then the session;
    returns what to say ("disarmed; recorded run.csv"). Never raises."""
    kept = ""
    try:
        session.disarm()  # first: a recording's last flush to a slow disk must not keep the motor on
    except Exception:  # noqa: BLE001 - the close below tries again; then the watchdog disarms, as said
        pass
    try:
        if scope is not None:
            scope.finish()
            kept = f"; recorded {', '.join(scope.recorded)}" if scope.recorded else ""
    except Exception:  # noqa: BLE001 - the board is disarmed; what was kept is said
        pass
    try:
        session.close()  # DISARM again, and its acknowledgement
    except Exception:  # noqa: BLE001 - then the watchdog disarms, as said
        pass
    return ("disarmed" if session.disarm_acked else "disarm not confirmed (the watchdog disarms)") + kept


def shot_saved(path: str, failures: list) -> bool:
    """Whether the screenshot at `path` was saved (it is there, and saving it did not fail)."""
    return Path(path).is_file() and not any(str(f).startswith("--screenshot ") for f in failures)
