"""`rodctl track` on videos rendered from the simulator, where the truth is known: every edge's angle,
the clock offset and drift, the estimate's error table; real MP4 files (OpenCV's mp4v), real readers
for what it writes; and the bad inputs."""

from __future__ import annotations

import json

import numpy as np
import pytest

from host_tools import run_rodctl

cv2 = pytest.importorskip("cv2")

FPS = (60, 120, 240)
SECONDS = {60: 20.0, 120: 6.0, 240: 6.0}  # at 60 fps the clock's drift needs more swinging (docs/howto/film-a-run.md)


@pytest.fixture(scope="module")
def filmed(tmp_path_factory):
    """One simulated run filmed at each rate (the camera's clock 0.6 s late and 60 ppm slow)."""
    from rodctl.track.render import demo

    out = {}
    for fps in FPS:
        out[fps] = demo(tmp_path_factory.mktemp(f"film{fps}"), fps=fps, seconds=SECONDS[fps])
    return out


def truth_angles(d, times, edges=8):
    """The design model's N chord angles of the simulated rod at the log times `times`."""
    from rodctl.track.render import points_at, rod_nodes

    data = np.loadtxt(d["truth"], delimiter=",", skiprows=1)
    tt, th = data[:, 0], data[:, 1:]
    s_nodes = np.concatenate([[0.0], np.cumsum(d["lengths"])])
    L = float(d["params"]["rod"]["length"])
    out = []
    for t in times:
        thk = np.array([np.interp(t, tt, th[:, i]) for i in range(th.shape[1])])
        pts = points_at(rod_nodes(thk, d["lengths"]), s_nodes, np.linspace(0, L, edges + 1))
        out.append(np.arctan2(np.diff(pts[:, 0]), -np.diff(pts[:, 1])))
    return np.array(out)


def wrap_deg(a):
    return np.degrees((a + np.pi) % (2 * np.pi) - np.pi)


@pytest.fixture(scope="module")
def tracked(filmed):
    from rodctl.track import track
    from rodctl.track.calibrate import View

    out = {}
    for fps, d in filmed.items():
        view = View.from_checkerboard(d["board"], (9, 6), 0.02)
        out[fps] = track(d["video"], d["log"], None, view=view)
    return out


# The drift is a timing error over the clip's length: the gearbox's play (the rod's foot lags the encoder more
# as the swing grows) and the camera's base-angle error are each about 1 ms over 10 s, so at 60 fps it takes
# 15 s of swinging to get within 100 ppm (docs/howto/film-a-run.md).
DRIFT_PPM = 100.0


@pytest.mark.parametrize("fps", FPS)
def test_the_clock_is_recovered(filmed, tracked, fps):
    f, a = filmed[fps]["filming"], tracked[fps].alignment
    assert abs(a.offset_s - f.offset_s) <= 1.0 / fps, a  # within one frame
    assert abs(a.drift_ppm - f.drift_ppm) <= DRIFT_PPM, a


@pytest.mark.parametrize("fps", [120, 240])
def test_every_edge_within_1_deg_rms(filmed, tracked, fps):
    r = tracked[fps]
    ok = np.isfinite(r.theta).all(axis=1)
    f = filmed[fps]["filming"]
    true_t = f.log_time(np.arange(r.frames))  # when each frame really was, on the log's clock
    err = wrap_deg(r.theta[ok] - truth_angles(filmed[fps], true_t[ok]))
    rms = np.sqrt(np.mean(err ** 2, axis=0))
    assert rms.max() <= 1.0, rms.round(2)


@pytest.mark.parametrize("fps", [120])
def test_the_estimate_error_table_agrees_with_the_truth(filmed, tracked, fps):
    r = tracked[fps]
    true = truth_angles(filmed[fps], r.time_s)
    ok = np.isfinite(r.theta).all(axis=1) & np.isfinite(r.estimate).all(axis=1)
    true_rms = np.sqrt(np.mean(wrap_deg(r.estimate[ok] - true[ok]) ** 2, axis=0))
    video_rms = np.array([row["rms_deg"] for row in r.errors])
    assert np.abs(video_rms - true_rms).max() <= 0.5, (video_rms.round(2), true_rms.round(2))


def test_repeated_frames_and_a_covered_marker_are_flagged(filmed, tracked):
    from rodctl.track.shape import FILLED, REPEATED

    r, f = tracked[120], filmed[120]["filming"]
    assert sorted(np.flatnonzero(r.quality == REPEATED)) == sorted(f.repeated_frames)
    a, b = f.hand_frames
    assert np.mean(r.quality[a:b] == FILLED) >= 0.8  # the hand hid marker 3: filled in from its neighbours
    assert np.all(np.isfinite(r.theta[a:b]))


def test_frames_outside_the_log_keep_their_angles_and_the_rest_take_the_estimates_turn():
    from rodctl.track.compare import on_branch

    tracked = np.array([[0.1, 0.2], [3.0, 3.1], [0.5, np.nan]])
    estimate = np.array([[np.nan, np.nan], [3.0 - 2 * np.pi, 3.2 - 2 * np.pi], [0.4, 0.4]])
    out = on_branch(tracked, estimate)
    assert out[0] == pytest.approx([0.1, 0.2])  # before the log began: as the camera saw them
    assert out[1] == pytest.approx([3.0 - 2 * np.pi, 3.1 - 2 * np.pi])  # one turn down, as the board counts
    assert out[2, 0] == pytest.approx(0.5) and np.isnan(out[2, 1])  # no marker: still no angle


def test_the_command_writes_parquet_mcap_and_the_figure(filmed, tmp_path):
    import pandas as pd
    from mcap.reader import make_reader

    d = filmed[120]
    out = tmp_path / "tracked.parquet"
    r = run_rodctl("track", str(d["video"]), "--log", str(d["log"]), "--out", str(out), "--plot",
                   str(tmp_path / "track.png"), "--calibrate", str(d["board"]), "--quiet", timeout=300)
    assert r.returncode == 0, r.stderr
    line = next(ln for ln in r.stdout.splitlines() if ln.startswith("alignment: the video's first frame at "))
    assert float(line.split(" at ")[1].split(" s ")[0]) == pytest.approx(0.6, abs=1 / 120)
    df = pd.read_parquet(out)
    assert len(df) == 720 and list(df.columns[:4]) == ["time_s", "video_time_s", "frame", "quality"]
    assert [f"theta_{i}_rad" for i in range(1, 9)] == [c for c in df.columns if c.startswith("theta_")]
    assert df["time_s"].iloc[0] == pytest.approx(0.6, abs=1 / 120)
    with open(tmp_path / "tracked.mcap", "rb") as f:
        msgs = [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(topics=["/rod/tracked"])]
    assert len(msgs) == 720 and len(msgs[0]["theta_rad"]) == 8
    assert (tmp_path / "track.png").stat().st_size > 20000


def test_a_log_of_another_run_is_refused(filmed, tmp_path):
    other = tmp_path / "other.csv"
    run = run_rodctl("sim", "--scenario", "balance", "--log", str(other), "--no-plot", "--duration", "8", timeout=120)
    assert run.returncode in (0, 1), run.stderr
    out = tmp_path / "t.parquet"
    r = run_rodctl("track", str(filmed[60]["video"]), "--log", str(other), "--out", str(out), "--quiet", timeout=300)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "a log of another run?" in r.stderr
    assert not out.exists() and not out.with_suffix(".mcap").exists()


def test_a_video_without_the_markers_is_refused(filmed, tmp_path):
    out = tmp_path / "t.parquet"
    r = run_rodctl("track", str(filmed[60]["video"]), "--log", str(filmed[60]["log"]), "--color",
                   "40,90,90-80,255,255", "--out", str(out), "--quiet", timeout=300)  # green: nothing there
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "no markers of the color" in r.stderr and not out.exists()


@pytest.mark.parametrize("args, message", [
    (["missing.mp4", "--log", "LOG"], "video missing.mp4: no such file"),
    (["VIDEO", "--log", "LOG", "--color", "0,0,0-200,255,255"], "H must be 0 <= low <= high <= 179"),
    (["VIDEO", "--log", "LOG", "--scale", "-1"], "--scale -1: metres per pixel"),
    (["VIDEO", "--log", "LOG", "--out", "x.csv"], "the tracked log is Parquet"),
    (["VIDEO", "--log", "LOG", "--markers", "1"], "--markers 1: between 2 and 64"),
    (["LOG", "--log", "LOG"], "OpenCV cannot read it as a video"),
])
def test_bad_input_is_one_line_and_exit_2(filmed, tmp_path, args, message):
    d = filmed[60]
    args = [str(d["video"]) if a == "VIDEO" else str(d["log"]) if a == "LOG" else a for a in args]
    if "--out" not in args:
        args += ["--out", str(tmp_path / "t.parquet")]
    r = run_rodctl("track", *args, "--quiet", timeout=120)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert message in r.stderr
    assert not (tmp_path / "t.parquet").exists()
