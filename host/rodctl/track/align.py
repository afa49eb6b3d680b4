"""The video's clock against the telemetry log's: offset and rate from the base angle both saw.

    log time = offset + rate * video time / slowdown

found by the normalized cross-correlation of the camera's base angle (the first edge) with the
encoder's, for each slow-motion factor (SLOWDOWNS) and for each sign: a camera behind the rod's
plane (or a selfie camera's mirrored picture) sees the rod turn the other way, and a swing's
negative correlates with a half-period shift of itself (0.98 on the demo), so the sign and the
factor are the ones that fit best, not a refusal as another run's. Then a least-squares fit of
offset, rate and a constant angle (the camera's roll and the encoder's zero) on the log's samples,
interpolated, over the frames the log covers (the video may start before the log or end after it).
Refused when the best correlation is too weak to trust (the video and the log are not of the same
run), or when the fit ends at its limits (a drift of MAX_DRIFT_PPM, or the offset at the edge of
its search): no clock fits the frames' times (frames dropped without a gap in their timestamps, or
the wrong lag).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rodgains.errors import InputError

MIN_CORRELATION = 0.9  # the fitted base angles must agree this well [-]
MIN_OVERLAP = 0.5  # share of the video the log must cover at the best lag [-]
MIN_SWING_DEG = 5.0  # the base must move this much in the video to time it
MAX_DRIFT_PPM = 5000.0  # camera clocks are good to a few hundred ppm; beyond this the fit is lost
PLAUSIBLE_DRIFT_PPM = 1000.0  # a fitted drift past this is not the camera's clock: it is said, with what it costs
# The camera's base angle and the encoder's differ by the gearbox's play (a degree or two), the foot's bend and the
# centroids' noise: 0.2 to 1.2 deg RMS on every clip of the filming guide, blurred, noisy or recompressed. A best fit
# 3 deg off is another run's log, or a clip too short to place in it (a 1 s clip fitted a half-swing away, 7.3 deg).
MAX_RESIDUAL_DEG = 3.0
GUIDE_CLIP_S = 6.0  # the swinging the filming guide asks for, at 120 fps and up [s]
# A slow-motion file plays slower than it was filmed: a phone films at 60 to 960 fps and writes a file that
# plays at 24, 25, 30 or 60. Its container's clock runs this many times slower than the log's [-]; each is
# tried (1 first) and the best correlation wins: a swing slowed by the wrong factor has the wrong period.
SLOWDOWNS = tuple(sorted({c / p for c in (60, 120, 240, 480, 960) for p in (24, 25, 30, 60) if c > p} | {1.0}))
# Of two lags that fit alike, the one the log covers more of wins, by this much correlation per share
# of the video outside the log [-]. Small, because a video started before the log (or stopped after
# it) is right to overlap it partly: r * overlap (0.97 at full overlap beat 0.9999 at 94 %) chose
# a wrong lag 0.86 s off. A swinging rod is nearly periodic, so a partial overlap can fit well by
# chance; it has to fit better than the full one by 0.02 per share lost to win.
OVERLAP_PENALTY = 0.02
COARSE_STEP_MIN_S = 1e-3  # the coarse search's grid step at least: the log's sample period at 1 kHz [s]
AT_LIMIT = 0.99  # a fitted value this close to its bound is pinned there, not found [-]


@dataclass
class Alignment:
    offset_s: float  # the log's time of the video's first frame [s]
    rate: float  # log seconds per second filmed (the file's seconds / slowdown) [-]
    angle_offset_rad: float  # camera base angle minus encoder angle, constant part [rad]
    correlation: float  # Pearson r of the fitted base angles [-]
    residual_rad: float  # RMS of the fit [rad]
    covered: float = 1.0  # share of the usable frames the log covers: the only ones compared [-]
    covered_s: float = 0.0  # the video time they span, over which the drift is measured [s]
    mirrored: bool = False  # the camera sees the rod turn against the encoder: its angles were negated
    slowdown: float = 1.0  # the video's seconds per second filmed: a slow-motion file's factor [-]
    drift_measured: bool = True  # False: the clip cannot tell its drift from 0, which it is held at
    drift_sd_ppm: float = 0.0  # the fitted drift's standard deviation, before any holding [ppm]

    @property
    def drift_ppm(self) -> float:
        return (self.rate - 1.0) * 1e6

    def drift_text(self) -> str:
        return (f"clock drift {self.drift_ppm:+.0f} ppm" if self.drift_measured else
                f"clock drift not measurable over {self.covered_s:.1f} s (+-{2 * self.drift_sd_ppm:.0f} ppm), held at 0")

    def drift_warning(self) -> str | None:
        """What a measured drift beyond a camera clock's (PLAUSIBLE_DRIFT_PPM) means, and what it may cost; None
        within it."""
        if not self.drift_measured or abs(self.drift_ppm) <= PLAUSIBLE_DRIFT_PPM:
            return None
        ms = abs(self.drift_ppm) * 1e-6 * self.covered_s / 2 * 1e3
        return (f"the fitted clock drift {self.drift_ppm:+.0f} ppm (+-{2 * self.drift_sd_ppm:.0f}) is more than a "
                f"camera's clock drifts (a few hundred ppm): frames left out without a gap in their timestamps, or too "
                f"little motion of the base over {self.covered_s:.1f} s to time the clip; frame times may be off by up "
                f"to {ms:.1f} ms at the clip's ends")

    def log_time(self, video_t: np.ndarray) -> np.ndarray:
        """The log's time [s] of the video's times video_t [s, the file's clock]."""
        return self.offset_s + self.rate * np.asarray(video_t) / self.slowdown


def _coarse(tau: np.ndarray, beta: np.ndarray, t_log: np.ndarray, th_log: np.ndarray,
            dt: float) -> tuple[tuple[float, float], tuple[float, float]]:
    """((offset [s], r) of the best normalized cross-correlation on a common grid of step dt, the same of
    the camera's angle negated): -beta correlates -r at every lag, so one correlation gives both.

    Every lag at once: the products' sums from one FFT correlation, the overlaps' sums and sums of
    squares from running sums, so a long video against a long log costs O((n + m) log(n + m))."""
    from scipy.signal import correlate

    x = np.interp(np.arange(tau[0], tau[-1], dt), tau, beta)
    grid = np.arange(t_log[0], t_log[-1], dt)
    y = np.interp(grid, t_log, th_log)
    n, m = len(x), len(y)
    need = int(MIN_OVERLAP * n)
    lags = np.arange(-(n - need), m - need + 1)  # video sample 0 at log sample `lag`
    a, b = np.maximum(0, -lags), np.minimum(n, m - lags)
    k = b - a
    sxy = correlate(y, x, mode="full", method="fft")[lags + n - 1]
    px, pxx = np.concatenate([[0.0], np.cumsum(x)]), np.concatenate([[0.0], np.cumsum(x * x)])
    py, pyy = np.concatenate([[0.0], np.cumsum(y)]), np.concatenate([[0.0], np.cumsum(y * y)])
    sx, sxx = px[b] - px[a], pxx[b] - pxx[a]
    sy, syy = py[b + lags] - py[a + lags], pyy[b + lags] - pyy[a + lags]
    cov = sxy - sx * sy / k
    den = np.sqrt(np.maximum(sxx - sx * sx / k, 0.0) * np.maximum(syy - sy * sy / k, 0.0))
    r = np.divide(cov, den, out=np.zeros_like(cov), where=den > 0)
    penalty = np.where(k >= need, OVERLAP_PENALTY * (1.0 - k / n), np.inf)
    out = []
    for sign in (1.0, -1.0):
        best = int(np.argmax(sign * r - penalty))
        out.append((grid[0] + lags[best] * dt - tau[0], float(sign * r[best])))
    return out[0], out[1]


def align(tau: np.ndarray, beta: np.ndarray, t_log: np.ndarray, th_log: np.ndarray, fps: float,
          slowdowns: tuple[float, ...] = SLOWDOWNS, play_deg: float = 0.0) -> Alignment:
    """tau: video times of the usable frames [s, the file's clock]; beta: the rod's base angle in them
    [rad] (unwrapped; rodctl.track.shape.base_tangent); t_log, th_log: the log's time [s] and encoder
    angle [rad]; fps: the file's frame rate [1/s]; slowdowns: the slow-motion factors to try (the
    file's seconds per second filmed); play_deg: the gearbox's play between the encoder and the rod [deg], which
    the camera's base angle may differ by on top of MAX_RESIDUAL_DEG. A mirrored video's alignment is of -beta
    (Alignment.mirrored)."""
    from scipy.optimize import least_squares

    if len(tau) < 20:
        raise InputError(f"only {len(tau)} usable frames: too few to align the video with the log")
    if np.ptp(beta) < np.radians(MIN_SWING_DEG):
        raise InputError(f"the rod's base moves {np.degrees(np.ptp(beta)):.1f} deg in the video: too little to "
                         "align it with the log (swing the rod by hand at the start of the run)")
    r0, offset0, slowdown, sign = -np.inf, 0.0, 1.0, 1.0
    for s in slowdowns:  # in the order given: of equal fits the first (1, unmirrored) is kept
        # a frame's step, no finer than the log's samples: a fast factor of a fast file would grid the log
        # at up to 40 x the video's rate (a minute's log: hundreds of MB)
        dt = max(1.0 / (fps * s), COARSE_STEP_MIN_S)
        for sg, (off, r) in zip((1.0, -1.0), _coarse(tau / s, beta, t_log, th_log, dt)):
            if r > r0:
                r0, offset0, slowdown, sign = r, off, s, sg
    mirrored = sign < 0
    # from here on the time filmed, its frame rate, and the rod's own sense
    tau, fps, beta = tau / slowdown, fps * slowdown, sign * beta
    if r0 < MIN_CORRELATION:
        raise InputError(f"the video's base angle does not follow the log's (best correlation {r0:.2f} < "
                         f"{MIN_CORRELATION}): a log of another run?")

    inside = _inside(offset0 + tau, t_log, 2.0 / fps)
    if inside.sum() < 20:
        raise InputError(f"the log covers only {inside.sum()} usable frames of the video: too few to align them")
    tau_in, beta_in = tau[inside], beta[inside]

    def resid(p):
        return beta_in - p[2] - np.interp(p[0] + p[1] * tau_in, t_log, th_log)

    c0 = float(np.median(beta_in - np.interp(offset0 + tau_in, t_log, th_log)))
    # the coarse lag is right to a frame at rate 1; a drift moves the first frame's time by up to
    # MAX_DRIFT_PPM of the clip's length from the lag that fits best in its middle
    span = 3.0 / fps + MAX_DRIFT_PPM * 1e-6 * float(np.ptp(tau))
    drift_max = MAX_DRIFT_PPM * 1e-6
    fit_bounds = ([offset0 - span, 1.0 - drift_max, -np.inf], [offset0 + span, 1.0 + drift_max, np.inf])
    fit = least_squares(resid, [offset0, 1.0, c0], x_scale=[1.0 / fps, 1e-4, 0.01], loss="soft_l1",
                        f_scale=np.radians(2.0), bounds=fit_bounds)
    off, rate, c = (float(v) for v in fit.x)
    _refuse_at_limit(off - offset0, span, rate - 1.0, drift_max)  # pinned at a bound: no clock fits the frames
    sd_ppm = _drift_sd(fit) * 1e6
    measured = 2 * sd_ppm <= PLAUSIBLE_DRIFT_PPM
    if not measured:
        # the clip cannot tell a camera's drift (a few hundred ppm) from none: a rate fitted anyway is the frames'
        # noise (a 2 s clip: +1100 ppm against the 60 put in), so the camera's nominal clock is taken
        def resid0(p):
            return resid([p[0], 1.0, p[1]])
        fit0 = least_squares(resid0, [offset0, c0], x_scale=[1.0 / fps, 0.01], loss="soft_l1",
                             f_scale=np.radians(2.0), bounds=([offset0 - span, -np.inf], [offset0 + span, np.inf]))
        off, rate, c = float(fit0.x[0]), 1.0, float(fit0.x[1])
        _refuse_at_limit(off - offset0, span, 0.0, drift_max)
    inside = _inside(off + rate * tau, t_log, 0.0)
    model = np.interp(off + rate * tau[inside], t_log, th_log) + c
    r = float(np.corrcoef(beta[inside], model)[0, 1]) if inside.sum() > 2 else 0.0
    if r < MIN_CORRELATION:
        raise InputError(f"the video's base angle does not follow the log's (correlation {r:.2f} < "
                         f"{MIN_CORRELATION}): a log of another run?")
    res = float(np.sqrt(np.mean((beta[inside] - model) ** 2)))
    max_residual_deg = MAX_RESIDUAL_DEG + 0.5 * play_deg
    if res > np.radians(max_residual_deg):
        why = (f"the frames that show the rod's markers span {np.ptp(tau):.1f} s, too short to place in the log "
               "(film 6 s or more of swinging)"
               if np.ptp(tau) < GUIDE_CLIP_S else "frames left out of the video")
        raise InputError(f"the video's base angle follows the log's only loosely at the best fit ({np.degrees(res):.1f} "
                         f"deg RMS, more than {max_residual_deg:g}; camera minus encoder {np.degrees(c):+.1f} deg): {why}, "
                         "or a log of another run?")
    return Alignment(off, rate, c, r, res, float(inside.mean()), float(np.ptp(tau[inside])), mirrored, slowdown,
                     measured, sd_ppm)


def _drift_sd(fit) -> float:
    """The fitted rate's standard deviation [-] from the fit's Gauss-Newton covariance (its residuals' variance times
    (J^T J)^-1), widened by the residuals' correlation time: they are the play's and the foot's bend, smooth over many
    frames, not independent per frame (white, a 2 s clip's +1100 ppm read as +-270 against the 60 put in). inf where
    the Jacobian cannot tell the rate."""
    J = np.asarray(fit.jac, float)
    res = np.asarray(fit.fun, float)
    dof = max(1, J.shape[0] - J.shape[1])
    s2 = 2.0 * float(fit.cost) / dof
    try:
        cov = s2 * np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        return float("inf")
    return float(np.sqrt(max(cov[1, 1], 0.0) * _correlation_samples(res)))


def _correlation_samples(res: np.ndarray) -> float:
    """How many consecutive residuals count as one independent one: twice the lag at which their autocorrelation
    falls below 1/e (at least 1, at most a tenth of them)."""
    x = res - res.mean()
    n = len(x)
    if n < 10 or not np.any(x):
        return 1.0
    ac = np.correlate(x, x, mode="full")[n - 1:] / float(x @ x)
    below = np.nonzero(ac[: max(2, n // 10)] < math.exp(-1.0))[0]
    lag = int(below[0]) if below.size else n // 10
    return float(max(1, 2 * lag))


def _inside(t: np.ndarray, t_log: np.ndarray, margin_s: float) -> np.ndarray:
    """The frames whose log times t [s] the log covers, margin_s [s] in from its ends: outside, the
    log's angle is not known (interpolation would repeat its first or last sample)."""
    return (t >= t_log[0] + margin_s) & (t <= t_log[-1] - margin_s)


def _refuse_at_limit(moved_s: float, span_s: float, drift: float, drift_max: float) -> None:
    """A fit that ends on its bounds has not found the clock, it has run out of room: the numbers it
    stops at (e.g. a drift of exactly MAX_DRIFT_PPM) would be printed as if measured."""
    if abs(drift) >= AT_LIMIT * drift_max:
        raise InputError(f"the video's clock does not fit the log's: the fitted drift ran into its limit "
                         f"({drift * 1e6:+.0f} ppm): frames dropped from the video, or a log of another run?")
    if abs(moved_s) >= AT_LIMIT * span_s:
        raise InputError(f"the video's clock does not fit the log's: the fitted offset ran into its limit "
                         f"({moved_s * 1e3:+.1f} ms from the best lag): frames dropped from the video, or a log "
                         "of another run?")
