"""rodctl tune: Optuna (TPE) searches weights, controller order and swing-up within safe ranges for the
largest robustness objective (score.py: the fraction of runs passing, the margin breaking ties).

Trials run one after another; the runs inside a trial go to the Runner (every core, or a Dask
cluster). The first trial of a new study is the parameter file itself, so the best trial is never
worse than the starting point. With `--study DIR` every finished trial is in DIR/journal.log
(Optuna JournalStorage on a file) the moment it finishes: Ctrl-C keeps them, and the same command
resumes until `--budget` trials have finished. DIR/trials.json lists every trial's values and
score. DIR/study.json pins what the objective means (parameters, cases, draws); resuming with
other inputs is refused.

A candidate that the parameter checks reject, or whose design the generator refuses, scores 0.

Nominal goals (`goals=True`, the default of `rodctl tune`): a design that is robust but slow is no
default, so the nominal case's strict runs (issue 8's goals: balance settled to 1 deg by 1.5 s,
swing-up caught by 5 s and settled 2 s after the catch) are a constraint, not two runs among many.
They are judged with an ideal gearbox and no trim (`gate_params`: the lean would fail every trial) and run
first; a candidate that misses one is infeasible and skips the rest of its runs (about thirty times
cheaper). Optuna's TPE takes the violation (how far past the goals, summed) through
`Trial.set_constraint`, and the best trial is the best feasible one.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from rodgains.errors import DesignRefused, InputError, ParamError
from rodgains.params import SCHEMA, Params

STUDY_NAME = "rodctl-tune"


@dataclass(frozen=True)
class Dim:
    """One searched parameter: a float range (log-uniform when `log`), or a list of choices."""

    name: str  # section.key
    low: float = 0.0
    high: float = 0.0
    log: bool = False
    choices: tuple = ()
    why: str = ""

    def bounds(self, params: Params) -> tuple[float, float]:
        lo, hi = self.low, self.high
        # the swing-up pump may never exceed the torque the driver and the safety limit allow
        if self.name == "swing_up.amplitude":
            hi = min(hi, params.torque_max)
        # a catch must happen inside the angle limit, or the catch itself trips it
        if self.name == "swing_up.catch_angle_deg":
            hi = min(hi, params["safety"]["angle_limit_deg"] - 5.0)
        # the starting point is always inside, so trial 0 is the parameter file itself
        sec, key = self.name.split(".")
        v = params[sec][key]
        return min(lo, v), max(hi, v)

    def text(self, params: Params) -> str:
        if self.choices:
            return f"{self.name} in {{{', '.join(map(str, self.choices))}}}"
        lo, hi = self.bounds(params)
        return f"{self.name} in [{lo:g}, {hi:g}]" + (" (log)" if self.log else "")


# The safe ranges. r_torque stays fixed: LQR is unchanged when Q and R scale together.
SPACE: tuple[Dim, ...] = (
    Dim("lqr.q_angle", 0.1, 1000.0, log=True, why="LQR weight on each angle error [1/rad^2]"),
    Dim("lqr.q_rate", 1e-4, 10.0, log=True, why="LQR weight on each rate error [s^2/rad^2]"),
    Dim("observer.process_noise_angle", 1e-3, 10.0, log=True, why="[rad^2/s]"),
    Dim("observer.process_noise_rate", 0.1, 1000.0, log=True, why="[rad^2/s^3]"),
    Dim("observer.measurement_noise", 1e-6, 1e-3, log=True, why="[rad^2 s]"),
    Dim("observer.process_noise_torque", 1e-5, 1.0, log=True, why="disturbance-torque random walk [(N m)^2/s]"),
    Dim("lqr.friction_compensation", 0.0, 0.02, why="dry-friction feedforward [N m]"),
    Dim("lqr.q_shaft_angle", 0.0, 1000.0, why="extra LQR weight on the shaft's angle [1/rad^2]"),
    # controller model order; the M4F step at N = 20 fits the 1 kHz budget (rodctl bench)
    Dim("rod.edges", choices=(3, 4, 5, 6, 8, 10, 12, 16, 20), why="controller model order [-]"),
    Dim("swing_up.amplitude", 0.02, 0.2, why="pump torque [N m], at most safety.torque_limit"),
    Dim("swing_up.angle_deg", 10.0, 180.0, why="pump while |theta_1| < this [deg]"),
    Dim("swing_up.energy_target", 0.8, 1.2, why="pump toward this fraction of the upright energy [-]"),
    Dim("swing_up.rate_filter_hz", 1.0, 20.0, log=True, why="low-pass on the base rate the pump reads [Hz]"),
    Dim("swing_up.catch_angle_deg", 10.0, 45.0, why="switch to balance within this of upright [deg]"),
    # searched only for design.method = "robust" (they change nothing otherwise)
    Dim("design.robust_radius", 0.999, 0.99995, why="spectral radius the model family must stay below [-]"),
    Dim("design.robust_gain_margin", 0.1, 0.8, log=True, why="torque fraction the loop must hold [-]"),
    Dim("design.robust_nominal_decay", 0.0, 5.0, why="every nominal mode decays at least this fast [1/s]"),
    Dim("design.robust_noise_torque", 0.0, 0.05, why="RMS torque encoder quantization may drive [N m]; 0: off"),
)
ROBUST_ONLY = tuple(d.name for d in SPACE if d.name.startswith("design.robust_"))


def space(only: str | None = None, params: Params | None = None) -> tuple[Dim, ...]:
    """The searched dimensions (those the parameter schema has, and the robust refinement's only when
    `params` use it), or the subset `only` (comma-separated)."""
    robust = params is not None and params["design"]["method"] == "robust"
    known = tuple(d for d in SPACE if d.name.split(".")[1] in SCHEMA.get(d.name.split(".")[0], {})
                  and (robust or d.name not in ROBUST_ONLY))
    if only is None:  # --only '' searches nothing, and is refused below
        return known
    names = [x.strip() for x in only.split(",") if x.strip()]
    by = {d.name: d for d in known}
    bad = [n for n in names if n not in by]
    if bad or not names:
        raise InputError(f"--only {only}: not a searched parameter; one or more of {', '.join(by)}")
    return tuple(by[n] for n in names)


def suggest(trial, dims: tuple[Dim, ...], params: Params) -> dict:
    out = {}
    for d in dims:
        if d.choices:
            out[d.name] = trial.suggest_categorical(d.name, list(d.choices))
        else:
            lo, hi = d.bounds(params)
            out[d.name] = trial.suggest_float(d.name, lo, hi, log=d.log)
    return out


def candidate(params: Params, values: dict) -> Params:
    return params.with_overrides(*(f"{k}={v!r}" for k, v in values.items()))


def starting_point(params: Params, dims: tuple[Dim, ...], searched: Params | None = None) -> dict:
    """The parameter file's own values, for the dimensions where they are inside the searched range (that of
    `searched`, the study's parameter file; default: params itself, whose values the range always holds)."""
    out = {}
    for d in dims:
        sec, key = d.name.split(".")
        v = params[sec][key]
        lo, hi = d.bounds(searched or params)
        if (d.choices and v in d.choices) or (not d.choices and lo <= v <= hi):
            out[d.name] = v
    return out


def outside_the_search(extra: Params, dims: tuple[Dim, ...], params: Params) -> list[str]:
    """The values of a --start-from file outside the range the study searches (params'), in words: they are not
    tried (a trial there would be outside every distribution the sampler knows)."""
    inside = starting_point(extra, dims, params)
    out = []
    for d in dims:
        if d.name not in inside:
            sec, key = d.name.split(".")
            lo, hi = d.bounds(params)
            out.append(f"{d.name} = {extra[sec][key]!r} is outside the searched "
                       + (f"choices {{{', '.join(map(str, d.choices))}}}" if d.choices else f"range [{lo:g}, {hi:g}]"))
    return out


def check_study(study_dir: str, meta: dict) -> None:
    """An existing --study folder can be resumed by this command: its study.json pins the same inputs and
    every line of its journal is one JSON record (a line cut short by a kill is named before Optuna appends
    to the file). InputError (exit 2) otherwise; a folder not made yet passes."""
    folder = Path(study_dir)
    if folder.exists() and not folder.is_dir():
        raise InputError(f"--study {study_dir}: not a folder")
    meta_path = folder / "study.json"
    journal = folder / "journal.log"
    for f in (meta_path, journal):
        if f.exists() and not f.is_file():
            raise InputError(f"--study {study_dir}: {f.name} is not a file; use a new --study folder")
    if meta_path.exists():
        try:
            old = json.loads(meta_path.read_text())
        except (UnicodeDecodeError, json.JSONDecodeError):
            old = None
        if not isinstance(old, dict):
            raise InputError(f"--study {study_dir}: {meta_path.name} is not this command's JSON; use a new --study "
                             "folder")
        diff = [k for k in meta if old.get(k) != meta[k]]
        if diff:
            raise InputError(f"--study {study_dir}: made for other inputs ({', '.join(diff)} differ); "
                             f"use a new --study folder")
    if journal.exists():
        with journal.open("rb") as f:
            for number, line in enumerate(f, 1):
                try:
                    json.loads(line)
                except (UnicodeDecodeError, json.JSONDecodeError):
                    raise InputError(f"--study {study_dir}: {journal.name} line {number} is not a whole record "
                                     "(cut short when a run was killed?); delete that line to resume, or use a "
                                     "new --study folder") from None


def open_study(study_dir: str | None, meta: dict, sampler_seed: int):
    """A new or resumed Optuna study (journal file in study_dir, or in memory)."""
    import optuna
    from optuna.storages import JournalStorage
    from optuna.storages.journal import JournalFileBackend

    optuna.logging.set_verbosity(optuna.logging.WARNING)

    def sampler(seed: int):
        return optuna.samplers.TPESampler(seed=seed, multivariate=True)
    if study_dir is None:
        return optuna.create_study(study_name=STUDY_NAME, direction="maximize", sampler=sampler(sampler_seed))
    check_study(study_dir, meta)
    folder = Path(study_dir)
    folder.mkdir(parents=True, exist_ok=True)
    meta_path = folder / "study.json"
    if not meta_path.exists():
        from rodctl.robust.output import write_json

        write_json(meta_path, meta)
    storage = JournalStorage(JournalFileBackend(str(folder / "journal.log")))
    study = optuna.create_study(study_name=STUDY_NAME, direction="maximize", sampler=sampler(sampler_seed),
                                storage=storage, load_if_exists=True)
    # a resumed study's sampler starts past the draws already made: seeded as new, its first random (startup)
    # draws would be those of trials #1, #2, ... again
    done = len(study.get_trials(deepcopy=False))
    if done:
        study.sampler = sampler(sampler_seed + done)
    return study


def completed(study) -> list:
    from optuna.trial import TrialState

    return [t for t in study.get_trials(deepcopy=False) if t.state == TrialState.COMPLETE]


def goal_violation(row: dict) -> float:
    """How far one strict (nominal) run is from its goals: 0 when it passed, else 1 + the settle time
    past the goal in goal units (capped), so TPE sees a slope towards feasibility."""
    if row.get("passed"):
        return 0.0
    from rodctl.sim import matrix as M

    goal = M.BALANCE_SETTLE_GOAL_S if row.get("task") == "balance" else M.SWINGUP_SETTLE_GOAL_S
    settle = row.get("settle_s")
    if settle is None or not math.isfinite(settle):
        return 1.0 + 5.0
    return 1.0 + min(max(settle - goal, 0.0) / goal, 5.0)


def gate_params(params: Params) -> Params:
    """What the nominal goals are judged on: params with matrix.IDEAL_GEARBOX, the rig without play and the
    design without the trim. With the play the rod rests on a flank 2 to 2.5 deg off upright whatever the
    gains (docs/control.md), so no trial would meet the 1 deg goals; the goals are about the design's
    speed, which the play swamps. The trim goes too, not only the play: with it, on the ideal gearbox
    alone, the default ends 2.3 deg off (its base rests 0.3 deg from upright, inside one encoder count,
    held by dry friction), against 0.23 deg without it. The scored runs keep the play and the trim."""
    from rodctl.sim.matrix import IDEAL_GEARBOX

    return params.with_overrides(*IDEAL_GEARBOX)


def evaluate(params: Params, runner, make_units: Callable[[Params], list], on_row=None, goals: bool = False) -> dict:
    """Score one candidate: {'objective', 'score', 'passed', 'runs', 'margin', 'violation', 'refused'}.
    A refusal scores 0. goals: the nominal (strict) runs on `gate_params` go first and a miss ends the
    trial (module docstring); its objective is then 0 and 'violation' > 0. They are not scored."""
    from rodctl.build.sil_build import build_sil
    from rodctl.robust import score as S

    empty = {"objective": 0.0, "score": 0.0, "passed": 0, "runs": 0, "margin": 0.0}
    try:
        build_sil(params)  # design + compile once, here, before the runs fan out
    except DesignRefused as e:
        return {**empty, "violation": 6.0 if goals else 0.0, "refused": str(e)}
    rest = make_units(params)
    gate = [u for u in make_units(gate_params(params)) if getattr(u.case, "strict", False)] if goals else []
    gate_rows = runner.run(gate, on_row=on_row, show=False) if gate else []
    miss = sum(goal_violation(r) for r in gate_rows)
    if miss > 0:
        return {**empty, "violation": miss, "refused": "",
                "missed_goals": [f"{r['case']}/{r['task']}" for r in gate_rows if not r.get("passed")]}
    rows = runner.run(rest, on_row=on_row, show=False)
    sc = S.score(rows, params)
    return {**sc.to_json(), "violation": 0.0, "refused": ""}


def best_feasible(study):
    """The trial with the largest objective among those that met the goals (violation 0); when none
    did, the one closest to them."""
    trials = completed(study)
    if not trials:
        raise ValueError("no finished trial")
    feasible = [t for t in trials if t.user_attrs.get("violation", 0.0) <= 0.0]
    if not feasible:
        return min(trials, key=lambda t: (t.user_attrs.get("violation", 0.0), t.number))
    return max(feasible, key=lambda t: (t.value, -t.number))


def tune(params: Params, runner, *, dims: tuple[Dim, ...], budget: int, make_units: Callable[[Params], list],
         study_dir: str | None, meta: dict, sampler_seed: int, progress: bool = True, goals: bool = False,
         starts: tuple[Params, ...] = ()) -> dict:
    """Run trials until `budget` have finished; returns the summary the output file is written from.
    goals: require the nominal goals (module docstring). starts: more parameter files whose values
    are tried right after the starting point (earlier tunes, hand designs).
    KeyboardInterrupt propagates after the running trial is marked failed (finished ones stay)."""
    from optuna.trial import TrialState

    study = open_study(study_dir, meta, sampler_seed)
    start = starting_point(params, dims)
    before = study.get_trials(deepcopy=False)
    if not before:
        study.enqueue_trial(start)
        for extra in starts:
            point = starting_point(extra, dims, params)
            if point:  # nothing of it inside the search: not a trial of its own (a random one)
                study.enqueue_trial(point, skip_if_exists=True)
    elif not any(t.state in (TrialState.COMPLETE, TrialState.WAITING) and t.params == start for t in before):
        study.enqueue_trial(start)  # cut short by a Ctrl-C: the start is what the result must not fall below
    done = completed(study)
    bar = None
    if progress:
        from rodctl.progress import bar as progress_bar

        bar = progress_bar(total=budget, initial=min(len(done), budget), desc="tune", unit="trial")

    def best_text() -> str:
        try:
            b = best_feasible(study)
        except ValueError:
            return "best -"
        if b.user_attrs.get("violation", 0.0) > 0.0:
            return f"no trial meets the nominal goals yet (closest #{b.number})"
        return f"best {b.user_attrs.get('score', 0):.4f} (#{b.number})"

    try:
        while len(completed(study)) < budget:
            trial = study.ask()
            try:
                values = suggest(trial, dims, params)
                try:
                    cand = candidate(params, values)
                except ParamError as e:
                    result = {"objective": 0.0, "score": 0.0, "passed": 0, "runs": 0, "margin": 0.0,
                              "violation": 6.0 if goals else 0.0, "refused": f"invalid parameters: {e}"}
                else:
                    count = [0]

                    def on_row(_unit, _row):
                        count[0] += 1
                        if bar is not None:
                            bar.set_postfix_str(f"trial {trial.number}: {count[0]} runs | {best_text()}", refresh=False)

                    result = evaluate(cand, runner, make_units, on_row, goals=goals)
            except BaseException:
                study.tell(trial, state=TrialState.FAIL)
                raise
            for k, v in result.items():
                trial.set_user_attr(k, v)
            # > 0: missed the nominal goals; TPE ranks such trials below every feasible one
            trial.set_constraint("nominal_goals", result.get("violation", 0.0))
            study.tell(trial, result["objective"])
            if bar is not None:
                bar.update(1)
                bar.set_postfix_str(best_text())
    finally:
        if bar is not None:
            bar.close()
        if study_dir is not None:
            write_trials(study, Path(study_dir) / "trials.json")
    trials = completed(study)
    best = best_feasible(study)
    first = min(trials, key=lambda t: (t.params != start, t.number))  # the starting point's trial
    goals_met = best.user_attrs.get("violation", 0.0) <= 0.0
    closest = best
    if not goals_met:  # no trial met the goals, so none was scored: nothing beats the starting point
        best = first
    return {
        "best_number": best.number,
        "best_values": {d.name: best.params[d.name] for d in dims if d.name in best.params},
        "best": dict(best.user_attrs),
        "start": dict(first.user_attrs),
        "start_number": first.number,
        "trials": len(trials),
        "goals_met": goals_met,
        "closest_number": closest.number,
        "closest_missed": list(closest.user_attrs.get("missed_goals", [])),
    }


def unscored_text(summary: dict) -> str:
    """What a search in which no trial met the nominal goals did (nothing was scored)."""
    missed = summary.get("closest_missed") or []
    closest = f"; the closest, trial #{summary['closest_number']}, missed {', '.join(missed)}" if missed else ""
    return (f"no trial met the nominal goals in {summary['trials']} trials{closest}: none was scored, so nothing "
            "was tuned")


def write_trials(study, path: Path) -> None:
    """Every trial (number, state, searched values, score, passed, runs, margin) as JSON, beside the journal."""
    from rodctl.robust.output import write_json

    rows = [{"number": t.number, "state": t.state.name, "values": dict(t.params), **dict(t.user_attrs)}
            for t in study.get_trials(deepcopy=False)]
    write_json(path, rows)


def tuned_file(params: Params, summary: dict, dims: tuple[Dim, ...], reproduce: str, check: str,
               goals: bool = False) -> str:
    """The complete parameter file of the best trial, with comments saying how it came to be."""
    from rodctl.paths import shown

    best_p = candidate(params, summary["best_values"])
    b, s = summary["best"], summary["start"]

    def sc(d):
        return f"{d.get('score', 0):.4f} ({d.get('passed', 0)}/{d.get('runs', 0)} runs pass, margin {d.get('margin', 0):.4f})"

    met = summary.get("goals_met", b.get("violation", 0.0) <= 0.0)
    lines = [
        "# Tuned by `rodctl tune` (Optuna TPE) for the robustness score: the fraction of matrix and",
        "# Monte Carlo runs that pass on the faithful plant, the margin breaking ties (host/rodctl/robust/score.py).",
    ]
    if met:
        lines += [
            f"# Starting point: {shown(params.source)} (sha256 {params.sha256()[:16]}), trial "
            f"#{summary['start_number']}: score {sc(s)}",
            f"# Tuned:          trial #{summary['best_number']} of {summary['trials']}: score {sc(b)}",
        ]
    else:
        lines += [
            f"# Starting point: {shown(params.source)} (sha256 {params.sha256()[:16]}), trial "
            f"#{summary['start_number']}: not scored",
            f"# NOT TUNED: {unscored_text(summary)}. These are the starting values, unchanged;",
            "# `--no-goals` scores the trials without the nominal goals.",
        ]
    if goals:
        lines.append("# Constraint: the nominal goals of the faithful-rod scenarios (balance within 1 deg by 1.5 s, swing-up "
                     "caught by 5 s and settled 2 s after the catch), judged with an ideal gearbox" + ("" if met else ": NOT MET by any trial"))
    lines.append("# Searched (everything else is the starting point's):")
    for d in dims:
        sec, key = d.name.split(".")
        old, new = params[sec][key], best_p[sec][key]
        lines.append(f"#   {d.text(params):52s} {old!r} -> {new!r}")
    lines += [f"# Reproduce: {reproduce}", f"# Check:     {check}", "#", ""]
    return "\n".join(lines) + best_p.to_toml()


def fmt_value(v) -> str:
    return f"{v:.6g}" if isinstance(v, float) and math.isfinite(v) else str(v)
