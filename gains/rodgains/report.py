"""Human-readable design report: poles, margins, critical lengths, and the paper's K run sampled."""

from __future__ import annotations

import numpy as np

from . import sampled
from .buckling import clamped_ratio, greenhill_length, margins_text, nlink_critical_length
from .design import Design, continuous_gains, weights
from .linearize import linearize_upright
from .params import SOFT_SHAFT_WEIGHTS
from .robust_design import Member, noise_torque_rms
from .rod_model import RodModel


def _poles(z: np.ndarray, dt: float, k: int = 4) -> str:
    """The k slowest discrete poles as s = ln(z)/dt [rad/s]; poles at z = 0 (a pure delay's, the tip IMU's latency)
    are infinitely fast and never among them."""
    z = z[np.abs(z) > 0]
    s = np.log(z.astype(complex)) / dt
    s = s[np.argsort(-s.real)][:k]
    return ", ".join(f"{v.real:.3g}{v.imag:+.3g}j" if abs(v.imag) > 1e-9 else f"{v.real:.4g}" for v in s)


# Sec. III: lqr weights Q_theta = 0.5, Q_thetadot = 0.1, R = 1; observer 0.05, 0.01, 1.
PAPER_WEIGHTS = ["lqr.q_angle=0.5", "lqr.q_shaft_angle=0.0", "lqr.q_rate=0.1", "lqr.r_torque=1.0",
                 "observer.process_noise_angle=0.05", "observer.process_noise_rate=0.01",
                 "observer.measurement_noise=1.0"]


def paper_continuous_sampled(d: Design, bare: bool) -> dict:
    """The paper's continuous design (its weights) run in the sampled loop at d.dt.

    bare: on the paper's model (no motor); else on the configured model. The observer in the
    loop is this design's discrete one, so the radius is the paper's K's doing.
    """
    p = d.params.with_overrides(*PAPER_WEIGHTS)
    rod = RodModel.from_params(p, design=True)
    if bare:
        rod = RodModel(rod.N, rod.l, rod.m, rod.EI, rod.d, rod.g, 0.0, 0.0)
    A, B = linearize_upright(rod)
    Q, R, W, V = weights(p, rod.N)
    K, _ = continuous_gains(A, B, d.C, Q, R, W, V)
    Ad, Bd = sampled.zoh(A, B, d.dt)
    cont = np.linalg.eigvals(A - B @ K)
    return {
        "K": K.ravel(),
        "fastest_continuous_pole": float(cont.real.min()),
        "state_feedback_radius": sampled.spectral_radius(Ad - Bd @ K),
        "output_feedback_radius": sampled.spectral_radius(sampled.closed_loop(Ad, Bd, d.C, K, d.L)),
    }


def one_period_delay_radius(d: Design) -> float:
    """Spectral radius when the torque reaches the rod one period late (observer unaware)."""
    return sampled.spectral_radius(d.loop(delay=1))


# A loop mode damped less than this rings: every encoder count the rod crosses kicks it, so the
# torque buzzes at its frequency once balanced (measured: the robust tuned files' 61 Hz mode at
# damping ratio 0.054 makes 58 mN m RMS of 64 Hz torque ripple on the faithful plant; the default
# design's least damped mode, 0.27 at 10 Hz, makes 29 mN m, mostly single counts through its stiff
# base-angle gain, and docs/tuned/low-ripple.toml's 12)
RINGING_DAMPING_RATIO = 0.1
KT_SPREAD = 0.15  # the robustness matrix's torque-constant cases, kt+15 and kt-15: the gain range must hold them [-]


def least_damped(z: np.ndarray, dt: float, below_hz: float = np.inf) -> tuple[float, float] | None:
    """(frequency [Hz], damping ratio [-]) of the least damped oscillation below below_hz among a sampled loop's
    eigenvalues z (period dt [s]), s = ln(z) / dt; None when none oscillates there."""
    s = np.log(z[z.imag > 1e-12].astype(complex)) / dt
    s = s[s.imag < 2 * np.pi * below_hz]
    if s.size == 0:
        return None
    zeta = -s.real / np.abs(s)
    k = int(np.argmin(zeta))
    return float(s[k].imag / (2 * np.pi)), float(zeta[k])


def least_damped_mode(d: Design) -> tuple[float, float]:
    """(frequency [Hz], damping ratio [-]) of the least damped oscillatory mode of the sampled loop
    on the design model (plant + observer + LQR); (nan, 1) when none oscillates."""
    return least_damped(np.linalg.eigvals(d.loop()), d.dt) or (float("nan"), 1.0)


def quantization_torque(d: Design) -> float:
    """RMS torque [N m] that encoder quantization (white, one count^2 / 12 per sample) drives through
    the sampled loop on the design model: the linear part of the balanced torque ripple."""
    Ao, Bo, Co, Ko, Lo = d.estimator()
    return noise_torque_rms(Member("design", d.Ad, d.Bd, d.C, nominal=True), Ao, Bo, Co, Ko, Lo,
                            d.params.rad_per_count)


# Measured (docs/scenarios.md, "Longest rod"): with lqr.q_shaft_angle > 0 the base clamps the rod's foot, and the
# default design and its observer variants hold 1.05 x the critical length from 10 deg but not 1.06;
# the soft-shaft weights (the previous default's, docs/tuned/low-ripple.toml) reach 1.08 to 1.10.
STIFF_SHAFT_MAX_RATIO = 1.05


def _stiff_shaft_note(p, ratio: float) -> list[str]:
    if p["lqr"]["q_shaft_angle"] <= 0.0 or ratio <= STIFF_SHAFT_MAX_RATIO:
        return []
    return [f"  NOTE: lqr.q_shaft_angle = {p['lqr']['q_shaft_angle']:g} clamps the rod's foot, and a clamped rod "
            f"past {STIFF_SHAFT_MAX_RATIO:g} x its critical length buckles: try the soft shaft of "
            f"docs/tuned/low-ripple.toml ({', '.join(SOFT_SHAFT_WEIGHTS)}; docs/scenarios.md, longest rod)"]


def _clamped_line(p) -> str:
    """The rod above the plant's hub against its clamped buckling length, and what takes it there."""
    hub, ratio = p["plant"]["hub_length"], clamped_ratio(p)
    imu = f" with the tip IMU's {p['sensors']['imu_mass'] * 1e3:g} g" if p["sensors"]["tip_imu"] else ""
    head = (f"  above the plant's {hub * 1e3:g} mm hub: {(p['rod']['length'] - hub) * 100:.2f} cm = {ratio:.3f} x continuum"
            f"{imu}, clamped at the hub")
    if ratio >= 1.0:
        return head + ": it buckles whenever the shaft holds still"
    if ratio == 0.0:
        return head + ": without gravity it cannot buckle"
    return f"{head}; it buckles there at {margins_text(p)}"


def radius_text(rho: float, places: int) -> str:
    """A spectral radius to `places` decimals, or to as many as it takes not to print a stable loop as 1 (the tip
    IMU's gyro-bias state sits 1e-9 inside the unit circle)."""
    text = f"{rho:.{places}f}"
    while rho < 1.0 and float(text) >= 1.0 and places < 12:
        places += 1
        text = f"{rho:.{places}f}"
    return text


def report_text(d: Design) -> str:
    p = d.params
    rod = d.rod
    L_tot = p["rod"]["length"]
    lc_cont = greenhill_length(p)
    lc_model = nlink_critical_length(p)
    open_loop = np.linalg.eigvals(d.A)
    unstable = sorted(v.real for v in open_loop if v.real > 0)
    ctrl = np.linalg.eigvals(d.Ad - d.Bd @ d.K)
    obs = np.linalg.eigvals(d.Ad - d.L @ d.C @ d.Ad)
    lo, hi = sampled.stable_gain_interval(d.loop)
    pm = sampled.phase_margin(d.loop)
    delay_radius = one_period_delay_radius(d)
    rad_per_count = p.rad_per_count
    bare = paper_continuous_sampled(d, bare=True)
    conf = paper_continuous_sampled(d, bare=False)
    rate = 1.0 / d.dt
    ring_hz, ring_zeta = least_damped_mode(d)
    lines = [
        f"Rod: N = {rod.N} edges of l = {rod.l * 1e3:.2f} mm, m = {rod.m * 1e3:.2f} g, EI = {rod.EI:.4g} N m^2, "
        f"d = {rod.d:g} N m s/rad",
        f"Base (design): J = {rod.J:.3g} kg m^2 ({rod.J / (rod.m * rod.l**2):.2f} x first-edge m l^2), "
        f"b = {rod.b:.3g} N m s/rad",
        f"Parameters: {p.source}  sha256 {p.sha256()[:16]}",
        "",
        "Critical self-buckling length (base clamped upright):",
        f"  continuum (Greenhill, corrected eq. 23): {lc_cont * 100:.2f} cm",
        f"  N = {rod.N} link model:                    {lc_model * 100:.2f} cm",
        f"  this rod: {L_tot * 100:.2f} cm = {L_tot / lc_cont:.3f} x continuum, {L_tot / lc_model:.3f} x model",
        _clamped_line(p),
        *_stiff_shaft_note(p, L_tot / lc_cont),
        "",
        f"Open loop about upright: unstable poles {', '.join(f'{v:.3g}' for v in unstable) + ' rad/s' if unstable else 'none'}; "
        f"fastest {open_loop.real.min():.3g} rad/s",
        "",
        f"Sampled design ({d.method}, ZOH at {rate:g} Hz, {d.observer_form}-estimate observer):",
        f"  K = [{', '.join(f'{v:.4g}' for v in d.K.ravel())}]  N m per rad, rad/s",
        f"  L = [{', '.join(f'{v:.4g}' for v in d.L.ravel())}]  rad, rad/s per rad of encoder innovation",
        f"  controller poles (slowest, as ln z / dt): {_poles(ctrl, d.dt)} rad/s",
        f"  observer poles   (slowest, as ln z / dt): {_poles(obs, d.dt)} rad/s",
        f"  closed-loop spectral radius (plant + observer + LQR): {radius_text(d.checks['closed_loop_spectral_radius'], 6)}"
        + ("  (the gyro bias's estimate: a random walk with no dynamics of its own, held just inside the unit"
           " circle by design)" if d.imu is not None else ""),
        # not the two lists above: the disturbance estimate's action closes a loop of its own (a slow integral mode)
        f"  closed-loop poles (slowest, as ln z / dt): {_poles(np.linalg.eigvals(d.loop()), d.dt)} rad/s",
        f"  stable for actuator gain in [{lo:.3g}, {hi:.3g}]; phase margin {pm:.1f} deg at the plant input"
        + (f"  <- WARNING: the robustness matrix's torque constant +-{100 * KT_SPREAD:g} % is outside it"
           if not (lo < 1 - KT_SPREAD and hi > 1 + KT_SPREAD) else ""),
        f"  with one extra period of delay: spectral radius {radius_text(delay_radius, 4)}"
        + ("  <- WARNING: unstable: one late interrupt's worth of delay tips the loop" if delay_radius > 1 else ""),
        f"  one encoder count ({np.degrees(rad_per_count):.3f} deg) moves the torque by "
        f"{abs((d.K @ d.L).item()) * rad_per_count * 1e3:.3g} mN m",
        f"  least damped loop mode: {ring_hz:.3g} Hz, damping ratio {ring_zeta:.3f}"
        + (f"  <- WARNING: below {RINGING_DAMPING_RATIO:g}, encoder quantization keeps it ringing "
           f"(expect torque ripple at {ring_hz:.3g} Hz once balanced)" if ring_zeta < RINGING_DAMPING_RATIO else ""),
        *([] if d.imu is not None else
          [f"  encoder quantization drives {quantization_torque(d) * 1e3:.3g} mN m RMS of torque (linear, design model)"]),
        f"  modal controllability {d.checks['controllability']:.2e}, observability from theta_1 alone "
        f"{d.checks['observability']:.2e}" + (" (the tip IMU's, below)" if d.imu is not None else ""),
        "",
        f"The paper's continuous LQR (its weights, Sec. III) run sampled at {rate:g} Hz:",
        f"  K (bare rod) = [{', '.join(f'{v:.4g}' for v in bare['K'])}]",
        f"  bare rod of Table I (no motor): fastest continuous pole {bare['fastest_continuous_pole']:.3g} rad/s; "
        f"sampled spectral radius {bare['state_feedback_radius']:.3g} (state feedback), "
        f"{bare['output_feedback_radius']:.3g} (with observer) -> {_verdict(bare['output_feedback_radius'])}",
        f"  this configuration:             fastest continuous pole {conf['fastest_continuous_pole']:.3g} rad/s; "
        f"sampled spectral radius {conf['state_feedback_radius']:.3g} (state feedback), "
        f"{conf['output_feedback_radius']:.3g} (with observer) -> {_verdict(conf['output_feedback_radius'])}",
    ]
    if d.imu is not None:
        lines += _imu_lines(d)
    fam = d.checks.get("robust_family_radii")
    if fam:
        lqg = d.checks["robust_family_radii_lqg"]
        target = d.params["design"]["robust_radius"]
        agree, runs = d.checks["robust_runs"]
        lines += ["", f"Robust refinement (design.method = robust): the design {agree} of {runs} L-BFGS runs reached; "
                      f"spectral radius on the design's model family, LQG -> refined (target {target:g}):"]
        lines += [f"  {name:28s} {lqg[name]:.5f} -> {r:.5f}" + ("  <- above target" if r > target + 1e-6 else "")
                  for name, r in fam.items()]
        guard = d.checks.get("robust_release")
        if guard:
            start = d.params["swing_up"]["catch_angle_deg"]
            lines += [f"Large-signal guard (design model released from {start:g} deg, torque limit, encoder; "
                      f"large_signal.py): kept {d.checks['robust_step']:.0%} of the refinement"
                      + ("" if guard["holds"] else " (none holds: the LQG gains)")]
            lines += [f"  {name:34s} " + (f"FELL at {g['fell_at_s']:.2f} s" if g["fell"] else
                                          f"within {g['final_deg']:.2f} deg at the end")
                      for name, g in guard["runs"].items()]
    return "\n".join(lines) + "\n"


def _imu_lines(d: Design) -> list[str]:
    """The tip IMU's part of the report: where it sits, and what it lets the estimator see."""
    from .imu import ImuSite, noise, observability

    p = d.params
    site = ImuSite.on_model(p, d.N)
    sg, sa = noise(p)
    lines = ["", f"Tip IMU (sensors.tip_imu): {p['sensors']['imu_mass'] * 1e3:g} g at {site.position * 100:.2f} cm from the axis, "
             f"edge {site.edge + 1} of {d.N} ({site.frac:.2f} along it); {d.imu.delay} period(s) of latency; per sample "
             f"gyro {sg * 1e3:.3g} mrad/s, accelerometer {sa * 1e3:.3g} mm/s^2 RMS",
             "  Observability of each mode of the design model (one sample of a 1 rad mode against the sensors' noise):",
             "  mode s [1/s]                 encoder alone   encoder + IMU   gain"]
    for r in observability(p, d.A, d.B, d.rod.l, d.rod.g):
        s = r["s"]
        name = f"{s.real:.4g}{s.imag:+.4g}j" if abs(s.imag) > 1e-9 else f"{s.real:.4g}"
        lines.append(f"  {name:28s} {r['seen_encoder']:13.3g}   {r['seen_with_imu']:13.3g}   "
                     f"x{r['seen_with_imu'] / max(r['seen_encoder'], 1e-300):.3g}")
    return lines


def _verdict(rho: float) -> str:
    return "stable" if rho < 1.0 else "UNSTABLE"
