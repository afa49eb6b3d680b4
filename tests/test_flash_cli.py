"""rodctl build / flash: each branch (PlatformIO there or not, platform installed or not, registry
reachable or not), chosen by what the code is shown (PATH, PLATFORMIO_CORE_DIR, the registry probe),
never by what this machine happens to have installed or whether it is online."""

from __future__ import annotations

import socket
import stat

import pytest

from host_tools import refusing_port
from rodctl import cli, paths
from rodctl.build import platformio


@pytest.fixture
def no_pio(tmp_path, monkeypatch):
    """A machine where PlatformIO was never installed: empty PATH, no platformio module."""
    empty = tmp_path / "bin-empty"
    empty.mkdir()
    monkeypatch.setenv("PATH", str(empty))
    monkeypatch.setattr(platformio, "module_available", lambda name: False)
    monkeypatch.setenv("PLATFORMIO_CORE_DIR", str(tmp_path / "pio-core"))
    monkeypatch.delenv("PLATFORMIO_PLATFORMS_DIR", raising=False)


def _fake_pio(tmp_path, monkeypatch, output: str = "", code: int = 0, platform_installed: bool = False):
    """A `pio` on PATH that prints `output` and exits `code`; records its arguments."""
    bindir = tmp_path / "bin"
    bindir.mkdir()
    pio = bindir / "pio"
    (tmp_path / "pio-output.txt").write_text(output)
    pio.write_text(f"#!/bin/sh\necho \"$@\" > '{tmp_path}/pio-args.txt'\n"  # shell builtins only: PATH is just bin/
                   f"while IFS= read -r line; do echo \"$line\"; done < '{tmp_path}/pio-output.txt'\nexit {code}\n")
    pio.chmod(pio.stat().st_mode | stat.S_IXUSR)
    monkeypatch.setenv("PATH", str(bindir))
    monkeypatch.setattr(platformio, "module_available", lambda name: False)
    core = tmp_path / "pio-core"
    if platform_installed:
        (core / "platforms" / "teensy").mkdir(parents=True)
    monkeypatch.setenv("PLATFORMIO_CORE_DIR", str(core))
    monkeypatch.delenv("PLATFORMIO_PLATFORMS_DIR", raising=False)
    monkeypatch.setattr(paths, "BUILD", tmp_path / "build")
    return tmp_path / "pio-args.txt"


def _offline(monkeypatch):
    monkeypatch.setattr(platformio, "registry_reachable", lambda *a, **k: False)


def _online(monkeypatch):
    monkeypatch.setattr(platformio, "registry_reachable", lambda *a, **k: True)


def _project(tmp_path, ini: str = "[env:teensy35]\nplatform = teensy\n"):
    d = tmp_path / "proj"
    d.mkdir()
    (d / "platformio.ini").write_text(ini)
    return d


def _one_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


@pytest.mark.parametrize("command", [["build"], ["flash", "--upload-port", "/dev/ttyACM0"]])
def test_without_platformio_build_and_flash_say_how_to_install_it(no_pio, capsys, command):
    header = paths.COMMITTED_HEADER.read_bytes()
    assert cli.main(command) == 1
    line = _one_line(capsys)
    assert line.startswith("rodctl: PlatformIO not found")
    assert "pip install platformio" in line
    assert paths.COMMITTED_HEADER.read_bytes() == header  # nothing touched before failing


@pytest.mark.parametrize("command", [["build"], ["flash", "--upload-port", "/dev/ttyACM0"]])
def test_offline_without_the_platform_is_one_clear_line(tmp_path, monkeypatch, capsys, command):
    args_file = _fake_pio(tmp_path, monkeypatch)
    _offline(monkeypatch)
    header = paths.COMMITTED_HEADER.read_bytes()
    assert cli.main([*command, "--project-dir", str(_project(tmp_path))]) == 1
    line = _one_line(capsys)
    assert line.startswith("rodctl: PlatformIO could not install platform teensy (no internet?)")
    assert "pio pkg install -g -p teensy" in line
    assert not args_file.exists()  # PlatformIO was never started
    assert paths.COMMITTED_HEADER.read_bytes() == header


def test_missing_environment_is_one_line(tmp_path, monkeypatch, capsys):
    _fake_pio(tmp_path, monkeypatch)
    _offline(monkeypatch)
    proj = _project(tmp_path, "[env:uno]\nplatform = atmelavr\n")
    assert cli.main(["build", "--project-dir", str(proj)]) == 2
    assert _one_line(capsys) == (f"rodctl: --env teensy35: {proj / 'platformio.ini'} has no [env:teensy35] "
                                 "(environments: uno)")


@pytest.mark.parametrize("argv, line", [
    (["--set", "rod.bogus=1"], "rodctl: --set rod.bogus: unknown key"),
    (["--set", "gearbox.backlash_deg=-1"], "rodctl: gearbox.backlash_deg: must be between 0 and 10"),
    (["--project-dir", "{missing}"], "rodctl: --project-dir {missing}: no platformio.ini there"),
    (["--project-dir", ""], "rodctl: --project-dir: empty folder name"),  # built this checkout, its header rewritten
])
@pytest.mark.parametrize("command", [["build"], ["flash", "--upload-port", "/dev/ttyACM0"]])
def test_bad_input_is_named_before_looking_for_platformio(no_pio, capsys, tmp_path, command, argv, line):
    """The user's own mistake comes first (exit 2), not a PlatformIO this machine happens to lack."""
    missing = str(tmp_path / "missing")
    header = paths.COMMITTED_HEADER.read_bytes()
    assert cli.main([*command, *(a.replace("{missing}", missing) for a in argv)]) == 2
    assert _one_line(capsys).startswith(line.replace("{missing}", missing))
    assert paths.COMMITTED_HEADER.read_bytes() == header


@pytest.mark.parametrize("port, line", [
    ("sim://", "rodctl: --port sim://: flash uploads to a Teensy on USB; the virtual board (sim://) needs no firmware"),
    ("/dev/ttyFAKE", "rodctl: --port /dev/ttyFAKE: no such serial port"),
])
def test_flash_to_a_port_that_takes_no_firmware_is_refused_before_the_header(no_pio, capsys, port, line):
    """`flash --port sim://` (which flash's own error suggested) regenerated the committed header for its --set, then
    ran PlatformIO against sim:// for a minute."""
    header = paths.COMMITTED_HEADER.read_bytes()
    assert cli.main(["flash", "--port", port, "--set", "rod.length=0.16"]) == 2
    assert _one_line(capsys).startswith(line)
    assert paths.COMMITTED_HEADER.read_bytes() == header


@pytest.mark.parametrize("command", [["build"], ["flash", "--upload-port", "/dev/ttyACM0"]])
def test_a_hand_written_project_header_is_kept_without_force(no_pio, capsys, tmp_path, command):
    """build/flash --project-dir replaced the project's own rod_gains.h, where `rodctl gains --header` refuses to."""
    proj = _project(tmp_path, "[env:teensy35]\nplatform = teensy\n")
    mine = proj / "firmware" / "include" / "rod_gains.h"
    mine.parent.mkdir(parents=True, exist_ok=True)
    mine.write_text("/* my hand-tuned gains */\n")
    assert cli.main([*command, "--project-dir", str(proj)]) == 2
    assert _one_line(capsys) == (f"rodctl: the project's {mine} exists and is not a file rodctl generated; pass "
                                 "--force to overwrite")
    assert mine.read_text() == "/* my hand-tuned gains */\n"


def test_online_without_the_platform_runs_platformio_and_summarizes_its_failure(tmp_path, monkeypatch, capsys):
    """Registry reachable: PlatformIO is left to install the platform; its failure is one line."""
    out = "Platform Manager: Installing teensy\nHTTPClientError: \n"
    args_file = _fake_pio(tmp_path, monkeypatch, output=out, code=1)
    _online(monkeypatch)
    assert cli.main(["build", "--project-dir", str(_project(tmp_path))]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("rodctl: build failed: PlatformIO could not install platform teensy (no internet?)")
    assert args_file.read_text().split() == ["run", "-e", "teensy35"]


def test_installed_platform_builds_offline(tmp_path, monkeypatch, capsys):
    """The header regenerated is the one PlatformIO builds: the project's (it was this checkout's, whatever
    --project-dir said), made from the parameters given."""
    args_file = _fake_pio(tmp_path, monkeypatch, output="SUCCESS\n", platform_installed=True)
    _offline(monkeypatch)
    committed = paths.COMMITTED_HEADER.read_bytes()
    project = _project(tmp_path)
    assert cli.main(["build", "--project-dir", str(project), "--set", "rod.length=0.16"]) == 0
    assert args_file.read_text().split() == ["run", "-e", "teensy35"]
    assert "build: done" in capsys.readouterr().err
    built = (project / "firmware" / "include" / "rod_gains.h").read_text()
    assert "--set rod.length=0.16" in built and paths.COMMITTED_HEADER.read_bytes() == committed


def test_platformio_as_a_python_module_is_found(tmp_path, monkeypatch):
    empty = tmp_path / "bin-empty"
    empty.mkdir()
    monkeypatch.setenv("PATH", str(empty))
    monkeypatch.setattr(platformio, "module_available", lambda name: name == "platformio")
    assert platformio.find_platformio()[1:] == ["-m", "platformio"]


def test_registry_probe_sees_a_closed_and_an_open_port(monkeypatch):
    for k in ("HTTPS_PROXY", "https_proxy", "HTTP_PROXY", "http_proxy", "ALL_PROXY"):
        monkeypatch.delenv(k, raising=False)
    with socket.socket() as srv:
        srv.bind(("127.0.0.1", 0))
        srv.listen(1)
        port = srv.getsockname()[1]
        assert platformio.registry_reachable(timeout=5, host="127.0.0.1", port=port)
    with refusing_port() as closed:
        assert not platformio.registry_reachable(timeout=5, host="127.0.0.1", port=closed)
    monkeypatch.setenv("HTTPS_PROXY", "http://proxy.invalid:3128")  # behind a proxy we cannot tell: assume yes
    assert platformio.registry_reachable(timeout=5, host="127.0.0.1", port=closed)


def test_outside_a_clone_build_and_flash_name_what_they_need(monkeypatch, capsys):
    monkeypatch.setattr(paths, "IN_CLONE", False)
    for command in (["build"], ["flash"], ["protocol"]):
        assert cli.main(command) == 2
        line = _one_line(capsys)
        assert "needs a clone of this repository" in line and "pip install -e ." in line


class _Port:
    def __init__(self, device, vid=0x16C0, pid=0x0483):
        self.device, self.vid, self.pid, self.serial_number = device, vid, pid, None


def test_a_board_still_listed_after_the_upload_is_not_taken_as_back_until_it_stays():
    """PlatformIO may return before the Teensy drops off USB: a port listed at the first look is the board that
    has not left yet (or is already back); it counts as back only once it has left and returned, or stayed."""
    from serial.tools import list_ports

    from rodctl.link import ports

    seq = [True, True, False, False, True]  # still there, gone, back
    calls = []

    def comports():
        calls.append(1)
        return [_Port("/dev/ttyACM0")] if seq[min(len(calls), len(seq)) - 1] else []

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(list_ports, "comports", comports)
        assert ports.wait_for_board("/dev/ttyACM0", timeout_s=30.0, poll_s=0.0, stay_s=30.0) == "/dev/ttyACM0"
        assert len(calls) == 5  # not at the first look: after it left and came back
        calls.clear()
        seq[:] = [True]  # never leaves: back once it has stayed
        assert ports.wait_for_board("/dev/ttyACM0", timeout_s=30.0, poll_s=0.01, stay_s=0.05) == "/dev/ttyACM0"
        assert len(calls) >= 3


@pytest.mark.parametrize("back_after", [3, None], ids=["back", "not-back"])
def test_flash_waits_for_the_board_to_come_back_on_usb(tmp_path, monkeypatch, capsys, back_after):
    """PlatformIO returns while the Teensy restarts: `rodctl status` at once found no Teensy. flash now says
    where the board is back (listed again after a few polls), or, when it does not come back, what to do."""
    from serial.tools import list_ports

    from rodctl.cli import flash

    args_file = _fake_pio(tmp_path, monkeypatch, output="SUCCESS\n", platform_installed=True)
    _offline(monkeypatch)
    polls = []

    def comports():
        polls.append(1)
        return [_Port("/dev/ttyACM0")] if back_after is not None and len(polls) > back_after else []

    monkeypatch.setattr(list_ports, "comports", comports)
    monkeypatch.setattr(flash, "BACK_ON_USB_S", 30.0 if back_after is not None else 0.5)  # back: within 1 s
    assert cli.main(["flash", "--upload-port", "/dev/ttyACM0", "--project-dir", str(_project(tmp_path))]) == 0
    assert args_file.read_text().split() == ["run", "-e", "teensy35", "-t", "upload", "--upload-port", "/dev/ttyACM0"]
    last = capsys.readouterr().out.strip().splitlines()[-1]
    if back_after is not None:
        assert last == "flashed: the board is back on /dev/ttyACM0, DISARMED; check it with `rodctl status`"
        assert len(polls) == back_after + 1
    else:
        assert last.startswith("flashed, but the board is not back on USB after 0.5 s: unplug it")
