"""Inputs a user can get wrong end in one line naming the problem, never "internal error"."""

from __future__ import annotations

import pytest

from host_tools import rodctl_env, run_rodctl


def _one_line(r) -> str:
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1, r.stderr
    return lines[0]


def test_binary_params_file_is_named(tmp_path):
    f = tmp_path / "rod.toml"
    f.write_bytes(b"\x00\xff\xfe\x89PNG\r\n")
    r = run_rodctl("gains", "--params", str(f), "--header", str(tmp_path / "h" / "rod_gains.h"))
    assert r.returncode == 2
    assert _one_line(r) == f"rodctl: {f}: not a parameter file (not UTF-8 text; expected TOML)"
    assert not (tmp_path / "h").exists()


def test_gains_json_into_a_missing_folder_writes_nothing(tmp_path):
    header = tmp_path / "rod_gains.h"
    missing = tmp_path / "missing"  # never made: absent on any machine, whoever runs the test
    r = run_rodctl("gains", "--json", str(missing / "d.json"), "--header", str(header))
    assert r.returncode == 2
    assert _one_line(r) == (f"rodctl: --json {missing / 'd.json'}: folder {missing} does not exist (a result named "
                            "alone is not given a folder of its own: make it first)")
    assert not header.exists()  # checked before anything was designed or written


def test_gains_json_onto_a_folder(tmp_path):
    r = run_rodctl("gains", "--json", str(tmp_path))
    assert r.returncode == 2
    assert _one_line(r) == f"rodctl: --json {tmp_path}: is a folder"


@pytest.mark.parametrize("value", ["1e42", "1e-40", "nan", "inf", "-3"])
def test_set_out_of_range_before_opening_the_port(value):
    """Checked before the port is opened: no board is needed to be told."""
    r = run_rodctl("set", f"catch_angle_deg={value}", "--port", "/dev/ttyNOPE0")
    assert r.returncode == 2
    line = _one_line(r)
    assert line.startswith("rodctl: catch_angle_deg")
    assert "2 <= catch_angle_deg" in line or "not a finite number" in line


def test_missing_params_file_of_a_sim_url_is_named():
    r = run_rodctl("status", "--port", "sim://?params=missing.toml")
    assert r.returncode == 2
    assert _one_line(r) == "rodctl: sim://: missing.toml: cannot read parameter file (No such file or directory)"


@pytest.mark.parametrize("url, says", [
    ("sim://?bogus=1", "unknown sim:// option 'bogus'"),
    ("sim://x", "sim:// takes options only after '?'"),
    ("sim://?edges=abc", "edges must be an integer, got 'abc'"),
    # edges is the plant's (as `rodctl sim --edges`), judged by the [plant] table's own range; 0 is not "unset"
    ("sim://?edges=0", "plant.edges: must be between 2 and 200 [-], got 0"),
    ("sim://?edges=201", "plant.edges: must be between 2 and 200 [-], got 201"),
    ("sim://?plant=foo", "unknown plant 'foo'"),
    ("sim://?plant=missing.toml", "missing.toml: cannot read parameter file"),
    ("sim://?set=rod.nope=1", "--set rod.nope: unknown key"),
])
def test_a_bad_sim_url_is_bad_input_not_a_board_fault(url, says):
    """The virtual board's URL is the user's own input: exit 2, as for a bad --params (a board that is not
    plugged in is exit 1)."""
    r = run_rodctl("status", "--port", url)
    assert r.returncode == 2, r.stderr
    line = _one_line(r)
    assert line.startswith("rodctl: ") and says in line


# inf or 1e300 s would be "until stopped" spelt as a number: that is leaving --duration out
@pytest.mark.parametrize("argv", [["log", "--duration", "0", "--port", "/dev/ttyNOPE0", "--out"],
                                  ["log", "--duration", "inf", "--port", "sim://", "--out"],
                                  ["arm", "--balance", "--duration", "nan", "--port", "/dev/ttyNOPE0", "--out"],
                                  ["arm", "--swing-up", "--duration", "1e300", "--port", "sim://", "--out"],
                                  ["sim-device", "--pty", "--duration", "-1", "--link"],
                                  ["sim-device", "--pty", "--duration", "inf", "--link"]])
def test_a_duration_not_in_a_week_is_refused_before_the_board_or_the_file(argv, tmp_path):
    out = tmp_path / "run.csv"  # the log, or the sim-device's link
    r = run_rodctl(*argv, str(out))
    assert r.returncode == 2, r.stderr
    assert _one_line(r).endswith(": must be in (0, 604800] s; leave it out to run until stopped")
    assert not out.exists()


@pytest.mark.parametrize("argv, what, folder", [
    (["sim", "--duration", "0.2", "--no-log", "--plot", "{blocked}/x.png"], "--plot", "{blocked}"),
    (["sim", "--duration", "0.2", "--no-plot", "--log", "{blocked}/x.csv"], "--log", "{blocked}"),
    (["gains", "--header", "{blocked}/rod_gains.h"], "--header", "{blocked}"),
    (["identify", "--port", "sim://", "--yes", "--experiment", "release", "--log-dir", "{blocked}/logs",
      "--out", "{tmp}/o.toml"], "--log-dir", "{blocked}/logs"),
])
def test_an_output_folder_with_a_file_in_the_way_is_one_line_before_any_work(argv, what, folder, tmp_path):
    """These outputs make their folder; a file where the folder should be is bad input (exit 2), said
    before the simulation, the design or the experiment (not an internal error after it)."""
    blocked = tmp_path / "a_file"
    blocked.write_text("not a folder\n")
    r = run_rodctl(*(a.format(blocked=blocked, tmp=tmp_path) for a in argv), timeout=120)
    assert r.returncode == 2, r.stderr
    line = _one_line(r)
    assert line.startswith(f"rodctl: {what} {blocked}/")
    assert line.endswith(f": cannot make folder {folder.format(blocked=blocked)}: a file is in the way")
    assert "simulated" not in r.stdout and "release:" not in r.stderr  # nothing ran
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file"]


def test_sim_compile_failure_is_one_clear_line(tmp_path):
    """The compiler's first `error:` line, not the "In file included from" chain before it."""
    cc = tmp_path / "cc"
    cc.write_text("#!/bin/sh\necho 'In file included from rod_control.c:1:' >&2\n"
                  "echo 'rod_config.h:97:1: error: static assertion failed' >&2\nexit 1\n")
    cc.chmod(0o755)
    env = rodctl_env(CC=str(cc), RODCTL_BUILD_DIR=str(tmp_path / "build"))
    r = run_rodctl("sim", "--duration", "0.2", "--no-plot", "--no-log", env=env)
    assert r.returncode != 0
    assert "Traceback" not in r.stderr and "internal error" not in r.stderr
    assert r.stderr.strip().splitlines()[-1] == ("rodctl: compiling rodsil failed: "
                                                 "rod_config.h:97:1: error: static assertion failed")


@pytest.mark.parametrize("override", ["rod.length=0.015", "rod.density=50", "rod.thickness=0.0004",
                                      "motor.gear_ratio=0.5"])
def test_a_value_just_outside_the_plausible_range_gets_no_made_up_reading(override):
    """0.015 m was answered "did you mean 1.5 m?", 50 kg/m^3 "5000", a ratio of 0.5 "500": no unit slip reads so."""
    from host_tools import run_rodctl

    r = run_rodctl("gains", "--check", "--set", override)
    assert r.returncode == 2 and "is not a testbed's" in r.stderr and "did you mean" not in r.stderr


@pytest.mark.parametrize("override, line", [
    ("rod.length=155", "rodctl: rod.length = 155 m is not a testbed's (plausible: 0.02 to 2 m): did you mean 0.155 m?"),
    ("rod.thickness=0.6",  # a 0.6 mm strip typed in mm: the commonest slip first, not the reading nearest the middle
     "rodctl: rod.thickness = 0.6 m is not a testbed's (plausible: 0.0005 to 0.1 m): did you mean 0.0006 m?"),
    ("rod.youngs_modulus=593",
     "rodctl: rod.youngs_modulus = 593 Pa is not a testbed's (plausible: 1000 to 2e+11 Pa): did you mean 593000 Pa?"),
    ("motor.gear_ratio=0.0204",
     "rodctl: motor.gear_ratio = 0.0204 is not a testbed's (plausible: 1 to 1000): did you mean 20.4?"),
])
def test_a_unit_slip_is_refused_with_the_reading_that_fits(override, line, tmp_path):
    from host_tools import run_rodctl

    r = run_rodctl("gains", "--set", override, "--header", str(tmp_path / "h.h"))
    assert r.returncode == 2 and r.stderr.strip() == line
    assert not (tmp_path / "h.h").exists()


def test_fewer_counts_per_turn_than_the_board_accepts_are_refused_before_a_header(tmp_path):
    """15 counts per output turn: the header would build a firmware whose angle arithmetic divides by a
    zero-count default (SET and a stored record refuse under 16)."""
    from host_tools import run_rodctl

    r = run_rodctl("gains", "--set", "encoder.counts_per_motor_rev=1", "--set", "motor.gear_ratio=15",
                   "--header", str(tmp_path / "h.h"))
    assert r.returncode == 2 and r.stderr.strip().startswith(
        "rodctl: encoder.counts_per_motor_rev: times motor.gear_ratio = 15 counts per output turn: the firmware "
        "needs at least 16"), r.stderr
    assert not (tmp_path / "h.h").exists()


# --- output paths: checked before any work, one line naming the option, exit 2, nothing written ----------

# {f}: a regular file, so {f}/x cannot be written by anyone (root included: root ignores permission bits,
# but not a file where a folder should be); {tmp}/nod: a folder that does not exist.
OUTPUT_CASES = [
    (["check", "--port", "sim://", "--yes", "--json", "{f}/c.json"], "--json"),
    (["identify", "--port", "sim://", "--yes", "--out", "{f}/a.toml"], "--out"),
    (["identify", "--port", "sim://", "--yes", "--out", "{tmp}/a.toml", "--plot", "{tmp}/a.xyz"], "--plot"),
    (["identify", "{tmp}/run.csv", "--out", "{tmp}/a.toml", "--plot", "{tmp}/nod/a.png"], "--plot"),
    (["robustness", "--samples", "0", "--cases", "quick", "--json", "{f}/r.json"], "--json"),
    (["robustness", "--samples", "0", "--cases", "quick", "--json", "", "--plot", "{tmp}/r.xyz"], "--plot"),
    (["sweep", "--grid", "rod.length=0.15", "--out", "{f}/a.parquet"], "--out"),
    (["sweep", "--grid", "rod.length=0.15", "--out", "{tmp}/a.parquet", "--plot", "{tmp}/a.xyz"], "--plot"),
    (["tune", "--budget", "1", "--out", "{f}/t.toml"], "--out"),
    (["tune", "--budget", "1", "--out", "{tmp}/t.toml", "--study", "{f}/study"], "--study"),
    (["bench", "--only", "m4", "--json", "{tmp}/nod/b.json"], "--json"),
    (["sim", "--scenario", "balance", "--no-log", "--plot", "{tmp}/x.xyz"], "--plot"),
    (["sim", "--scenario", "balance", "--no-log", "--plot", "{tmp}"], "--plot"),
    (["sim", "--scenario", "balance", "--no-plot", "--log", "{tmp}/x.xyz"], "--log"),
    (["plot", "{tmp}/run.csv", "--out", "{tmp}/a.xyz"], "--out"),
    (["plot", "{tmp}/run.csv", "--out", "{f}/a.png"], "--out"),
    (["sim-device", "--link", "{tmp}/nod/x"], "--link"),
    (["sim-device", "--link", "{f}"], "--link"),
    (["scope", "--port", "sim://", "--screenshot", "{tmp}/s.xyz"], "--screenshot"),
    (["scope", "--port", "sim://", "--screenshot", "{f}/s.png"], "--screenshot"),
    (["scope", "--port", "sim://", "--record", "{f}/r.csv"], "--record"),
    (["log", "--port", "sim://", "--duration", "1", "--out", "{f}/x.csv"], "--out"),
    (["log-convert", "{tmp}/run.csv", "--out", "{f}/x.parquet"], "--out"),
    (["gains", "--json", "{f}/d.json"], "--json"),
    (["sil-lib", "-o", "{f}/lib.so"], "--output"),
]


@pytest.mark.parametrize("argv, option", OUTPUT_CASES, ids=[" ".join(a[:1] + [o]) + f"-{i}" for i, (a, o) in
                                                             enumerate(OUTPUT_CASES)])
def test_an_output_that_cannot_be_written_is_refused_before_any_work(argv, option, tmp_path, capsys):
    """A missing or unwritable folder, a folder for a file, or a figure format matplotlib does not write:
    one line naming the option, exit 2, before any design, run, board or motor motion, nothing written."""
    from rodctl.cli import main

    f = tmp_path / "file.txt"
    f.write_text("a file, not a folder\n")
    code = main([a.format(f=f, tmp=tmp_path) for a in argv])
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"rodctl: {option} "), err
    assert "internal error" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file.txt"]


def test_sim_plot_onto_the_current_folder_is_a_folder_not_dot_png(tmp_path, monkeypatch, capsys):
    from rodctl.cli import main

    monkeypatch.chdir(tmp_path)
    assert main(["sim", "--scenario", "balance", "--no-log", "--plot", "."]) == 2
    assert capsys.readouterr().err.strip() == "rodctl: --plot .: is a folder"
    assert list(tmp_path.iterdir()) == []


def test_a_read_only_folder_is_found_by_writing_not_by_permission_bits(tmp_path, monkeypatch):
    """Root passes os.access on a read-only bind mount's folder only if the mount is not read-only; either
    way the helper makes (and removes) a file there, which is what fails on a read-only mount."""
    import errno
    import tempfile

    from rodgains.errors import InputError

    from rodctl.cli import outputs

    ok = tmp_path / "a.json"
    outputs.check_output(ok, "--json")
    assert list(tmp_path.iterdir()) == []  # the probe file is gone again

    def read_only(*a, **kw):
        raise OSError(errno.EROFS, "Read-only file system")

    monkeypatch.setattr(tempfile, "mkstemp", read_only)
    with pytest.raises(InputError) as e:
        outputs.check_output(ok, "--json")
    assert str(e.value) == f"--json {ok}: cannot write into folder {tmp_path} (Read-only file system)"


def test_an_existing_sim_device_link_file_is_bad_input(tmp_path):
    f = tmp_path / "port"
    f.write_text("not a link\n")
    r = run_rodctl("sim-device", "--link", str(f), "--duration", "1")
    assert r.returncode == 2
    assert _one_line(r) == f"rodctl: --link {f} exists and is not a symlink; name another path"
    assert f.read_text() == "not a link\n"


def test_an_earlier_sim_devices_link_is_replaced_whatever_it_points_at(tmp_path):
    """The link of a board that ended (or still runs) points into /dev/pts, where nobody may make files: the check
    looked there, not in the link's own folder, and said "cannot write into folder /dev/pts"."""
    link = tmp_path / "port"
    link.symlink_to("/dev/pts/999")
    r = run_rodctl("sim-device", "--link", str(link), "--duration", "1")
    assert r.returncode == 0, r.stderr
    assert f"connect with: rodctl status --port {link}" in r.stdout
    assert not link.is_symlink()  # replaced, then removed when the board stopped


@pytest.mark.parametrize("argv, option", [
    (["sweep", "--grid", "rod.length=0.15", "--out", "{tmp}/old.parquet"], "--out"),
    (["sweep", "--grid", "rod.length=0.15", "--out", "{tmp}/s.parquet", "--plot", "{tmp}/old.png"], "--plot"),
    (["robustness", "--cases", "quick", "--samples", "0", "--json", "{tmp}/old.json", "--plot", ""], "--json"),
    (["robustness", "--cases", "quick", "--samples", "0", "--json", "", "--plot", "{tmp}/old.png"], "--plot"),
])
def test_sweep_and_robustness_do_not_replace_a_file_without_force(argv, option, tmp_path, capsys):
    from rodctl.cli import main

    for name in ("old.parquet", "old.png", "old.json"):
        (tmp_path / name).write_text("keep me\n")
    assert main([a.format(tmp=tmp_path) for a in argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"rodctl: {option} ") and err.endswith("exists; pass --force to overwrite"), err
    assert all((tmp_path / n).read_text() == "keep me\n" for n in ("old.parquet", "old.png", "old.json"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.json", "old.parquet", "old.png"]


@pytest.mark.parametrize("argv, start", [
    (["robustness", "--seconds", "1e9", "--json", "", "--plot", ""],
     "rodctl: --seconds 1e+09: must be in [0.05, 600] s"),
    (["sweep", "--grid", "rod.length=0.15", "--seconds", "601", "--out", "{tmp}/s.parquet"], "rodctl: --seconds 601"),
    (["identify", "--port", "sim://", "--yes", "--settle", "-5", "--out", "{tmp}/a.toml"], "rodctl: --settle -5"),
    (["plot", "{tmp}/run.csv", "--snapshots", "-3", "--out", "{tmp}/a.png"], "rodctl: --snapshots -3"),
    (["bench", "--only", ""], "rodctl: --only ''"),
    (["bench", "--only", "m4,"], "rodctl: --only 'm4,'"),
    (["scope", "--port", "sim://", "--window", "-1"], "rodctl: --window -1"),
    (["scope", "--port", "sim://", "--window", "nan"], "rodctl: --window nan"),
    # a Monte Carlo count past uncertainty.samples' bound would build its runs until memory runs out
    (["robustness", "--samples", "100001", "--json", "", "--plot", ""],
     "rodctl: --samples 100001: must be between 0 and 100,000"),
    (["tune", "--samples", "100000000", "--budget", "1", "--out", "{tmp}/t.toml"], "rodctl: --samples 100000000"),
    (["sweep", "--scenario", "score", "--samples", "100001", "--grid", "rod.length=0.15", "--out", "{tmp}/s.parquet"],
     "rodctl: --samples 100001"),
    (["scope", "--port", "sim://", "--duration", "inf"], "rodctl: --duration inf: must be in (0, 604800] s"),
    (["scope", "--port", "sim://", "--set", "gearbox.backlash_deg=-1"], "rodctl: gearbox.backlash_deg: must be"),
    # a run shorter than a control period has no samples: an IndexError after the firmware was built
    (["sim", "--scenario", "balance", "--duration", "1e-9", "--no-plot", "--no-log"],
     "rodctl: --duration 1e-09: must be in [0.05, 600] s"),
    (["robustness", "--seconds", "0.001", "--json", "", "--plot", ""], "rodctl: --seconds 0.001: must be in [0.05"),
    (["sweep", "--grid", "rod.length=0.15", "--seconds", "1e-9", "--out", "{tmp}/s.parquet"],
     "rodctl: --seconds 1e-09: must be in [0.05"),
    (["tune", "--seconds", "0.01", "--budget", "1", "--out", "{tmp}/t.toml"], "rodctl: --seconds 0.01: must be in"),
])
def test_numbers_out_of_range_are_one_line_before_any_work(argv, start, tmp_path, capsys):
    from rodctl.cli import main

    assert main([a.format(tmp=tmp_path) for a in argv]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and err.startswith(start), err
    assert list(tmp_path.iterdir()) == []


def test_a_ctrl_c_while_the_modules_load_is_acted_on_after_they_have(monkeypatch, capsys, tmp_path):
    """Raised inside an import, a library's bare `except:` could swallow it and the command would go on to
    arm: while the parser's modules load it is only noted, then the command stops."""
    import os
    import signal

    import rodctl.cli as cli

    # what a shell gives rodctl: Python's own Ctrl-C handler (a pytest-xdist worker has another)
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    monkeypatch.chdir(tmp_path)  # were it to go on, its log lands here

    real = cli.build_parser

    def build_parser_with_a_ctrl_c():
        os.kill(os.getpid(), signal.SIGINT)  # noted, not raised here
        return real()

    monkeypatch.setattr(cli, "build_parser", build_parser_with_a_ctrl_c)
    assert cli.main(["log", "--port", "sim://", "--arm", "swing-up", "--duration", "1"]) == 130
    assert capsys.readouterr().err == "rodctl: interrupted\n"
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # main() leaves Python's own behind
    signal.signal(signal.SIGINT, previous)


def test_ctrl_c_anywhere_is_one_line_and_exit_130(monkeypatch, capsys):
    """Even while the command modules load (nothing can be armed before the link opens)."""
    import rodctl.cli as cli

    def interrupted_import():
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "build_parser", interrupted_import)
    assert cli.main(["log", "--port", "sim://"]) == 130
    assert capsys.readouterr().err == "rodctl: interrupted\n"


def test_a_ctrl_c_a_library_turned_into_another_error_is_still_an_interrupt(monkeypatch, capsys):
    """Measured: 2 of 40 Ctrl-Cs 0.3 s into `rodctl log --port sim://` cut scipy's import, which raised
    "ImportError: initialization failed", and the user read "internal error"."""
    import rodctl.cli as cli
    from rodctl.cli import record

    def cut_import(args, **kw):
        cli._SIGINTS[0] += 1  # what the SIGINT handler counts
        raise ImportError("initialization failed")

    monkeypatch.setattr(record, "stream", cut_import)
    monkeypatch.setattr(cli, "_SIGINTS", [0])
    assert cli.main(["log", "--port", "sim://", "--duration", "1"]) == 130
    assert capsys.readouterr().err == "rodctl: interrupted\n"


def test_sigterm_stops_a_device_command_as_ctrl_c_does_and_is_named(capsys):
    """A device command under stop_signals: SIGTERM (a service manager, `timeout`) unwinds it as Ctrl-C would,
    exit 130, and the line names the signal instead of a Ctrl-C nobody pressed."""
    import argparse
    import os
    import signal
    import time

    import rodctl.cli as cli
    from rodctl.cli.common import stop_signals

    cleaned = []

    def command(args):
        with stop_signals():
            try:
                os.kill(os.getpid(), signal.SIGTERM)
                time.sleep(5)
            finally:
                cleaned.append(True)  # where a command disarms and closes its log
        return 0

    before = signal.getsignal(signal.SIGTERM)
    assert cli._main(argparse.ArgumentParser(), argparse.Namespace(func=command)) == 130
    assert capsys.readouterr().err == "rodctl: stopped by SIGTERM\n" and cleaned == [True]
    assert signal.getsignal(signal.SIGTERM) is before


def test_an_early_ctrl_c_of_rodctl_log_is_one_line_exit_130_and_arms_nothing(tmp_path):
    """A Ctrl-C before the board answered: rodctl says so in one line, exits 130, arms nothing, writes no log."""
    import os
    import pty
    import signal
    import tty

    from host_tools import start_rodctl, until
    from rodctl.link import protocol as P

    # A port nobody answers on: the Ctrl-C goes once rodctl's first HELLO_REQUEST is on it, so it always lands
    # while rodctl waits for the board, which it does for 3 s (a sim:// board could answer first on one machine
    # and not on another).
    master, slave = pty.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    dec, sent = P.Decoder(), []

    def host_sent() -> list:
        try:
            sent.extend(f.type for f in dec.feed(os.read(master, 4096)))
        except BlockingIOError:
            pass
        return sent

    out = tmp_path / "early.csv"
    p = start_rodctl("log", "--port", os.ttyname(slave), "--arm", "swing-up", "--out", str(out))
    try:
        assert until(lambda: P.MsgType.HELLO_REQUEST in host_sent(), timeout=60), p.poll()
        p.send_signal(signal.SIGINT)
        _, err = p.communicate(timeout=60)
        host_sent()
    finally:
        if p.poll() is None:
            p.kill()
            p.communicate()
        os.close(master)
        os.close(slave)
    assert p.returncode == 130, err
    assert err.strip().splitlines() == ["rodctl: interrupted before the board answered; nothing was armed or written"]
    assert P.MsgType.ARM not in sent
    assert not out.exists()


@pytest.mark.parametrize("argv, says", [
    (("log", "--duration", "abc"), "rodctl log: argument --duration: invalid float value: 'abc'"),
    (("arm", "--port", "sim://"), "rodctl arm: one of the arguments --swing-up --balance is required"),
    (("track", "v.mp4", "--markers", "abc"), "rodctl track: argument --markers: invalid int value: 'abc'"),
])
def test_a_mistyped_option_is_one_line_pointing_at_help(argv, says):
    r = run_rodctl(*argv)
    assert r.returncode == 2
    assert _one_line(r) == f"{says}; see {says.split(':')[0]} --help"


def test_a_parameter_file_given_as_a_log_is_not_called_an_old_log(tmp_path):
    """A TOML file starts with a comment, as an old rodctl-log 1 CSV did: only a header with seq_count after the
    comments makes it one."""
    f = tmp_path / "full.toml"
    f.write_text("# a parameter file\n[rod]\nlength = 0.16\n")
    r = run_rodctl("plot", str(f), "--out", str(tmp_path / "x.png"))
    assert r.returncode == 2 and _one_line(r) == f"rodctl: {f}: not a rodctl log (CSV, Parquet or MCAP)"
    assert not (tmp_path / "x.png").exists()


@pytest.mark.parametrize("option", ["--header", "--json"])
def test_gains_with_an_empty_output_name_writes_nothing(option):
    """`--header "$OUT"` with OUT unset: refused, not taken for no --header (the committed header)."""
    from rodctl import paths

    before = {f: f.read_bytes() for f in (paths.COMMITTED_HEADER, paths.COMMITTED_HEADER.with_suffix(".toml"))}
    try:
        r = run_rodctl("gains", option, "")
        assert r.returncode == 2
        assert _one_line(r) == f"rodctl: {option}: empty file name"
    finally:
        changed = [f for f, b in before.items() if f.read_bytes() != b]
        for f in changed:
            f.write_bytes(before[f])
    assert not changed, f"{option} '' rewrote {changed}"


@pytest.mark.parametrize("text, says", [
    ("[rod]\nlenght = 0.14\n", "{f}: rod.lenght: unknown key (did you mean rod.length?)"),
    ("[rod]\nbacklash_deg = 1.5\n", "{f}: rod.backlash_deg: unknown key (it belongs in [gearbox])"),
    ("", "{f}: no parameters in it (`rodctl params --out FILE` writes a complete file to edit)"),
    ("# my rig\n", "{f}: no parameters in it (`rodctl params --out FILE` writes a complete "
                   "file to edit)"),
])
def test_a_parameter_file_that_is_empty_or_misspelled_is_named(tmp_path, text, says):
    """The file is named (a sim:// URL can carry two: params= and plant=) with the key it meant."""
    f = tmp_path / "my_rig.toml"
    f.write_text(text)
    r = run_rodctl("gains", "--params", str(f), "--report")
    assert r.returncode == 2
    assert _one_line(r) == "rodctl: " + says.format(f=f)
    r = run_rodctl("status", "--port", f"sim://?plant={f}")
    assert r.returncode == 2
    assert _one_line(r) == "rodctl: sim://: " + says.format(f=f)


def _a_log(tmp_path):
    log = tmp_path / "run.csv"
    r = run_rodctl("sim", "--scenario", "balance", "--duration", "0.2", "--no-plot", "--log", str(log))
    assert r.returncode == 0, r.stderr
    return log


@pytest.mark.parametrize("argv, kept, message", [
    # the user's own parameter file is never the header's parameter copy, --force or not
    (["gains", "--params", "{tmp}/mine.toml", "--header", "{tmp}/mine.h"], "mine.toml",
     "--header: would write {tmp}/mine.toml, which is an input of this command; choose another name"),
    (["gains", "--params", "{tmp}/mine.toml", "--header", "{tmp}/mine.h", "--force"], "mine.toml",
     "--header: would write {tmp}/mine.toml, which is an input of this command; choose another name"),
    (["gains", "--header", "{tmp}/other.h"], "other.toml",
     "--header {tmp}/other.toml exists and is not a file rodctl generated; pass --force to overwrite"),
    (["gains", "--json", "{tmp}/d.json"], "d.json", "--json {tmp}/d.json exists; pass --force"),
    (["sil-lib", "-o", "{tmp}/lib.so"], "lib.so", "--output {tmp}/lib.so exists; pass --force"),
    (["plot", "LOG", "--out", "{tmp}/p.png"], "p.png", "--out {tmp}/p.png exists; pass --force"),
])
def test_a_file_the_user_has_is_not_replaced(tmp_path, argv, kept, message):
    log = _a_log(tmp_path) if "LOG" in argv else None
    if kept == "mine.toml":
        r = run_rodctl("params", "--set", "rod.edges=6", "--out", str(tmp_path / "mine.toml"))
        assert r.returncode == 0, r.stderr
    else:
        (tmp_path / kept).write_text("mine\n")
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    argv = [str(log) if a == "LOG" else a.format(tmp=tmp_path) for a in argv]
    r = run_rodctl(*argv, timeout=300)
    assert r.returncode == 2 and message.format(tmp=tmp_path) in _one_line(r), r.stderr
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


def test_a_generated_header_is_regenerated_and_force_replaces_a_users_file(tmp_path):
    (tmp_path / "other.toml").write_text("mine\n")
    r = run_rodctl("gains", "--header", str(tmp_path / "other.h"), "--force", timeout=300)
    assert r.returncode == 0, r.stderr
    assert "DO NOT EDIT" in (tmp_path / "other.toml").read_text().splitlines()[0]
    first = {n: (tmp_path / n).read_bytes() for n in ("other.h", "other.toml")}
    r = run_rodctl("gains", "--header", str(tmp_path / "other.h"), timeout=300)  # the regenerate line, as it is
    assert r.returncode == 0, r.stderr
    assert r.stdout.startswith(f"wrote {tmp_path / 'other.h'}, {tmp_path / 'other.toml'}  (N=")
    assert {n: (tmp_path / n).read_bytes() for n in first} == first  # no timestamp: the same bytes again


@pytest.mark.parametrize("argv, line", [
    (["plot"], "rodctl: name a log to plot (rodctl plot run.csv), or --live --port PORT"),
    (["plot", "run.csv", "--live"], "rodctl: --live opens the scope of a board, not a log: drop run.csv or --live"),
    (["protocol", "--root", "{missing}"],
     "rodctl: --root {missing}: no protocol definition at {missing}/firmware/protocol/rodlink.toml"),
    (["sweep", "--grid", "rod.length=0.1:0.2:1e-9", "--out", "s.parquet"],
     "rodctl: --grid rod.length=0.1:0.2:1e-9: 100,000,001 points on one axis (at most 1,000,000); use a larger step"),
    # the JSON was dropped without a word (--check), or written over by the header's own file
    (["gains", "--check", "--json", "d.json"], "rodctl: --check writes nothing; drop --json, or write the design "
                                                "without --check"),
    (["gains", "--header", "j.h", "--json", "j.h", "--force"], "rodctl: --json j.h: --header j.h writes that file "
                                                                "too; name another"),
    (["gains", "--header", "j.h", "--json", "j.toml"], "rodctl: --json j.toml: --header j.h writes that file too; "
                                                        "name another"),
])
def test_more_bad_input_is_exit_2(tmp_path, argv, line):
    missing = str(tmp_path / "missing")  # never made (the folder is checked empty below): absent on any machine
    r = run_rodctl(*[a.replace("{missing}", missing) for a in argv], cwd=tmp_path)
    assert r.returncode == 2 and _one_line(r) == line.replace("{missing}", missing)
    assert list(tmp_path.iterdir()) == []


def test_a_study_folder_whose_journal_is_a_folder_is_refused_before_any_trial(tmp_path, capsys):
    from rodctl.cli import main

    study = tmp_path / "st"
    (study / "journal.log").mkdir(parents=True)
    assert main(["tune", "--cases", "nominal", "--samples", "0", "--budget", "1", "--study", str(study),
                 "--out", str(tmp_path / "t.toml")]) == 2
    assert capsys.readouterr().err == (f"rodctl: --study {study}: journal.log is not a file; use a new --study "
                                       "folder\n")
    assert sorted(p.name for p in study.iterdir()) == ["journal.log"] and not (tmp_path / "t.toml").exists()


def test_a_killed_tune_s_cut_journal_line_is_named_and_left_as_it_was(tmp_path, capsys):
    """A tune killed mid-write leaves its journal's last line cut short: resuming names the file and line,
    exit 2, and appends nothing to it (Optuna would have written first and then failed to read it)."""
    from rodctl.cli import main

    study = tmp_path / "st"
    argv = ["tune", "--cases", "nominal", "--samples", "0", "--seconds", "0.2", "--jobs", "1", "--budget", "1",
            "--no-goals", "--study", str(study), "--out", str(tmp_path / "t.toml")]
    assert main(argv) in (0, 1)
    (tmp_path / "t.toml").unlink()
    journal = study / "journal.log"
    whole = journal.read_bytes()
    cut = whole[:-7]  # the last record without its end
    journal.write_bytes(cut)
    capsys.readouterr()
    assert main(argv) == 2
    n = whole.count(b"\n")
    assert capsys.readouterr().err == (
        f"rodctl: --study {study}: journal.log line {n} is not a whole record (cut short when a run was killed?); "
        "delete that line to resume, or use a new --study folder\n")
    assert journal.read_bytes() == cut and not (tmp_path / "t.toml").exists()
    journal.write_bytes(whole)
    (study / "study.json").write_text('{"cases": ')
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"rodctl: --study {study}: study.json is not this command's JSON") and err.count("\n") == 1
    assert journal.read_bytes() == whole


def test_protocol_writes_neither_file_when_one_cannot_be_written(tmp_path, capsys):
    """A file where docs/ should be: one line, exit 2, and the C header is not written either."""
    import shutil

    from rodctl import paths
    from rodctl.cli import main

    (tmp_path / "firmware" / "protocol").mkdir(parents=True)
    shutil.copy(paths.SPEC, tmp_path / "firmware" / "protocol" / "rodlink.toml")
    (tmp_path / "docs").write_text("a file, not a folder\n")
    assert main(["protocol", "--root", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].endswith(f"{tmp_path / 'docs'} is a file, not a folder"), err
    assert not (tmp_path / "firmware" / "src").exists()


def test_sim_of_several_runs_writes_nothing_when_one_log_exists(tmp_path, capsys):
    """fig2 writes a log per run (LOG-<label>.csv), named once it has run: an existing one stops the command
    before the figure or any log is written."""
    from rodctl.cli import main

    argv = ["sim", "--scenario", "fig2", "--duration", "0.3", "--log", str(tmp_path / "f.csv"), "--plot",
            str(tmp_path / "f.png")]
    assert main([*argv[:-4], "--log", str(tmp_path / "probe" / "f.csv"), "--no-plot"]) in (0, 1)  # 1: 0.3 s is short
    runs = sorted(p.name for p in (tmp_path / "probe").iterdir() if p.suffix == ".csv" and ".truth" not in p.name
                  and ".events" not in p.name)
    assert len(runs) > 1, runs
    (tmp_path / runs[-1]).write_text("mine\n")
    capsys.readouterr()
    assert main(argv) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("rodctl")]
    assert len(err) == 1 and "--force" in err[0], err  # one line; above it only the run's own progress
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["probe", runs[-1]])
    assert (tmp_path / runs[-1]).read_text() == "mine\n"


def test_sil_lib_into_a_folder_keeps_a_library_already_there(tmp_path):
    lib = run_rodctl("sil-lib", "-o", f"{tmp_path}/")
    assert lib.returncode == 0, lib.stderr
    path = tmp_path / lib.stdout.strip().splitlines()[-1].rsplit("/", 1)[-1]
    path.write_bytes(b"mine")
    r = run_rodctl("sil-lib", "-o", f"{tmp_path}/")
    assert r.returncode == 2 and _one_line(r) == f"rodctl: --output {path} exists; pass --force to overwrite"
    assert path.read_bytes() == b"mine"
    assert run_rodctl("sil-lib", "-o", f"{tmp_path}/", "--force").returncode == 0 and path.read_bytes() != b"mine"


def test_a_folder_where_a_log_s_events_file_goes_is_a_warning_not_a_crash(tmp_path):
    """The telemetry is still converted; the events are named as unreadable (one warning line)."""
    import pandas as pd

    log = _a_log(tmp_path)
    events = log.with_name(log.name + ".events.csv")
    events.unlink()
    events.mkdir()
    r = run_rodctl("log-convert", str(log), "--out", str(tmp_path / "o.parquet"))
    assert r.returncode == 0, r.stderr
    assert r.stderr.strip().splitlines() == [f"rodctl: warning: {events}: not a file; reading the log without its "
                                             "events"]
    assert len(pd.read_parquet(tmp_path / "o.parquet")) == len(pd.read_csv(log))


def test_a_folder_beside_the_header_is_refused_before_the_header_is_written(tmp_path):
    """--force replaces a user's file beside the header, never a folder: that write would fail after the header
    was written (exit 2 with the header half of the pair on disk)."""
    (tmp_path / "rod_gains.toml").mkdir()
    r = run_rodctl("gains", "--header", str(tmp_path / "rod_gains.h"), "--force")
    assert r.returncode == 2
    assert _one_line(r) == f"rodctl: --header {tmp_path / 'rod_gains.toml'}: is a folder"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rod_gains.toml"]


def test_a_header_named_like_its_parameter_record_is_refused(tmp_path):
    """The record goes beside the header with .toml: --header x.toml --force would write the record over the
    header it was asked for."""
    mine = tmp_path / "mine.toml"
    mine.write_text("[rod]\n")
    r = run_rodctl("gains", "--header", str(mine), "--force")
    assert r.returncode == 2
    assert _one_line(r) == (f"rodctl: --header {mine}: the header's parameter record is written beside it as {mine}; "
                            "name the header *.h")
    assert mine.read_text() == "[rod]\n" and sorted(p.name for p in tmp_path.iterdir()) == ["mine.toml"]


def test_check_of_a_header_that_is_not_text_says_it_is_stale(tmp_path):
    png = tmp_path / "h.png"
    png.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)))
    r = run_rodctl("gains", "--header", str(png), "--check")
    assert r.returncode == 1 and "Traceback" not in r.stderr
    assert _one_line(r).startswith(f"rodctl gains --check: {png.with_suffix('.toml')} missing; {png} not what the "
                                   "parameters generate; regenerate with: ")


@pytest.mark.parametrize("extra, said", [(["--arm", "balance", "--duration", "3"], "--arm, --duration"),
                                         (["--window", "5"], "--window"), (["--port", "sim://"], "--port")])
def test_scope_options_on_a_logs_plot_are_refused_not_dropped(extra, said, tmp_path):
    """`plot LOG --arm balance --duration 3` drew the log and ignored them (exit 0): a user who meant --live got a
    figure of an old run."""
    log = tmp_path / "run.csv"
    log.write_text("not read\n")
    r = run_rodctl("plot", str(log), "--out", str(tmp_path / "x.png"), *extra)
    assert r.returncode == 2 and not (tmp_path / "x.png").exists()
    assert _one_line(r) == f"rodctl: {said}: only with --live (the scope of a board), not for a log's figure"


def test_a_bad_value_in_a_file_names_the_file_and_a_byte_order_mark_is_no_error(tmp_path):
    """A key error named the file, a value error did not ("rodctl: rod.density: must be > 0"); a date printed as
    Python's datetime.date(...); a file saved with a byte-order mark was "not valid TOML" at line 1."""
    from rodgains.params import DEFAULT_PARAMS

    text = DEFAULT_PARAMS.read_text()
    for name, changed, said in (("neg.toml", "density = -5.0", "neg.toml: rod.density: must be > 0 [kg/m^3], got -5.0"),
                                ("date.toml", "density = 1979-05-27",
                                 "date.toml: rod.density: expected a number [kg/m^3], got 1979-05-27")):
        (tmp_path / name).write_text(text.replace("density = 1080.0", changed, 1))
        r = run_rodctl("gains", "--check", "--params", name, cwd=tmp_path)
        assert r.returncode == 2 and _one_line(r) == f"rodctl: {said}"
    fixed = run_rodctl("gains", "--check", "--params", "neg.toml", "--set", "rod.density=-1", cwd=tmp_path)
    assert _one_line(fixed) == "rodctl: rod.density: must be > 0 [kg/m^3], got -1.0"  # the --set's, not the file's
    (tmp_path / "bom.toml").write_bytes(b"\xef\xbb\xbf" + text.encode())
    r = run_rodctl("gains", "--check", "--params", "bom.toml", cwd=tmp_path)
    assert r.returncode == 0 and r.stdout.startswith("up to date:"), r.stderr  # the defaults' header, spelled apart


# An empty name (an unset shell variable) is refused with the option's name, never taken for the default name,
# for stdout, for "no such output" or for the current folder.
EMPTY_NAME_CASES = [
    (["params", "--out", ""], "--out: empty file name"),
    (["log", "--port", "/dev/ttyNOPE0", "--duration", "1", "--out", ""], "--out: empty file name"),
    (["arm", "--balance", "--port", "/dev/ttyNOPE0", "--out", ""], "--out: empty file name"),
    (["log-convert", "{tmp}/run.csv", "--out", ""], "--out: empty file name"),
    (["sim", "--scenario", "balance", "--no-plot", "--log", ""], "--log: empty file name"),
    (["sim", "--scenario", "balance", "--no-log", "--plot", ""], "--plot: empty file name"),
    (["sil-lib", "-o", ""], "--output: empty file name"),
    (["sim-device", "--duration", "1", "--link", ""], "--link: empty file name"),
    (["check", "--port", "/dev/ttyNOPE0", "--json", ""], "--json: empty file name"),
    (["bench", "--only", "m4", "--json", ""], "--json: empty file name"),
    (["tune", "--budget", "1", "--out", "{tmp}/t.toml", "--study", ""], "--study: empty folder name"),
    (["identify", "{tmp}/run.csv", "--out", "{tmp}/a.toml", "--plot", ""], "--plot: empty file name"),
    (["track", "v.mp4", "--log", "run.csv", "--out", "{tmp}/t.parquet", "--plot", ""], "--plot: empty file name"),
    (["scope", "--port", "sim://", "--record", ""], "--record: empty file name"),
    (["protocol", "--root", ""], "--root: empty folder name"),
]


@pytest.mark.parametrize("argv, line", EMPTY_NAME_CASES, ids=[f"{a[0]}-{i}" for i, (a, _) in
                                                              enumerate(EMPTY_NAME_CASES)])
def test_an_empty_output_name_is_refused_and_nothing_is_written(argv, line, tmp_path, monkeypatch, capsys):
    from rodctl.cli import main

    monkeypatch.chdir(tmp_path)  # where a default name or "." would have put the files
    assert main([a.format(tmp=tmp_path) for a in argv]) == 2
    assert capsys.readouterr().err == f"rodctl: {line}\n"
    assert list(tmp_path.iterdir()) == []


def test_tune_only_empty_searches_nothing_and_is_refused(tmp_path, capsys):
    from rodctl.cli import main

    assert main(["tune", "--budget", "1", "--only", "", "--out", str(tmp_path / "t.toml")]) == 2
    assert capsys.readouterr().err.startswith("rodctl: --only : not a searched parameter; one or more of lqr.q_angle")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv, option", [
    (["robustness", "--cases", "nominal", "--samples", "0", "--json", "{tmp}/r.png", "--plot", "{tmp}/r.png"],
     "--plot {tmp}/r.png is also the --json"),
    (["identify", "{tmp}/run.csv", "--out", "{tmp}/a.png", "--plot", "{tmp}/a.png"], "--plot {tmp}/a.png is also "
                                                                                     "the --out"),
])
def test_two_outputs_of_one_name_are_refused_before_any_work(argv, option, tmp_path, capsys):
    """The figure would replace the JSON (or the parameter file) written just before it."""
    from rodctl.cli import main

    assert main([a.format(tmp=tmp_path) for a in argv]) == 2
    assert capsys.readouterr().err == (f"rodctl: {option.format(tmp=tmp_path)}: one would replace the other; "
                                       "name them apart\n")
    assert list(tmp_path.iterdir()) == []


def _edited_log(tmp_path, edit):
    """A copy of a simulated CSV log (and its sidecar) with `edit` applied to its lines."""
    src = _a_log(tmp_path / "src")
    bad = tmp_path / "bad.csv"
    bad.write_text("".join(edit(src.read_text().splitlines(keepends=True))))
    bad.with_name("bad.csv.json").write_text(src.with_name(src.name + ".json").read_text())
    return bad


def _no_theta_hat_1(lines):
    return [lines[0].replace("theta_hat_1_rad", "foo"), *lines[1:]]


def _an_infinite_time(lines):
    return [lines[0], lines[1], "1e400" + lines[2][lines[2].index(","):], *lines[3:]]


@pytest.mark.parametrize("edit, says", [
    (_no_theta_hat_1, "no column theta_hat_1_rad (of 7 theta_hat columns, one per edge)"),
    (_an_infinite_time, "time_s of telemetry row 2 is inf, not a time"),
])
@pytest.mark.parametrize("command", ["plot", "log-convert"])
def test_a_log_missing_a_column_or_with_a_non_finite_time_is_one_line_and_writes_nothing(command, edit, says,
                                                                                         tmp_path):
    """Was an internal error (plot), and a converted file or its .partial left behind (log-convert)."""
    bad = _edited_log(tmp_path, edit)
    before = sorted(p.name for p in tmp_path.iterdir())
    out = tmp_path / ("out.png" if command == "plot" else "out.mcap")
    r = run_rodctl(command, str(bad), "--out", str(out))
    assert r.returncode == 2 and _one_line(r) == f"rodctl: {bad}: {says}", r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    if command == "log-convert":  # every format the writer makes
        for name in ("out.parquet", "out.csv"):
            r = run_rodctl(command, str(bad), "--out", str(tmp_path / name))
            assert r.returncode == 2 and says in _one_line(r)
        assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_identify_on_a_log_without_a_column_it_fits_names_it(tmp_path):
    bad = _edited_log(tmp_path, lambda lines: [lines[0].replace("mode_code", "mode_kode"), *lines[1:]])
    r = run_rodctl("identify", str(bad), "--out", str(tmp_path / "a.toml"))
    assert r.returncode == 2 and _one_line(r).startswith(f"rodctl: {bad}: no column mode_code"), r.stderr
    assert not (tmp_path / "a.toml").exists() and not (tmp_path / "a.png").exists()


@pytest.mark.parametrize("where, says", [("{tmp}", "eeprom={tmp}: is a folder; name the EEPROM's file"),
                                         ("{tmp}/missing/e.bin", "eeprom={tmp}/missing/e.bin: folder {tmp}/missing "
                                                                 "does not exist")])
def test_a_sim_eeprom_that_cannot_be_a_file_is_bad_input_not_a_board_that_stopped(where, says, tmp_path):
    """It was found at the SAVE_RIG, as "device disconnected (virtual board stopped: IsADirectoryError)", exit 1."""
    r = run_rodctl("set", "--save", "encoder_sign=-1", "--port", "sim://?eeprom=" + where.format(tmp=tmp_path))
    assert r.returncode == 2, r.stderr
    assert _one_line(r) == "rodctl: sim://: " + says.format(tmp=tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_a_sim_eeprom_file_that_is_someone_elses_is_not_written_over(tmp_path):
    """`set --save` on sim://?eeprom=notes.txt would replace the notes with the board's 16-byte rig record."""
    notes = tmp_path / "notes.txt"
    notes.write_text("my measurements\n")
    r = run_rodctl("set", "--save", "encoder_sign=-1", "--port", f"sim://?eeprom={notes}")
    assert r.returncode == 2, r.stderr
    assert _one_line(r) == (f"rodctl: sim://: eeprom={notes}: not an EEPROM image (the board's rig record starts "
                            "with 'RG'); name a new file")
    assert notes.read_text() == "my measurements\n" and [p.name for p in tmp_path.iterdir()] == ["notes.txt"]


@pytest.mark.parametrize("hub", ["inf,1", "nan,nan"])
def test_track_hub_must_be_finite(hub, tmp_path):
    r = run_rodctl("track", "v.mp4", "--log", "run.csv", "--out", str(tmp_path / "t.parquet"), "--hub", hub)
    assert r.returncode == 2 and _one_line(r) == f"rodctl: --hub '{hub}': expected X,Y in pixels, finite numbers"
    assert list(tmp_path.iterdir()) == []


def test_track_of_a_file_that_is_no_video_is_its_one_line_without_a_progress_bar(tmp_path):
    log = _a_log(tmp_path)
    video = tmp_path / "clip.mp4"
    video.write_text("not a video\n")
    before = sorted(p.name for p in tmp_path.iterdir())
    r = run_rodctl("track", str(video), "--log", str(log), "--out", str(tmp_path / "t.parquet"))
    assert r.returncode == 2 and _one_line(r) == f"rodctl: video {video}: OpenCV cannot read it as a video"
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_a_pgf_figure_without_latex_is_refused_before_anything_is_written(tmp_path, monkeypatch, capsys):
    """matplotlib finds LaTeX missing only while drawing: a traceback-free 'internal error', exit 1, after
    `rodctl track` had written its logs (or robustness its JSON, identify its parameter file)."""
    import shutil

    import matplotlib

    from rodctl.cli import main

    tex = matplotlib.rcParams["pgf.texsystem"]
    which = shutil.which
    monkeypatch.setattr(shutil, "which", lambda name, *a, **kw: None if name == tex else which(name, *a, **kw))
    (tmp_path / "run.csv").write_text("")
    assert main(["plot", str(tmp_path / "run.csv"), "--out", str(tmp_path / "p.pgf")]) == 2
    assert capsys.readouterr().err == (f"rodctl: --out {tmp_path / 'p.pgf'}: a .pgf figure needs {tex} (LaTeX), "
                                       "which is not installed; use .pdf or .svg\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.csv"]


@pytest.mark.parametrize("override, line", [
    ("plant.hub_length=0",
     'rodctl: plant.hub_length: must be > 0 with plant.model = "der" (the rod\'s foot is clamped in a hub), got 0'),
    ("motor.rotor_inertia=0", "rodctl: motor.rotor_inertia: must be > 0 with a compliant gearbox or no hub (the motor "
     "side of the gear train needs its inertia), got 0"),
])
def test_a_value_the_faithful_plant_cannot_take_is_named_before_the_report(override, line):
    """The ranges allow 0 (the paper's model has no hub and no motor), the faithful plant does not: the report
    refuses before printing any of itself, and a simulation before compiling the firmware."""
    r = run_rodctl("gains", "--report", "--set", override)
    assert r.returncode == 2 and _one_line(r) == line and r.stdout == ""
    r = run_rodctl("sim", "--scenario", "balance", "--no-plot", "--no-log", "--set", override, timeout=300)
    assert r.returncode == 2 and _one_line(r) == line  # before the firmware is compiled


def test_the_report_judges_a_rig_at_the_edge_of_plausible_on_its_scaled_cases():
    """20000 kg/m^3 is plausible; the matrix's rho +15 % case of it, 23000, is past the guard against typed unit
    slips, and is judged, not refused ("did you mean 230 kg/m^3?")."""
    r = run_rodctl("gains", "--report", "--set", "rod.density=20000", timeout=300)
    assert r.returncode == 0, r.stderr
    assert "rho+15 " in r.stdout and "did you mean" not in r.stderr


def test_a_loop_too_slow_for_the_rate_filter_is_refused_naming_both_keys(tmp_path):
    """At 100 Hz the default 50 Hz tracking filter's sampled pole is 1 - 2 pi 50 / 100 = -2.1: the rate estimate
    blows up and the board trips SPEED_LIMIT 20 ms after arming. The ceiling is the pole at 0."""
    r = run_rodctl("gains", "--report", "--set", "loop.rate_hz=100")
    assert r.returncode == 2 and _one_line(r) == ("rodctl: encoder.rate_bandwidth_hz: must be at most loop.rate_hz / (2 pi) "
                                                  "= 15.9 [Hz], got 50.0: past it the sampled rate filter rings (with --set "
                                                  "loop.rate_hz=100)")
    out = tmp_path / "d.json"
    ok = run_rodctl("gains", "--json", str(out), "--set", "loop.rate_hz=100", "--set", "encoder.rate_bandwidth_hz=15")
    assert ok.returncode == 0 and out.stat().st_size > 0, ok.stderr


def test_a_run_that_faults_says_which_fault_and_when():
    """The pass rule reads "no FAULT; ..."; a FAIL line alone left the fault to the events file."""
    import numpy as np

    from rodctl.cli.sim import summary_lines
    from rodctl.sim.scenarios import MODE_BALANCE, MODE_FAULT, Outcome, Trace

    t = np.arange(0.0, 1.0, 1e-3)
    mode = np.where(t < 0.572, MODE_BALANCE, MODE_FAULT)
    tr = Trace("firmware", t, np.full((t.size, 3), np.pi), np.zeros(t.size), 0.01, mode=mode, reason=2)
    ok = Trace("held", t, np.full((t.size, 3), np.pi), np.zeros(t.size), 0.01, mode=np.full(t.size, MODE_BALANCE))
    m = {"settle_s": 0.0, "overshoot_deg": 0.0, "peak_torque_Nm": 0.0, "swingup_s": float("nan"),
         "est_rms_deg": float("nan"), "final_dev_deg": 0.0}
    lines = summary_lines(Outcome("balance", "Balance", [tr, ok], {"firmware": m, "held": m}, False, "no FAULT", None))
    assert lines[2] == "  firmware: FAULT ANGLE_LIMIT at 0.572 s" and not any("held: FAULT" in x for x in lines)


@pytest.mark.parametrize("override, line", [
    ("rod.length=NaN", "rodctl: rod.length: must be finite, got nan"),  # TOML spells it nan; a user may not
    ("rod.length=-Inf", "rodctl: rod.length: must be finite, got -inf"),
    ("rod.edges=true", "rodctl: rod.edges: expected an integer [-], got true"),  # the file's spelling, not Python's
    ("motor.gear_ratio=5", "rodctl: swing_up.amplitude: must be in [0.001, 0.04964] N m, the firmware's torque "
     "ceiling (set by driver.current_limit 1.7 A x the motor's torque at the output, motor.gear_ratio 5 x "
     "torque_constant 0.01123 x gearbox_efficiency 0.52), got 0.05 (with --set motor.gear_ratio=5)"),  # and the --set
])
def test_a_value_is_named_as_the_user_wrote_it(override, line):
    r = run_rodctl("gains", "--report", "--set", override)
    assert r.returncode == 2 and _one_line(r) == line


def test_a_missing_key_names_the_file(tmp_path):
    f = tmp_path / "rod.toml"
    text = run_rodctl("params").stdout
    f.write_text("\n".join(x for x in text.splitlines() if not x.startswith("gravity")) + "\n")
    r = run_rodctl("gains", "--params", str(f), "--check")
    assert r.returncode == 2 and _one_line(r) == f"rodctl: {f}: rod.gravity: missing key [m/s^2]"
