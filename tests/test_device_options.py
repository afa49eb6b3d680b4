"""One meaning for every option: --params/--set configure sim://, angles from upright, overrides in titles."""

from __future__ import annotations

import json

import pytest

from host_tools import run_rodctl
from rodgains.params import load_params

from rodctl.logs import read_log


def test_set_on_a_device_command_configures_the_virtual_board():
    r = run_rodctl("status", "--port", "sim://", "--set", "rod.length=0.14", "--json")
    assert r.returncode == 0, r.stderr
    st = json.loads(r.stdout)
    # the board's firmware was built for the overridden rod: its header hash is that design's
    assert st["header_sha256"] == load_params(None, ["rod.length=0.14"]).sha256()
    assert st["params_source"].endswith("--set rod.length=0.14 (sim://)") or "rod.length=0.14" in st["params_source"]


def test_status_json_gives_settings_as_set_with_their_units():
    """The settings were the board's f32 made double (swing_angle_deg 180.00000500895632) with no unit beside
    swing_amplitude or heartbeat_timeout."""
    st = json.loads(run_rodctl("status", "--port", "sim://", "--json").stdout)
    assert st["settings"]["swing_angle_deg"] == 180.0 and st["settings"]["catch_angle_deg"] == 32.0
    assert st["settings"]["swing_amplitude"] == 0.05 and st["torque_max_Nm"] == 0.2
    assert st["settings_units"] == {"swing_amplitude": "N m", "swing_angle_deg": "deg", "catch_angle_deg": "deg",
                                    "telemetry_decimation": "1", "heartbeat_timeout": "s", "encoder_sign": "1",
                                    "motor_sign": "1", "counts_per_rev": "counts/turn"}
    text = run_rodctl("status", "--port", "sim://").stdout
    assert "swing_angle_deg 180 deg, catch_angle_deg 32 deg," in text


def test_a_log_and_its_plot_carry_the_overrides(tmp_path):
    out = tmp_path / "short.csv"
    r = run_rodctl("log", "--port", "sim://?theta0_deg=180", "--set", "rod.length=0.14", "--duration", "0.5",
                   "--out", str(out))
    assert r.returncode == 0, r.stderr
    assert "deg from upright" in r.stderr  # the status line
    meta, data = read_log(out)
    assert meta["overrides"] == "rod.length=0.14" and json.loads(meta["params_json"])["rod"]["length"] == 0.14
    from rodctl.logs.plots import make_figure

    fig = make_figure(meta, data)
    assert "overrides: rod.length=0.14" in fig._suptitle.get_text()


def test_a_bad_set_for_sim_is_one_line_before_the_board_starts():
    r = run_rodctl("status", "--port", "sim://", "--set", "rod.length=-1")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.strip().startswith("rodctl: rod.length") and len(r.stderr.strip().splitlines()) == 1


def test_sim_device_takes_set_for_its_firmware_and_plant():
    from host_tools import sim_device

    with sim_device("--set", "rod.length=0.14", "--theta0-deg", "180") as (_, pts):
        r = run_rodctl("status", "--port", pts, "--set", "rod.length=0.14", "--json")
    assert r.returncode == 0, r.stderr
    st = json.loads(r.stdout)
    assert st["header_sha256"] == load_params(None, ["rod.length=0.14"]).sha256()
    assert st["params_source"] == "defaults with --set rod.length=0.14"
    assert abs(abs(st["theta_hat_rad"][0]) - 3.14159) < 0.05  # it powered on upright


@pytest.mark.parametrize("model", ["der", "inextensible"])
def test_sim_device_drives_the_plant_of_its_parameter_file(model):
    """As sim://?params=FILE does: `rodctl sim-device --params FILE` is no other rod than FILE's [plant]."""
    r = run_rodctl("sim-device", "--set", f"plant.model={model}", "--duration", "0.5", timeout=120)
    assert r.returncode == 0, r.stderr
    assert f", plant {model} with " in r.stdout.splitlines()[0], r.stdout


def test_a_board_that_cannot_keep_up_with_real_time_says_so(monkeypatch, capsys):
    """A plant too heavy for the machine (measured: 200 DER edges ran at 0.07 x real time here) is made to
    happen on any machine: each step takes 2 ms of a 1 ms period. The board warns once while it runs and
    says how much time it skipped when it stops."""
    import time

    from rodctl.cli import main
    from rodctl.sim.device import VirtualDevice

    step = VirtualDevice.step

    def slow_step(self):
        time.sleep(0.002)
        return step(self)

    monkeypatch.setattr(VirtualDevice, "step", slow_step)
    assert main(["sim-device", "--duration", "1"]) == 0
    err = capsys.readouterr().err.splitlines()
    warnings = [line for line in err if "cannot keep up with real time" in line]
    assert len(warnings) == 1 and "fewer edges or the inextensible plant keep up" in warnings[0], err
    assert "s skipped: it ran behind real time)" in err[-1], err
