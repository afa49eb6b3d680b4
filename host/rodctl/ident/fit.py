"""Output-error fit of the rig's motor and rod parameters against the project's C plant.

Model: the plant the parameter file describes (sim.plant.faithful_plant: its [plant] table, Coulomb
friction, hub), driven by the duty each logged period held (the firmware's own translation of its
torque command, so the fit sees the driver, back-EMF and current limit as the rig did), started at
rest at the first logged count (`Plant.start_hanging`). The residual is simulated minus measured theta_1 at
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
    # a 95 % half-width within this is identified whatever the value [unit]: a rig with no play, or a boot zero
    # taken exactly, is measured as such (+-0.02 deg around 0 is "50 x its value" to a relative rule, which kept
    # the nominal 1 deg of play and 0.18 deg of zero error in the file)
    known_within: float = 0.0


FIT_PARAMS = (
    FitParam("rotor_inertia", "motor.rotor_inertia", "kg m^2", (1e-9, 1e-4), (1e-8, 2e-5), 5e-7),
    FitParam("viscous_friction", "motor.viscous_friction", "N m s/rad", (0.0, 0.05), (0.0, 0.02), 5e-4),
    FitParam("coulomb_friction", "motor.coulomb_friction", "N m", (0.0, 0.1), (0.0, 0.05), 5e-3),
    FitParam("torque_constant_scale", None, "-", (0.2, 5.0), (0.5, 2.0), 1.0),
    FitParam("youngs_modulus", "rod.youngs_modulus", "Pa", (1e4, 1e8), (5e4, 1e7), 6e5),
    FitParam("damping", "rod.damping", "N m s/rad", (0.0, 0.1), (0.0, 0.05), 1e-3),
    # between the encoder and the rod: the gearbox's play (a torque reversal crosses it) and where the
    # boot zero sits from the rod's true hanging (the rod's free swings center on the latter)
    FitParam("backlash", "gearbox.backlash_deg", "deg", (0.0, 6.0), (0.0, 5.0), 1.0, known_within=0.1),
    FitParam("zero_error", "encoder.zero_error_deg", "deg", (-3.0, 3.0), (-2.0, 2.0), 0.2, known_within=0.05),
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

        plant = faithful_plant(params, input_mode="duty", at_rest=False)  # each record's start puts its rod at rest
        cpr = float(params.counts_per_rev)
        zero = math.radians(params["encoder"]["zero_error_deg"])
        out = []
        fp = ctypes.POINTER(ctypes.c_float)
        from rodctl.sim.statics import hanging_shape

        rest = hanging_shape(params)  # a rod curved at rest starts each record bent, as it hangs (None: straight)
        for i, (r, duty, torque) in enumerate(zip(self.records, self._duty, self._torque)):
            within = 0.0 if starts is None else float(starts[i])
            theta0 = 2 * math.pi * (r.count[0] + within) / cpr - zero
            # where the last experiment left the rig: most often the motor on a flank and the rod a few tenths of a
            # degree off hanging; started at the encoder's angle instead, up to half the gap off its rest, and the
            # fit tunes the friction to a swing the rig never made
            plant.start_hanging(theta0, rest)
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
    check_identifiable(records, params)
    model = fit_model(params) if model is None else tuple(model)
    t0 = time.monotonic()
    problem = FitProblem(records, params, fitted, model)
    best = best_start(problem, starts, max_nfev, progress)
    if polish and problem.model:
        problem.model = ()  # FitProblem.simulate reads it: from here on, the file's own plant
        if progress:
            progress("fit: polish on the parameter file's plant")
        best = problem.solve("polish", best.x, POLISH_NFEV)
    return fit_result(problem, best, t0)


class FitProblem:
    """The least-squares problem of fit(). Its unknowns x: the fitted parameters in the optimizer's scaled
    units (value / scale), then where each record starts within its first count [counts, -0.5 to 0.5].
    Its residual: simulated minus measured theta_1 at the moving samples of each record's fitted part
    (all but its last VALIDATION_FRACTION), in units of the quantization noise."""

    def __init__(self, records: list[Record], params, fitted: tuple[str, ...], model: tuple[str, ...]):
        self.records, self.params = records, params
        self.model = model  # --set overrides of the plant simulated
        self.nominal = nominal_values(params)
        self.scale = _scales(self.nominal)
        self.fitted = [fp for fp in FIT_PARAMS if fp.name in fitted]  # in FIT_PARAMS' order
        self.n_fitted = len(self.fitted)  # x[:n_fitted] are the parameters, x[n_fitted:] the records' start places
        self.counts_per_rev = float(params.counts_per_rev)
        self.noise = 2 * math.pi / self.counts_per_rev / math.sqrt(12.0)  # quantization noise of theta_1 [rad]
        self.measured = [measured_theta(r, self.counts_per_rev) for r in records]
        self.split = [max(1, int(round(len(r.count) * (1 - VALIDATION_FRACTION)))) for r in records]
        self.moving = [moving_mask(r.count)[:k] for r, k in zip(records, self.split)]
        rows = [int(u.sum()) for u in self.moving]
        self.row_of = np.repeat(np.arange(len(records)), rows)  # the record each residual row comes from
        nr = len(records)
        self.lo = np.array([fp.bounds[0] / self.scale[fp.name] for fp in self.fitted] + [-0.5] * nr)
        self.hi = np.array([fp.bounds[1] / self.scale[fp.name] for fp in self.fitted] + [0.5] * nr)
        self.simulator = Simulator(records)
        self.evaluations = 0  # simulations run
        self.tried: list[dict] = []  # each solve: where it started, its cost and simulations
        # least_squares asks for the Jacobian where it has just evaluated the residual; the plant is part of the
        # key, as the polish starts on another plant where the search ended
        self._last: tuple = (None, None, None)

    def values(self, x: np.ndarray) -> dict[str, float]:
        """Every FIT_PARAMS value at x (the ones not fitted at their nominal) [unit]."""
        v = dict(self.nominal)
        v.update({fp.name: float(xi) * self.scale[fp.name] for fp, xi in zip(self.fitted, x[:self.n_fitted])})
        return v

    def simulate(self, x: np.ndarray) -> list[np.ndarray]:
        self.evaluations += 1
        candidate = with_values(self.params, self.values(x)).with_overrides(*self.model)
        return self.simulator.run(candidate, starts=x[self.n_fitted:])

    def residual(self, x: np.ndarray) -> np.ndarray:
        last_model, last_x, last_r = self._last
        if last_x is not None and last_model == self.model and np.array_equal(last_x, x):
            return last_r.copy()
        th = self.simulate(x)
        r = np.concatenate([(s[:k] - m[:k])[u] / self.noise
                            for s, m, k, u in zip(th, self.measured, self.split, self.moving)])
        self._last = (self.model, np.array(x, copy=True), r)
        return r.copy()

    def jacobian(self, x: np.ndarray) -> np.ndarray:
        """Forward differences; the records' own start places share one simulation (each moves
        only its own record's rows)."""
        n, row_of = self.n_fitted, self.row_of
        f0 = self.residual(x)
        J = np.empty((len(f0), len(x)))
        step = STEP * np.maximum(1.0, np.abs(x))
        h = np.where(x + step <= self.hi, step, -step)
        for j in range(n):
            xj = x.copy()
            xj[j] += h[j]
            J[:, j] = (self.residual(xj) - f0) / h[j]
        xs = x.copy()
        xs[n:] += h[n:]
        d = self.residual(xs) - f0
        J[:, n:] = 0.0
        J[np.arange(len(f0)), n + row_of] = d / h[n + row_of]
        return J

    def start_points(self) -> list[np.ndarray]:
        """Deterministic starts: the nominal point (each record in the middle of its first count), then
        every parameter low, then high (rotor and rod guesses are often off by tens of percent, the
        friction terms by factors)."""
        n, lo, hi = self.n_fitted, self.lo, self.hi
        x_nom = np.clip(np.array([self.nominal[fp.name] / self.scale[fp.name] for fp in self.fitted]
                                 + [0.0] * len(self.records)), lo, hi)
        low, high = x_nom.copy(), x_nom.copy()
        low[:n], high[:n] = x_nom[:n] * 0.6, x_nom[:n] * 1.6
        return [x_nom, np.clip(low, lo, hi), np.clip(high, lo, hi)]

    def solve(self, kind: str, x0: np.ndarray, nfev: int):
        """scipy.optimize.least_squares from x0 with at most nfev simulations, noted in `tried` as `kind`."""
        from scipy.optimize import least_squares

        x_scale = np.concatenate([np.maximum(x0[:self.n_fitted], 0.05), np.full(len(self.records), 0.25)])
        r = least_squares(self.residual, x0, jac=self.jacobian, bounds=(self.lo, self.hi), x_scale=x_scale,
                          max_nfev=nfev, method="trf")
        self.tried.append({kind: {fp.name: float(a * self.scale[fp.name]) for fp, a in zip(self.fitted, x0)},
                           "cost": float(r.cost), "nfev": int(r.nfev)})
        return r


def best_start(problem: FitProblem, starts: int, max_nfev: int, progress=None):
    """The lowest-cost solve of the first `starts` start points (at least one)."""
    candidates = problem.start_points()
    best = None
    for i, x0 in enumerate(candidates[:max(1, starts)]):
        if progress:
            progress(f"fit: start {i + 1}/{min(starts, len(candidates))}")
        r = problem.solve("start", x0, max_nfev)
        if best is None or r.cost < best.cost:
            best = r
    return best


def fit_result(problem: FitProblem, best, t0: float) -> FitResult:
    """The FitResult of the solve `best` (a least_squares result); t0: when the fit began [monotonic s]."""
    fitted, n, scale = problem.fitted, problem.n_fitted, problem.scale
    x = best.x
    J = np.asarray(best.jac)
    m = J.shape[0]
    cov = covariance(J, best.cost, n)
    jn, sv = scaled_sensitivity(J[:, :n])
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    corr = cov / np.outer(np.where(sd > 0, sd, 1), np.where(sd > 0, sd, 1))
    values = problem.values(x)
    ci = {fp.name: float(1.96 * sd[i] * scale[fp.name]) for i, fp in enumerate(fitted)}
    why = {fp.name: why_not_identifiable(i, fitted, values[fp.name], ci[fp.name], jn, corr)
           for i, fp in enumerate(fitted)}
    th = problem.simulate(x)
    validation_pct, fit_pct = validation_and_fit_pct(problem.measured, th, problem.split)
    cpr, q = problem.counts_per_rev, problem.noise
    return FitResult(
        nominal=problem.nominal, values=values, ci95=ci, fitted=tuple(fp.name for fp in fitted),
        identifiable={name: not reason for name, reason in why.items()}, why=why,
        out_of_range=out_of_range(fitted, values), correlation=corr, singular_values=sv,
        validation_fit_pct=validation_pct,
        fit_pct=fit_pct, rms_counts=float(np.sqrt(2 * best.cost / m) * q * cpr / (2 * math.pi)),
        starts=problem.tried, seconds=time.monotonic() - t0, evaluations=problem.evaluations,
        theta_meas=problem.measured, theta_sim=th, split=problem.split, record_names=[r.name for r in problem.records],
        period=problem.records[0].period, counts_per_rev=cpr, model=problem.model,
        start_counts=[float(v) for v in x[n:]])


def covariance(J: np.ndarray, cost: float, n: int) -> np.ndarray:
    """cov = s^2 (J'J)^-1 of the first n unknowns (the fitted parameters) [scaled units^2]."""
    s2 = 2 * cost / max(1, J.shape[0] - J.shape[1])
    # the intervals allow for the records' start places (the whole covariance's block); the
    # identifiability is the fitted parameters' own
    return (s2 * np.linalg.pinv(J.T @ J))[:n, :n]


def scaled_sensitivity(J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The norms of J's columns (how strongly theta_1 responds to each parameter) and the singular values
    of J with its columns scaled to norm 1 (a zero column stays zero)."""
    jn = np.linalg.norm(J, axis=0)
    jn_safe = np.where(jn > 0, jn, 1.0)
    return jn, np.linalg.svd(J / jn_safe, compute_uv=False)


def why_not_identifiable(i: int, fitted: list[FitParam], value: float, ci: float, jn: np.ndarray,
                         corr: np.ndarray) -> str:
    """Why fitted[i] is not identifiable, or "" when it is. value, ci: its value and
    95 % half-width [unit]; jn: the column norms of scaled_sensitivity; corr: the parameters' correlation."""
    rel = ci / abs(value) if value != 0 else math.inf
    if jn[i] == 0 or jn[i] < 1e-6 * jn.max():
        return "theta_1 does not respond to it in these logs"
    if not rel > UNIDENTIFIABLE_REL_CI or ci <= fitted[i].known_within:  # not `<=`: a NaN interval is no reason
        return ""
    partners = [(fitted[j].name, corr[i, j]) for j in range(len(fitted))
                if j != i and abs(corr[i, j]) > CORRELATION_LIMIT]
    if partners:
        with_ = ", ".join(f"{n} (r = {r:+.3f})" for n, r in partners)
        return f"95 % interval +-{100 * rel:.0f} % of the value; correlated with {with_}"
    return (f"95 % interval +-{100 * rel:.0f} % of the value; its effect on theta_1 is "
            f"{jn[i] / jn.max():.1e} of the strongest parameter's")


def out_of_range(fitted: list[FitParam], values: dict[str, float]) -> dict[str, str]:
    """The fitted values outside their parameter's physical range, in words (flagged, not written)."""
    out = {}
    for fp in fitted:
        lo_p, hi_p = fp.physical
        v = values[fp.name]
        if not lo_p <= v <= hi_p:
            out[fp.name] = f"{v:.4g} {fp.unit} is outside the physical range [{lo_p:g}, {hi_p:g}]"
    return out


def validation_and_fit_pct(meas: list[np.ndarray], sim: list[np.ndarray], split: list[int]) -> tuple[float, float]:
    """percent_fit of the records' held-out ends together (the validation), and of their fitted parts."""
    val_m = np.concatenate([mm[k:] for mm, k in zip(meas, split)])
    val_s = np.concatenate([ss[k:] for ss, k in zip(sim, split)])
    fit_m = np.concatenate([mm[:k] for mm, k in zip(meas, split)])
    fit_s = np.concatenate([ss[:k] for ss, k in zip(sim, split)])
    return percent_fit(val_m, val_s), percent_fit(fit_m, fit_s)


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


QUANTIZATION_RMS_COUNTS = 12 ** -0.5  # a perfect model's residual: the encoder's rounding alone [counts RMS]
MODEL_MISS_FACTOR = 2.0  # a residual this many times that is the rig doing something the model does not


def model_miss_text(rms_counts: float) -> str | None:
    """A warning when the best fit leaves much more than the encoder's rounding: the nominal file is not the rig
    (a rod 0.17 m long fitted as the file's 0.155 m left 1.28 counts RMS, every value written wrong, b +304 %, and
    the held-out fit still read 96 %). None within MODEL_MISS_FACTOR x the rounding (the hidden rigs: 0.29 to 0.36)."""
    ratio = rms_counts / QUANTIZATION_RMS_COUNTS
    if not ratio > MODEL_MISS_FACTOR:
        return None
    return (f"the fit leaves {rms_counts:.2f} counts RMS, {ratio:.1f} x the encoder's rounding alone: the model misses "
            "what the rig does. Is --params the rig you have (the rod's length, width, thickness and density, the gear "
            "ratio, the encoder's counts)? The values written may all be off")


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
