"""`rodctl track` measures the rod's curvature at rest (rod.rest_curvature) from the frames where it hangs still
before the run: real MP4 files rendered from the simulator (rodctl.track.render), the rod hanging in its static
shape for a second (simulate_filmed_run's still_s), then let go and swung up, the camera's clock 60 ppm slow.
Measured values are in docs/howto/film-a-run.md."""

from __future__ import annotations

import numpy as np
import pytest

from host_tools import run_rodctl

cv2 = pytest.importorskip("cv2")

FPS = 120
SECONDS = 2.0
STILL_S = 1.0  # the rod hangs still this long from the log's start [s]
SHOWN_STILL_S = 0.45  # of which the video shows the last [s]
# 2400 px/m: the rod 372 px long. At 1600 (250 px, the least docs/howto/film-a-run.md allows) the codec's
# colour errors, 0.1 to 0.3 px on each marker, put the curvature up to 0.09 1/m off
SCENE = dict(width=640, height=440, px_per_m=2400.0, hub_px=(320.0, 40.0))
TOLERANCE_PER_M = 0.1  # a file 0.4 1/m off the rod costs it little lean, the wrong sign 16.9 deg on the 0.82 1/m rod (docs/control.md)
CASES = {"curved": (0.82, STILL_S), "curved_back": (-0.82, STILL_S), "straight": (0.0, STILL_S),
         "no_lead_in": (0.82, 0.0)}


def film_run(folder, kappa: float, still_s: float) -> dict:
    """A filmed run of the rod curved kappa [1/m] at rest: hanging still for still_s [s] (0: let go at once from 30
    deg), 0.3 s swinging freely, then a slow swing-up (rodctl.track.render.DEMO_SWING) so the base swings through
    the clip; the video 2 s at 120 fps from SHOWN_STILL_S before the release."""
    from rodgains.params import load_params

    from rodctl.track.render import DEMO_SWING, Filming, RodScene, film, simulate_filmed_run, write_video

    p = load_params().with_overrides(f"rod.rest_curvature={kappa}", *DEMO_SWING)
    log = folder / "run.csv"
    t, th, lengths = simulate_filmed_run(p, log, swing_deg=30.0, free_s=0.3, armed_s=1.9, after_s=0.0,
                                         still_s=still_s)
    scene = RodScene(**SCENE)
    filming = Filming(fps=FPS, offset_s=max(still_s - SHOWN_STILL_S, 0.05), drift_ppm=60.0, seconds=SECONDS)
    marker_s = np.linspace(0.0, float(p["rod"]["length"]), int(p["rod"]["edges"]) + 1)[1:]
    video = folder / "run.mp4"
    write_video(video, FPS, film(scene, filming, t, th, lengths, marker_s), (scene.width, scene.height))
    return {"log": log, "video": video, "params": p, "kappa": kappa, "filming": filming}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    return {name: film_run(tmp_path_factory.mktemp(name), kappa, still) for name, (kappa, still) in CASES.items()}


def tracked(d, video=None):
    """(Tracked, the notes said, the warnings) of the run d's video (or another of its log's)."""
    from rodctl.track import track

    said, warned = [], []
    r = track(video or d["video"], d["log"], None, say=said.append, warn=warned.append)
    return r, said, warned


@pytest.mark.parametrize("name", ["curved", "curved_back"])
def test_the_matrix_s_curved_rod_is_measured_with_its_sign(runs, name):
    from rodctl.sim.statics import hanging_tip_offset_m

    d = runs[name]
    r, said, _ = tracked(d)
    rest = r.rest_shape
    assert rest is not None, said
    assert abs(rest.kappa_per_m - d["kappa"]) <= TOLERANCE_PER_M, rest  # measured +0.830 and -0.810
    assert np.sign(rest.tip_offset_m) == np.sign(d["kappa"])
    assert abs(rest.tip_offset_m - hanging_tip_offset_m(d["params"])) <= 0.6e-3, rest  # 5.0 mm truth
    # the still frames the video shows: from its first to the release (the log's clock)
    assert rest.still_from_s == pytest.approx(d["filming"].offset_s, abs=1.5 / FPS)
    assert STILL_S - 0.1 <= rest.still_to_s <= STILL_S and rest.frames >= 0.3 * FPS, rest
    assert rest.rms_residual_m <= 0.2e-3, rest
    line = [s for s in said if s.startswith("at rest (hanging still")]
    assert len(line) == 1 and f"rest curvature {rest.kappa_per_m:+.2f} 1/m" in line[0], said
    side = "increasing" if d["kappa"] > 0 else "decreasing"
    assert f"mm toward {side} angles: rod.rest_curvature in the parameter file" in line[0], line


def test_a_straight_rod_reads_straight(runs):
    r, said, _ = tracked(runs["straight"])
    assert r.rest_shape is not None and abs(r.rest_shape.kappa_per_m) < TOLERANCE_PER_M, r.rest_shape  # +0.014


def test_a_mirrored_video_gives_the_same_curvature(runs, tmp_path):
    """Flipped left to right (a camera behind the rod's plane): the alignment turns x back, so the sign is the
    rod's own, not the picture's."""
    from test_track import rewrite

    d = runs["curved"]
    video = rewrite(d["video"], tmp_path / "mirrored.mp4", change=lambda k, f: cv2.flip(f, 1))
    r, said, _ = tracked(d, video)
    front, _, _ = tracked(d)
    assert r.alignment.mirrored and said[0].startswith("mirrored:"), said
    assert abs(r.rest_shape.kappa_per_m - d["kappa"]) <= TOLERANCE_PER_M, r.rest_shape
    assert abs(r.rest_shape.kappa_per_m - front.rest_shape.kappa_per_m) <= 0.05, (r.rest_shape, front.rest_shape)


def test_without_a_still_lead_in_it_is_not_measured_and_the_tracking_goes_on(runs):
    """The usual video has no still lead-in: no note and no warning from track() (rodctl track prints why)."""
    r, said, warned = tracked(runs["no_lead_in"])
    assert r.rest_shape is None and r.rest_note.startswith("rest curvature not measured: no 0.3 s in the video")
    assert "film the rod hanging still for a second before arming" in r.rest_note
    assert not any("rest" in s for s in said + warned), (said, warned)
    assert np.isfinite(r.theta).all(axis=1).mean() > 0.9 and len(r.errors) == 8  # tracked as ever


def test_a_model_that_does_not_converge_is_a_line_not_a_traceback(runs, monkeypatch):
    from rodctl.track import rest_shape

    def no_static_shape(*args, **kw):
        raise ArithmeticError("no static shape found with the hub 0 deg from upright")

    monkeypatch.setattr(rest_shape, "fit_rest_curvature", no_static_shape)
    r, said, _ = tracked(runs["straight"])
    assert r.rest_shape is None and len(r.errors) == 8
    assert r.rest_note == ("rest curvature not measured: the hanging rod's model did not fit the still frames (no "
                           "static shape found with the hub 0 deg from upright)")
    assert not any("rest" in s for s in said), said


def test_a_shape_the_hanging_rod_does_not_explain_is_not_put_in_a_file(runs, monkeypatch):
    """A hand on the rod, a marker mistaken: the markers 0.8 mm RMS from the best hanging shape (the tests' fits:
    0.13 mm) say nothing about rod.rest_curvature, whose wrong sign costs 16.9 deg on the matrix's rod."""
    from rodctl.track import rest_shape

    monkeypatch.setattr(rest_shape, "fit_rest_curvature", lambda *a, **k: (0.8, np.zeros(3), 0.8e-3))
    r, said, _ = tracked(runs["curved"])
    assert r.rest_shape is None and r.rest_note.endswith("(its markers are 0.80 mm RMS from the hanging rod's best "
                                                         "shape, more than 0.4 mm)")
    assert not any("rest curvature" in s for s in said), said


def test_a_file_the_plant_cannot_be_made_of_still_tracks(runs):
    """The rest shape needs the plant's rod; the tracking does not: a file the faithful plant refuses (no hub on
    the der plant) is a note, and the video is tracked."""
    from rodctl.track import track

    d = runs["straight"]
    r = track(d["video"], d["log"], d["params"].with_overrides("plant.hub_length=0.0"), say=None, warn=None)
    assert r.rest_shape is None and "plant.hub_length: must be > 0" in r.rest_note and len(r.errors) == 8


@pytest.mark.parametrize("name", ["curved", "no_lead_in"])
def test_the_command_prints_it_and_writes_it_in_the_tracked_log(runs, tmp_path, name):
    import pyarrow.parquet as pq
    from mcap.reader import make_reader

    d = runs[name]
    out = tmp_path / "tracked.parquet"
    r = run_rodctl("track", str(d["video"]), "--log", str(d["log"]), "--out", str(out), "--quiet", timeout=300)
    assert r.returncode == 0 and r.stderr == "", r.stderr
    lines = [ln for ln in r.stdout.splitlines() if ln.startswith(("at rest (", "rest curvature not measured"))]
    meta = {k.decode(): v.decode() for k, v in pq.read_schema(out).metadata.items()}
    with open(out.with_suffix(".mcap"), "rb") as f:
        (m,) = [m for m in make_reader(f).iter_metadata() if m.name == "rodctl.track"]
    assert m.metadata["rest_curvature_per_m"] == meta["rest_curvature_per_m"]
    if name == "no_lead_in":
        assert len(lines) == 1 and lines[0].startswith("rest curvature not measured"), r.stdout
        assert meta["rest_curvature_per_m"] == "not measured" and "rest_tip_offset_m" not in meta, meta
        assert meta["rest_note"] == lines[0], meta
        return
    assert len(lines) == 1 and lines[0].startswith("at rest (hanging still"), r.stdout
    assert abs(float(meta["rest_curvature_per_m"]) - 0.82) <= TOLERANCE_PER_M, meta
    assert float(meta["rest_tip_offset_m"]) > 0 and int(meta["rest_frames"]) >= 0.3 * FPS, meta


# --- the still frames, on made-up arrays -----------------------------------------------------------------

CPR = 979.2  # the encoder's counts per output turn (rodctl.logs.schema)


def still_case(swing_m=0.0, mode=0, count_step_at_s=None, count=0):
    """A second of frames at 120 fps of markers [m] (the axis and 8 along a 155 mm rod) swaying by swing_m at 3 Hz,
    and a 1 kHz log in mode `mode` whose encoder count is `count`, one more from count_step_at_s [s]."""
    t = np.arange(FPS) / FPS
    markers = np.zeros((len(t), 9, 2))
    markers[:, :, 1] = -np.linspace(0.0, 0.155, 9)
    markers[:, :, 0] = swing_m * np.sin(2 * np.pi * 3.0 * t)[:, None] * np.linspace(0.0, 1.0, 9)
    t_log = np.arange(1000) / 1000
    counts = np.full(1000, count)
    if count_step_at_s is not None:
        counts[t_log >= count_step_at_s] += 1
    return t, markers, np.ones(len(t), bool), t_log, np.full(1000, mode), counts, 0.155, CPR


def test_still_frames_need_the_log_disarmed_the_encoder_and_the_markers_still():
    from rodctl.track.rest_shape import MIN_STILL_S, still_stretch

    frames = still_stretch(*still_case())
    assert frames is not None and len(frames) == FPS
    assert still_stretch(*still_case(mode=1)) is None  # balancing: the board holds it, not at rest
    assert still_stretch(*still_case(count=int(CPR / 2))) is None  # upright on a stop: not hanging
    assert still_stretch(*still_case(count=int(CPR) + 5)) is not None  # hanging, a turn and 2 deg on
    assert still_stretch(*still_case(swing_m=3e-3)) is None  # swaying by 3 mm at the tip
    assert still_stretch(*still_case(swing_m=0.5e-3)) is not None  # by 0.5 mm: within the threshold
    t = still_case()[0]
    frames = still_stretch(*still_case(count_step_at_s=0.6))  # the encoder moved: the longer side
    assert t[frames[0]] == 0.0 and t[frames[-1]] < 0.6
    assert still_stretch(*still_case(count_step_at_s=MIN_STILL_S * 0.9))[0] > 0  # the later 0.73 s
    both = still_case(count_step_at_s=0.2)
    both[4][np.arange(1000) >= 500] = 1  # armed from 0.5 s: 0.3 s still between 0.2 and 0.5 at most
    assert still_stretch(*both) is None
