"""rodctl robustness / tune / sweep: seeded draws, the score, grids, bad input, and the same rows from the
local pool, a Dask LocalCluster and a `dask scheduler` + `dask worker` pair, also when a worker dies."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from host_tools import ctrl_c_as_at_a_terminal, refusing_port, until

from rodgains.params import load_params

from rodctl.cli import main
from rodctl.robust import score as S
from rodctl.robust import sweep as W
from rodctl.robust.execute import Runner
from rodctl.robust.uncertainty import draws

SECONDS = 1.0  # simulated length of every run in these tests [s]: the verdicts do not matter, the rows do


def quick_units(samples=2):
    return S.units(load_params(), "quick", samples=samples, seed=7, seconds=SECONDS)


@pytest.fixture(scope="module")
def local_rows():
    from rodctl.build.sil_build import build_sil

    build_sil(load_params())  # compiled once here; every worker then finds it in the build cache
    with Runner(jobs=2, progress=False) as runner:
        return runner.run(quick_units())


# ---- draws and score -------------------------------------------------------------------------------

def test_draws_are_seeded_and_stay_inside_the_ranges():
    p = load_params()
    a, b, c = draws(p, 50, seed=3), draws(p, 50, seed=3), draws(p, 50, seed=4)
    assert a == b and a != c
    u = p["uncertainty"]
    for d in a:
        vals = dict(o.split("=") for o in d.overrides)
        E = float(vals["rod.youngs_modulus"]) / p["rod"]["youngs_modulus"]
        assert 1 - u["youngs_modulus_rel"] <= E <= 1 + u["youngs_modulus_rel"]
        damp = float(vals["rod.damping"]) / p["rod"]["damping"]
        assert 1 / u["rod_damping_factor"] <= damp <= u["rod_damping_factor"]
        assert 11.0 - 1e-9 <= float(vals["driver.supply_voltage"]) <= 13.0 + 1e-3
        assert vals["motor.torque_constant"] == vals["motor.back_emf_constant"]
        assert d.delay_periods in (0, 1)
    assert {d.delay_periods for d in a} == {0, 1}


def test_switching_one_range_off_leaves_the_other_draws_alone():
    p = load_params()
    off = p.with_overrides("uncertainty.density_rel=0.0")
    for d_on, d_off in zip(draws(p, 10, 1), draws(off, 10, 1)):
        on = dict(o.split("=") for o in d_on.overrides)
        of = dict(o.split("=") for o in d_off.overrides)
        assert "rod.density" in on and "rod.density" not in of
        assert on["rod.youngs_modulus"] == of["rod.youngs_modulus"]
        assert d_on.delay_periods == d_off.delay_periods


def test_score_is_the_pass_fraction_and_the_margin_only_breaks_ties():
    p = load_params()
    fast = {"passed": True, "settle_s": 0.5, "max_dev_deg": 30.0, "peak_torque_Nm": 0.1}
    slow = {"passed": True, "settle_s": 3.0, "max_dev_deg": 60.0, "peak_torque_Nm": 0.2}
    fell = {"passed": False, "settle_s": None, "max_dev_deg": 180.0, "peak_torque_Nm": 0.2}
    refused = {"passed": False, "refused": True}
    a, b = S.score([fast, fell], p), S.score([slow, fell], p)
    assert a.score == b.score == 0.5
    assert a.objective > b.objective
    # any 4/4 beats any 3/4, whatever the margins
    assert S.score([fast] * 3 + [fell], p).objective < S.score([slow] * 4, p).objective
    assert S.score([fell] * 4, p).score == 0.0 and S.score([slow] * 3 + [refused], p).score == 0.75
    assert 0.0 <= a.margin <= 1.0 and S.run_margin(refused, 0.2) == 0.0


def test_units_cover_every_case_of_the_set_for_both_tasks_and_the_draws():
    from rodctl.sim.matrix import CASE_SETS, cases_for

    units = quick_units(samples=3)
    cases = sum(len(cases_for(t, CASE_SETS["quick"])) for t in ("balance", "swingup"))
    assert len(units) == cases + 3 * 2
    assert len({u.key for u in units}) == len(units)
    assert S.unit_count(load_params(), "quick", samples=3) == len(units)  # what a sweep counts before it runs


# ---- the pool, Dask, and dying workers ------------------------------------------------------------

def test_local_pool_rows_are_complete_and_in_order(local_rows):
    units = quick_units()
    assert [(r["case"], r["task"]) for r in local_rows] == [(u.case.name, u.task) for u in units]
    for r in local_rows:
        assert isinstance(r["passed"], bool) and r["simulated_s"] == pytest.approx(SECONDS)
    json.dumps(local_rows, allow_nan=False)  # every run's metrics, strict JSON


def test_a_killed_pool_worker_loses_nothing(local_rows):
    with Runner(jobs=2, progress=False) as runner:
        killed = []

        def kill_once(_unit, _row):
            pids = runner.local_worker_pids()
            if not killed and pids:
                os.kill(pids[0], signal.SIGKILL)
                killed.append(pids[0])

        rows = runner.run(quick_units(), on_row=kill_once)
    assert killed
    assert rows == local_rows


def test_dask_local_cluster_gives_the_same_rows(local_rows):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                  dashboard_address=None) as cluster:
        with Runner(scheduler=cluster.scheduler_address, progress=False) as runner:
            assert runner.jobs == 2
            rows = runner.run(quick_units())
    assert rows == local_rows


def _scheduler_address(scheduler_file: Path, proc: subprocess.Popen, timeout: float = 120) -> str:
    """The address a `dask scheduler --scheduler-file` wrote once it listens (bounded generously: two noisy
    cores)."""
    def written() -> str | None:
        try:
            return json.loads(scheduler_file.read_text())["address"]
        except (OSError, ValueError, KeyError):  # not yet written, or half written
            return None

    until(lambda: written() is not None or proc.poll() is not None, timeout=timeout)
    assert proc.poll() is None, f"dask scheduler exited ({proc.returncode})"
    address = written()
    assert address is not None, "dask scheduler did not come up"
    return address


def _dask(*args, log: Path) -> subprocess.Popen:
    # the dask CLI of this interpreter's environment, not whatever is first on PATH
    code = "import sys; from dask.__main__ import main; sys.argv[0] = 'dask'; sys.exit(main())"
    return subprocess.Popen([sys.executable, "-c", code, *args], stdout=log.open("w"), stderr=subprocess.STDOUT,
                            start_new_session=True)


def test_dask_scheduler_and_workers_as_subprocesses_survive_a_killed_worker(local_rows, tmp_path):
    pytest.importorskip("distributed")
    from distributed import Client

    # port 0: the scheduler binds a free port itself and names it in the file, so no port chosen here can be
    # taken by another program before it binds
    scheduler_file = tmp_path / "scheduler.json"
    procs = [_dask("scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                   "--scheduler-file", str(scheduler_file), log=tmp_path / "scheduler.log")]
    try:
        address = _scheduler_address(scheduler_file, procs[0])
        for i in range(2):
            procs.append(_dask("worker", address, "--nthreads", "1", "--no-nanny", "--no-dashboard",
                               "--host", "127.0.0.1", "--name", f"w{i}", log=tmp_path / f"worker{i}.log"))
        deadline = time.monotonic() + 120
        while True:  # bounded generously: two noisy cores
            try:
                with Client(address, timeout=5) as c:
                    if len(c.scheduler_info()["workers"]) == 2:
                        break
            except OSError:
                pass
            assert time.monotonic() < deadline, "dask workers did not come up"
            time.sleep(0.5)
        with Runner(scheduler=address, progress=False) as runner:
            same = runner.run(quick_units())
            killed = []

            def kill_once(_unit, _row):
                if not killed:
                    procs[1].send_signal(signal.SIGKILL)
                    killed.append(procs[1].pid)

            after_kill = runner.run(quick_units(), on_row=kill_once)
        assert same == local_rows
        assert killed and procs[1].wait(timeout=30) == -signal.SIGKILL
        assert after_kill == local_rows
    finally:
        # workers before the scheduler: a worker whose scheduler is gone hangs on its way out
        for p in procs[::-1]:
            if p.poll() is None:
                p.terminate()
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(timeout=30)


# ---- grids -----------------------------------------------------------------------------------------

def test_grid_ranges_lists_and_frontier():
    a = W.parse_axis("rod.length=0.13:0.21:0.005")
    assert len(a.values) == 17 and a.values[0] == 0.13 and a.values[-1] == 0.21
    assert W.parse_axis("rod.edges=5,10,20").values == (5, 10, 20)
    assert W.parse_axis("plant.model=der,inextensible").values == ("der", "inextensible")
    assert W.size(W.parse_grid(["rod.length=0.13:0.21:0.005", "rod.edges=5,10,20"])) == 51
    rows = [{"x": x, "y": 1, "passed": x < 3} for x in range(5)] + [{"x": x, "y": 2, "passed": x != 1}
                                                                     for x in range(5)]
    assert W.frontier(rows, "x", "y") == {1: 2, 2: 0}


@pytest.mark.parametrize("spec, words", [
    ("rod.nope=1,2", "unknown parameter"),
    ("rod.length=0.2:0.1:0.01", "inverted range"),
    ("rod.length=", "empty"),
    ("rod.length=0.1:0.2:0", "step must be > 0"),
    ("rod.edges=1,5", "rod.edges"),
    ("rod.edges=2:8:0.5", "integer"),
])
def test_bad_grids_are_one_line_exit_2(spec, words, tmp_path, capsys):
    out = tmp_path / "s.parquet"
    assert main(["sweep", "--grid", spec, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("rodctl: ") and "\n" not in err and words in err
    assert not out.exists()


def test_a_huge_grid_asks_for_yes(tmp_path, capsys):
    out = tmp_path / "s.parquet"
    assert main(["sweep", "--grid", "rod.length=0.1:0.2:0.0001", "--grid", "lqr.q_angle=1:200:1",
                 "--out", str(out)]) == 2
    assert "--yes" in capsys.readouterr().err and not out.exists()
    # Monte Carlo plants count: 2 points x (the matrix + 100,000 draws) x 2 tasks, counted, not made
    assert main(["sweep", "--scenario", "score", "--samples", "100000", "--grid", "rod.length=0.15,0.16",
                 "--out", str(out)]) == 2
    assert "the grid is 400,156 runs" in capsys.readouterr().err and not out.exists()


@pytest.mark.parametrize("argv", [
    ["robustness", "--cases", "nope"],
    ["tune", "--cases", "nope", "--out", "x.toml"],
    ["sweep", "--grid", "rod.edges=5", "--cases", "nope", "--scenario", "score", "--out", "x.parquet"],
])
def test_unknown_case_set_is_one_line_exit_2(argv, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("rodctl: --cases nope: unknown case set") and "\n" not in err
    assert list(tmp_path.iterdir()) == []


def test_unreachable_scheduler_is_one_line_exit_2(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    with refusing_port() as port:
        assert main(["robustness", "--cases", "nominal", "--samples", "0", "--scheduler", f"127.0.0.1:{port}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"rodctl: --scheduler tcp://127.0.0.1:{port}: cannot reach the Dask scheduler (Connection refused)"]
    assert not (tmp_path / "robustness.json").exists()


def test_draws_and_units_perturb_the_plant_given_not_the_design():
    p = load_params()
    hidden = p.with_overrides("rod.youngs_modulus=7.0e5")

    def E(d):
        return float(dict(o.split("=") for o in d.overrides)["rod.youngs_modulus"])

    for own, other in zip(draws(p, 5, seed=3), draws(p, 5, seed=3, plant=hidden)):
        assert E(other) / E(own) == pytest.approx(7.0e5 / p["rod"]["youngs_modulus"])
    units = S.units(p, "quick", samples=1, plant=hidden)
    assert {u.plant_json for u in units} == {hidden.canonical_json()}
    assert {u.params_json for u in units} == {p.canonical_json()}


@pytest.mark.parametrize("text, words", [
    (None, "cannot read parameter file"),
    ("x = [", "not valid TOML"),
])
def test_a_bad_plant_file_is_one_line_exit_2(text, words, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    bad = tmp_path / "hidden.toml"
    if text is not None:
        bad.write_text(text)
    assert main(["robustness", "--cases", "nominal", "--samples", "0", "--plant", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"rodctl: --plant: {bad}: {words}") and "\n" not in err
    assert not (tmp_path / "robustness.json").exists()


# ---- the commands end to end (short runs) -------------------------------------------------------------

def test_robustness_writes_json_and_heatmap(tmp_path, capsys):
    js, png = tmp_path / "r.json", tmp_path / "r.png"
    assert main(["robustness", "--cases", "quick", "--samples", "1", "--seconds", str(SECONDS), "--jobs", "2",
                 "--json", str(js), "--plot", str(png)]) == 0
    doc = json.loads(js.read_text())
    cap = capsys.readouterr()
    out = cap.out
    assert f"score {doc['score']['score']:.4f}" in out
    assert doc["score"]["runs"] == len(doc["runs"]) == len(quick_units(samples=1))
    # stderr is no terminal here (a log file, CI): the progress comes as whole lines, the last one complete
    assert "\r" not in cap.err and ", 2 of them on Monte Carlo plants)" in cap.err, cap.err
    assert any(line.startswith("robustness: 100%") for line in cap.err.splitlines()), cap.err
    assert doc["parameters"]["uncertainty"]["samples"] == load_params()["uncertainty"]["samples"]
    draw_rows = [r for r in doc["runs"] if r["kind"] == "draw"]
    assert draw_rows and all(r["plant_overrides"] for r in draw_rows)
    assert png.stat().st_size > 10_000


def test_sweep_refused_design_is_a_row_and_parquet_has_one_row_per_run(tmp_path, capsys):
    pq = pytest.importorskip("pyarrow.parquet")
    out = tmp_path / "s.parquet"
    # design.method = continuous on the paper's model is refused by the generator (docs/scenarios.md)
    assert main(["sweep", "--grid", "design.method=sampled,continuous", "--set", "motor.design_includes_motor=false",
                 "--seconds", str(SECONDS), "--jobs", "2", "--out", str(out)]) == 0
    rows = pq.read_table(out).to_pylist()
    assert [r["design.method"] for r in rows] == ["sampled", "continuous"]
    assert rows[1]["refused"] and rows[1]["reason"].count("design refused") == 1 and not rows[0]["refused"]
    # every run column, typed, whatever the runs did: two sweeps' files read together (pl.read_parquet([a, b]));
    # a balance sweep's caught_at_s was a `null` column, and a sweep of refused points had no metric columns
    from rodctl.robust.output import RUN_COLUMN_TYPES

    schema = pq.read_schema(out)
    assert {k: str(schema.field(k).type) for k in RUN_COLUMN_TYPES} == {
        k: {"float64": "double"}.get(t, t) for k, t in RUN_COLUMN_TYPES.items()}
    # a sweep of refused points only, read with this one as one table
    polars = pytest.importorskip("polars")
    refused = tmp_path / "r.parquet"
    assert main(["sweep", "--grid", "design.method=continuous", "--set", "motor.design_includes_motor=false",
                 "--seconds", str(SECONDS), "--jobs", "1", "--out", str(refused), "--plot", ""]) == 0
    both = polars.read_parquet([out, refused])
    assert both.height == 3 and both["refused"].to_list() == [False, True, True]
    assert out.with_suffix(".png").exists()
    assert "1 refused" in capsys.readouterr().out


def test_tune_tiny_budget_writes_a_complete_file_and_resumes(tmp_path, capsys):
    study, out = tmp_path / "study", tmp_path / "tuned.toml"
    argv = ["tune", "--cases", "nominal", "--samples", "1", "--seconds", str(SECONDS), "--only",
            "lqr.q_angle,swing_up.amplitude", "--jobs", "2", "--study", str(study), "--out", str(out),
            "--no-goals"]  # runs this short meet no goal: every trial scored, not NOT TUNED (exit 1)
    assert main(argv + ["--budget", "2"]) == 0
    text = out.read_text()
    assert "# Reproduce: rodctl tune" in text and "lqr.q_angle in [0.1, 1000] (log)" in text
    tuned = load_params(out)  # a complete parameter file
    start = load_params()
    assert tuned["rod"] == start["rod"] and tuned["observer"] == start["observer"]
    capsys.readouterr()
    assert main(argv + ["--budget", "3", "--force"]) == 0  # resumes: one more trial, not three
    assert "(3 trials" in capsys.readouterr().out
    trials = json.loads((study / "trials.json").read_text())
    assert [t["number"] for t in trials] == [0, 1, 2] and all("score" in t for t in trials)
    # the resumed sampler draws anew: seeded as a new study, its first draw was trial #1's again (budget wasted)
    assert trials[2]["values"] != trials[1]["values"]
    # the study pins its inputs
    assert main(argv[:4] + ["2"] + argv[5:] + ["--budget", "3", "--force"]) == 2


def test_a_start_cut_short_by_ctrl_c_is_tried_again_on_resume(tmp_path, capsys, monkeypatch):
    """Ctrl-C in trial #0 (the parameter file itself) marked it failed; resumed, it was never run again, and the
    file said "Starting point ... trial #1: not scored" of a random trial. The start is what a tune must not fall
    below, so it runs again and is named as the start."""
    from rodctl.robust import tune as T

    study, out = tmp_path / "study", tmp_path / "tuned.toml"
    argv = ["tune", "--cases", "nominal", "--samples", "0", "--seconds", str(SECONDS), "--only", "lqr.q_angle",
            "--no-goals", "--jobs", "1", "--study", str(study), "--out", str(out), "--budget", "2"]
    real = T.evaluate

    def interrupted(*a, **kw):
        raise KeyboardInterrupt
    monkeypatch.setattr(T, "evaluate", interrupted)
    assert main(argv) == 130
    monkeypatch.setattr(T, "evaluate", real)
    capsys.readouterr()
    assert main(argv) == 0
    trials = json.loads((study / "trials.json").read_text())
    start = load_params()["lqr"]["q_angle"]
    assert trials[0]["state"] == "FAIL" and trials[1]["state"] == "COMPLETE"
    assert trials[1]["values"] == {"lqr.q_angle": start}  # the start, run again first
    assert "# Starting point: " in out.read_text() and "trial #1: score" in out.read_text()


def test_tune_refuses_a_starting_design_it_cannot_make(tmp_path, capsys):
    """It said "no trial met the nominal goals ... use --no-goals" (exit 0) and wrote the refused design to --out,
    which robustness then refused (exit 3)."""
    out = tmp_path / "t.toml"
    assert main(["tune", "--set", "rod.edges=20", "--set", "observer.process_noise_torque=0.53", "--cases", "quick",
                 "--samples", "0", "--budget", "2", "--jobs", "1", "--out", str(out)]) == 3
    err = capsys.readouterr().err
    assert err.startswith("rodctl: the starting design is refused (discrete Riccati equation failed") and \
        "gains --report" in err
    assert not out.exists()


def test_tune_says_plainly_when_no_trial_met_the_nominal_goals(tmp_path, capsys):
    """0.5 s runs cannot settle by 1.5 s: every trial misses the goals, so none is scored. The file holds
    the starting values and says so; the output says so too, with --no-goals as the way to score. Exit 1: a
    script that tunes and then flashes must not take the starting values for a tuned design (it exited 0)."""
    out = tmp_path / "t.toml"
    assert main(["tune", "--cases", "nominal", "--samples", "0", "--seconds", "0.5", "--only", "lqr.q_angle",
                 "--budget", "2", "--jobs", "1", "--out", str(out)]) == 1
    text = capsys.readouterr().out
    assert "no trial met the nominal goals in 2 trials" in text and "none was scored" in text, text
    assert "--no-goals" in text and "starting values unchanged" in text
    assert "score 0.0000 (0/0)" not in text
    written = out.read_text()
    assert "# NOT TUNED: no trial met the nominal goals" in written and "(0/0 runs pass" not in written
    assert load_params(out).values == load_params().values


def test_the_first_trial_is_the_parameter_file_itself_in_every_searched_dimension():
    from rodctl.robust.tune import space, starting_point

    p = load_params()
    dims = space()
    start = starting_point(p, dims)
    # a default outside a searched range would make trial 0 a random design, not the file
    assert {d.name for d in dims} == set(start)
    for d in dims:
        sec, key = d.name.split(".")
        assert start[d.name] == p[sec][key]
    assert {"observer.process_noise_torque", "swing_up.energy_target", "swing_up.rate_filter_hz"} <= set(start)
    amp = next(d for d in dims if d.name == "swing_up.amplitude")
    tight = p.with_overrides("driver.current_limit=0.5", "swing_up.amplitude=0.02")
    assert amp.bounds(tight)[1] == pytest.approx(tight.torque_max)  # the driver's ceiling, not only safety's


def _finished_trials(study: Path) -> int:
    import optuna
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    if not (study / "journal.log").exists():
        return 0
    s = optuna.load_study(study_name="rodctl-tune", storage=JournalStorage(JournalFileBackend(str(study / "journal.log"))))
    return sum(1 for t in s.trials if t.state.name == "COMPLETE")


def test_sigterm_stops_a_robustness_run_as_ctrl_c_does(tmp_path):
    """docs/host.md: SIGTERM cuts short work that has an end with 130, as Ctrl-C does. robustness (and sim, bench)
    died of the signal (143) and left the pool's semaphores behind."""
    from host_tools import start_rodctl

    p = start_rodctl("robustness", "--samples", "0", "--jobs", "1", "--json", "", "--plot", "", cwd=tmp_path)
    try:
        line = ""
        while "robustness:" not in line:  # the runs have started
            line = p.stderr.readline()
            assert line, "robustness ended before its runs started"
        p.send_signal(signal.SIGTERM)
        _, err = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 130 and err.strip().splitlines()[-1] == "rodctl: stopped by SIGTERM", err
    assert "leaked semaphore" not in err and "Traceback" not in err


def test_ctrl_c_keeps_finished_trials_and_the_study_resumes(tmp_path):
    study, out = tmp_path / "study", tmp_path / "tuned.toml"
    argv = [sys.executable, "-m", "rodctl.cli", "tune", "--cases", "nominal", "--samples", "0", "--seconds", "0.5",
            "--only", "lqr.q_angle", "--jobs", "1", "--study", str(study), "--out", str(out), "--no-goals"]
    # PYTHONFAULTHANDLER: if it hangs after Ctrl-C, SIGABRT makes it print where every thread is
    p = subprocess.Popen(argv + ["--budget", "1000"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         start_new_session=True, env={**os.environ, "PYTHONFAULTHANDLER": "1"},
                         preexec_fn=ctrl_c_as_at_a_terminal)
    try:
        deadline = time.monotonic() + 180
        while _finished_trials(study) < 2:
            assert p.poll() is None and time.monotonic() < deadline
            time.sleep(0.5)
        os.killpg(p.pid, signal.SIGINT)  # what Ctrl-C sends: the whole process group
        try:
            _, err = p.communicate(timeout=120)
        except subprocess.TimeoutExpired:
            os.kill(p.pid, signal.SIGABRT)
            _, err = p.communicate(timeout=60)
            pytest.fail("rodctl tune still ran 120 s after Ctrl-C; its threads then:\n" + err[-6000:])
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
    assert p.returncode == 130 and "every finished trial is kept" in err
    assert not out.exists()
    kept = _finished_trials(study)
    assert kept >= 2
    r = subprocess.run(argv + ["--budget", str(kept + 1)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert f"({kept + 1} trials" in r.stdout


@pytest.mark.parametrize("argv, words", [
    (["robustness", "--json", "{tmp}/missing/r.json"], "does not exist"),
    (["robustness", "--plot", "{tmp}"], "is a folder"),
    (["sweep", "--grid", "rod.edges=5", "--out", "{tmp}/missing/s.parquet"], "does not exist"),
    (["tune", "--out", "{tmp}/missing/t.toml"], "does not exist"),
    (["robustness", "--jobs", "0"], "--jobs 0"),
    (["tune", "--budget", "0", "--out", "{tmp}/t.toml"], "--budget 0"),
])
def test_bad_outputs_and_counts_fail_before_any_run(argv, words, tmp_path, capsys):
    assert main([a.replace("{tmp}", str(tmp_path)) for a in argv]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("rodctl: ") and "\n" not in err and words in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("command", [["robustness"], ["sweep", "--grid", "rod.edges=5", "--out", "{tmp}/s.parquet"],
                                     ["tune", "--out", "{tmp}/t.toml"]])
def test_more_local_workers_than_four_a_core_are_refused(command, monkeypatch, tmp_path, capsys):
    """--jobs 100000 would start a Python process per queued run on a 2-core machine."""
    from rodctl.robust import execute

    monkeypatch.setattr(execute, "default_jobs", lambda: 2)
    assert main([a.replace("{tmp}", str(tmp_path)) for a in command] + ["--jobs", "9"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "rodctl: --jobs 9: at most 8 local worker processes on these 2 cores; --scheduler ADDRESS runs on a Dask cluster"
    assert list(tmp_path.iterdir()) == []


def test_plant_option_judges_the_design_on_another_rod(tmp_path, capsys):
    """--plant FILE: the design stays the default's, the rod (physics and [plant] table) is FILE's."""
    far = tmp_path / "far.toml"  # a rotor 5x heavier on a 10-edge N-link rod: the default design drops it
    far.write_text(load_params().with_overrides("motor.rotor_inertia=2.5e-6", 'plant.model="inextensible"',
                                                "plant.edges=10").to_toml())
    runs, docs = {}, {}
    for tag, extra in (("own", []), ("far", ["--plant", str(far)])):
        js = tmp_path / f"{tag}.json"
        assert main(["robustness", "--cases", "nominal", "--samples", "0", "--seconds", "8", "--jobs", "1",
                     "--json", str(js), "--plot", "", *extra]) == 0
        docs[tag] = json.loads(js.read_text())
        runs[tag] = {r["task"]: r for r in docs[tag]["runs"]}
    for task in ("balance", "swingup"):
        own, other = runs["own"][task], runs["far"][task]
        assert own["fault_reason"] == 0 and own["final_dev_deg"] < 5, own  # 8 s on the rig with play
        assert not other["passed"] and other["fault_reason"] != 0, other
        assert own["plant"].startswith("der, 30 edges") and other["plant"].startswith("inextensible, 10 edges")
    assert docs["far"]["plant_source"] == str(far) and docs["own"]["plant_source"] is None
    assert docs["far"]["parameters"]["motor"]["rotor_inertia"] == load_params()["motor"]["rotor_inertia"]
    assert docs["far"]["plant_parameters"]["motor"]["rotor_inertia"] == 2.5e-6


class _ScriptedRunner:
    """Rows without simulations: every run passes except, when `slow`, the nominal (strict) ones."""

    def __init__(self, slow: bool):
        self.slow, self.ran, self.gearbox = slow, [], []

    def run(self, units, on_row=None, show=None):
        rows = []
        for u in units:
            strict = u.case.strict
            ok = not (self.slow and strict)
            rows.append({"case": u.case.name, "task": u.task, "passed": ok, "settle_s": 3.0 if not ok else 0.5,
                         "max_dev_deg": 30.0, "peak_torque_Nm": 0.2})
            self.ran.append((u.case.name, u.task))
            self.gearbox.append(json.loads(u.params_json)["gearbox"]["model"])
        return rows


def test_tune_goals_cut_a_slow_candidate_short_and_never_pick_it():
    """`rodctl tune` keeps the nominal goals: a design that misses them runs only its two nominal runs,
    scores nothing, and a feasible trial with a lower score still wins."""
    import optuna

    from rodctl.robust import tune as T

    p = load_params()

    def make(q):
        return S.units(q, "quick", samples=1, seed=7, seconds=SECONDS)

    slow = _ScriptedRunner(slow=True)
    r = T.evaluate(p, slow, make, goals=True)
    assert sorted(slow.ran) == [("nominal", "balance"), ("nominal", "swingup")]  # cut after the gate
    assert slow.gearbox == ["rigid", "rigid"]  # the goals judged with an ideal gearbox: the play's lean is not the gains
    # 1 per missed run + how far past its goal, in goal units: (1 + 1.5 s / 1.5 s) + (1 + 1 s / 2 s)
    assert r["objective"] == 0.0 and r["violation"] == pytest.approx(3.5)
    assert r["missed_goals"] == ["nominal/balance", "nominal/swingup"]
    fast = _ScriptedRunner(slow=False)
    r = T.evaluate(p, fast, make, goals=True)
    assert len(fast.ran) == len(make(p)) + 2 and r["violation"] == 0.0 and r["score"] == 1.0  # the gate's not scored
    no_goals = _ScriptedRunner(slow=True)
    r = T.evaluate(p, no_goals, make, goals=False)  # --no-goals: every run, the slow ones count as fails
    assert len(no_goals.ran) == len(make(p)) and r["passed"] == len(make(p)) - 2

    study = optuna.create_study(direction="maximize")
    dist = {"x": optuna.distributions.FloatDistribution(0, 1)}
    for n, (value, violation) in enumerate([(0.7, 0.0), (0.95, 2.5), (0.8, 0.0)]):
        study.add_trial(optuna.trial.create_trial(params={"x": n / 3}, distributions=dist, value=value,
                                                  user_attrs={"violation": violation}))
    assert T.best_feasible(study).value == 0.8  # not the infeasible 0.95


def test_tune_searches_the_robust_refinement_only_for_robust_designs():
    from rodctl.robust.tune import ROBUST_ONLY, space

    assert not {d.name for d in space(None, load_params())} & set(ROBUST_ONLY)  # they change nothing there
    robust = load_params(None, ["design.method=robust"])
    dims = {d.name: d for d in space(None, robust)}
    assert set(ROBUST_ONLY) <= set(dims)
    lo, hi = dims["design.robust_radius"].bounds(robust)
    assert lo < robust["design"]["robust_radius"] < hi < 1.0  # never a target the loop cannot meet


def test_a_sweeps_axes_carry_the_keys_units():
    from rodctl.robust.figures import _with_unit

    assert _with_unit("rod.length") == "rod.length [m]" and _with_unit("rod.youngs_modulus") == "rod.youngs_modulus [Pa]"
    assert _with_unit("rod.edges") == "rod.edges"  # a count has no unit to name


def test_a_start_from_value_outside_the_search_is_said_and_not_tried(tmp_path, capsys):
    """It ran lqr.q_angle = 5000 against the searched [0.1, 1000] with only Optuna's own UserWarning."""
    big = tmp_path / "big_q.toml"
    assert main(["params", "--set", "lqr.q_angle=5000", "--out", str(big)]) == 0
    study, out = tmp_path / "study", tmp_path / "t.toml"
    assert main(["tune", "--start-from", str(big), "--only", "lqr.q_angle", "--cases", "nominal", "--samples", "0",
                 "--seconds", str(SECONDS), "--budget", "2", "--jobs", "1", "--no-goals", "--study", str(study),
                 "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert (f"rodctl: warning: --start-from {big}: lqr.q_angle = 5000.0 is outside the searched range [0.1, 1000]; "
            "that value is not tried") in err and "UserWarning" not in err
    trials = json.loads((study / "trials.json").read_text())
    assert all(0.1 <= t["values"]["lqr.q_angle"] <= 1000 for t in trials)


def test_a_score_sweep_says_each_point_s_score_and_keeps_it(tmp_path, capsys):
    """It printed only "2 grid points: 0 pass, 2 fail" (all runs passing or not), kept no score in the file, and
    took --case and --criterion, which a score does not use, without a word."""
    pq = pytest.importorskip("pyarrow.parquet")
    out = tmp_path / "sc.parquet"
    argv = ["sweep", "--scenario", "score", "--cases", "nominal", "--samples", "0", "--grid", "rod.edges=5,8",
            "--seconds", str(SECONDS), "--jobs", "1", "--out", str(out), "--plot", ""]
    assert main(argv) == 0
    text = capsys.readouterr().out
    meta = json.loads(pq.read_schema(out).metadata[b"rodctl"])
    points = meta["points"]
    assert [p["rod.edges"] for p in points] == [5, 8] and meta["cases"] == "nominal" and "case" not in meta
    for p in points:
        assert p["score"] == p["passed_runs"] / p["runs"] and p["runs"] == 2
        assert (f"  rod.edges = {p['rod.edges']}: score {p['score']:.4f} ({p['passed_runs']}/2 runs pass), margin "
                f"{p['margin']:.4f}") in text
    assert main(argv + ["--case", "E+15", "--force"]) == 2
    assert "--case picks one task's run" in capsys.readouterr().err
