"""The scope's window: the rod (red, node 0 on the motor axis), every edge angle from the nearest upright, torque
and duty, and the mode over the last window_s seconds; its keys and buttons arm, disarm, set and record.

The figure is the caller's (a Tk window for `rodctl scope`, an Agg figure in the tests); matplotlib's widgets
are imported when the window is built.
"""

from __future__ import annotations

import collections
import threading
import time
from typing import Callable

import numpy as np

from rodgains.errors import UserError

from rodctl.link import protocol as P

ROD_COLOR = "#ff0000"  # nothing else in the window is pure red: the Xvfb test finds the rod by it
BALANCED_ZOOM_S = 1.0  # balanced this long: the angle panel zooms to upright [s]
KEYS = {"s": "swing-up", "b": "balance", "d": "disarm", " ": "disarm", "c": "clear", "r": "record", "q": "quit"}


class Scope:
    """The window's state and actions; `action(name)` is what a key or button does, and `say` is told its
    outcome (the line under the plots shows it too)."""

    def __init__(self, session, fig, *, edge_length_m: float, window_s: float, args, title: str,
                 say: Callable[[str], None] | None = None):
        self.s = session
        self.say = say
        self.fig = fig
        self.l = edge_length_m
        self.window_s = window_s
        self.args = args
        self.writer = None
        self.recorded: list[str] = []
        self.message = "keys: s swing-up, b balance, d disarm, c clear fault, r record, q quit"
        self.stop_requested = False
        self.closed = False
        h = session.hello
        self.n = h.n
        keep = int(window_s * 1e6 / (h.period_us * max(1, h.decimation))) + 10
        self.buf: collections.deque = collections.deque(maxlen=keep)
        self._buf_lock = threading.Lock()  # the reader thread appends while the window copies
        self._frames_at = (time.monotonic(), session.frames)
        self.fps = 0.0
        session.add_listener(self._listen, replay=False)
        self._build(title)

    # --- data -------------------------------------------------------------------------------
    def _listen(self, frame, _t) -> None:
        if frame.type == P.MsgType.TELEMETRY:
            m = frame.msg
            with self._buf_lock:
                self.buf.append((frame.time_us, m.theta_hat, m.torque, m.duty, int(m.mode), int(m.reason)))

    def arrays(self):
        """(t [s, 0 = newest], theta (rows, N) [rad], torque [N m], duty, mode) of the buffered frames."""
        with self._buf_lock:
            rows = list(self.buf)
        if not rows:
            return None
        from rodctl.logs.schema import unwrap_us

        t = unwrap_us([r[0] for r in rows])
        t = t - t[-1]
        th = np.array([r[1] for r in rows], dtype=float).reshape(len(rows), -1)
        return (t, th, np.array([r[2] for r in rows]), np.array([r[3] for r in rows]),
                np.array([r[4] for r in rows]))

    # --- window -----------------------------------------------------------------------------
    def _build(self, title: str) -> None:
        from matplotlib.widgets import Button, TextBox

        from rodctl.logs.plots import MODE_NAMES

        fig = self.fig
        gs = fig.add_gridspec(3, 2, width_ratios=(1, 1.6), left=0.07, right=0.98, top=0.9, bottom=0.17,
                              hspace=0.35, wspace=0.2)
        self.ax_sh = fig.add_subplot(gs[:, 0])
        self.ax_th = fig.add_subplot(gs[0, 1])
        self.ax_tq = fig.add_subplot(gs[1, 1], sharex=self.ax_th)
        self.ax_mo = fig.add_subplot(gs[2, 1], sharex=self.ax_th)
        L = self.l * self.n
        self.ax_sh.set_xlim(-1.15 * L, 1.15 * L)
        self.ax_sh.set_ylim(-1.15 * L, 1.15 * L)
        self.ax_sh.set_aspect("equal")
        self.ax_sh.grid(True, lw=0.3)
        self.ax_sh.set_xlabel("x [m]")
        self.ax_sh.set_ylabel("y [m]")
        self.ax_sh.plot([0], [0], "ks", ms=7)
        self.rod, = self.ax_sh.plot([], [], "-o", color=ROD_COLOR, lw=4, ms=5)
        self.lines_th = [self.ax_th.plot([], [], lw=0.9, label=f"edge {i + 1}")[0] for i in range(self.n)]
        self.ax_th.axhline(0, color="0.6", ls="--", lw=0.6)
        self.ax_th.set_ylim(-185, 185)
        self.ax_th.set_yticks(range(-180, 181, 90))
        self.ax_th.set_ylabel("from upright [deg]")
        if self.n <= 10:
            self.ax_th.legend(fontsize=8, loc="upper left", ncol=min(5, self.n))
        # torque and duty on axes of their own: a 30 mN m ripple must show beside a duty of 0.5
        self.line_tq, = self.ax_tq.plot([], [], color="C1", lw=0.9, label="torque [mN m]")
        self.ax_tq.set_ylabel("torque [mN m]", color="C1")
        self.ax_du = self.ax_tq.twinx()
        self.line_du, = self.ax_du.plot([], [], color="C4", lw=0.7, alpha=0.7, label="duty")
        self.ax_du.set_ylim(-1.05, 1.05)
        self.ax_du.set_ylabel("duty [-]", color="C4")
        self.ax_tq.legend(handles=[self.line_tq, self.line_du], fontsize=9, loc="upper left")
        self.line_mo, = self.ax_mo.step([], [], where="post", color="k")
        self.ax_mo.set_yticks(range(len(MODE_NAMES)), MODE_NAMES, fontsize=7)
        self.ax_mo.set_ylim(-0.5, len(MODE_NAMES) - 0.5)
        self.ax_mo.set_xlabel("device time [s] (0 = now)")
        for ax in (self.ax_th, self.ax_tq, self.ax_mo):
            ax.set_xlim(-self.window_s, 0)
            ax.grid(True, lw=0.3)
        self.title = fig.suptitle(title, fontsize=9)
        self.status = fig.text(0.07, 0.925, "", fontsize=9, family="monospace")
        self.note = fig.text(0.07, 0.095, self.message, fontsize=8)
        self.buttons = []
        for i, (label, name) in enumerate((("swing-up (s)", "swing-up"), ("balance (b)", "balance"),
                                           ("disarm (d)", "disarm"), ("clear fault (c)", "clear"),
                                           ("record (r)", "record"))):
            b = Button(fig.add_axes((0.07 + 0.105 * i, 0.02, 0.1, 0.05)), label)
            b.on_clicked(lambda _e, name=name: self.action(name))
            self.buttons.append(b)
        self.setbox = TextBox(fig.add_axes((0.66, 0.02, 0.32, 0.05)), "set ", initial="")
        self.setbox.on_submit(self._set_submitted)
        # the scope owns its keys: matplotlib's own bindings (s save, c back, r home, q quit, ...) would
        # open a dialog and arm the board when it is dismissed
        handler = getattr(getattr(fig.canvas, "manager", None), "key_press_handler_id", None)
        if handler is not None:
            fig.canvas.mpl_disconnect(handler)
        fig.canvas.mpl_connect("key_press_event", self._key)
        fig.canvas.mpl_connect("close_event", lambda _e: setattr(self, "closed", True))

    def _key(self, event) -> None:
        if self.setbox.capturekeystrokes:  # typing into the set box
            return
        name = KEYS.get(event.key)
        if name:
            self.action(name)

    def _set_submitted(self, text: str) -> None:
        if text.strip():
            self.action("set", text)
            self.setbox.set_val("")

    # --- actions ----------------------------------------------------------------------------
    def action(self, name: str, text: str = "") -> None:
        from rodctl.link.session import cleared_text

        s = self.s
        try:
            # the mode at the ack goes stale at once (CATCH becomes BALANCE): the status line has the live one
            if name in ("swing-up", "balance"):
                mode = P.ArmMode.SWING_UP if name == "swing-up" else P.ArmMode.BALANCE
                s.arm(mode)
                self.message = f"armed {name}"
            elif name == "disarm":
                s.disarm()
                self.message = "disarmed"
            elif name == "clear":
                before = s.telemetry  # streaming: the board's mode a frame ago
                self.message = cleared_text(before, s.clear_fault())
            elif name == "record":
                self.toggle_recording()
            elif name == "set":
                from rodctl.link.design import apply_settings

                done: list[str] = []
                apply_settings(s, text.split(), self.args, out=done.append)
                self.message = "; ".join(done)
            elif name == "quit":
                self.stop_requested = True
                self.message = "quit"
        except UserError as e:
            self.message = f"refused: {e}"
        if self.say is not None:
            self.say(self.message)

    def toggle_recording(self) -> None:
        from rodctl.link.design import design_params
        from rodctl.logs.writer import attach_device_log, default_log_name, log_format

        if self.writer is not None:
            w, self.writer = self.writer, None
            self.s.remove_listener(w)
            w.note("recording stopped (scope)")
            try:
                w.close(self.s.log_trailer("scope"))
            except UserError as e:  # a full disk
                self._record_failed(w, e)
                return
            self.recorded.append(str(w.path))
            self.message = f"recorded {w.path}: {w.rows} frames"
            return
        a = self.args
        fmt = log_format(a.record or "x.csv", a.format) if a.record or a.format else "csv"
        path = a.record if a.record and not self.recorded else default_log_name(fmt)
        params, source = design_params(self.s, a)
        self.writer = attach_device_log(self.s, path, params=params, params_source=source, fmt=fmt,
                                        overwrite=bool(a.force))
        self.writer.note("recording started (scope)")
        self.message = f"recording to {path}"

    def _record_failed(self, w, e) -> None:
        """A recording the disk refused: the run it was recording ends as `rodctl log`'s does (the board disarmed),
        and the window says what the file keeps; the scope stays open."""
        try:
            self.s.disarm()
        except UserError:
            pass  # the link's own trouble: the watchdog disarms, and the window says the link is lost
        text = w.failure_text() if w.failure is not None else str(e)
        if w.path.exists():
            self.recorded.append(f"{w.path} (cut short)")
        self.message = f"recording stopped, disarmed: {text}"

    def finish(self) -> None:
        if self.writer is not None:
            self.toggle_recording()

    # --- drawing ----------------------------------------------------------------------------
    def update(self) -> None:
        from rodctl.link.session import mode_text
        from rodctl.logs.plots import shape_nodes
        from rodctl.logs.schema import from_upright

        if self.stop_requested:
            import matplotlib.pyplot as plt

            plt.close(self.fig)
            return
        try:
            self.s.check()
        except UserError as e:
            self.message = f"link lost: {e}"
            self.stop_requested = True
        if self.writer is not None:
            try:
                self.writer.maybe_flush()
            except UserError:  # a full disk
                w, self.writer = self.writer, None
                self.s.remove_listener(w)
                self._record_failed(w, None)
        now = time.monotonic()
        t0, f0 = self._frames_at
        if now - t0 >= 1.0:
            self.fps = (self.s.frames - f0) / (now - t0)
            self._frames_at = (now, self.s.frames)
        a = self.arrays()
        if a is not None:
            t, th, tq, du, mo = a
            dev = np.degrees(from_upright(th))
            for i, ln in enumerate(self.lines_th):
                ln.set_data(t, dev[:, i])
            self.line_tq.set_data(t, 1e3 * tq)
            self.line_du.set_data(t, du)
            shown = t >= -self.window_s
            top = max(5.0, 1.15 * float(np.max(np.abs(1e3 * tq[shown])))) if shown.any() else 5.0
            self.ax_tq.set_ylim(-top, top)
            # balanced for the last second: the error is degrees, not half a turn, so zoom to upright
            recent = t >= -BALANCED_ZOOM_S
            if (mo[recent] == P.Mode.BALANCE).all():
                span = max(2.0, 1.2 * float(np.max(np.abs(dev[recent]))))
                self.ax_th.set_ylim(-span, span)
                self.ax_th.set_yticks(np.linspace(-span, span, 5).round(1))
            else:
                self.ax_th.set_ylim(-185, 185)
                self.ax_th.set_yticks(range(-180, 181, 90))
            self.line_mo.set_data(t, mo)
            x, y = shape_nodes(th[-1], self.l)
            self.rod.set_data(x, y)
            tlm = self.s.telemetry
            mode = mode_text(tlm.mode, tlm.reason, "press c") if tlm is not None else "?"
            rec = f"  REC {self.writer.path} ({self.writer.rows} frames)" if self.writer else ""
            self.status.set_text(f"mode {mode} | theta1 {dev[-1, 0]:+7.1f} deg from upright, tip "
                                 f"{dev[-1, -1]:+7.1f} deg | {self.fps:5.0f} frames/s{rec}")
        self.note.set_text(self.message)
        self.fig.canvas.draw_idle()
