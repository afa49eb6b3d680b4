"""The session and the one-shot commands against the virtual board (sim://, the real protocol path)."""

from __future__ import annotations

import math
import re
import time

import pytest

from host_tools import run_rodctl, until
from rodgains.errors import UserError
from rodgains.params import load_params

from rodctl import cli
from rodctl.link import protocol as P
from rodctl.link.session import SETTINGS, Session, parse_assignment


@pytest.fixture
def session():
    with Session("sim://") as s:
        yield s


def test_hello_identifies_the_firmware(session):
    h = session.hello
    assert (h.fw_major, h.fw_minor, h.fw_patch) >= (0, 1, 0)
    assert h.n == _default_edges()  # the controller's model order from the parameter file
    assert h.period_us == 1000
    assert bytes(h.header_sha256).hex() == _committed_sha()


def _default_edges() -> int:
    from rodgains.params import load_params

    return load_params().N


def _committed_sha() -> str:
    from rodgains.params import load_params

    return load_params().sha256()


def _telemetry_times_us(session, frames: int, timeout: float = 30.0) -> list[int]:
    """Device timestamps [us] of the next `frames` telemetry frames (the device's clock, not ours)."""
    times = []

    def listener(f, _t):
        if f.type == P.MsgType.TELEMETRY:
            times.append(f.time_us)

    session.add_listener(listener, replay=False)
    deadline = time.monotonic() + timeout
    while len(times) < frames and time.monotonic() < deadline:
        time.sleep(0.02)
    session.remove_listener(listener)
    assert len(times) >= frames
    return times[:frames]


def test_telemetry_arrives_at_1khz_with_contiguous_sequence(session):
    times = _telemetry_times_us(session, 500)
    assert set(b - a for a, b in zip(times, times[1:])) == {1000}  # every control step, by the device's clock
    assert session.seq_gaps == 0 and session.counters()["seq_gaps"] == 0
    assert session.counters()["errors"] == 0


@pytest.mark.parametrize("reason", list(P.Reason))
def test_every_fault_reason_of_the_protocol_reads_as_words(reason):
    """A FAULT the board reports is told in words, whatever its reason (an IMU fault raised KeyError in the
    status line: its reason had no text)."""
    from rodctl.link.session import mode_text, reason_text

    text, line = reason_text(reason), mode_text(P.Mode.FAULT, reason)
    assert text and not text.startswith("reason ") and text in line
    # the board's own faults are left by a restart, not by clear-fault, and the line does not send the user there
    held = reason in (P.Reason.NO_TIMER, P.Reason.UPLOAD, P.Reason.RESET)
    assert ("clear-fault" in line) != held, line


def test_status_command_prints_hello_and_one_telemetry(capsys):
    assert cli.main(["status", "--port", "sim://"]) == 0
    out = capsys.readouterr().out
    assert "firmware    0.1.0" in out
    assert f"N={_default_edges()} at 1000 Hz" in out
    assert "mode        DISARMED" in out
    assert "theta_hat [-180.0, -180.0," in out and "] deg from upright" in out  # hanging: 180 from upright


def test_set_out_of_range_is_refused_with_the_range(capsys):
    assert cli.main(["set", "catch_angle_deg=70", "--port", "sim://"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == ("rodctl: catch_angle_deg=70 out of range: allowed 2 <= catch_angle_deg <= 60 deg "
                   "(the balance angle limit, at most 90 deg)")


@pytest.mark.parametrize("text, allowed", [
    ("catch_angle_deg=1e42", "2 <= catch_angle_deg <= min(90, the balance angle limit), in deg (--params names the "
                             "design's safety.angle_limit_deg)"),
    ("catch_angle_deg=1e-40", "2 <= catch_angle_deg"),
    ("swing_amplitude=0", "0.001 <= swing_amplitude <= the firmware's torque ceiling, in N m (rodctl status gives the "
                          "ceiling)"),
    ("swing_angle_deg=190", "2 <= swing_angle_deg <= 180 deg"),
    ("swing_angle_deg=1", "2 <= swing_angle_deg <= 180 deg"),
    ("telemetry_decimation=2.5", "integer 1 <= telemetry_decimation <= 1000"),
    ("heartbeat_timeout=20", "0.2 <= heartbeat_timeout <= 10 s"),
])
def test_every_setting_has_a_physical_range_checked_before_sending(text, allowed):
    with pytest.raises(UserError, match=re.escape(f"out of range: allowed {allowed}")) as e:
        parse_assignment(text)
    assert e.value.exit_code == 2


def test_device_ceiling_comes_from_the_hello(session):
    setting, value = parse_assignment("swing_amplitude=0.5")
    with pytest.raises(UserError, match="allowed 0.001 <= swing_amplitude <= 0.2 N m"):
        session.set(setting, value)


def test_the_device_refuses_what_the_host_refuses(session):
    """The firmware checks the same ranges (rodlink.toml): send past the host's check."""
    for setting, value in [(SETTINGS["catch_angle_deg"], 1.0), (SETTINGS["swing_angle_deg"], 1.0),
                           (SETTINGS["swing_amplitude"], 0.0005), (SETTINGS["catch_angle_deg"], 1e30)]:
        with pytest.raises(UserError, match="out of range"):
            session.command(P.Set(setting.param, setting.to_device(value)), what="raw set")
    for setting, value in [(SETTINGS["catch_angle_deg"], 2.0), (SETTINGS["swing_angle_deg"], 2.0)]:
        session.command(P.Set(setting.param, setting.to_device(value)), what="raw set")  # the bounds themselves
    hello = session.request_hello()
    assert hello.catch_angle == pytest.approx(math.radians(2.0), rel=1e-6)  # taken, not merely not refused
    assert hello.swing_angle == pytest.approx(math.radians(2.0), rel=1e-6)


def test_set_applies_all_or_none(session, capsys):
    before = session.request_hello()
    with pytest.raises(UserError, match="catch_angle_deg=100 out of range"):
        session.set_all([parse_assignment("swing_amplitude=0.15"), (SETTINGS["catch_angle_deg"], 100.0)])
    after = session.request_hello()
    assert after.swing_amplitude == before.swing_amplitude  # the first was not applied


def test_set_rolls_back_when_the_device_refuses_a_later_one(session):
    """A bound only the device knows (the angle limit without the design): undo what was applied."""
    before = session.request_hello()
    with pytest.raises(UserError, match="device refused catch_angle_deg=80"):
        session.set_all([(SETTINGS["swing_amplitude"], 0.15), (SETTINGS["catch_angle_deg"], 80.0)])
    after = session.request_hello()
    assert after.swing_amplitude == before.swing_amplitude
    assert after.catch_angle == before.catch_angle


def test_set_command_applies_nothing_when_one_value_is_bad(capsys):
    assert cli.main(["set", "swing_amplitude=0.15", "catch_angle_deg=100", "--port", "sim://"]) == 2
    assert "catch_angle_deg=100 out of range" in capsys.readouterr().err


def test_a_setting_given_twice_is_refused_before_anything_is_sent(capsys):
    """It printed "swing_amplitude = 0.07 N m" twice, for 0.05 and 0.07, exit 0."""
    assert cli.main(["set", "swing_amplitude=0.05", "swing_amplitude=0.07", "--port", "sim://"]) == 2
    out, err = capsys.readouterr()
    assert err.strip() == "rodctl: swing_amplitude given more than once; give each setting once" and not out


def test_set_round_trip_changes_what_the_device_reports(session):
    session.set("swing_angle_deg", 45.0)
    session.set("swing_amplitude", 0.05)
    h = session.request_hello()
    assert h.swing_angle == pytest.approx(math.radians(45.0), rel=1e-6)
    assert h.swing_amplitude == pytest.approx(0.05, rel=1e-6)


def test_telemetry_decimation_slows_the_telemetry(session):
    session.set("telemetry_decimation", 10)
    session.request_hello()  # frames after this ack come at the new rate
    times = _telemetry_times_us(session, 50)
    assert set(b - a for a, b in zip(times, times[1:])) == {10_000}  # every 10th step


def test_set_command_prints_the_new_value(capsys):
    assert cli.main(["set", "catch_angle_deg=25", "heartbeat_timeout=1", "--port", "sim://"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out == ["catch_angle_deg = 25 deg (until the board resets)",
                   "heartbeat_timeout = 1 s (until the board resets)"]


def test_unknown_setting_names_the_choices(capsys):
    assert cli.main(["set", "gain=3", "--port", "sim://"]) == 2
    err = capsys.readouterr().err
    assert "unknown setting 'gain'" in err
    for name in SETTINGS:
        assert name in err


def test_arm_swing_up_drives_the_motor_and_disarm_stops_it(session):
    ack = session.arm(P.ArmMode.SWING_UP)
    assert ack.mode == P.Mode.SWING_UP
    t = session.wait_telemetry()
    assert t.mode == P.Mode.SWING_UP
    assert t.flags & P.TelemetryFlag.DRIVER_ENABLED
    amplitude = load_params()["swing_up"]["amplitude"]
    assert abs(t.torque) == pytest.approx(amplitude, rel=1e-5)  # eq. (22): the configured amplitude
    counts = []
    session.add_listener(lambda f, _t: counts.append(f.msg.encoder_count) if f.type == P.MsgType.TELEMETRY else None,
                         replay=False)
    assert until(lambda: max(map(abs, counts), default=0) > 20)  # the simulated rod swings (20 counts = 7 deg)
    ack = session.disarm()
    assert ack.mode == P.Mode.DISARMED
    t = session.wait_telemetry()
    assert (t.mode, t.reason) == (P.Mode.DISARMED, P.Reason.HOST)
    assert not t.flags & P.TelemetryFlag.DRIVER_ENABLED and t.duty == 0.0


def test_heartbeat_keeps_an_armed_device_armed(session):
    session.arm(P.ArmMode.BALANCE)
    times = _telemetry_times_us(session, 2000)  # 2 s of the board's own clock: 4x the heartbeat timeout
    assert len(times) == 2000 and times[-1] - times[0] >= 1_999_000
    t = session.wait_telemetry()
    assert (t.mode, t.reason) == (P.Mode.CATCH, P.Reason.NONE)
    assert t.flags & P.TelemetryFlag.HEARTBEAT_OK


def test_silent_host_faults_and_arm_in_fault_is_refused_naming_clear_fault(session):
    session.arm(P.ArmMode.BALANCE)
    with session.heartbeat_paused():
        # how soon it trips, by the device's clock, is test_firmware_safety.py's
        # test_heartbeat_timeout_trips_at_the_configured_time; here only that it trips and why
        until(lambda: session.telemetry.mode == P.Mode.FAULT, timeout=30)
    assert (session.telemetry.mode, session.telemetry.reason) == (P.Mode.FAULT, P.Reason.HEARTBEAT)
    with pytest.raises(UserError) as e:
        session.arm(P.ArmMode.SWING_UP)
    assert str(e.value) == "device is in FAULT (heartbeat lost): run `rodctl clear-fault`"
    ack = session.clear_fault()
    assert ack.mode == P.Mode.DISARMED
    assert session.arm(P.ArmMode.BALANCE).mode == P.Mode.CATCH


def test_a_holder_that_stops_looking_at_the_link_lets_the_board_disarm_itself():
    """A command's session (liveness_s) heartbeats only while the code holding it calls check(): a main thread
    stuck elsewhere (writing to a terminal paused with Ctrl-S kept `rodctl arm` armed past its duration, and
    Ctrl-C could not reach the DISARM) leaves the board to trip HEARTBEAT. Looking at the link keeps it armed."""
    from rodctl.cli.common import LIVENESS_S

    with Session("sim://", liveness_s=LIVENESS_S) as s:
        s.arm(P.ArmMode.BALANCE)
        end = time.monotonic() + 2 * LIVENESS_S  # past the window: the looking is what keeps it
        while time.monotonic() < end:  # looking: the heartbeats go on
            s.check()
            time.sleep(0.05)
        assert s.telemetry.mode == P.Mode.CATCH and s.telemetry.flags & P.TelemetryFlag.HEARTBEAT_OK
        assert until(lambda: s.telemetry.mode == P.Mode.FAULT, timeout=30)  # not looking (no check())
        assert s.telemetry.reason == P.Reason.HEARTBEAT


def test_an_attach_disarms_before_it_writes_its_last_line():
    """The end of `rodctl log/arm` writes to the terminal (the status line's newline), which blocks while the
    terminal is paused: the DISARM goes out first, so a blocked write cannot keep the board armed."""
    from rodctl.link.attach import attach

    s = Session("sim://")
    seen = []
    a = attach(s, arm_mode=P.ArmMode.BALANCE, duration_s=0.3,
               stopping=lambda: seen.append((s.closed, s.disarm_acked)))
    assert seen == [(True, True)] and a.ended == "duration"


def test_a_bare_session_heartbeats_while_open():
    """The Python API's Session (no liveness_s) heartbeats for as long as it is open, so a script that only
    sleeps while a log fills (docs/api.md) keeps its board armed."""
    with Session("sim://") as s:
        s.arm(P.ArmMode.BALANCE)
        time.sleep(4 * s.hello.heartbeat_timeout)
        assert s.telemetry.mode == P.Mode.CATCH


def test_a_board_started_by_its_watchdog_says_a_power_cycle_and_not_clear_fault_leaves_it(capsys):
    """The board's own fault (RESET: started by its watchdog, its zero wherever the rod was): status names it
    without sending the user to clear-fault, clear-fault says it was not cleared (exit 1), arming is refused
    with the same words, and the driver is never enabled."""
    port = "sim://?restart=watchdog"
    assert cli.main(["status", "--port", port]) == 0
    mode = next(ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("mode"))
    assert "FAULT (the board restarted while running (its watchdog" in mode and "clear-fault" not in mode, mode
    assert cli.main(["clear-fault", "--port", port]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("rodctl: not cleared: device is in FAULT (the board restarted"), err
    with Session(port) as s:
        with pytest.raises(UserError) as e:
            s.arm(P.ArmMode.SWING_UP)
        assert "power it off and on with the rod hanging still" in str(e.value) and "clear-fault" not in str(e.value)
        t = s.wait_telemetry()
        assert (t.mode, t.reason) == (P.Mode.FAULT, P.Reason.RESET) and not t.flags & P.TelemetryFlag.DRIVER_ENABLED


def test_two_sim_ports_are_two_independent_boards():
    with Session("sim://") as a, Session("sim://") as b:
        a.arm(P.ArmMode.SWING_UP)
        assert until(lambda: abs(a.telemetry.encoder_count) > 20)  # a's rod swings (20 counts = 7 deg)
        assert a.wait_telemetry().mode == P.Mode.SWING_UP
        assert b.wait_telemetry().mode == P.Mode.DISARMED
        assert b.telemetry.encoder_count == 0


def test_sim_url_options_choose_the_plant():
    with Session("sim://?plant=der&edges=12") as s:
        assert s.ser.device.plant.N == 12 + 1 and s.ser.device.kind == "der"  # 12 edges beyond the hub edge
        assert s.hello.n == _default_edges()  # the controller's model keeps the parameters' N
        counts = []
        s.add_listener(lambda f, _t: counts.append(f.msg.encoder_count) if f.type == P.MsgType.TELEMETRY else None)
        s.arm(P.ArmMode.SWING_UP)
        assert until(lambda: max(map(abs, counts), default=0) > 5)  # the simulated DER rod moves


def test_bad_sim_option_is_one_line(capsys):
    assert cli.main(["status", "--port", "sim://?plant=rubber"]) == 2  # bad input, not a board fault
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown plant 'rubber'" in err[0]


def test_arm_command_stays_attached_then_disarms(capsys):
    assert cli.main(["arm", "--balance", "--port", "sim://", "--duration", "1"]) == 0
    err = capsys.readouterr().err
    assert "armed balance: mode CATCH" in err
    assert "disarmed" in err.splitlines()[-1]


@pytest.mark.parametrize("command", [["arm", "--swing-up"], ["log", "--arm", "swing-up"]])
def test_a_run_the_board_trips_ends_there_with_exit_1_and_says_so(command, tmp_path, capsys):
    """A reversed motor trips RUNAWAY within 0.1 s of arming: the command ends there, not at its --duration, exit 1
    (it exited 0 saying "disarmed", and logged 2 s of FAULT). The log keeps the run and its trailer says FAULT, which
    only a run ended by the trip writes (one that ran its --duration says "duration")."""
    from rodctl.logs import read_log

    out = tmp_path / "run.csv"
    assert cli.main([*command, "--port", "sim://?motor_sign=-1", "--duration", "5", "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-2].endswith("; the board is in FAULT, its driver off") and "disarmed" not in err[-2]
    assert err[-1].startswith("rodctl: the board tripped ") and "FAULT (runaway" in err[-1]
    assert err[-1].endswith(f"{out} keeps the run up to the trip")
    log = read_log(out)
    assert log.meta["end"] == "FAULT"
    # the time the board's clock gives, not the host's to a USB batch ("0.1 s" for a 36 ms trip)
    said = float(err[-1].split("tripped ")[1].split(" s after")[0])
    ev = log.events
    arm = next(t for t, name, info in zip(ev["time_s"], ev["event_name"], ev["info_text"]) if info.startswith("ACK ARM"))
    fault = log.data["time_s"][log.data["mode_name"] == "FAULT"][0]
    assert abs(said - (fault - arm)) <= 0.003, (said, fault - arm)


def test_disarm_and_clear_fault_commands(capsys):
    assert cli.main(["disarm", "--port", "sim://"]) == 0
    assert capsys.readouterr().out.strip() == "disarmed: mode DISARMED"
    assert cli.main(["clear-fault", "--port", "sim://"]) == 0
    assert capsys.readouterr().out.strip() == "no fault to clear: mode DISARMED"


def test_console_session_from_a_script():
    script = "status\nset catch_angle_deg=200\narm balance\nstatus\nfly\ndisarm\nquit\n"
    r = run_rodctl("console", "--port", "sim://", input=script, timeout=60)
    assert r.returncode == 0, r.stderr
    out = r.stdout
    assert "mode DISARMED;" in out
    assert ("error: catch_angle_deg=200 out of range: allowed 2 <= catch_angle_deg <= "
            "min(90, the balance angle limit), in deg") in out
    assert "armed balance: mode CATCH" in out
    assert "mode CATCH;" in out
    assert "error: unknown command 'fly'" in out
    assert out.rstrip().endswith("disarmed and disconnected")
    assert "Traceback" not in r.stderr


def test_the_console_takes_a_typo_as_a_typo_and_a_disarm_with_words_still_disarms():
    """An unbalanced quote ended the session with an internal error; `status verbose` ran a bare status and `disarm
    now please` dropped the words without a word."""
    script = 'arm swing-up\nset "x\nstatus verbose\ndisarm now please\nstatus\nquit\n'
    r = run_rodctl("console", "--port", "sim://", input=script, timeout=60)
    assert r.returncode == 0 and "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr
    out = r.stdout
    assert "error: no closing quotation" in out
    assert "error: status takes nothing after it (got 'verbose'); 'help' lists commands" in out
    assert "mode DISARMED (ignored: now please)" in out and "mode DISARMED (last: disarmed by the host)" in out
    assert out.rstrip().endswith("disarmed and disconnected")


def test_a_balancing_rod_is_not_pumped_by_a_second_arm():
    """ARM SWING_UP while balancing threw the estimate and the trim away at the next catch, and with the rod 32 to
    60 deg off put the full pump on it near the top (swing-up has no angle limit): refused, disarm first."""
    script = "arm balance\narm swing-up\narm balance\nstatus\nquit\n"
    r = run_rodctl("console", "--port", "sim://?theta0_deg=180", input=script, timeout=60)
    assert r.returncode == 0, r.stderr
    assert "error: device refused arm swing-up in mode BALANCE: disarm first (type `disarm`)" in r.stdout
    assert r.stdout.count("armed balance: mode ") == 2 and "\nrodctl> mode BALANCE;" in r.stdout  # still balancing


def test_a_setting_refused_while_armed_says_to_disarm_first():
    script = "arm swing-up\nset encoder_sign=-1\ndisarm\nquit\n"
    r = run_rodctl("console", "--port", "sim://", input=script, timeout=60)
    assert r.returncode == 0, r.stderr
    assert "error: device refused encoder_sign=-1 in mode SWING_UP: disarm first (type `disarm`)" in r.stdout
