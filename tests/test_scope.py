"""rodctl scope: one live session (rod shape, time series, arm/disarm/set/record), in a window under Xvfb."""

from __future__ import annotations

import os
import queue
import shutil
import signal
import subprocess
import threading
import time
from types import SimpleNamespace

import numpy as np
import pytest

from host_tools import RODCTL, ctrl_c_as_at_a_terminal, rodctl_env, until

from rodctl.link import protocol as P

# matplotlib would pick a window backend by what is installed (Qt before Tk) and a user's MPLBACKEND or
# matplotlibrc could name another: the tests drive Tk's window, so they say so
WINDOW_BACKEND = "TkAgg"


@pytest.fixture
def xdisplay():
    """A private Xvfb; -displayfd makes it pick a free display number and tell us when it is ready."""
    xvfb = shutil.which("Xvfb")
    if xvfb is None:
        pytest.fail("Xvfb is not installed (bash .ci/run installs it)")
    r, w = os.pipe()
    proc = subprocess.Popen([xvfb, "-displayfd", str(w), "-screen", "0", "1280x800x24", "-nolisten", "tcp"],
                            pass_fds=(w,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(w)
    try:
        with os.fdopen(r) as f:
            number = f.readline().strip()
        assert number.isdigit(), "Xvfb did not start"
        yield f":{number}"
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def _start_scope(display: str, *args):
    env = rodctl_env(DISPLAY=display, MPLBACKEND=WINDOW_BACKEND)
    return subprocess.Popen([*RODCTL, "scope", *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=env, preexec_fn=ctrl_c_as_at_a_terminal)


def _wait_for_window(proc, seconds: float = 60.0) -> None:
    deadline = time.monotonic() + seconds
    line = ""
    while time.monotonic() < deadline and not line.startswith("scope: "):
        line = proc.stderr.readline()
        if not line and proc.poll() is not None:
            raise AssertionError(f"scope exited: {proc.stderr.read()}")


def _red_rod(img: np.ndarray):
    """(rows, cols) of the pure-red pixels the scope draws the rod with."""
    red = (img[..., 0] > 240) & (img[..., 1] < 25) & (img[..., 2] < 25)
    return np.nonzero(red)


def test_scope_draws_a_balanced_rod_upright_in_a_real_window(xdisplay, tmp_path):
    from PIL import Image, ImageGrab

    # The virtual board's rod starts at rest upright (theta0_deg=180) and the scope arms balance at once.
    shot = tmp_path / "scope.png"  # how docs/img/scope.png is made (docs/tutorials/logging.md)
    proc = _start_scope(xdisplay, "--port", "sim://?theta0_deg=180", "--arm", "balance", "--duration", "60",
                        "--screenshot", str(shot))
    try:
        _wait_for_window(proc)

        def screen() -> np.ndarray:
            return np.asarray(ImageGrab.grab(xdisplay=xdisplay).convert("RGB")).astype(int)

        # the window redraws every 100 ms: grab it until a rod is drawn (a loaded machine draws it later)
        until(lambda: _red_rod(screen())[0].size > 200, timeout=60)
        time.sleep(1.0)  # then a second more of balance on screen
        img = screen()
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    rows, cols = _red_rod(img)
    assert rows.size > 200, "no rod drawn"
    height, width = rows.max() - rows.min(), cols.max() - cols.min()
    assert height > 5 * width, (height, width)  # a vertical rod
    # the base (black square on the motor axis) is at the bottom end of the rod: it points up
    cx = int(np.median(cols))
    black = (img[..., :3] < 40).all(axis=-1)
    near_bottom = black[rows.max() - 10:rows.max() + 10, cx - 12:cx + 12].sum()
    near_top = black[rows.min() - 10:rows.min() + 10, cx - 12:cx + 12].sum()
    assert near_bottom > 10 and near_top == 0, (near_bottom, near_top)
    assert proc.returncode == 0, err
    assert "Traceback" not in err and "scope ended: disarmed" in err
    # the screenshot shows the same upright rod
    rows, cols = _red_rod(np.asarray(Image.open(shot).convert("RGB")).astype(int))
    assert rows.size > 100 and rows.max() - rows.min() > 5 * (cols.max() - cols.min())
    assert f"screenshot {shot}" in err


def test_ctrl_c_disarms_and_closes_without_a_traceback(xdisplay):
    proc = _start_scope(xdisplay, "--port", "sim://", "--arm", "swing-up")
    try:
        _wait_for_window(proc)
        time.sleep(1.5)
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err
    assert "Traceback" not in err and "Exception" not in err
    assert err.strip().splitlines()[-1] == "scope ended: disarmed"


def test_a_screenshot_that_cannot_be_saved_at_the_end_still_disarms_and_ends(xdisplay, tmp_path):
    """The screenshot's folder disappears while the board is armed: saving it fails when the scope ends,
    and the scope must still end (no traceback from the window's callback, no heartbeat keeping the board
    armed): disarmed, the recording kept, then one line naming --screenshot."""
    folder = tmp_path / "shots"
    folder.mkdir()
    rec = tmp_path / "run.csv"
    proc = _start_scope(xdisplay, "--port", "sim://", "--arm", "swing-up", "--duration", "4", "--record", str(rec),
                        "--screenshot", str(folder / "s.png"))
    try:
        _wait_for_window(proc)
        folder.rmdir()
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
            pytest.fail("the scope did not end after --duration")
    assert "Traceback" not in err and "Exception" not in err, err
    lines = err.strip().splitlines()
    assert lines[-2] == f"scope ended: disarmed; recorded {rec}", err
    assert lines[-1].startswith(f"rodctl: --screenshot {folder / 's.png'}: not saved: "), err
    assert proc.returncode == 1
    from rodctl.logs import read_log

    log = read_log(rec)
    assert log.meta["end"] == "scope" and len(log.data) > 100  # closed cleanly; "disarmed" above is the board's ACK


def test_scope_without_a_display_is_one_clear_line():
    env = rodctl_env()  # headless: rodctl_env drops DISPLAY and WAYLAND_DISPLAY
    r = subprocess.run([*RODCTL, "scope", "--port", "sim://"], capture_output=True, text=True, env=env, timeout=60)
    assert r.returncode == 1 and "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("rodctl: the scope needs a display: no display")


def test_the_headless_scopes_suggestion_keeps_what_the_user_asked_for(tmp_path):
    """`scope --arm swing-up --duration 2 --record r.parquet` suggested a plain `rodctl log --port sim:// --out run.csv`."""
    rec = tmp_path / "r.parquet"
    r = subprocess.run([*RODCTL, "scope", "--port", "sim://", "--arm", "swing-up", "--duration", "2", "--record", str(rec),
                        "--set", "rod.length=0.14"], capture_output=True, text=True, env=rodctl_env(), timeout=60)
    assert r.returncode == 1 and not rec.exists()
    assert (f"`rodctl log --port sim:// --arm swing-up --duration 2 --out {rec} --set rod.length=0.14`, then "
            f"`rodctl plot {rec} --out {tmp_path / 'r.png'}`") in r.stderr  # the figure named after the log
    parquet = subprocess.run([*RODCTL, "scope", "--port", "sim://", "--format", "parquet"], capture_output=True,
                             text=True, env=rodctl_env(), timeout=60)  # the name follows the format it names
    assert "--out run.parquet --format parquet`, then `rodctl plot run.parquet --out run.png`" in parquet.stderr


def test_the_headless_scopes_suggestion_pastes_into_a_shell():
    """The suggested command quotes a port with ? and & (zsh refuses an unmatched glob; bash runs `&` in the background)."""
    env = rodctl_env()  # headless: rodctl_env drops DISPLAY and WAYLAND_DISPLAY
    r = subprocess.run([*RODCTL, "scope", "--port", "sim://?theta0_deg=150&motor_sign=1"], capture_output=True,
                       text=True, env=env, timeout=60)
    assert r.returncode == 1
    assert "`rodctl log --port 'sim://?theta0_deg=150&motor_sign=1' --out run.csv`" in r.stderr


def test_keys_and_buttons_arm_set_record_and_disarm(tmp_path):
    """The scope's actions on a live virtual board, drawn with Agg (what a key or button calls)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from rodctl.link.session import Session
    from rodctl.logs import read_log
    from rodctl.scope.window import Scope

    out = tmp_path / "rec.csv"
    args = SimpleNamespace(port="sim://?theta0_deg=180", params=None, overrides=[], record=str(out), format=None,
                           force=False)
    with Session(args.port) as s:
        fig = Figure(figsize=(12, 7))
        FigureCanvasAgg(fig)
        scope = Scope(s, fig, edge_length_m=0.031, window_s=5.0, args=args, title="test")
        scope._key(SimpleNamespace(key="r"))  # start recording
        scope._key(SimpleNamespace(key="b"))
        assert s.wait_telemetry(timeout=5).mode == P.Mode.BALANCE
        assert scope.message == "armed balance"  # not the mode at the ack (CATCH), stale at once
        scope.action("set", "swing_amplitude=0.03")
        assert "swing_amplitude = 0.03" in scope.message
        scope.action("set", "swing_amplitude=0.03 catch_angle_deg=1e42")
        assert scope.message.startswith("refused: ")
        def drawn_upright():
            scope.update()
            return scope.rod.get_data()[1][-1] > 0.9 * 0.031 * s.hello.n

        assert until(drawn_upright)  # the drawn rod is the estimate: upright
        assert "theta1" in scope.status.get_text() and "from upright" in scope.status.get_text()
        def zoomed():
            scope.update()
            lo, hi = scope.ax_th.get_ylim()
            return -30 < lo < 0 < hi < 30

        assert until(zoomed)  # balanced: the angle panel zooms to upright
        assert scope.ax_tq.get_ylabel() == "torque [mN m]" and scope.ax_du.get_ylim() == (-1.05, 1.05)
        scope._key(SimpleNamespace(key="d"))
        assert scope.message.startswith("disarmed")
        scope._key(SimpleNamespace(key="r"))  # stop recording
        assert scope.recorded == [str(out)]
    log = read_log(out)
    assert len(log.data) > 300 and "BALANCE" in set(log.data["mode_name"])
    notes = [e for e in log.events["info_text"] if "recording" in e]
    assert notes == ["recording started (scope)", "recording stopped (scope)"]
    # the same account of the link as `rodctl log` gives: how it ended and every loss counted
    assert log.trailer["end"] == "scope" and int(log.trailer["frames"]) >= len(log.data)
    assert {k: log.trailer[k] for k in ("seq_gaps", "crc_errors", "decode_errors", "device_frames_dropped")} == \
        {"seq_gaps": "0", "crc_errors": "0", "decode_errors": "0", "device_frames_dropped": "0"}



def _xdotool(display: str, *args: str) -> str:
    return subprocess.run(["xdotool", *args], env={**os.environ, "DISPLAY": display}, capture_output=True,
                          text=True, timeout=30).stdout


def test_each_key_does_what_the_window_says_and_no_dialog_opens(xdisplay, tmp_path):
    """Real key events (XTEST, xdotool) in the real Tk window: s arms swing-up at the key press, d and space
    disarm, b arms balance, r records, c clears, q quits; matplotlib's own bindings (s save, c back, r home,
    q quit) are off, so no window but the scope's ever opens."""
    if shutil.which("xdotool") is None:
        pytest.fail("xdotool is not installed (bash .ci/run installs it)")
    env = rodctl_env(DISPLAY=xdisplay, MPLBACKEND=WINDOW_BACKEND)
    shot = tmp_path / "at-q.png"  # the help: saved when the scope ends, q included
    proc = subprocess.Popen([*RODCTL, "scope", "--port", "sim://?theta0_deg=150", "--duration", "90", "--screenshot",
                             str(shot)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            cwd=tmp_path)
    said: list[str] = []
    lines: queue.Queue = queue.Queue()
    reader = threading.Thread(target=lambda: [lines.put(ln) for ln in proc.stderr], daemon=True)
    reader.start()

    def press(key: str, expect: str) -> None:
        _xdotool(xdisplay, "key", key)
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            try:
                line = lines.get(timeout=1.0)
            except queue.Empty:
                continue
            said.append(line)
            if line.startswith("scope: ") and not line.startswith("scope: sim://"):
                assert line.strip().startswith(f"scope: {expect}"), said
                windows = _xdotool(xdisplay, "search", "--onlyvisible", "--name", ".").split()
                assert len(windows) <= 1, (key, windows)  # the scope's (gone after q), no dialog
                return
        raise AssertionError(f"no answer to {key!r}: {said}")

    try:
        wid = []
        deadline = time.monotonic() + 60
        while not wid and time.monotonic() < deadline:  # the window is mapped and drawing
            wid = _xdotool(xdisplay, "search", "--onlyvisible", "--name", "rodctl scope").split()
            time.sleep(0.5)
        assert len(wid) == 1, (wid, proc.poll())
        time.sleep(2.0)
        _xdotool(xdisplay, "windowfocus", "--sync", wid[0])
        press("s", "armed swing-up")
        press("d", "disarmed")
        press("b", "armed balance")
        press("space", "disarmed")
        press("c", "no fault to clear: mode DISARMED")
        press("r", "recording to rod-")
        press("r", "recorded rod-")
        press("q", "quit")
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    reader.join(timeout=30)  # it ends at the end of the scope's stderr: every line is in the queue
    while not lines.empty():
        said.append(lines.get())
    assert proc.returncode == 0, said
    assert not any("Traceback" in ln for ln in said) and said[-1].startswith("scope ended: disarmed"), said
    assert len([f for f in tmp_path.glob("rod-*.csv") if not f.name.endswith(".events.csv")]) == 1
    assert said[-1].rstrip().endswith(f"; screenshot {shot}") and shot.stat().st_size > 10_000, said


@pytest.mark.parametrize("how", ["server killed", "window destroyed"])
def test_a_lost_display_disarms_the_board_and_closes_the_recording(tmp_path, how):
    """Xlib ends the process from C when its X server goes (an ssh -X session dropped) or an X error reaches its
    default handler (the window destroyed under Tk): the scope died with the board armed until its watchdog, and
    its recording cut short. Now the board is disarmed by the host and the recording closed, said in one line."""
    from host_tools import run_rodctl, sim_device

    from rodctl.logs import read_log
    from rodctl.logs.reader import cut_short

    xvfb = shutil.which("Xvfb")
    if xvfb is None or shutil.which("xdotool") is None:
        pytest.fail("Xvfb or xdotool is not installed (bash .ci/run installs them)")
    r, w = os.pipe()
    server = subprocess.Popen([xvfb, "-displayfd", str(w), "-screen", "0", "1280x800x24", "-nolisten", "tcp"],
                              pass_fds=(w,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(w)
    rec = tmp_path / "run.csv"
    try:
        with os.fdopen(r) as f:
            display = f":{f.readline().strip()}"
        with sim_device() as (dev, pts):
            proc = _start_scope(display, "--port", pts, "--arm", "swing-up", "--record", str(rec))
            try:
                _wait_for_window(proc)
                assert proc.stderr.readline().startswith("scope: armed swing-up")  # the board's ack
                time.sleep(1.0)  # a second of swing-up, recorded
                if how == "server killed":
                    server.kill()
                else:
                    subprocess.run(["xdotool", "search", "--name", "rodctl scope", "windowclose"], timeout=30,
                                   env=rodctl_env(DISPLAY=display), capture_output=True)
                _, err = proc.communicate(timeout=60)
            finally:
                if proc.poll() is None:
                    proc.kill()
                    proc.communicate()
            status = run_rodctl("status", "--port", pts).stdout
    finally:
        server.kill()
        server.wait(timeout=10)
    assert proc.returncode == 1, err
    assert err.strip().splitlines()[-1].endswith(f": disarmed; recorded {rec}"), err
    assert err.strip().splitlines()[-1].startswith("rodctl: the scope's ") and "Traceback" not in err, err
    assert "DISARMED (last: disarmed by the host)" in status, status  # not the watchdog's FAULT
    assert cut_short(read_log(rec)) is None
