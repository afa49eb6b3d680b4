"""What a user sees from the CLI: finding the board, build/flash without PlatformIO's platform, plots."""

from __future__ import annotations

import os

import numpy as np
import pytest

from host_tools import rodctl_env, run_rodctl
from rodgains.errors import UserError
from rodgains.params import load_params

from rodctl import cli
from rodctl.build import platformio
from rodctl.link import ports
from rodctl.link import protocol as P
from rodctl.logs.plots import PANELS, make_figure, shape_nodes
from rodctl.logs import LogWriter, read_log, simulator_metadata


def _one_error_line(r) -> str:
    assert "Traceback" not in r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    return lines[0]


# ---- finding the board ------------------------------------------------------------------------

def test_no_board_is_one_line_naming_what_was_seen(monkeypatch, capsys):
    from types import SimpleNamespace

    from serial.tools import list_ports

    # whatever this machine has plugged in (a Teensy would make the command open it): two ports, neither a Teensy
    seen = [SimpleNamespace(device="/dev/ttyFAKE0", vid=None, pid=None, serial_number=None),
            SimpleNamespace(device="/dev/ttyFAKE1", vid=0x0403, pid=0x6001, serial_number="A10K")]
    monkeypatch.setattr(list_ports, "comports", lambda *a, **k: seen)
    assert cli.main(["status"]) == 1
    out, err = capsys.readouterr()
    assert out == ""
    assert err.splitlines() == [
        "rodctl: no Teensy found (USB 16C0:0483); serial ports seen: /dev/ttyFAKE0 (no USB id), "
        "/dev/ttyFAKE1 (0403:6001 serial A10K). Plug the board in, or pass --port PORT (or --port sim:// for "
        "the simulated rod)"]


def test_explicit_port_is_used_as_given():
    assert ports.find_port("sim://?edges=7") == "sim://?edges=7"
    assert ports.find_port("/dev/ttyACM9") == "/dev/ttyACM9"


def test_missing_explicit_port_is_one_line():
    r = run_rodctl("status", "--port", "/dev/ttyNOPE0")
    assert r.returncode == 1
    assert _one_error_line(r).startswith("rodctl: cannot open /dev/ttyNOPE0: no such port")


@pytest.mark.parametrize("port, reason", [("bogus://x", "invalid URL, protocol 'bogus' not known"),
                                          ("FILE", "not a serial port"), ("FOLDER", "not a serial port")])
def test_a_port_that_names_no_serial_device_is_bad_input(tmp_path, port, reason):
    """A mistyped URL scheme or a plain file given as --port is the user's input (exit 2), not a board that
    could not be reached (exit 1, as a port that is missing now and may be plugged in)."""
    if port == "FILE":
        port = str(tmp_path / "notes.txt")
        (tmp_path / "notes.txt").write_text("not a board\n")
    if port == "FOLDER":  # it was pyserial's "[Errno 21] could not open port ...: Is a directory", exit 1
        port = str(tmp_path)
    r = run_rodctl("status", "--port", port)
    assert r.returncode == 2
    assert _one_error_line(r) == f"rodctl: cannot open {port}: {reason}"


@pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs pseudo-terminals")
def test_a_port_without_the_firmware_is_named_as_such():
    import tty

    master, slave = os.openpty()  # a serial device where nothing answers
    tty.setraw(slave)
    try:
        r = run_rodctl("status", "--port", os.ttyname(slave), timeout=60)
    finally:
        os.close(master)
        os.close(slave)
    assert r.returncode == 1
    assert "no rodlink frames within 3 s: is the board running the rod firmware" in _one_error_line(r)


@pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs pseudo-terminals")
def test_a_board_of_another_protocol_version_is_named_as_such():
    """Whole, CRC-valid frames of another rodlink version: the board runs the rod firmware, of another checkout.
    It was told "is the board running the rod firmware?"; now the versions are named, and what to do."""
    import threading
    import tty

    from rodctl.link.protocol import cobs_encode, crc16

    master, slave = os.openpty()
    tty.setraw(slave)
    stop = threading.Event()

    def board():  # a HELLO-sized frame of version + 1, every 20 ms
        body = bytes([P.VERSION + 1, int(P.MsgType.HELLO)]) + bytes(40)
        frame = cobs_encode(body + crc16(body).to_bytes(2, "little")) + b"\0"
        while not stop.wait(0.02):
            os.write(master, frame)

    t = threading.Thread(target=board, daemon=True)
    t.start()
    try:
        r = run_rodctl("status", "--port", os.ttyname(slave), timeout=60)
    finally:
        stop.set()
        t.join(timeout=5)
        os.close(master)
        os.close(slave)
    assert r.returncode == 1
    line = _one_error_line(r)
    assert f"speaks another rodlink version than this rodctl (v{P.VERSION}" in line and "rodctl flash" in line, line


@pytest.mark.parametrize("err, says", [(13, "permission denied (on Linux: `sudo usermod -aG dialout $USER`"),
                                       (16, "is in use by another program")], ids=["EACCES", "EBUSY"])
def test_a_port_the_user_may_not_open_says_how_to_fix_it(monkeypatch, err, says):
    """pyserial's own text for these is the bare OS error; the first one is every new Linux user's first run."""
    import serial

    from rodctl.link.session import open_serial

    def refuse(port, **kw):
        raise serial.SerialException(err, f"could not open port {port}: [Errno {err}] {os.strerror(err)}: '{port}'")

    monkeypatch.setattr(serial, "Serial", refuse)
    with pytest.raises(UserError) as e:
        open_serial("/dev/ttyACM7")
    assert says in str(e.value) and "\n" not in str(e.value), e.value


# ---- build / flash ------------------------------------------------------------------------------

# Which branch build/flash takes (PlatformIO there or not, platform installed, registry reachable)
# is tested in tests/test_flash_cli.py, by controlling what the code sees.


def test_platformio_output_is_summarized_in_one_line():
    out = ("Processing teensy35 (platform: teensy; board: teensy35; framework: arduino)\n" + "-" * 40 + "\n"
           "Platform Manager: Installing teensy\nHTTPClientError: \n")
    assert platformio.summarize_failure(out, "teensy") == "PlatformIO could not install platform teensy (no internet?)"
    out = "Compiling .pio/build/teensy35/src/core/rod_angle.c.o\nfirmware/src/core/x.c:3:1: error: expected ';'\n"
    assert platformio.summarize_failure(out, "teensy") == "firmware/src/core/x.c:3:1: error: expected ';'"


def test_platform_names_from_platformio_ini_specs():
    assert platformio.platform_name("teensy") == "teensy"
    assert platformio.platform_name("platformio/teensy@^5.0.0") == "teensy"
    assert platformio.platform_name("https://github.com/platformio/platform-teensy.git") == "teensy"


# ---- plots --------------------------------------------------------------------------------------

def _swing_log(path, seconds: float = 2.0):
    """A log the simulator way: the plant swinging, written through the writer API."""
    from rodctl.sim.plant import Plant

    p = load_params()
    plant = Plant(p, input_mode="torque")
    w = LogWriter(path, simulator_metadata(p))
    for k in range(int(seconds * 1000)):
        plant.advance(0.02 * np.sign(np.sin(2 * np.pi * 1.3 * k / 1000)), 1e-3)
        th, dth = plant.state()
        w.write_telemetry(P.Telemetry(mode=P.Mode.SWING_UP, reason=0, flags=5, n=p.N, encoder_count=plant.encoder(),
                                      base_rate=dth[0], torque=0.02, duty=0.1, step_us=50, overruns=0,
                                      frames_dropped=0, rx_errors=0, theta_hat=tuple(th), rate_hat=tuple(dth)),
                          seq=k, time_us=1000 * k)
    w.close()
    return path


def test_plot_writes_a_png_with_every_panel(tmp_path):
    log = _swing_log(tmp_path / "swing.csv")
    fig = make_figure(*read_log(log))
    assert len(fig.axes) == len(PANELS) == 6
    assert [len(ax.lines) for ax in fig.axes[:4]][0] >= 5  # one line per angle estimate
    shapes = [ln for ln in fig.axes[4].lines if ", t = " in ln.get_label()]
    assert [ln.get_label().split(",")[0] for ln in shapes] == ["start", "end"]  # snapshots at events only
    out = tmp_path / "swing.png"
    r = run_rodctl("plot", str(log), "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert out.exists() and out.stat().st_size > 20_000
    assert r.stdout.startswith(f"wrote {out}: 2000 telemetry frames, panels: ")


def test_shape_nodes_follow_the_convention():
    l = 0.031
    x, y = shape_nodes([0.0, np.pi / 2, np.pi], l)
    assert np.allclose(x, [0, 0, l, l]) and np.allclose(y, [0, -l, -l, 0])


def test_plot_without_a_display_writes_a_file_next_to_the_log(tmp_path):
    log = _swing_log(tmp_path / "run.csv", seconds=0.5)
    env = rodctl_env()  # headless: rodctl_env drops DISPLAY and WAYLAND_DISPLAY
    r = run_rodctl("plot", str(log), env=env)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "run.png").stat().st_size > 0
    assert f"no display: writing {tmp_path / 'run.png'}" in r.stderr


def test_live_plot_on_a_headless_machine_is_a_clear_message():
    env = rodctl_env()  # headless: rodctl_env drops DISPLAY and WAYLAND_DISPLAY
    r = run_rodctl("plot", "--live", "--port", "sim://", env=env)
    assert r.returncode == 1
    line = _one_error_line(r)
    assert line.startswith("rodctl: the scope needs a display: no display (DISPLAY is not set).")
    assert "rodctl log --port sim:// --out run.csv" in line


def test_live_plot_with_the_agg_backend_is_a_clear_message():
    r = run_rodctl("plot", "--live", "--port", "sim://", env=rodctl_env(DISPLAY=":0", MPLBACKEND="Agg"))
    assert r.returncode == 1
    assert "cannot open windows" in _one_error_line(r)


def _xvfb() -> bool:
    import shutil

    try:
        import tkinter  # noqa: F401
    except ImportError:
        return False
    return shutil.which("xvfb-run") is not None


@pytest.mark.skipif(not _xvfb(), reason="needs xvfb-run and tkinter")
def test_live_plot_runs_in_a_window_under_a_virtual_display():
    import re
    import subprocess

    env = rodctl_env(MPLBACKEND="TkAgg")  # the window tkinter (checked above) makes, whatever else is installed
    r = subprocess.run(["xvfb-run", "-a", *__import__("host_tools").RODCTL, "plot", "--live", "--port", "sim://",
                        "--duration", "2"], capture_output=True, text=True, timeout=120, env=env)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    # The start line comes only when the window is about to show (run_window's ready); Xvfb may add lines of its own.
    lines = r.stderr.splitlines()
    assert any(re.fullmatch(r"scope: sim:// \(firmware \d+\.\d+\.\d+, N=\d+\); keys: s swing-up, b balance, "
                            r"d disarm, c clear fault, r record, q quit; closing the window disarms", line)
               for line in lines), r.stderr
    assert lines[-1] == "scope ended: disarmed", r.stderr


def test_rodctl_runs_blas_on_one_thread_unless_the_user_chose_more(monkeypatch, capsys):
    """--jobs shares the cores out among whole runs; a BLAS pool in each would only spin on them. A user's
    own setting is kept, and what main() sets is in the environment the workers it starts inherit."""
    for name in cli.BLAS_THREAD_VARIABLES:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "3")
    with pytest.raises(SystemExit):
        cli.main(["--version"])
    assert capsys.readouterr().out.startswith("rodctl ")
    assert os.environ["OPENBLAS_NUM_THREADS"] == "3"
    assert os.environ["MKL_NUM_THREADS"] == os.environ["OMP_NUM_THREADS"] == "1"


def test_values_that_start_with_a_minus_are_values_not_options(tmp_path):
    """A hub left of the image and a time before the log's start, as a user types them (no `=`)."""
    args = cli.build_parser().parse_args(["track", "v.mp4", "--log", "l.csv", "--hub", "-10,-12", "--at", "-1e-3,2"])
    assert (args.hub, args.at) == ("-10,-12", "-1e-3,2")
    r = run_rodctl("track", str(tmp_path / "v.mp4"), "--log", str(tmp_path / "l.csv"), "--hub", "-10,-12", "-x")
    assert r.returncode == 2 and "unrecognized arguments: -x" in r.stderr  # a word is still an option


def test_help_texts_print_their_percent_signs_once():
    from host_tools import run_rodctl

    r = run_rodctl("identify", "--help")
    assert r.returncode == 0 and "95 % intervals" in r.stdout and "%%" not in r.stdout


def test_every_file_the_parameter_file_cites_is_in_the_repository(tmp_path):
    """rodctl params writes the default file's source notes: a cited file must exist in the clone."""
    import re

    from host_tools import run_rodctl
    from rodctl import paths

    out = tmp_path / "p.toml"
    assert run_rodctl("params", "--out", str(out)).returncode == 0
    cited = set(re.findall(r"\b((?:docs|firmware|host|gains)/[\w./-]+\.(?:md|toml|c|h|py))", out.read_text()))
    assert "docs/physics-notes.md" in cited
    assert all((paths.REPO / c).is_file() for c in cited), [c for c in cited if not (paths.REPO / c).is_file()]


@pytest.mark.parametrize("argv", [["gains"], ["protocol"], ["docs"], ["build"]])
def test_from_a_folder_in_another_clone_the_default_files_are_not_written(tmp_path, argv):
    """An editable rodctl run from a second clone wrote the first clone's committed header, protocol files and
    reference pages ("wrote firmware/include/rod_gains.h": the first clone's, shown as if it were this one's)."""
    from rodctl import paths

    other = tmp_path / "clone2"
    (other / "firmware" / "protocol").mkdir(parents=True)
    (other / "firmware" / "protocol" / "rodlink.toml").write_text("")
    (other / "platformio.ini").write_text("")
    (other / "sub").mkdir()
    before = {f: f.stat().st_mtime_ns for f in (paths.COMMITTED_HEADER, paths.COMMITTED_PARAMS)}
    r = run_rodctl(*argv, cwd=other / "sub")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    line = r.stderr.strip().splitlines()[-1]
    assert f"this rodctl is installed from the clone {paths.REPO} and works on its files, but this folder is in " \
           f"another clone, {other}: run this clone's own rodctl" in line, line
    assert {f: f.stat().st_mtime_ns for f in before} == before


def test_a_parameter_file_says_which_values_differ_from_the_default():
    """`params --set motor.gear_ratio=30` kept the default's sources and notes ("[V]: 12 V / (500 rpm * 20.4)") beside
    30 as if they were its own."""
    r = run_rodctl("params", "--set", "motor.gear_ratio=30")
    assert r.returncode == 0, r.stderr
    ratio = next(ln for ln in r.stdout.splitlines() if ln.startswith("gear_ratio ="))
    assert ratio.split("#", 1)[1].startswith(" CHANGED (default 20.4; the sources and notes here are the default's): G,")
    assert sum("CHANGED" in ln for ln in r.stdout.splitlines()) == 1  # the one value set, nothing else
    assert load_params(overrides=["motor.gear_ratio=30"]).to_toml() == r.stdout
