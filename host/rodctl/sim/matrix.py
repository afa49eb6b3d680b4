"""The robustness matrix: the firmware judged on the faithful plant, case by case (issue 8).

    from rodgains.params import load_params
    from rodctl.sim.matrix import CASES, run_case
    r = run_case(load_params(), CASES["E+15"], "swingup")   # {"passed": True, "caught_at_s": 2.9, ...}

Every case runs the SIL firmware designed from `params` (+ the case's design_overrides, normally
none) against the FAITHFUL plant: the parameter file's [plant] table (model, edges, hub_length),
the physical motor (rotor inertia, viscous and Coulomb friction), the MAX14870 in duty mode and
the 979.2 counts/turn encoder, with the case's plant_overrides applied to the plant only. The
design never sees a plant override: that is the point of the matrix. `plant_params` (run_case,
run_matrix) puts another rod in the plant's place: a hidden rig judged against an identified design.

Tasks: "balance" (a straight rod released at rest BALANCE_START_DEG from upright, armed in
BALANCE) and "swingup" (from rest hanging, armed in SWING_UP). Pass rules: `criterion(task)`;
the nominal case is held to the stricter goals of issue 8 (`criterion(task, strict=True)`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Callable

import numpy as np

from rodgains.buckling import clamped_ratio
from rodgains.errors import InputError
from rodgains.params import SOFT_SHAFT_WEIGHTS, Params

TASKS = ("balance", "swingup")

BALANCE_START_DEG = 30.0
SETTLE_DEG = 1.0  # the nominal goal band [deg]
ROBUST_BAND_DEG = 3.0  # every case: every link within this at the end [deg]
FINAL_WINDOW_S = 0.5  # "at the end": the largest deviation over the last this many seconds [s]
HELD_WINDOW_S = 4.0  # held_fraction: the share of this last stretch the rod spends within the band [s]
# long enough to see a rod on a rig with play either rest on one flank or hunt across the gap (the first
# crossing can come 10 s in): shorter runs pass a design that hunts (docs/control.md "Finding upright")
DEFAULT_SECONDS = {"balance": 20.0, "swingup": 20.0}
# nominal goals
BALANCE_SETTLE_GOAL_S = 1.5
SWINGUP_CATCH_GOAL_S = 5.0
SWINGUP_SETTLE_GOAL_S = 2.0  # every link within SETTLE_DEG this long after the catch
SWINGUP_TURNS_GOAL = 1.0
# every case
SWINGUP_CATCH_LIMIT_S = 10.0

MODE_BALANCE, MODE_SWING_UP, MODE_FAULT = 1, 2, 3

# The curved rod: a uniform rest curvature [1/m] that puts the tip of the Table I rod hanging at rest
# CURVED_TIP_M to the side (gravity straightens it: the same curvature without gravity gives 8.6 mm;
# tests/test_plant_gearbox.py measures it).
CURVED_TIP_M = 0.005
CURVED_REST_CURVATURE = 0.82
LAG_075_INDUCTANCE = 0.75e-3 * 2.4  # [H]: L / R = 0.75 ms on the 2.4 ohm winding
# Cases the linear check flags for the default design (sampled-loop radius > 1 without dry friction,
# `rodctl gains --report`), run again with no Coulomb friction at all.
NO_FRICTION_CASES = ("E-15", "rho+15")


@dataclass(frozen=True)
class Case:
    """One row of the matrix.

    plant_overrides / design_overrides: "section.key=value" or "section.key*=factor".
    delay_periods: extra control periods between the command and the plant (0 or 1).
    disturbance: (torque [N m], start [s] after balancing begins, duration [s]) on the shaft; balance task only.
    strict: hold the case to the nominal goals (settle times, catch time, base turns).
    """

    name: str
    title: str
    plant_overrides: tuple[str, ...] = ()
    design_overrides: tuple[str, ...] = ()
    delay_periods: int = 0
    disturbance: tuple[float, float, float] | None = None
    strict: bool = False
    tasks: tuple[str, ...] = TASKS


def _cases() -> dict[str, Case]:
    c = [Case("nominal", "the faithful plant as the parameter file describes it", strict=True)]
    for sign, f in (("+", 1.15), ("-", 0.85)):
        c.append(Case(f"E{sign}15", f"Young's modulus {sign}15 %", (f"rod.youngs_modulus*={f}",)))
    for sign, f in (("+", 1.15), ("-", 0.85)):
        c.append(Case(f"rho{sign}15", f"density {sign}15 %", (f"rod.density*={f}",)))
    c.append(Case("damping*0.1", "rod damping x0.1", ("rod.damping*=0.1",)))
    c.append(Case("damping*10", "rod damping x10", ("rod.damping*=10",)))
    c.append(Case("viscous*3", "gearbox viscous friction x3", ("motor.viscous_friction*=3",)))
    c.append(Case("coulomb*0", "no Coulomb friction", ("motor.coulomb_friction*=0",)))
    c.append(Case("coulomb*2", "Coulomb friction x2", ("motor.coulomb_friction*=2",)))
    for sign, f in (("+", 1.3), ("-", 0.7)):
        c.append(Case(f"J{sign}30", f"rotor inertia {sign}30 %", (f"motor.rotor_inertia*={f}",)))
    for sign, f in (("+", 1.15), ("-", 0.85)):
        # k_t and k_e are one constant of the motor (SI units): both move together
        c.append(Case(f"kt{sign}15", f"torque (and back-EMF) constant {sign}15 %",
                      (f"motor.torque_constant*={f}", f"motor.back_emf_constant*={f}")))
    for sign, f in (("+", 1.03), ("-", 0.97)):
        c.append(Case(f"L{sign}3", f"rod length {sign}3 %", (f"rod.length*={f}",)))
    for v in (11, 13):
        c.append(Case(f"supply{v}", f"motor supply {v} V", (f"driver.supply_voltage={v}.0",)))
    c.append(Case("delay+1", "one extra control period of delay", delay_periods=1))
    for sign, T in (("+", 0.05), ("-", -0.05)):
        c.append(Case(f"dist{sign}", f"{T:+.2f} N m for 50 ms on the shaft while balanced", disturbance=(T, 3.0, 0.05),
                      tasks=("balance",)))
    for model, tag in (("inextensible", "inext"), ("der", "der")):
        for n in (10, 20, 40):
            c.append(Case(f"{tag}{n}", f"{model} plant, {n} edges beyond the hub",
                          (f'plant.model="{model}"', f"plant.edges={n}")))
    # what a real rig adds between the encoder and the rod (docs/plant.md, "The gearbox")
    for gap in (0.0, 0.5, 2.0, 3.0):
        c.append(Case(f"backlash{gap:g}", f"{gap:g} deg of gearbox backlash (nominal 1)", (f"gearbox.backlash_deg={gap}",)))
    for k in (20.0, 200.0):
        c.append(Case(f"gear{k:g}", f"gear train stiffness {k:g} N m/rad (nominal 60)", (f"gearbox.stiffness={k}",)))
    for sign in ("+", "-"):
        c.append(Case(f"zero{sign}0.5", f"encoder zero {sign}0.5 deg off (nominal: half a count)",
                      (f"encoder.zero_error_deg={sign}0.5",)))
    c.append(Case("curved", f"a rod curved at rest: the hanging tip {1e3 * CURVED_TIP_M:g} mm off",
                  (f"rod.rest_curvature={CURVED_REST_CURVATURE}",)))
    c.append(Case("lag0.75", "1.8 mH: a 0.75 ms current lag on the 2.4 ohm winding (nominal 0.29 ms)",
                  (f"motor.inductance={LAG_075_INDUCTANCE}",)))
    c.append(Case("jitter100", "the control interrupt up to 100 us late", ("plant.isr_jitter_us=100.0",)))
    # no dry friction where the sampled loop is unstable without it (sim/linear_check.py): a pass must
    # not rest on Coulomb friction holding a leaning rod
    for name in NO_FRICTION_CASES:
        base = {x.name: x for x in c}[name]
        c.append(Case(f"{name},coulomb*0", f"{base.title}, no Coulomb friction",
                      base.plant_overrides + ("motor.coulomb_friction*=0",)))
    return {x.name: x for x in c}


CASES: dict[str, Case] = _cases()
# (case, task) the default design does not pass, and why (docs/control.md "What the matrix shows").
# Every other run is expected to pass, but with the gearbox's play the rod rests on one flank 2 to
# 2.8 deg off upright (docs/control.md "Finding upright"), near the 3 deg band, so
# tests/test_robustness_matrix.py holds those to a pass share, not one by one.
# The rig with an ideal gearbox (no play, no compliance, an exact boot zero, no current lag) and the
# design tuned for it (no set-point trim, the paper's 30 deg catch): the limit the faithful plant
# reduces to (tests/test_plant_gearbox.py). Mechanisms that were measured on it (the identified rigs'
# friction compensation, the robust refinement, the stiff shaft) are tested there, where the
# gearbox's play does not swamp what they change.
IDEAL_GEARBOX = ('gearbox.model="rigid"', "encoder.zero_error_deg=0.0", "motor.inductance=0.0",
                 "gearbox.output_inertia=0.0", "trim.time_constant=0.0", "swing_up.catch_angle_deg=30.0")

_LINEARLY = "the sampled loop is unstable without dry friction on the faithful plant (rodctl gains --report)"
KNOWN_FAILURES: dict[tuple[str, str], str] = {
    **{(c, t): _LINEARLY for c in ("E-15", "rho+15", "E-15,coulomb*0", "rho+15,coulomb*0") for t in TASKS},
    **{("L+3", t): "3 % longer: 0.97 x the clamped buckling length with the gearbox's play; it bends over"
       for t in TASKS},
    **{("curved", t): "a rod curved at rest has no shape within 3 deg of upright: the straightest a steady base torque "
       "holds (2.1 mN m) is 3.22 deg off, and its zero-moment shape, which the set-point trim finds, 6.07 deg "
       "(rodctl.sim.statics; docs/control.md)" for t in TASKS},
}
# In-range runs (not KNOWN_FAILURES, rod short of its buckling length) the default design must pass, as
# a share: with 0.5 to 1 deg of play the rod rests 2 to 2.9 deg off upright, near the 3 deg band
# (docs/control.md: measured 62 of 78 runs, 62 of the 66 in range, with the defaults, 59 to 62 of 78 with
# the trim's band from 0.25 to 0.75 mN m; the fails are the nominal's 1 deg goals, a plant without dry
# friction, which hunts across the gap, and the Coulomb x2 swing-up, 3.3 deg off).
MIN_PASS_SHARE = 0.8
CASE_SETS: dict[str, tuple[str, ...]] = {
    "matrix": tuple(CASES),
    "nominal": ("nominal",),
    "quick": ("nominal", "E-15", "delay+1", "inext10"),
    "plants": tuple(n for n in CASES if n.startswith(("inext", "der"))),
}


def own_design(case: Case) -> Case:
    """The case with a design that knows its rod: the plant's overrides made in the design too, what a design
    from `rodctl identify`'s file is (Young's modulus within 0.3 % on the hidden rigs of tests/test_identify.py,
    three of them with play; the density is weighed). The matrix itself judges the file's own design on every
    case (docs/sensors.md, "Near buckling the design needs the rod's own modulus")."""
    return replace(case, name=f"{case.name} (own design)", title=f"{case.title}, the design made for it",
                   design_overrides=case.plant_overrides + case.design_overrides)


def cases_for(task: str, names=None) -> list[Case]:
    """The cases of a set (default: the whole matrix) that apply to `task`."""
    names = CASE_SETS["matrix"] if names is None else names
    return [CASES[n] for n in names if task in CASES[n].tasks]


def criterion(task: str, strict: bool = False) -> str:
    """The pass rule in words."""
    if task == "balance":
        rule = f"no FAULT; every link within {ROBUST_BAND_DEG:g} deg of upright over the last {FINAL_WINDOW_S:g} s"
        if strict:
            rule = (f"no FAULT; every link within {SETTLE_DEG:g} deg of upright by {BALANCE_SETTLE_GOAL_S:g} s after "
                    f"arming, and to the end")
        return rule
    if task == "swingup":
        rule = (f"caught within {SWINGUP_CATCH_LIMIT_S:g} s, no FAULT, every link within {ROBUST_BAND_DEG:g} deg "
                f"over the last {FINAL_WINDOW_S:g} s")
        if strict:
            rule = (f"caught within {SWINGUP_CATCH_GOAL_S:g} s, every link within {SETTLE_DEG:g} deg by "
                    f"{SWINGUP_SETTLE_GOAL_S:g} s after the catch and to the end, never more than "
                    f"{SWINGUP_TURNS_GOAL:g} base turn from the start, no FAULT")
        return rule
    raise InputError(f"unknown task {task!r}; one of {', '.join(TASKS)}")


def scaled_overrides(p: Params, items) -> list[str]:
    """"section.key*=f" -> "section.key=<value of p times f>"; other items pass through."""
    out = []
    for it in items:
        if "*=" in it:
            name, f = it.split("*=", 1)
            sec, key = name.strip().split(".")
            v = p[sec][key] * float(f)
            out.append(f"{name.strip()}={v!r}" if isinstance(v, float) else f"{name.strip()}={v}")
        else:
            out.append(it)
    return out


def apply_overrides(p: Params, items) -> Params:
    """p with a case's overrides. A case scales a checked file's values (E x0.85, viscous friction x3), so the
    guard against typed unit slips does not apply: a rig at the edge of plausible keeps its cases."""
    items = scaled_overrides(p, items)
    return p.with_overrides(*items, plausible=False) if items else p


def buckled_cases(plant: Params) -> dict[str, float]:
    """The matrix cases whose rod, above the hub, is past its clamped buckling length on this plant:
    case name -> rodgains.buckling.clamped_ratio [-]. Measured with the designs for rig B, rig D and
    Table I, E scaled across it (docs/identification.md): every run from 1.007 on ended bent
    25 to 55 deg, and one of six at 1.000 to 1.002 held; so these cases measure the buckling more
    than the design."""
    out = {}
    for name, case in CASES.items():
        ratio = clamped_ratio(apply_overrides(plant, case.plant_overrides))
        if ratio >= 1.0:
            out[name] = ratio
    return out


def past_band_cases(plant: Params) -> dict[str, float]:
    """The matrix cases whose rod has no static shape within the band of upright on this plant (a rod curved
    at rest): case name -> the largest edge deviation of its straightest shape [deg] (rodctl.sim.statics). No
    controller acting at the base holds such a rod within the band, so these cases measure the rod, not the
    design."""
    out = {}
    for name, case in CASES.items():
        dev = straightest_deg(apply_overrides(plant, case.plant_overrides))
        if dev is not None and dev > ROBUST_BAND_DEG:
            out[name] = dev
    return out


def past_band(row: dict) -> bool:
    """Had this run's rod no static shape within the band (run_case's straightest_deg past it)?"""
    return (row.get("straightest_deg") or 0.0) > ROBUST_BAND_DEG


def marks(row: dict) -> str:
    """What a table or figure appends to a run's case name: " ^" past the buckling length, " ~" no shape within the
    band (their footnotes: rodctl.cli.robustness.table_lines)."""
    return (" ^" if buckled(row) else "") + (" ~" if past_band(row) else "")


def buckled(row: dict) -> bool:
    """Was this run's rod past its clamped buckling length (run_case's buckling_ratio >= 1)? A refused
    design's row has no ratio."""
    return (row.get("buckling_ratio") or 0.0) >= 1.0


def _deviation_deg(theta: np.ndarray) -> np.ndarray:
    return np.degrees(np.abs(np.mod(theta, 2 * np.pi) - np.pi))


def tail_deviation_deg(log: dict, window_s: float) -> tuple[float, float]:
    """(mean, peak) of the largest link deviation from upright over a run's last `window_s` [deg]."""
    t = log["time"]
    dev = _deviation_deg(log["theta"]).max(axis=1)[t > t[-1] - window_s]
    return float(dev.mean()), float(dev.max())


def simulate(design_p: Params, plant_p: Params, task: str, *, seconds: float, delay_periods: int = 0,
             disturbance=None, progress: Callable[[str, float], None] | None = None, label: str = "",
             start_deg: float = BALANCE_START_DEG) -> dict:
    """One closed-loop run of the SIL firmware for `design_p` against the faithful plant of `plant_p`.
    Returns the raw log (time, theta, torque, mode, est, ...) plus plant_bounds (node arc positions [m]),
    reason and plant description."""
    from rodctl.build.sil_build import build_sil
    from rodctl.sim.plant import SilController, faithful_plant, run_closed_loop

    if progress:
        progress(f"{label}: compiling the firmware", 0.0)
    ctl = SilController(build_sil(design_p))
    pl = faithful_plant(plant_p, input_mode="duty", at_rest=False)  # its state is set below
    nq = pl.N
    if task == "balance":
        pl.set_state(np.full(nq, math.pi - math.radians(start_deg)), np.zeros(nq))
        arm = 1
    elif task == "swingup":
        pl.set_state(np.zeros(nq), np.zeros(nq))
        arm = 2
    else:
        raise InputError(f"unknown task {task!r}; one of {', '.join(TASKS)}")
    dt = ctl.period
    periods = int(round(seconds / dt))
    # chunk boundaries: progress every 0.5 s, and the disturbance window's edges
    cuts = set(range(0, periods, max(1, int(round(0.5 / dt))))) | {periods}
    if disturbance is not None:
        if task != "balance":
            raise InputError("a disturbance case runs on the balance task only")
        T, t0, dur = disturbance
        k0, k1 = int(round(t0 / dt)), int(round((t0 + dur) / dt))
        cuts |= {min(k0, periods), min(k1, periods)}
    cuts = sorted(cuts)
    parts = []
    for a, b in zip(cuts[:-1], cuts[1:]):
        if disturbance is not None:
            pl.external_torque = disturbance[0] if k0 <= a < k1 else 0.0
        parts.append(run_closed_loop(pl, ctl, b - a, arm_mode=arm, delay_periods=delay_periods, reset=(a == 0)))
        if progress:
            progress(label, b / periods)
    pl.external_torque = 0.0
    log = {k: np.concatenate([q[k] for q in parts]) for k in parts[0] if isinstance(parts[0][k], np.ndarray)}
    log["reason"] = int(ctl.lib.rod_sil_reason()) if hasattr(ctl.lib, "rod_sil_reason") else 0
    log["plant_bounds"] = pl.node_arc()
    log["plant"] = repr(pl)
    log["plant_label"] = pl.label()
    log["controller_edges"] = ctl.edges
    return log


def summarize(log: dict, task: str, strict: bool = False) -> dict[str, Any]:
    """The numbers of one run and its verdict (JSON-serializable; inf/nan as None)."""
    t, theta, mode = log["time"], log["theta"], log["mode"]
    dev = _deviation_deg(theta).max(axis=1)
    fault = bool((mode == MODE_FAULT).any())
    caught = np.where(mode == MODE_BALANCE)[0]
    caught_at = float(t[caught[0]]) if (task == "swingup" and len(caught)) else None
    start = (caught_at if caught_at is not None else math.inf) if task == "swingup" else 0.0
    after = t >= start
    dt = float(t[1] - t[0]) if len(t) > 1 else 1e-3
    nfin = max(1, int(round(FINAL_WINDOW_S / dt)))
    final = float(dev[-nfin:].max())
    nheld = max(1, int(round(HELD_WINDOW_S / dt)))
    held = float(np.mean(dev[-nheld:] <= ROBUST_BAND_DEG)) if after[-nheld:].all() else 0.0
    outside = np.where(after & (dev > SETTLE_DEG))[0]
    if fault or final > SETTLE_DEG or not after.any():
        settle = math.inf
    else:
        settle = max(0.0, float(t[outside[-1] + 1] - start)) if len(outside) else 0.0
    turns = float(np.max(np.abs(theta[:, 0] - theta[0, 0])) / (2 * math.pi))
    r: dict[str, Any] = {
        "task": task,
        "settle_s": settle,
        "final_dev_deg": final,
        "held_fraction": held,
        "max_dev_deg": float(dev[after].max()) if after.any() else float(dev.max()),
        "peak_torque_Nm": float(np.max(np.abs(log["torque"][after]))) if after.any() else 0.0,
        "caught_at_s": caught_at,
        "fault": fault,
        "fault_reason": int(log["reason"]) if fault else 0,
        "base_turns_max": turns,
        "est_rms_deg": math.nan,
        "simulated_s": float(t[-1] + dt) if len(t) else 0.0,
    }
    n = log["controller_edges"]
    use = (mode == MODE_BALANCE) & (t >= (start if math.isfinite(start) else math.inf) + 0.5)
    if use.any():
        from rodctl.sim.scenarios import resample_edges  # scenarios imports this module at load

        err = log["est"][use, :n].astype(float) - resample_edges(theta[use], n, log["plant_bounds"])
        err = np.mod(err + np.pi, 2 * np.pi) - np.pi
        r["est_rms_deg"] = float(np.degrees(np.sqrt(np.mean(err**2))))
    if task == "balance":
        ok = not fault and final <= ROBUST_BAND_DEG
        if strict:
            ok = not fault and settle <= BALANCE_SETTLE_GOAL_S
    else:
        ok = caught_at is not None and caught_at <= SWINGUP_CATCH_LIMIT_S and not fault and final <= ROBUST_BAND_DEG
        if strict:
            ok = (caught_at is not None and caught_at <= SWINGUP_CATCH_GOAL_S and not fault
                  and settle <= SWINGUP_SETTLE_GOAL_S and turns <= SWINGUP_TURNS_GOAL)
    r["passed"] = bool(ok)
    return r


def _json_safe(d: dict) -> dict:
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in d.items()}


def straightest_deg(plant: Params) -> float | None:
    """How close to upright a steady base torque can hold this plant's rod: its straightest static shape's
    largest edge deviation [deg]; 0 for a rod straight at rest, None for a curved one with no static shape near
    upright (past its clamped buckling length: the buckling label says it)."""
    if plant["rod"]["rest_curvature"] == 0.0:
        return 0.0
    from rodctl.sim.statics import straightest_shape

    try:
        return straightest_shape(plant).largest_deviation_deg
    except ArithmeticError:
        return None


def run_case(params: Params, case: Case, task: str, *, extra_plant_overrides=(), seconds: float | None = None,
             progress: Callable[[str, float], None] | None = None, keep_log: bool = False,
             start_deg: float = BALANCE_START_DEG, plant_params: Params | None = None) -> dict[str, Any]:
    """Run one case of the matrix: the firmware designed from params (+ design_overrides) against the
    faithful plant (params' [plant] table + plant_overrides + extra_plant_overrides).

    plant_params: the true rod when it is not the one the design believes in (a hidden rig, `rodctl
    robustness --plant`): its physics and [plant] table make the plant, and the case's relative
    overrides ("*=") scale its values, not the design's.

    Returns a JSON-serializable dict: passed, case, task, criterion, settle_s, final_dev_deg, max_dev_deg,
    peak_torque_Nm, caught_at_s (swing-up), fault_reason (0 none), base_turns_max, est_rms_deg, plant,
    buckling_ratio (the plant's rod above the hub over its clamped buckling length, rodgains.buckling),
    straightest_deg (the largest edge deviation of the straightest static shape the plant's rod has upright:
    0 for a straight rod, rodctl.sim.statics).
    Non-finite numbers are None. keep_log=True adds the raw log under "log" (not JSON-serializable).
    start_deg: where the balance task releases the rod, from upright [deg].
    """
    if task not in TASKS:
        raise InputError(f"unknown task {task!r}; one of {', '.join(TASKS)}")
    if task not in case.tasks:
        raise InputError(f"case {case.name} does not apply to the {task} task")
    design_p = apply_overrides(params, case.design_overrides)
    plant_p = apply_overrides(params if plant_params is None else plant_params,
                              tuple(case.plant_overrides) + tuple(extra_plant_overrides))
    T = seconds or DEFAULT_SECONDS[task]
    log = simulate(design_p, plant_p, task, seconds=T, delay_periods=case.delay_periods,
                   disturbance=case.disturbance, progress=progress, label=f"{case.name}/{task}", start_deg=start_deg)
    r = summarize(log, task, strict=case.strict)
    r = _json_safe(r)
    r.update(case=case.name, title=case.title, criterion=criterion(task, case.strict), plant=log["plant_label"],
             buckling_ratio=clamped_ratio(plant_p), straightest_deg=straightest_deg(plant_p))
    if keep_log:
        r["log"] = log
    return r


def run_matrix(params: Params, tasks=TASKS, names=None, *, progress=None, seconds=None,
               plant_params: Params | None = None) -> list[dict[str, Any]]:
    """Every case of a set (default: the whole matrix) for every task; one dict per run.
    plant_params: the true rod, if not params' own (run_case)."""
    out = []
    for task in tasks:
        for case in cases_for(task, names):
            out.append(run_case(params, case, task, progress=progress, seconds=seconds, plant_params=plant_params))
    return out


LONGEST_START_DEG = 10.0
# The design is per rod: for the longest-rod measure each length gets the first of these design
# variants (overrides of the parameter file) that holds it. Measured (docs/scenarios.md, "Where the paper's design
# fails"), on the soft-shaft weights: their base-torque disturbance state explains the torque that
# holds a bent rod on a still shaft as a disturbance, so past ~1.05 L_crit the rod buckles unseen. Without it 1.06 holds;
# with process noise 300 on the rates as well 1.07 to 1.10 (1.08 and 1.16 only at model order 6).
# Those were measured on issue 8's weights; on the tuned weights the same variants reach 1.08,
# so issue 8's weights are variants too (with them, 1.10 again). The default's stiff shaft clamps the
# rod's foot, and a clamped rod past its critical length buckles: the stiff default holds 1.05 and no
# observer variant of it 1.06, so the soft-shaft weights (docs/tuned/low-ripple.toml's) are variants too.
ISSUE8_WEIGHTS = ("lqr.q_angle=10.0", "lqr.q_shaft_angle=0.0", "lqr.q_rate=0.01",
                  "observer.process_noise_angle=0.05",
                  "observer.measurement_noise=3e-5", "lqr.friction_compensation=0.0075")
_LONG_ROD_OBSERVERS: tuple[tuple[str, ...], ...] = (
    ("observer.process_noise_torque=0.0",),
    ("observer.process_noise_torque=0.0", "observer.process_noise_rate=300.0"),
    ("observer.process_noise_torque=0.0", "observer.process_noise_rate=300.0", "rod.edges=6"),
)
LONG_ROD_DESIGNS: tuple[tuple[str, ...], ...] = ((),) + _LONG_ROD_OBSERVERS + tuple(
    w + v for w in (SOFT_SHAFT_WEIGHTS, ISSUE8_WEIGHTS) for v in ((),) + _LONG_ROD_OBSERVERS)

# With the tip IMU the estimate sees the bend, and what stops a long rod is the stiff shaft again: the default
# (q_shaft_angle 325) falls from 1.20 L_crit, and so does the soft shaft at the default rate weight. A free shaft
# with ~50 x the rate weight lets the base swing the rod back (measured, no play: every length 1.00 to 1.30 within
# 1.2 deg at 20 s, 1.32 falls; q_rate 0.02 alike, 0.005 falls at 1.30). Not the default: on Table I's rod it is
# the rod ten times more damped that falls (docs/sensors.md).
IMU_LONG_ROD_WEIGHTS = ("lqr.q_shaft_angle=0.0", "lqr.q_rate=0.01")
IMU_LONG_ROD_DESIGNS: tuple[tuple[str, ...], ...] = ((), IMU_LONG_ROD_WEIGHTS)


def balances(params: Params, length: float, start_deg: float = LONGEST_START_DEG,
             designs: tuple[tuple[str, ...], ...] = ((),), band_deg: float = SETTLE_DEG) -> tuple[str, ...] | None:
    """Does a design for a rod of this length [m] (same hub, same plant table) hold it from start_deg,
    every link within band_deg at the end, no FAULT? Tries each of `designs` (design-only overrides,
    applied to the design and never to the plant) in order; returns the first that holds (() for the
    parameter file's own design, so test `is not None`), else None."""
    from rodgains.errors import DesignRefused

    p = params.with_overrides(f"rod.length={length!r}")
    for ovs in designs:
        try:
            r = run_case(p, Case("longest", "longest rod", design_overrides=tuple(ovs)), "balance", start_deg=start_deg)
        except DesignRefused:
            continue
        if r["fault_reason"] == 0 and r["final_dev_deg"] <= band_deg:
            return tuple(ovs)
    return None


def longest_balanced(params: Params, lo: float = 1.0, hi: float = 1.6, step: float = 0.01, progress=None,
                     designs: tuple[tuple[str, ...], ...] = ((),), band_deg: float = SETTLE_DEG) -> dict:
    """The longest rod (as a ratio to the continuum critical length, Greenhill) a design holds from
    LONGEST_START_DEG on the faithful plant, with no gap below it: lengths lo, lo + step, ... up to hi,
    stopping at the first that no design holds. (Not a bisection: near the limit pass/fail is not
    monotone in length; with LONG_ROD_DESIGNS 1.10 holds, 1.11 to 1.15 fail, 1.16 holds.)
    designs: the design variants tried at each length (LONG_ROD_DESIGNS: the design redone for the
    long rod; default: the parameter file's design only). band_deg: "held" = every link within it at the
    end (the gearbox's play keeps the rod off the 1 deg default; ROBUST_BAND_DEG then). Returns ratio, length_m, critical_length_m,
    design (the overrides that held the longest rod), first_failure (ratio), note."""
    from rodgains.buckling import greenhill_length

    lc = greenhill_length(params)
    best, held, first_fail = None, None, None
    k = 0
    while lo + k * step <= hi + 1e-9:
        ratio = round(lo + k * step, 6)
        if progress:
            progress(f"L = {ratio:.3f} L_crit", (ratio - lo) / max(hi - lo, 1e-9))
        got = balances(params, ratio * lc, designs=designs, band_deg=band_deg)
        if got is None:
            first_fail = ratio
            break
        best, held = ratio, got
        k += 1
    if best is None:
        return {"ratio": None, "length_m": None, "critical_length_m": lc, "design": None, "first_failure": lo,
                "note": f"fails at {lo:g} x L_crit"}
    return {"ratio": best, "length_m": best * lc, "critical_length_m": lc, "design": list(held),
            "first_failure": first_fail, "note": "" if first_fail is not None else f"holds up to {hi:g} (searched)"}


def table_markdown(rows: list[dict[str, Any]]) -> str:
    """The matrix as a markdown table, one row per case, both tasks side by side."""
    from rodctl.sim.figures import fmt

    by = {}
    for r in rows:
        by.setdefault(r["case"], {})[r["task"]] = r
    out = ["| case | balance: final [deg] | settle 1 deg [s] | result | swing-up: caught [s] | final [deg] | "
           "base turns | result |", "|---|---|---|---|---|---|---|---|"]
    nan = math.nan
    for name, d in by.items():
        b, s = d.get("balance"), d.get("swingup")

        def v(r, k, nd=2):
            if r is None:
                return "-"
            x = r.get(k)
            return fmt(nan if x is None else x, nd) if x is not None or k != "caught_at_s" else "never"

        def res(r):
            if r is None:
                return "-"
            return "pass" if r["passed"] else "**fail**" + (f" (FAULT {r['fault_reason']})" if r["fault_reason"] else "")

        out.append(f"| {name} | {v(b, 'final_dev_deg')} | {v(b, 'settle_s')} | {res(b)} | {v(s, 'caught_at_s')} | "
                   f"{v(s, 'final_dev_deg')} | {v(s, 'base_turns_max')} | {res(s)} |")
    return "\n".join(out) + "\n"
