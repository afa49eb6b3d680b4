"""The Teensy board layer (firmware/src/board/teensy35) without the Teensyduino framework: it
compiles warning-free for the M4F against a stand-in of the framework API (tests/c/teensy_stub),
includes the framework only through board_framework.h, and, built for the host against that
stand-in with simulated time (board_harness.cpp), keeps the driver off when its timer does not
start, counts failed USB writes as dropped, and paces the watchdog refresh."""

from __future__ import annotations

import os
import re
import subprocess
from pathlib import Path

import pytest

from firmware_sil import header_path
from host_tools import host_compiler, host_cxx, tool
from rodctl import paths
from rodctl.link import protocol as P

BOARD = paths.FIRMWARE / "src" / "board" / "teensy35"
STUB = Path(__file__).parent / "c" / "teensy_stub"
ARM = ["-mcpu=cortex-m4", "-mthumb", "-mfpu=fpv4-sp-d16", "-mfloat-abi=hard", "-O2", "-fno-exceptions", "-fno-rtti"]
WARN = ["-std=gnu++14", "-Wall", "-Wextra", "-Wdouble-promotion", "-Werror"]


def _code(text: str) -> str:
    return re.sub(r"//[^\n]*|/\*.*?\*/", " ", text, flags=re.S)


@pytest.mark.parametrize("source", sorted(p.name for p in BOARD.glob("*.cpp")))
def test_board_sources_compile_with_wextra_against_the_framework_api(source, tmp_path):
    """The stand-in has an unused parameter, as kinetis.h does: only the wrapped include passes -Wextra."""
    r = subprocess.run([tool("arm-none-eabi-g++"), *WARN, *ARM, f"-I{STUB}", f"-I{header_path().parent}",
                        f"-I{paths.CORE_SRC}", "-c", str(BOARD / source), "-o", str(tmp_path / "b.o")],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr


def test_framework_headers_are_included_only_through_the_wrapper():
    for f in sorted(BOARD.glob("*.[ch]*")):
        if f.name == "board_framework.h":
            continue
        code = _code(f.read_text())
        assert not re.search(r"#include\s*<(Arduino|IntervalTimer|kinetis|WProgram)\.h>", code), f.name


@pytest.fixture(scope="module")
def harness(tmp_path_factory):
    """The board layer + core built for the host against the stand-in API (board_harness.cpp)."""
    cc, cxx = host_compiler(), host_cxx()
    d = tmp_path_factory.mktemp("board")
    inc = [f"-I{STUB}", f"-I{header_path().parent}", f"-I{paths.CORE_SRC}"]
    objs = []
    for c in sorted(paths.CORE_SRC.glob("*.c")):
        o = d / (c.stem + ".o")
        r = subprocess.run([cc, "-std=c11", "-O1", *inc, "-c", str(c), "-o", str(o)], capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        objs.append(str(o))
    exe = d / "board"
    r = subprocess.run([cxx, "-std=gnu++14", "-O1", *inc, str(STUB / "board_harness.cpp"),
                        *map(str, sorted(BOARD.glob("*.cpp"))), *objs, "-lm", "-o", str(exe)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return exe


def run_board(exe, seconds=1.0, timer_ok=True, fail_writes=(-1, 0), host: bytes = b"", upload_at_s=-1.0,
              reset_cause=(0x82, 0), eeprom_fails=0):
    """reset_cause: RCM_SRS0, RCM_SRS1 at start-up (default a power-on's: POR and LVD); eeprom_fails: the first
    EEPROM writes that change nothing."""
    r = subprocess.run([str(exe), str(seconds), "1" if timer_ok else "0", f"{fail_writes[0]},{fail_writes[1]}",
                        host.hex() or "-", str(upload_at_s), f"{reset_cause[0]:x},{reset_cause[1]:x}"],
                       capture_output=True, text=True, timeout=120,
                       env={**os.environ, "HARNESS_EEPROM_FAILS": str(eeprom_fails)})
    assert r.returncode == 0, r.stderr
    lines = r.stdout.splitlines()
    out = dict(ln.split("=", 1) for ln in lines[1:])
    dec = P.Decoder()
    frames = dec.feed(bytes.fromhex(lines[0].split(" ", 1)[1] if " " in lines[0] else ""))
    return frames, dec, out


def test_a_timer_that_does_not_start_keeps_the_driver_off_and_says_so(harness):
    host = P.encode(P.Arm(P.ArmMode.SWING_UP), 1) + P.encode(P.ClearFault(), 2) + P.encode(P.Arm(P.ArmMode.BALANCE), 3)
    frames, dec, out = run_board(harness, seconds=1.5, timer_ok=False, host=host)
    hellos = [f.msg for f in frames if f.type == P.MsgType.HELLO]
    assert hellos and all((h.mode, h.reason) == (P.Mode.FAULT, P.Reason.NO_TIMER) for h in hellos)
    tlm = [f.msg for f in frames if f.type == P.MsgType.TELEMETRY]
    assert len(tlm) > 100 and all(t.mode == P.Mode.FAULT and not t.flags & P.TelemetryFlag.DRIVER_ENABLED for t in tlm)
    acks = {f.msg.command_seq: f.msg for f in frames if f.type == P.MsgType.ACK}
    assert acks[1].result == P.AckResult.BAD_STATE and acks[3].result == P.AckResult.BAD_STATE  # no arming
    assert out["nen_low_ever"] == "0"  # nEN never driven low: the driver stayed off
    assert int(out["led_toggles"]) >= 20  # the FAULT blink (60 ms), not swing-up's 250 ms


def test_failed_usb_writes_count_as_dropped_and_cost_only_their_frames(harness):
    frames, dec, _ = run_board(harness, seconds=1.0, fail_writes=(200, 3))
    assert dec.seq_gaps == 3  # the three frames cut short, nothing else
    assert dec.errors <= 3  # each cut frame ended by a delimiter: the next one decodes
    last = [f.msg for f in frames if f.type == P.MsgType.TELEMETRY][-1]
    assert last.frames_dropped == 3  # and the board says so


def test_from_reset_the_driver_is_held_off_before_setup_runs(harness):
    """The core's startup takes ~300 ms (clocks, USB) before setup(): the board's early hook drives nEN high and
    the PWM pin low first, and leaves the watchdog as the core's own hook does (off, reconfigurable)."""
    _, _, out = run_board(harness, seconds=0.1)
    assert out["early_driver_off"] == "1"
    assert out["early_wdog_stctrlh"] == "16"  # WDOG_STCTRLH_ALLOWUPDATE


def test_watchdog_is_refreshed_at_its_pace(harness):
    """LPO clock undivided, a 250 ms timeout (a healthy loop() can be held 80 ms, and a false restart costs a
    power cycle: RESET), first refresh not before 5 ms, then at least 10 ms apart, and kept up."""
    _, _, out = run_board(harness, seconds=1.0)
    assert out["wdog_presc"] == "0" and out["wdog_stctrlh"] == "1"  # WDOGEN, CLKSRC = LPO, locked
    assert out["wdog_timeout_ms"] == "250"  # LPO ticks of 1 ms
    t = [int(x) for x in out["refresh_ms"].split(",")]
    assert t[0] >= 5
    gaps = [b - a for a, b in zip(t, t[1:])]
    assert min(gaps) >= 10 and max(gaps) <= 20  # far inside the 250 ms timeout


def test_serial_reads_never_wait(harness):
    """Stream's 1 s timeout would let readBytes spin past the 250 ms watchdog when the host re-enumerates
    between available() and it (teensy3/usb_dev.c frees the queued packets): setup() sets it to 0."""
    _, _, out = run_board(harness, seconds=0.1)
    assert out["serial_timeout_ms"] == "0"


@pytest.mark.parametrize("vector", ["nmi", "svcall", "debugmonitor", "hard"])
def test_an_exception_the_firmware_does_not_expect_turns_the_driver_off(harness, vector):
    """Swinging up (nEN low, PWM running), an NMI or a stray SVCall / DebugMonitor lands in the core's
    unused_isr, which spins with the pins as they were until the watchdog resets the chip (250 ms of drive):
    the board's handlers turn the driver off first, as its fault handlers do."""
    host = P.encode(P.Arm(P.ArmMode.SWING_UP), 1)
    r = subprocess.run([str(harness), "0.4", "1", "-1,0", host.hex(), "0.2", "82,0", vector],
                       capture_output=True, text=True, timeout=60)
    out = dict(ln.split("=", 1) for ln in r.stdout.splitlines() if "=" in ln and not ln.startswith("serial "))
    assert out["nen_low_before"] == "1"  # the driver was on when the exception came
    assert out["handler_driver_off"] == "1", r.stdout


def test_an_upload_request_turns_the_driver_off_on_the_next_step(harness):
    """Swinging up, the host sets the port to 134 baud (an upload asks for the bootloader; 15 ms later the
    CPU halts where it stands, PWM and nEN held): nEN goes high within one control period and stays high,
    and the board says why (FAULT, reason UPLOAD)."""
    host = P.encode(P.Arm(P.ArmMode.SWING_UP), 1)
    frames, _, out = run_board(harness, seconds=0.4, host=host, upload_at_s=0.2)
    upload, last_low = float(out["upload_ms"]), float(out["nen_low_last_ms"])
    assert upload - 1.0 <= last_low <= upload + 1.0, out  # driving until then, off within one step
    tlm = [f.msg for f in frames if f.type == P.MsgType.TELEMETRY]
    assert tlm[-1].mode == P.Mode.FAULT and tlm[-1].reason == P.Reason.UPLOAD
    assert not tlm[-1].flags & P.TelemetryFlag.DRIVER_ENABLED


@pytest.mark.parametrize("cause, held", [((0x20, 0), True), ((0, 0x02), True), ((0x02, 0), True), ((0, 0x04), True),
                                         ((0x04, 0), True), ((0x08, 0), True), ((0, 0x20), True),
                                         ((0x40, 0), False), ((0x82, 0), False), ((0, 0x08), False)],
                         ids=["watchdog", "lockup", "brown-out", "software", "clock-lost", "pll-lost", "stop-error",
                              "pin-reset", "power-on", "debugger"])
def test_a_restart_of_the_running_board_refuses_to_arm(harness, cause, held):
    """After the watchdog, a core lockup, a brown-out (a low-voltage reset without a power-on: the USB 5 V dipping
    as the motor starts), a software reset, a lost clock or a stop-mode error the count's zero is wherever the run
    left the rod (upright, mid-swing): the board holds FAULT, reason RESET, refuses ARM and CLEAR_FAULT, and never
    enables the driver. After a power-on, a pin reset (an upload's) or a debugger's the rod hung with the driver
    off, and it arms. A brown-out was taken for a power-on."""
    host = P.encode(P.ClearFault(), 1) + P.encode(P.Arm(P.ArmMode.SWING_UP), 2)
    frames, _, out = run_board(harness, seconds=0.3, host=host, reset_cause=cause)
    acks = {f.msg.command_seq: f.msg for f in frames if f.type == P.MsgType.ACK}
    tlm = [f.msg for f in frames if f.type == P.MsgType.TELEMETRY]
    if held:
        hellos = [f.msg for f in frames if f.type == P.MsgType.HELLO]
        assert hellos and all((h.mode, h.reason) == (P.Mode.FAULT, P.Reason.RESET) for h in hellos)
        assert acks[2].result == P.AckResult.BAD_STATE and out["nen_low_ever"] == "0"
        assert all(t.mode == P.Mode.FAULT and t.reason == P.Reason.RESET for t in tlm)
    else:
        assert acks[2].result == P.AckResult.OK and out["nen_low_ever"] == "1"
        assert tlm[-1].mode == P.Mode.SWING_UP


def test_a_rig_record_that_does_not_read_back_never_holds_arm(harness):
    """A SAVE_RIG whose EEPROM write failed left the save pending for good: every ARM and IDENTIFY after it was BUSY
    ("send again") until a power cycle. Now the failed write only keeps STORED off; a second SAVE_RIG stores it."""
    idle = b"\0" * (64 * 100)  # empty frames: the main loop reads 64 bytes a pass, 20 passes a step: 5 ms of nothing
    host = (P.encode(P.SaveRig(), 1) + idle + P.encode(P.HelloRequest(), 2) + P.encode(P.Arm(P.ArmMode.SWING_UP), 3)
            + P.encode(P.Disarm(), 4) + P.encode(P.SaveRig(), 5) + idle + P.encode(P.HelloRequest(), 6))
    frames, _, _ = run_board(harness, seconds=0.5, host=host, eeprom_fails=1)
    acks = {f.msg.command_seq: f.msg.result for f in frames if f.type == P.MsgType.ACK}
    assert acks[1] == P.AckResult.OK and acks[3] == P.AckResult.OK and acks[5] == P.AckResult.OK
    hellos = [f.msg for f in frames if f.type == P.MsgType.HELLO]
    assert not hellos[-2].rig & P.RigFlag.STORED and hellos[-1].rig & P.RigFlag.STORED  # the first did not store
