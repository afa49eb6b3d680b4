"""Output-error fit of the rig's motor and rod parameters against the project's C plant.

Model: the plant the parameter file describes (sim.plant.faithful_plant: its [plant] table, Coulomb
friction, hub), driven by the duty each logged period held (the firmware's own translation of its
torque command, so the fit sees the driver, back-EMF and current limit as the rig did), started at
rest at the first logged count (`set_start`). The residual is simulated minus measured theta_1 at
every control period, in units of the encoder's quantization noise (one count / sqrt(12)).

Where in its first count each record starts is one more unknown per record (`start_counts`): a
record starts where the last left the rig, and a tenth of a degree there (a quarter count) moved the
viscous friction by 6 % on a matched plant (docs/identification.md).

Fitted (FIT_PARAMS): rotor inertia, viscous and Coulomb friction, a torque-constant scale (k_t and
k_e together: equal in SI units), and the rod's Young's modulus and damping. Length, width,
thickness and density stay as the user measured them.

scipy.optimize.least_squares (trust region, bounded) runs from several starts; the best cost wins.
The 95 % intervals come from the Jacobian at the optimum (cov = s^2 (J'J)^-1); identifiability from
the singular values of the column-scaled Jacobian and the parameter correlations. The last
VALIDATION_FRACTION of every record never enters the fit: its percent fit is the validation.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
from rodgains.errors import InputError

from rodctl.ident.experiments import Record

VALIDATION_FRACTION = 0.25
MIN_SECONDS = 1.0  # of IDENTIFY data in all records together
MIN_COUNTS_MOVED = 4  # theta_1 must move more than this many encoder counts
SATURATED_FRACTION = 0.05  # of samples at the duty or torque ceiling
CORRELATION_LIMIT = 0.95
UNIDENTIFIABLE_REL_CI = 0.5  # a 95 % half-width beyond 50 % of the value: not identifiable
# The search's plant: the parameter file's rod, as the inextensible N-link with at most this many
# flexible edges (a DER plant integrates at ~12 steps per control period, ~5x slower). Its mismatch
# with a DER rig biases the viscous friction: on 30 random DER N = 30 rigs it came out -5.8 % to
# +7.5 % (5 of 30 beyond 5 %), so the best start is then polished on the file's own plant
# (`polish` in fit()), which brought those rigs within 1.5 % (docs/identification.md).
FAST_MODEL_EDGES = 20
POLISH_NFEV = 30  # simulations the polish may take: it starts next to the optimum
STEP = 1e-4  # forward-difference step, relative to max(1, |x|) in the optimizer's scaled units
STILL_WINDOW = 25  # periods each side: a sample whose count did not change within them is "still"


class NotIdentifiable(InputError):
    def __init__(self, why: str):
        super().__init__(f"not identifiable: {why}")


@dataclass(frozen=True)
class FitParam:
    name: str
    key: str | None  # section.key in the parameter file (None: the torque-constant scale)
    unit: str
    bounds: tuple[float, float]  # where the optimizer may look [unit]
    physical: tuple[float, float]  # outside this the value is flagged, not written [unit]
    typical: float  # scale when the nominal value is 0 [unit]
    tolerance_doc: str = ""


FIT_PARAMS = (
    FitParam("rotor_inertia", "motor.rotor_inertia", "kg m^2", (1e-9, 1e-4), (1e-8, 2e-5), 5e-7),
    FitParam("viscous_friction", "motor.viscous_friction", "N m s/rad", (0.0, 0.05), (0.0, 0.02), 5e-4),
    FitParam("coulomb_friction", "motor.coulomb_friction", "N m", (0.0, 0.1), (0.0, 0.05), 5e-3),
    FitParam("torque_constant_scale", None, "-", (0.2, 5.0), (0.5, 2.0), 1.0),
    FitParam("youngs_modulus", "rod.youngs_modulus", "Pa", (1e4, 1e8), (5e4, 1e7), 6e5),
    FitParam("damping", "rod.damping", "N m s/rad", (0.0, 0.1), (0.0, 0.05), 1e-3),
    # between the encoder and the rod: the gearbox's play (a torque reversal crosses it) and where the
    # boot zero sits from the rod's true hanging (the rod's free swings center on the latter)
    FitParam("backlash", "gearbox.backlash_deg", "deg", (0.0, 6.0), (0.0, 5.0), 1.0),
    FitParam("zero_error", "encoder.zero_error_deg", "deg", (-3.0, 3.0), (-2.0, 2.0), 0.2),
)
NAMES = tuple(p.name for p in FIT_PARAMS)


def fit_model(params, exact: bool = False) -> tuple[str, ...]:
    """--set overrides that turn the parameter file's [plant] into the plant the fit simulates."""
    pp = params["plant"]
    if exact or (pp["model"] == "inextensible" and pp["edges"] <= FAST_MODEL_EDGES):
        return ()
    return ("plant.model=inextensible", f"plant.edges={min(pp['edges'], FAST_MODEL_EDGES)}")


def nominal_values(params) -> dict[str, float]:
    out = {}
    for fp in FIT_PARAMS:
        if fp.key is None:
            out[fp.name] = 1.0
        else:
            s, k = fp.key.split(".")
            out[fp.name] = float(params[s][k])
    return out


def with_values(params, values: dict[str, float]):
    """The parameter file with these fitted values (the scale applied to k_t and k_e)."""
    m = params["motor"]
    sets = [f"{fp.key}={float(values[fp.name])!r}" for fp in FIT_PARAMS if fp.key is not None and fp.name in values]
    if "torque_constant_scale" in values:
        s = float(values["torque_constant_scale"])
        sets += [f"motor.torque_constant={m['torque_constant'] * s!r}",
                 f"motor.back_emf_constant={m['back_emf_constant'] * s!r}"]
    return params.with_overrides(*sets)


class Simulator:
    """Replays records through the plant of a parameter set: one plant per evaluation, each record
    from rest at its first measured angle, in C (the plant's closed-loop runner with the replay
    controller of native/rod_replay.c)."""

    def __init__(self, records: list[Record]):
        self.records = records
        self._duty = [np.ascontiguousarray(r.duty, np.float32) for r in records]
        self._torque = [np.ascontiguousarray(r.torque, np.float32) for r in records]
        self._ctl = replay_controller()

    def run(self, params, starts: np.ndarray | None = None) -> list[np.ndarray]:
        """theta_1 as the encoder would read it, per record. starts: where each record's encoder side
        starts within its first count [counts, -0.5 to 0.5] (None: in its middle)."""
        import ctypes

        from rodctl.sim.plant import SimulationError, faithful_plant, run_closed_loop

        plant = faithful_plant(params, input_mode="duty")
        cpr = float(params.counts_per_rev)
        zero = math.radians(params["encoder"]["zero_error_deg"])
        out = []
        fp = ctypes.POINTER(ctypes.c_float)
        for i, (r, duty, torque) in enumerate(zip(self.records, self._duty, self._torque)):
            within = 0.0 if starts is None else float(starts[i])
            theta0 = 2 * math.pi * (r.count[0] + within) / cpr - zero
            set_start(plant, theta0)
            plant.time = 0.0
            self._ctl.lib.rod_replay_load(duty.ctypes.data_as(fp), torque.ctypes.data_as(fp), len(duty),
                                          ctypes.c_float(r.period))
            try:
                log = run_closed_loop(plant, self._ctl, len(duty), reset=False)
                # what the encoder reads: the motor side (or the hub, for an output-shaft encoder), off by the zero
                th = (log["theta"][:, 0] if plant.config.encoder_on_shaft else log["motor"]) + zero
            except SimulationError:  # the plant left its model (a wild trial point): a large residual
                th = np.full(len(duty), theta0 + 10.0)
            out.append(th)
        return out


def set_start(plant, theta_enc: float) -> None:
    """The rig at rest with its encoder side at theta_enc [rad, zero removed], the rod straight.

    The rod hangs wherever the play lets it: straight down if the gap around the motor side reaches
    that far, otherwise against the nearer flank, where the motor's dry friction holds it. A record
    starts where the last experiment left the rig, most often with the motor on a flank and the rod
    a few tenths of a degree off hanging; starting the rod at the encoder's angle instead puts it up
    to half the gap off its rest, and the fit then tunes the friction to a swing the rig never made.
    With the encoder on the output shaft (or no gearbox) the rod is where the encoder says."""
    c = plant.config
    if not c.compliant or c.encoder_on_shaft:
        plant.set_state(np.full(plant.N, theta_enc))
        return
    half = 0.5 * c.backlash
    hanging = 2.0 * math.pi * round(theta_enc / (2.0 * math.pi))  # the count may be turns from the boot zero
    plant.set_state(np.full(plant.N, min(max(hanging, theta_enc - half), theta_enc + half)))
    plant.set_motor_state(theta_enc)


_REPLAY = None


def replay_controller():
    """The replay controller library (built once, cached by content like the SIL)."""
    global _REPLAY
    if _REPLAY is None:
        import ctypes
        from pathlib import Path

        from rodctl.build.native import compile_shared
        from rodctl.sim.plant import SilController

        lib = compile_shared("rod_replay", [Path(__file__).parent / "native" / "rod_replay.c"], flags=("-O2",))
        ctl = SilController(lib)
        ctl.lib.rod_replay_load.restype = None
        ctl.lib.rod_replay_load.argtypes = [ctypes.POINTER(ctypes.c_float), ctypes.POINTER(ctypes.c_float),
                                            ctypes.c_int64, ctypes.c_float]
        _REPLAY = ctl
    return _REPLAY


def measured_theta(rec: Record, cpr: float) -> np.ndarray:
    return 2 * math.pi * rec.count / cpr


def moving_mask(count: np.ndarray, window: int = STILL_WINDOW) -> np.ndarray:
    """True where the count changed within +-window periods. While the rod stands still (stuck in
    its Coulomb band) one count hides up to a count of offset for seconds: that quantization error
    is one constant, not noise, and fitting it would tune the friction to land inside the right
    count instead of to the motion. Those samples are left out of the residual."""
    from numpy.lib.stride_tricks import sliding_window_view

    c = np.pad(np.asarray(count, np.int64), window, mode="edge")
    w = sliding_window_view(c, 2 * window + 1)
    return w.max(axis=1) != w.min(axis=1)


# ---- refusals --------------------------------------------------------------------------------------


def check_identifiable(records: list[Record], params) -> None:
    """Refuse data that cannot identify anything: no IDENTIFY data, too short, no motion, saturated."""
    if not records:
        raise NotIdentifiable("no IDENTIFY data in the logs (mode 5 rows): record them with `rodctl identify --port`")
    seconds = sum(r.seconds for r in records)
    if seconds < MIN_SECONDS:
        raise NotIdentifiable(f"too short: {seconds:.2f} s of excitation, at least {MIN_SECONDS:g} s needed")
    peak = max(float(np.max(np.abs(r.torque))) if len(r.torque) else 0.0 for r in records)
    if peak < 1e-4:
        raise NotIdentifiable(f"no excitation: the torque command never exceeds {peak * 1e3:.3g} mN m")
    moved = max(int(np.ptp(r.count)) if len(r.count) else 0 for r in records)
    if moved <= MIN_COUNTS_MOVED:
        raise NotIdentifiable(f"no excitation: theta_1 moved only {moved} encoder counts")
    duty_max = params["driver"]["max_duty"]
    tau_max = params.torque_max
    n = sum(len(r.duty) for r in records)
    at_limit = sum(int(np.sum((np.abs(r.duty) >= 0.999 * duty_max) | (np.abs(r.torque) >= 0.999 * tau_max)))
                   for r in records)
    if at_limit > SATURATED_FRACTION * n:
        raise NotIdentifiable(f"saturated: the duty or torque is at its limit in {100 * at_limit / n:.0f} % of the "
                              f"samples (> {100 * SATURATED_FRACTION:g} %); lower the amplitude")


# ---- the fit ------------------------------------------------------------------------------------------


@dataclass
class FitResult:
    nominal: dict[str, float]
    values: dict[str, float]
    ci95: dict[str, float]  # half-widths [unit]
    fitted: tuple[str, ...]
    identifiable: dict[str, bool]
    why: dict[str, str]  # per parameter: why it is not identifiable (or "")
    out_of_range: dict[str, str]
    correlation: np.ndarray
    singular_values: np.ndarray
    validation_fit_pct: float
    fit_pct: float
    rms_counts: float
    starts: list[dict]
    seconds: float
    evaluations: int
    theta_meas: list[np.ndarray] = field(repr=False, default_factory=list)
    theta_sim: list[np.ndarray] = field(repr=False, default_factory=list)
    split: list[int] = field(default_factory=list)
    record_names: list[str] = field(default_factory=list)
    period: float = 1e-3
    counts_per_rev: float = 979.2
    model: tuple[str, ...] = ()
    start_counts: list[float] = field(default_factory=list)  # each record's start within its first count [counts]


def _scales(nominal: dict[str, float]) -> dict[str, float]:
    return {fp.name: (nominal[fp.name] if nominal[fp.name] > 0 else fp.typical) for fp in FIT_PARAMS}


def validation_text(pct: float) -> str:
    """The held-out data's percent fit in words: NaN when that data holds still (a record that ended at rest),
    where a percent fit means nothing."""
    return f"{pct:.1f} % fit" if math.isfinite(pct) else "none: the held-out data does not move"


def percent_fit(meas: np.ndarray, sim: np.ndarray) -> float:
    """100 (1 - |y - y_sim| / |y - mean y|): 100 is perfect, 0 is no better than the mean."""
    if not len(meas) or np.ptp(meas) == 0:  # still: the mean's rounding would make any fit -1e17 %
        return float("nan")
    den = np.linalg.norm(meas - meas.mean())
    return float(100.0 * (1.0 - np.linalg.norm(meas - sim) / den))


def fit(records: list[Record], params, *, fitted: tuple[str, ...] = NAMES, starts: int = 3,
        progress=None, max_nfev: int = 60, model: tuple[str, ...] | None = None, polish: bool = True) -> FitResult:
    """Identify `fitted` (names of FIT_PARAMS) from the records, the others fixed at params' values.
    model: --set overrides of the plant the starts search on (default fit_model(params): the fast rod).
    polish: when that plant is not the parameter file's own, refine the best start on the file's plant
    (what the rig is taken to be); the intervals and the report then come from that plant."""
    from scipy.optimize import least_squares

    check_identifiable(records, params)
    model = fit_model(params) if model is None else tuple(model)
    t0 = time.monotonic()
    nominal = nominal_values(params)
    scale = _scales(nominal)
    fps = [fp for fp in FIT_PARAMS if fp.name in fitted]
    cpr = float(params.counts_per_rev)
    q = 2 * math.pi / cpr / math.sqrt(12.0)  # quantization noise of theta_1 [rad]
    meas = [measured_theta(r, cpr) for r in records]
    split = [max(1, int(round(len(r.count) * (1 - VALIDATION_FRACTION)))) for r in records]
    use = [moving_mask(r.count)[:k] for r, k in zip(records, split)]
    sim = Simulator(records)
    evals = [0]
    pg, nr = len(fps), len(records)
    rows = [int(u.sum()) for u in use]
    row_of = np.repeat(np.arange(nr), rows)  # the record each residual row comes from

    def values_of(x) -> dict[str, float]:
        v = dict(nominal)
        v.update({fp.name: float(xi) * scale[fp.name] for fp, xi in zip(fps, x[:pg])})
        return v

    def simulate(x) -> list[np.ndarray]:
        evals[0] += 1
        return sim.run(with_values(params, values_of(x)).with_overrides(*model), starts=x[pg:])

    last = [None, None]  # least_squares asks for the Jacobian where it has just evaluated the residual

    def residual(x) -> np.ndarray:
        if last[0] is not None and np.array_equal(last[0], x):
            return last[1].copy()
        th = simulate(x)
        r = np.concatenate([(s[:k] - m[:k])[u] / q for s, m, k, u in zip(th, meas, split, use)])
        last[0], last[1] = np.array(x, copy=True), r
        return r.copy()

    def jacobian(x) -> np.ndarray:
        """Forward differences; the records' own start places share one simulation (each moves
        only its own record's rows)."""
        f0 = residual(x)
        J = np.empty((len(f0), len(x)))
        step = STEP * np.maximum(1.0, np.abs(x))
        h = np.where(x + step <= hi, step, -step)
        for j in range(pg):
            xj = x.copy()
            xj[j] += h[j]
            J[:, j] = (residual(xj) - f0) / h[j]
        xs = x.copy()
        xs[pg:] += h[pg:]
        d = residual(xs) - f0
        J[:, pg:] = 0.0
        J[np.arange(len(f0)), pg + row_of] = d / h[pg + row_of]
        return J

    # Each record's encoder side starts somewhere in its first count: one unknown per record.
    lo = np.array([fp.bounds[0] / scale[fp.name] for fp in fps] + [-0.5] * nr)
    hi = np.array([fp.bounds[1] / scale[fp.name] for fp in fps] + [0.5] * nr)
    x_nom = np.clip(np.array([nominal[fp.name] / scale[fp.name] for fp in fps] + [0.0] * nr), lo, hi)
    # Deterministic starts: the nominal point, then every parameter low, then high (rotor and rod
    # guesses are often off by tens of percent, the friction terms by factors).
    low, high = x_nom.copy(), x_nom.copy()
    low[:pg], high[:pg] = x_nom[:pg] * 0.6, x_nom[:pg] * 1.6
    candidates = [x_nom, np.clip(low, lo, hi), np.clip(high, lo, hi)]
    tried = []

    def solve(kind: str, x0, nfev: int):
        x_scale = np.concatenate([np.maximum(x0[:pg], 0.05), np.full(nr, 0.25)])
        r = least_squares(residual, x0, jac=jacobian, bounds=(lo, hi), x_scale=x_scale, max_nfev=nfev, method="trf")
        tried.append({kind: {fp.name: float(a * scale[fp.name]) for fp, a in zip(fps, x0)},
                      "cost": float(r.cost), "nfev": int(r.nfev)})
        return r

    best = None
    for i, x0 in enumerate(candidates[:max(1, starts)]):
        if progress:
            progress(f"fit: start {i + 1}/{min(starts, len(candidates))}")
        r = solve("start", x0, max_nfev)
        if best is None or r.cost < best.cost:
            best = r
    if polish and model:
        model = ()  # simulate() reads it: from here on, the file's own plant
        if progress:
            progress("fit: polish on the parameter file's plant")
        best = solve("polish", best.x, POLISH_NFEV)
    x = best.x
    J = np.asarray(best.jac)
    m = J.shape[0]
    s2 = 2 * best.cost / max(1, m - J.shape[1])
    # the intervals allow for the records' start places (the whole covariance's block); the
    # identifiability is the fitted parameters' own
    cov = (s2 * np.linalg.pinv(J.T @ J))[:pg, :pg]
    J = J[:, :pg]
    p = pg
    jn = np.linalg.norm(J, axis=0)
    jn_safe = np.where(jn > 0, jn, 1.0)
    Js = J / jn_safe
    sv = np.linalg.svd(Js, compute_uv=False)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    corr = cov / np.outer(np.where(sd > 0, sd, 1), np.where(sd > 0, sd, 1))
    values = values_of(x)
    ci = {fp.name: float(1.96 * sd[i] * scale[fp.name]) for i, fp in enumerate(fps)}
    identifiable, why = {}, {}
    for i, fp in enumerate(fps):
        v = values[fp.name]
        rel = ci[fp.name] / abs(v) if v != 0 else math.inf
        reasons = []
        if jn[i] == 0 or jn[i] < 1e-6 * jn.max():
            reasons.append("theta_1 does not respond to it in these logs")
        elif rel > UNIDENTIFIABLE_REL_CI:
            partners = [(fps[j].name, corr[i, j]) for j in range(p) if j != i and abs(corr[i, j]) > CORRELATION_LIMIT]
            if partners:
                with_ = ", ".join(f"{n} (r = {r:+.3f})" for n, r in partners)
                reasons.append(f"95 % interval +-{100 * rel:.0f} % of the value; correlated with {with_}")
            else:
                reasons.append(f"95 % interval +-{100 * rel:.0f} % of the value; its effect on theta_1 is "
                               f"{jn[i] / jn.max():.1e} of the strongest parameter's")
        identifiable[fp.name] = not reasons
        why[fp.name] = "; ".join(reasons)
    out_of_range = {}
    for fp in fps:
        lo_p, hi_p = fp.physical
        v = values[fp.name]
        if not lo_p <= v <= hi_p:
            out_of_range[fp.name] = f"{v:.4g} {fp.unit} is outside the physical range [{lo_p:g}, {hi_p:g}]"
    th = simulate(x)
    val_m = np.concatenate([mm[k:] for mm, k in zip(meas, split)])
    val_s = np.concatenate([ss[k:] for ss, k in zip(th, split)])
    fit_m = np.concatenate([mm[:k] for mm, k in zip(meas, split)])
    fit_s = np.concatenate([ss[:k] for ss, k in zip(th, split)])
    return FitResult(
        nominal=nominal, values=values, ci95=ci, fitted=tuple(fp.name for fp in fps), identifiable=identifiable,
        why=why, out_of_range=out_of_range, correlation=corr, singular_values=sv,
        validation_fit_pct=percent_fit(val_m, val_s),
        fit_pct=percent_fit(fit_m, fit_s), rms_counts=float(np.sqrt(2 * best.cost / m) * q * cpr / (2 * math.pi)),
        starts=tried, seconds=time.monotonic() - t0, evaluations=evals[0], theta_meas=meas, theta_sim=th,
        split=split, record_names=[r.name for r in records], period=records[0].period, counts_per_rev=cpr,
        model=model, start_counts=[float(v) for v in x[pg:]])


def identifiability_text(res: FitResult) -> list[str]:
    """Which parameters the data cannot separate, and why (lines for the report)."""
    lines = []
    names = list(res.fitted)
    sv = res.singular_values
    cond = float(sv[0] / sv[-1]) if sv[-1] > 0 else math.inf
    lines.append(f"singular values of the scaled Jacobian: {', '.join(f'{s:.3g}' for s in sv)} "
                 f"(condition {cond:.3g})")
    pairs = [(names[i], names[j], res.correlation[i, j]) for i in range(len(names)) for j in range(i + 1, len(names))
             if abs(res.correlation[i, j]) > CORRELATION_LIMIT]
    for a, b, r in pairs:
        lines.append(f"{a} and {b} are correlated (r = {r:+.3f}): the logs constrain a combination of them, not each")
    for n in names:
        if not res.identifiable[n]:
            lines.append(f"{n}: not identifiable ({res.why[n]})")
    if not pairs and all(res.identifiable.values()):
        lines.append(f"every parameter separable: largest |correlation| "
                     f"{max((abs(res.correlation[i, j]) for i in range(len(names)) for j in range(len(names)) if i != j), default=0):.3f}")
    return lines


def report_lines(res: FitResult) -> list[str]:
    out = []
    for fp in FIT_PARAMS:
        if fp.name not in res.fitted:
            continue
        v, ci, nom = res.values[fp.name], res.ci95[fp.name], res.nominal[fp.name]
        flag = ""
        if fp.name in res.out_of_range:
            flag = "  OUT OF PHYSICAL RANGE"
        elif not res.identifiable[fp.name]:
            flag = "  not identifiable"
        out.append(f"  {fp.name:22s} {v:11.4g} +- {ci:9.3g} {fp.unit:10s} (nominal {nom:.4g}){flag}")
    return out
