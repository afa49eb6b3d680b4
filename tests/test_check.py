"""`rodctl check` against the virtual board, right and with each first-power-on fault (sim:// options):
the exact FAIL line and its fix, the exit status, the JSON, Ctrl-C, a silent board, bad input."""

from __future__ import annotations

import json
import os
import pty
import re
import signal
import time

import pytest

from host_tools import BoardSaid, run_rodctl, sim_device, start_rodctl, until

ENCODER_SIGN_FIX = ("Fix: the encoder counts backwards: flip the board's encoder sign (`rodctl check --fix` stores "
                    "it), or swap the encoder's A and B wires")
MOTOR_SIGN_FIX = ("Fix: the motor turns the wrong way: flip the board's motor sign (`rodctl check --fix` stores it), "
                  "or swap the motor leads M1 and M2")
STEPS = ("identity", "loop", "driver", "encoder", "motor", "heartbeat")


def check(url: str, *args, input: str | None = None):
    r = run_rodctl("check", "--port", url, *args, timeout=240, input=input)
    lines = {ln.split()[1]: ln for ln in r.stdout.splitlines() if ln[:4] in ("PASS", "FAIL", "SKIP")}
    return r, lines


def test_a_right_board_passes_every_step_and_writes_the_json(tmp_path):
    out = tmp_path / "check.json"
    r, lines = check("sim://", "--json", str(out))
    assert r.returncode == 0, r.stdout + r.stderr
    assert list(lines) == list(STEPS)
    assert all(ln.startswith("PASS") for ln in lines.values()), r.stdout
    assert "the design of gains/rodgains/default.toml" in lines["identity"]
    assert "signs encoder +1 motor +1, 979.2 counts/turn (not stored on the board)" in lines["identity"]
    assert "0 overruns; telemetry 1000 of 1000 Hz, 0 frames dropped" in lines["loop"]
    assert "the turn read +2" in lines["encoder"]  # about +245 counts: a quarter turn of 979.2
    assert "tripped HEARTBEAT after 0.50" in lines["heartbeat"]
    assert r.stdout.splitlines()[-1].startswith("check: 6 passed, 0 failed, 0 skipped")
    data = json.loads(out.read_text())
    assert data["passed"] is True and [x["step"] for x in data["results"]] == list(STEPS)
    motor = data["results"][4]["values"]
    assert 0.7 < motor["gain"] < 1.4  # the rig is its own model
    assert abs(data["results"][3]["values"]["turn_peak_deg"] - 90) < 8
    assert abs(data["results"][5]["values"]["trip_s"] - 0.5) <= 0.003


def test_a_virtual_board_is_checked_against_its_own_file(tmp_path):
    """`check --port sim://?params=FILE` failed identity against the default file (and judged the motor by its model),
    where status and log on the same port name FILE as the board's design."""
    from rodgains.params import load_params

    f = tmp_path / "long.toml"
    f.write_text(load_params(overrides=["rod.length=0.14"]).to_toml())
    r, lines = check(f"sim://?params={f}", "--yes")
    assert r.returncode == 0, r.stdout + r.stderr
    assert lines["identity"].startswith("PASS") and lines["identity"].endswith(f"= the design of {f}")


def test_a_rod_hanging_whole_turns_from_its_zero_still_passes():
    """After a swing-up that went over the top the rod hangs a whole turn (979.2 counts) from its boot zero, which
    the firmware's angle counts: the check failed it and told the user to reset the board."""
    r, lines = check("sim://?theta0_deg=360", "--yes")
    assert r.returncode == 0, r.stdout + r.stderr
    assert re.search(r"PASS encoder   still at rest, hanging -?[0-3] counts from zero after 1 whole turn; ",
                     lines["encoder"]), lines["encoder"]


# fault -> (step, start of its FAIL line's measurement, its fix)
FAULTS = {
    "encoder_sign=-1": ("encoder", "still at rest, hanging 0 counts from zero; the turn read -2", ENCODER_SIGN_FIX),
    "ab_swapped": ("encoder", "still at rest, hanging 0 counts from zero; the turn read -2", ENCODER_SIGN_FIX),
    "motor_sign=-1": ("motor", "+-20 mN m pulses: the rod moved -", MOTOR_SIGN_FIX),
    "encoder=dead": ("encoder", "still at rest, hanging 0 counts from zero; the count did not change while the "
                                "rod turned", "Fix: the encoder is not connected: check the encoder's 5 V and GND, "
                                              "and A and B to pins 3 and 4 (docs/wiring.md)"),
    "counts_per_rev=1958.4": ("encoder", "still at rest, hanging 0 counts from zero; the turn read +",
                              "Fix: the counts per output turn are not 979.2: check encoder.counts_per_motor_rev "
                              "and motor.gear_ratio in gains/rodgains/default.toml (a gearmotor of another ratio?); "
                              "for another encoder on this gearbox, `rodctl set counts_per_rev=N --save` keeps the "
                              "rig's own on the board"),
    "nfault=low": ("driver", "nFAULT is low: the MAX14870 reports a fault and the board keeps the motor off",
                   "Fix: check the motor supply (VM, 4.5 to 36 V) and that the motor leads do not short, and "
                   "nFAULT's wire to pin 8 (docs/wiring.md)"),
    "supply=off": ("motor", "+-20 mN m pulses moved the encoder ",
                   "Fix: the motor gets no power: the motor supply (VM) is off or the motor leads M1/M2 are loose; "
                   "or the encoder is not connected (the encoder step tells which)"),
    "boot_angle_deg=10": ("encoder", "the hanging rod reads -27 counts (-9.9 deg) from zero",
                          "Fix: the board takes its zero at power-on: let the rod hang still, then reset the board "
                          "(its button, or unplug and replug USB)"),
    "header=stale": ("identity", "firmware 0.1.0, protocol v2, N=8 at 1000 Hz, signs encoder +1 motor +1, "
                                 "979.2 counts/turn (not stored on the board), header ",
                     "Fix: the board runs another design: flash this one with `rodctl flash`"),
}


@pytest.mark.parametrize("fault", list(FAULTS))
def test_each_fault_fails_its_step_with_the_fix(fault):
    step, measured, fix = FAULTS[fault]
    r, lines = check(f"sim://?{fault}")
    assert r.returncode == 1, r.stdout + r.stderr
    line = lines[step]
    assert line.startswith(f"FAIL {step:<9} {measured}"), line
    assert line.endswith(fix), line
    if fault.startswith("counts_per_rev="):
        # the hand's quarter turn reads twice the counts the file expects (the hand itself within 8 deg, as above)
        counts, ratio = re.search(r"the turn read \+(\d+) counts \(.*\), ([\d.]+) x a quarter turn", line).groups()
        assert abs(int(counts) / (1958.4 / 4) - 1) < 8 / 90 and 1.8 <= float(ratio) <= 2.2, line
    assert "Traceback" not in r.stderr
    # the steps before the faulty one pass; the board is never armed for balance or swing-up
    for before in STEPS[:STEPS.index(step)]:
        assert lines[before].startswith("PASS"), (fault, lines[before])


def test_a_reversed_motor_with_a_reversed_encoder_is_told_apart():
    r, lines = check("sim://?encoder_sign=-1&motor_sign=-1")
    assert lines["encoder"].endswith(ENCODER_SIGN_FIX)
    assert lines["motor"].startswith("FAIL") and lines["motor"].endswith(MOTOR_SIGN_FIX)


def test_a_reversed_encoder_alone_leaves_the_motor_passing():
    r, lines = check("sim://?encoder_sign=-1")
    assert lines["motor"].startswith("PASS") and "the motor turns the right way" in lines["motor"]


def test_a_wrong_gear_ratio_shows_in_the_motor_gain_too():
    r, lines = check("sim://?counts_per_rev=2937.6")
    # the hand turns the rod's side of the gearbox; the encoder on the motor side reads the turn to within
    # the 1 deg of play, so three times the counts reads as 3.0 or 3.1 quarter turns (printed to 0.1)
    factor = float(lines["encoder"].split(" x a quarter turn")[0].rsplit(", ", 1)[1])
    assert factor in (3.0, 3.1), lines["encoder"]
    assert lines["motor"].startswith("FAIL") and "more motion than the model: check motor.torque_constant" \
        in lines["motor"]


def test_without_yes_an_input_that_ends_says_nobody_pressed_enter():
    """Piped in with nothing to read, it said "--yes asks nobody", though --yes was never given."""
    r, lines = check("sim://?hand=none", input="")
    assert lines["encoder"].endswith("Why: turning the rod needs a hand: nobody pressed Enter (the input ended): run "
                                     "the check from a terminal at the rod"), lines["encoder"]


def test_yes_skips_the_hand_and_then_cannot_tell_encoder_from_motor():
    r, lines = check("sim://?hand=none&motor_sign=-1", "--yes")
    assert lines["encoder"] == ("SKIP encoder   still at rest, hanging 0 counts from zero; the direction was not "
                                "checked. Why: turning the rod needs a hand: --yes asks nobody: run the check without "
                                "--yes at the rod and press Enter")
    assert lines["motor"].endswith("Fix: the encoder or the motor is reversed: the encoder step with a hand "
                                   "(without --yes) tells which")
    assert r.returncode == 1


def test_no_answer_at_the_prompt_skips_the_hand_step():
    r, lines = check("sim://?hand=none", input="")
    assert lines["encoder"].startswith("SKIP encoder")


def test_a_person_who_presses_enter_but_does_not_turn_fails_the_encoder():
    r, lines = check("sim://?hand=none", input="\n")
    assert "Turn the rod by hand about a quarter turn counter-clockwise (seen from the front)" in r.stdout + r.stderr
    assert lines["encoder"].startswith("FAIL encoder   still at rest, hanging 0 counts from zero; the count did "
                                       "not change while the rod turned")


@pytest.mark.parametrize("url, message", [
    ("sim://?encoder=broken", "rodctl: sim://: encoder=broken: choose one of ok, dead"),
    ("sim://?magnet=1", "rodctl: cannot open sim://?magnet=1: unknown sim:// option 'magnet'"),
    ("sim://?boot_angle_deg=400", "rodctl: sim://: boot_angle_deg must be within -180..180 [deg], got '400'"),
])
def test_a_bad_fault_option_is_one_line_and_exit_2(url, message):
    r = run_rodctl("check", "--port", url, "--yes", timeout=120)
    assert r.returncode == 2
    assert r.stderr.startswith(message) and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert r.stdout == ""


def test_json_into_a_missing_folder_is_refused_before_the_board_is_touched(tmp_path):
    r = run_rodctl("check", "--port", "sim://", "--json", str(tmp_path / "no" / "c.json"), timeout=60)
    assert r.returncode == 2 and "does not exist" in r.stderr and r.stdout == ""


def test_an_existing_json_is_kept_unless_forced_and_refused_before_the_board_is_touched(tmp_path):
    """A check's record (the rig's measured signs and gains) is never replaced silently."""
    out = tmp_path / "c.json"
    out.write_text("{}\n")
    r = run_rodctl("check", "--port", "sim://", "--json", str(out), timeout=60)
    assert r.returncode == 2 and r.stderr.strip() == f"rodctl: --json {out} exists; pass --force to overwrite"
    assert r.stdout == "" and out.read_text() == "{}\n"
    r, lines = check("sim://", "--json", str(out), "--force")
    assert r.returncode == 0 and "results" in json.loads(out.read_text())


def test_a_board_that_does_not_answer_exits_1_with_one_line():
    master, slave = pty.openpty()  # a port that exists, with nothing behind it
    try:
        r = run_rodctl("check", "--port", os.ttyname(slave), "--yes", timeout=120)
    finally:
        os.close(master)
        os.close(slave)
    assert r.returncode == 1
    assert len(r.stderr.strip().splitlines()) == 1 and "no rodlink frames within" in r.stderr, r.stderr


def test_ctrl_c_during_the_pulses_leaves_the_board_disarmed():
    with sim_device() as (dev, port):
        proc = start_rodctl("check", "--port", port, "--yes")
        seen = ""
        deadline = time.monotonic() + 120
        while "motor:" not in seen and time.monotonic() < deadline:
            line = proc.stderr.readline()
            if not line:
                break
            seen += line
        assert "motor:" in seen, seen
        # the virtual board reports its mode changes on stderr; its first IDENTIFY is the pulses
        board_said = BoardSaid(dev)
        assert until(lambda: "-> IDENTIFY" in board_said(), timeout=60), board_said()
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
        assert proc.returncode == 130
        assert err.strip().splitlines()[-1] == "rodctl: interrupted; the board is disarmed (nothing was written)"
        st = run_rodctl("status", "--port", port, "--json", timeout=60)
        status = json.loads(st.stdout)
        assert (status["mode"], status["reason"]) == ("DISARMED", "HOST")  # disarmed by the host, not a timeout
        # and it was the pulses the Ctrl-C stopped (a DISARM while disarmed also reads HOST)
        assert until(lambda: "IDENTIFY -> DISARMED" in board_said(), timeout=30), board_said()


def test_fix_stores_the_measured_signs_and_the_next_power_on_passes(tmp_path):
    """Both signs wrong: --fix --yes stores both (SAVE_RIG into the board's EEPROM, a file here); the board
    powered on again reads them, and the same miswired rig passes every step with no reflash."""
    url = f"sim://?encoder_sign=-1&motor_sign=-1&eeprom={tmp_path / 'eeprom.bin'}"
    r, lines = check(url, "--fix", "--yes", "--json", str(tmp_path / "c.json"))
    assert r.returncode == 1
    assert ("fix: stored encoder_sign=-1, motor_sign=-1 on the board (its HELLO: encoder_sign -1, motor_sign -1, "
            "stored)") in r.stdout
    assert json.loads((tmp_path / "c.json").read_text())["stored"] == {"encoder_sign": -1, "motor_sign": -1}
    again, lines = check(url)
    assert again.returncode == 0, again.stdout
    assert "signs encoder -1 motor -1, 979.2 counts/turn (stored on the board)" in lines["identity"]
    assert all(ln.startswith("PASS") for ln in lines.values())


def test_fix_stores_nothing_it_could_not_measure(tmp_path):
    r, lines = check(f"sim://?hand=none&motor_sign=-1&eeprom={tmp_path / 'e.bin'}", "--fix", "--yes")
    assert "fix: no sign was measured unambiguously (the encoder step needs a hand); the board's signs are " \
           "unchanged" in r.stdout
    assert not (tmp_path / "e.bin").exists()


def test_fix_without_an_answer_stores_nothing_and_says_how_to_store(tmp_path):
    """--fix asks before it writes the board's EEPROM; a closed input (a script, a pipe) is no yes."""
    r, lines = check(f"sim://?motor_sign=-1&eeprom={tmp_path / 'e.bin'}", "--fix", input="")
    assert r.returncode == 1 and lines["motor"].startswith("FAIL"), r.stdout
    assert r.stderr.rstrip().endswith("Store motor_sign=-1 on the board? [y/N] fix: not stored (no answer: the input "
                                      "is closed; --fix --yes stores without asking)"), r.stderr
    assert not (tmp_path / "e.bin").exists()


def test_unreadable_stored_settings_fall_back_to_the_compiled_defaults_and_say_so(tmp_path):
    bad = tmp_path / "eeprom.bin"
    bad.write_bytes(b"RG\x01\xff\x01\x00\x12\x34")  # a record with a wrong CRC
    r = run_rodctl("status", "--port", f"sim://?eeprom={bad}", timeout=60)
    assert ("wiring      encoder_sign +1, motor_sign +1, counts_per_rev 979.2 counts/turn (not stored on the "
            "board: the stored settings were unreadable)") in r.stdout


def test_another_encoder_is_set_and_kept_on_the_board_without_a_reflash(tmp_path):
    """An encoder with twice the counts: the check fails the hand's turn; `rodctl set counts_per_rev=1958.4 --save`
    stores the rig's own counts (SAVE_RIG, the board's EEPROM a file here), and the board powered on again reads
    the hand's quarter turn as a quarter turn and passes every step."""
    url = f"sim://?counts_per_rev=1958.4&eeprom={tmp_path / 'eeprom.bin'}"
    r = run_rodctl("set", "--port", url, "counts_per_rev=1958.4", "--save", timeout=60)
    assert r.returncode == 0, r.stderr
    assert "counts_per_rev = 1958.4 counts/turn\n" in r.stdout
    assert "stored on the board for every power-on: encoder_sign +1, motor_sign +1, counts_per_rev 1958.4 " \
           "counts/turn" in r.stdout
    again, lines = check(url, "--json", str(tmp_path / "c.json"))
    assert again.returncode == 0, again.stdout
    assert "979.2" not in lines["encoder"] and \
        "signs encoder +1 motor +1, 1958.4 counts/turn (the design's 979.2) (stored on the board)" in lines["identity"]
    values = {x["step"]: x["values"] for x in json.loads((tmp_path / "c.json").read_text())["results"]}
    assert abs(values["encoder"]["turn_peak_deg"] - 90) < 8  # +490 counts of 1958.4: a quarter turn
    assert 0.7 < values["motor"]["gain"] < 1.4


def test_counts_per_rev_is_refused_out_of_range_and_while_armed():
    from rodctl.link.session import Session
    from rodgains.errors import UserError

    r = run_rodctl("set", "--port", "sim://", "counts_per_rev=8", timeout=60)
    assert r.returncode == 2 and r.stderr.strip().endswith(
        "counts_per_rev=8 out of range: allowed 16 <= counts_per_rev <= 1e+06 counts/turn")
    with Session("sim://?theta0_deg=175") as s:
        s.arm(1)
        with pytest.raises(UserError, match="refused counts_per_rev=1958.4 in mode"):
            s.set("counts_per_rev", 1958.4)


def test_signs_change_only_while_disarmed_and_only_to_plus_or_minus_one():
    from rodctl.link.session import Session
    from rodgains.errors import UserError

    with Session("sim://?theta0_deg=175") as s:
        s.arm(1)  # balance: CATCH, then BALANCE
        with pytest.raises(UserError, match="refused encoder_sign=-1 in mode"):
            s.set("encoder_sign", -1.0)
        s.disarm()
        s.set("encoder_sign", -1.0)
        assert s.request_hello().rig & 1  # ENCODER_REVERSED
    r = run_rodctl("set", "--port", "sim://", "motor_sign=0", timeout=60)
    assert r.returncode == 2 and "motor_sign=0 out of range: allowed motor_sign = 1 or -1" in r.stderr


def test_a_check_whose_reader_leaves_early_is_not_a_pass():
    """`rodctl check | head -1`: the report was cut short, so the exit is SIGPIPE's 141 (under `set -o pipefail` the
    pipeline fails), with no second error at exit; before, it was 0, read as a passed check."""
    import subprocess

    from host_tools import RODCTL, rodctl_env

    p = subprocess.Popen([*RODCTL, "check", "--port", "sim://", "--yes"], stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True, env=rodctl_env())
    try:
        first = p.stdout.readline()
        p.stdout.close()  # the reader leaves, as head does
        err = p.stderr.read()
        p.wait(timeout=240)
    finally:
        if p.poll() is None:
            p.kill()
    assert first.startswith("PASS identity")
    assert p.returncode == 141 and "Traceback" not in err and "BrokenPipe" not in err and "Exception ignored" not in err
