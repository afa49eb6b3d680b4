"""`rodctl track` on videos rendered from the simulator, where the truth is known: every edge's angle,
the clock offset and drift, the estimate's error table; real MP4 files (OpenCV's mp4v), real readers
for what it writes; and the bad inputs."""

from __future__ import annotations

import json
from pathlib import Path

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
    assert not a.mirrored, a  # a swing's negative fits its half-period shift nearly as well: not taken for it
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
    (["VIDEO", "--log", "LOG", "--color", "0,0,0-200,255,255"], "H must be within 0..179 (low > high wraps through red)"),
    (["VIDEO", "--log", "LOG", "--color", "170,200,0-10,90,255"], "S must be 0 <= low <= high <= 255"),
    (["VIDEO", "--log", "LOG", "--scale", "-1"], "--scale -1: metres per pixel"),
    (["VIDEO", "--log", "LOG", "--out", "x.csv"], "the tracked log is Parquet"),
    (["VIDEO", "--log", "LOG", "--markers", "1"], "--markers 1: between 2 and 64"),
    (["VIDEO", "--log", "LOG", "--fps", "0"], "--fps 0: the rate the video was filmed at, above 0"),
    (["LOG", "--log", "LOG"], "OpenCV cannot read it as a video"),
    (["VIDEO", "--log", "LOG", "--calibrate", "VIDEO", "--board", "2x2"], "--board '2x2': at least 3x3 inner corners"),
    (["VIDEO", "--log", "LOG", "--board", "9x6"], "--board: describes the checkerboard of --calibrate IMAGE, which is not given"),
    (["VIDEO", "--log", "LOG", "--hub", "1e9,1e9"], "--hub 1e+09,1e+09: outside the video's 480x360 px image"),
    (["VIDEO", "--log", "FOLDER"], "is a folder, not a file"),
    (["VIDEO", "--log", "LOG", "--at", "nan"], "--at 'nan': times [s] on the log's clock"),
    (["VIDEO", "--log", "LOG", "--at", "1"], "--at 1: times of the figure's shape panels; add --plot PNG"),
    # known once the video is tracked: refused before the Parquet, the MCAP or the figure is written
    (["VIDEO", "--log", "LOG", "--plot", "PNG", "--at", "1,1e9"], "--at 1e+09: outside the tracked span"),
])
def test_bad_input_is_one_line_and_exit_2(filmed, tmp_path, args, message):
    d = filmed[60]
    args = [str(d["video"]) if a == "VIDEO" else str(d["log"]) if a == "LOG" else str(tmp_path) if a == "FOLDER"
            else str(tmp_path / "t.png") if a == "PNG" else a for a in args]
    if "--out" not in args:
        args += ["--out", str(tmp_path / "t.parquet")]
    r = run_rodctl("track", *args, "--quiet", timeout=120)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert message in r.stderr
    assert list(tmp_path.iterdir()) == []


def test_a_log_that_covers_part_of_the_video_is_said_so(filmed, tmp_path):
    """The log copied while the run went on (it ends 70 % of the way through the video): the frames it covers
    are compared, and a warning says how few and over how long the drift was measured."""
    d = filmed[120]
    lines = d["log"].read_text().splitlines(keepends=True)
    t = np.array([float(line.split(",", 1)[0]) for line in lines[1:]])
    keep = 1 + int(np.searchsorted(t, 0.6 + 0.7 * SECONDS[120]))
    cut = tmp_path / "cut.csv"
    cut.write_text("".join(lines[:keep]))
    for suffix in (".json", ".events.csv"):
        side = Path(f"{d['log']}{suffix}")
        if side.exists():
            Path(f"{cut}{suffix}").write_bytes(side.read_bytes())
    r = run_rodctl("track", str(d["video"]), "--log", str(cut), "--out", str(tmp_path / "t.parquet"), "--quiet",
                   timeout=300)
    assert r.returncode == 0, r.stderr
    warning = [ln for ln in r.stderr.splitlines() if "warning: the log covers" in ln]
    assert len(warning) == 1 and "only those are compared" in warning[0], r.stderr
    share = float(warning[0].split("covers ")[1].split(" %")[0])
    assert 65 <= share <= 72, warning  # 70 % of the clip, less the frames too few markers left unusable
    full = run_rodctl("track", str(d["video"]), "--log", str(d["log"]), "--out", str(tmp_path / "f.parquet"),
                      "--quiet", timeout=300)
    assert full.returncode == 0 and "warning: the log covers" not in full.stderr, full.stderr


def test_red_markers_are_tracked_with_a_hue_range_that_wraps(filmed, tmp_path):
    """The clip's pink markers turned red, half of each dot's pixels on either side of hue 0 (as a red sticker
    under warm light): a range that wraps through red finds the rod as the pink one did; the default pink
    range finds nothing."""
    from rodgains.errors import InputError

    from rodctl.track import track
    from rodctl.track.markers import ColorRange

    d = filmed[120]

    def redden(k, frame):
        hsv = cv2.cvtColor(frame, cv2.COLOR_BGR2HSV)
        pink = cv2.inRange(hsv, np.array([145, 90, 90], np.uint8), np.array([179, 255, 255], np.uint8)) > 0
        h = hsv[..., 0].astype(int)
        hsv[..., 0] = np.where(pink, np.where((np.arange(h.shape[1]) % 2)[None, :] == 0, 176, 3), h).astype(np.uint8)
        return cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)

    video = rewrite(d["video"], tmp_path / "red.mp4", change=redden)
    red = track(video, d["log"], None, color=ColorRange.parse("165,90,90-12,255,255"), say=None)
    pink = track(d["video"], d["log"], None, say=None)
    # measured: 688 frames with every marker seen in both
    assert red.counts()["good"] >= 0.98 * pink.counts()["good"], (red.counts(), pink.counts())
    assert red.alignment.offset_s == pytest.approx(pink.alignment.offset_s, abs=1 / 120)
    for one_side in (None, "0,90,90-12,255,255"):  # each half of a dot alone is no marker
        with pytest.raises(InputError):
            track(video, d["log"], None, color=ColorRange.parse(one_side), say=None)


def test_a_calibration_image_too_small_for_a_board_is_said_so(tmp_path):
    """An 8 x 8 px picture: OpenCV's adaptive threshold refuses it with an assertion; the user hears that no
    board is in it, exit 2."""
    from rodgains.errors import InputError

    from rodctl.track.calibrate import View

    tiny = tmp_path / "tiny.png"
    cv2.imwrite(str(tiny), np.full((8, 8, 3), 200, np.uint8))
    with pytest.raises(InputError, match=r"^--calibrate .*tiny.png: no 9x6 checkerboard \(inner corners\) found$"):
        View.from_checkerboard(tiny, (9, 6), 0.02)


@pytest.mark.parametrize("existing", ["t.parquet", "t.mcap", "t.png"])
def test_existing_outputs_are_kept_without_force(filmed, tmp_path, existing):
    d = filmed[60]
    (tmp_path / existing).write_text("mine")
    r = run_rodctl("track", str(d["video"]), "--log", str(d["log"]), "--out", str(tmp_path / "t.parquet"),
                   "--plot", str(tmp_path / "t.png"), "--quiet", timeout=120)
    assert r.returncode == 2 and "pass --force" in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == [existing] and (tmp_path / existing).read_text() == "mine"


# --- clips made from the 120 fps one with OpenCV (read, change, write again as MP4) ----------------------

def frames_of(src, keep=lambda k: True):
    """(fps, (width, height), an iterator over (index, BGR frame) of the frames of src that `keep` keeps)."""
    cap = cv2.VideoCapture(str(src))
    fps, size = cap.get(cv2.CAP_PROP_FPS), (int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)))

    def frames():
        k = 0
        try:
            while True:
                ok, f = cap.read()
                if not ok:
                    return
                if keep(k):
                    yield k, f
                k += 1
        finally:
            cap.release()

    return fps, size, frames()


def rewrite(src, dst, change=lambda k, frame: frame, keep=lambda k: True):
    """dst: src's frames (those `keep` keeps) through `change(index, frame)`, encoded again (mp4v)."""
    from rodctl.track.render import write_video

    fps, size, frames = frames_of(src, keep)
    write_video(dst, fps, (change(k, f) for k, f in frames), size)
    return dst


def test_a_video_started_before_the_log_is_aligned(tmp_path):
    """The camera started 0.5 s before the log: the log covers 92 % of the clip (the lag search scored
    r * overlap and took a lag 0.86 s off, with the drift at its +5000 ppm limit)."""
    from rodctl.track import track
    from rodctl.track.render import Filming, demo

    n = 720
    f = Filming(fps=120, offset_s=-0.5, drift_ppm=60.0, seconds=6.0, repeated_frames=(n // 8, n // 3),
                hand_frames=(n // 2, n // 2 + 30))
    d = demo(tmp_path, fps=120, seconds=6.0, filming=f)
    a = track(d["video"], d["log"], None, say=None).alignment
    assert abs(a.offset_s - (-0.5)) <= 1 / 120, a
    assert abs(a.drift_ppm - 60.0) <= DRIFT_PPM, a


def test_dropped_frames_are_refused_not_fitted(filmed, tmp_path):
    """10 frames of 720 left out (the container still says 120 fps): no clock fits; the fit's drift
    would stop at its +5000 ppm limit and be printed as measured."""
    d = filmed[120]
    drop = {60, 130, 200, 270, 340, 410, 480, 550, 620, 690}
    video = rewrite(d["video"], tmp_path / "dropped.mp4", keep=lambda k: k not in drop)
    out = tmp_path / "t.parquet"
    r = run_rodctl("track", str(video), "--log", str(d["log"]), "--out", str(out), "--quiet", timeout=300)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "ran into its limit" in r.stderr and not out.exists() and not out.with_suffix(".mcap").exists()


def rewrite_timed(src, dst, keep):
    """dst: src's frames that `keep` keeps, each stamped in the container with its own time (a camera that left
    frames out and said so, as a phone's variable frame rate does), encoded again with FFmpeg's mpeg4 (PyAV)."""
    import fractions

    av = pytest.importorskip("av")
    fps, (width, height), frames = frames_of(src, keep)
    tick = fractions.Fraction(1, 12_000)  # 100 ticks a frame at 120 fps (MPEG-4 part 2 allows 65535 a second)
    with av.open(str(dst), "w") as out:
        s = out.add_stream("mpeg4", rate=round(fps))
        s.width, s.height, s.pix_fmt = width, height, "yuv420p"
        s.time_base = s.codec_context.time_base = tick
        s.bit_rate = 20_000_000
        for k, f in frames:
            frame = av.VideoFrame.from_ndarray(f, format="bgr24")
            frame.pts, frame.time_base = round(k / fps / tick), tick
            out.mux(s.encode(frame))
        out.mux(s.encode())
    return dst


def test_frames_left_out_with_their_timestamps_are_timed_by_the_container(filmed, tracked, tmp_path):
    """The same 10 frames of 720 left out, but the container keeps each frame's own time (a real variable-rate
    file): the frames are timed by it, the clock fits as on the whole clip, and the warning says why."""
    from rodctl.track import track

    d = filmed[120]
    drop = {60, 130, 200, 270, 340, 410, 480, 550, 620, 690}
    video = rewrite_timed(d["video"], tmp_path / "vfr.mp4", keep=lambda k: k not in drop)
    r = track(video, d["log"], None, say=None)
    assert any("uneven frame timing (10 of 709 intervals" in w for w in r.warnings), r.warnings
    f, a = d["filming"], r.alignment
    assert abs(a.offset_s - f.offset_s) <= 1.0 / 120, a
    assert abs(a.drift_ppm - f.drift_ppm) <= DRIFT_PPM, a
    # the whole clip's fit: each frame put at the same log time within a tenth of a frame. Not the drift
    # itself: over 6 s it moves by 30 ppm (0.2 ms at the clip's end) with the sensor noise's draw alone
    whole, video_t = tracked[120].alignment, np.arange(720) / 120
    assert np.abs(a.log_time(video_t) - whole.log_time(video_t)).max() <= 0.1 / 120, (a, whole)


def test_a_still_rod_at_the_clips_ends_is_no_repeat_and_a_repeat_amid_motion_is():
    """Where the motion test cannot judge (the first two frames and the last two), the picture alone decided: a rod
    hanging still at the start shows the same picture twice and was called a dropped frame. A frame that repeats
    its predecessor while the rod moves on is still one."""
    from rodctl.track import REPEATED, flag_repeats

    F = 12
    still = np.zeros((F, 9, 2)) + np.arange(9)[None, :, None] * 20.0
    moving = still + np.arange(F)[:, None, None] * 3.0  # 3 px a frame
    moving[1], moving[F - 1] = moving[0], moving[F - 2]  # the first frame after and the last shown again
    for pos, repeated in ((still, []), (moving, [1, F - 1])):
        quality, same = np.zeros(F, np.int8), np.zeros(F, bool)
        same[[1, F - 1]] = True
        flag_repeats(pos.copy(), quality, same)
        assert np.flatnonzero(quality == REPEATED).tolist() == repeated


def test_a_rolled_camera_without_calibration_is_levelled(filmed, tmp_path):
    """The camera rolled 10 deg, no --calibrate: the roll the alignment measures is taken off every angle
    (it was left in: every edge 9 to 10 deg off)."""
    from rodctl.track import track

    d = filmed[120]
    h, w = cv2.imread(str(d["board"])).shape[:2]
    M = cv2.getRotationMatrix2D((w / 2, h / 2), 10.0, 1.0)  # counter-clockwise in the image
    video = rewrite(d["video"], tmp_path / "rolled.mp4",
                    change=lambda k, f: cv2.warpAffine(f, M, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE))
    said = []
    r = track(video, d["log"], None, say=said.append)
    assert np.degrees(r.roll_removed_rad) == pytest.approx(10.0, abs=1.0)
    assert len(said) == 1 and said[0].startswith("level: no --calibrate")
    ok = np.isfinite(r.theta).all(axis=1)
    true_t = d["filming"].log_time(np.arange(r.frames))
    rms = np.sqrt(np.mean(wrap_deg(r.theta[ok] - truth_angles(d, true_t[ok])) ** 2, axis=0))
    assert rms.max() <= 1.5, rms.round(2)


def test_a_mirrored_video_is_tracked_with_the_rod_s_own_sense(filmed, tmp_path):
    """The picture flipped left to right (a camera behind the rod's plane, a selfie camera): the rod turns
    against the encoder. It was refused as a clock that does not fit (the swing's negative correlates 0.98
    with a half-period shift of itself); now every edge is within 1.5 deg RMS of the truth, the clock
    within a frame, and a line says the video was mirrored."""
    from rodctl.track import track

    d = filmed[120]
    video = rewrite(d["video"], tmp_path / "mirrored.mp4", change=lambda k, f: cv2.flip(f, 1))
    said = []
    r = track(video, d["log"], None, say=said.append)
    assert r.alignment.mirrored and said[0].startswith("mirrored:"), said
    assert abs(r.alignment.offset_s - d["filming"].offset_s) <= 1 / 120, r.alignment
    ok = np.isfinite(r.theta).all(axis=1)
    true_t = d["filming"].log_time(np.arange(r.frames))
    rms = np.sqrt(np.mean(wrap_deg(r.theta[ok] - truth_angles(d, true_t[ok])) ** 2, axis=0))
    assert rms.max() <= 1.5, rms.round(2)
    # the markers are written in the rod's own plane, as seen from the front: the tip on the truth's side
    tip_x = r.markers_m[ok, -1, 0]
    assert np.corrcoef(tip_x, np.sin(truth_angles(d, true_t[ok])).sum(axis=1))[0, 1] > 0.99


def test_a_slow_motion_file_is_timed_as_filmed(filmed, tmp_path):
    """The 240 fps clip written into a file that plays at 30 fps, as a phone's slow-motion video is: it was
    refused as a log of another run (a clock 8 x slow fits nothing). The factor is found from the swing and said; the clock comes out
    within a frame as filmed, every edge within 1.5 deg RMS of the truth; --fps 240 gives the same clock."""
    from rodctl.track import track
    from rodctl.track.render import write_video

    d = filmed[240]
    _, size, frames = frames_of(d["video"])
    video = tmp_path / "slomo.mp4"
    write_video(video, 30.0, (f for _, f in frames), size)
    said = []
    r = track(video, d["log"], None, say=said.append)
    a, f = r.alignment, d["filming"]
    assert a.slowdown == 8.0 and r.fps == 240.0 and said[0].startswith("slow motion: the file plays at 30 fps, 8 x"), said
    assert abs(a.offset_s - f.offset_s) <= 1 / 240 and abs(a.drift_ppm - f.drift_ppm) <= DRIFT_PPM, a
    ok = np.isfinite(r.theta).all(axis=1)
    true_t = f.log_time(np.arange(r.frames))
    assert np.allclose(r.time_s, a.offset_s + a.rate * np.arange(r.frames) / 240.0)
    rms = np.sqrt(np.mean(wrap_deg(r.theta[ok] - truth_angles(d, true_t[ok])) ** 2, axis=0))
    assert rms.max() <= 1.5, rms.round(2)
    told = track(video, d["log"], None, filmed_fps=240.0, say=None).alignment
    assert told.slowdown == 8.0 and abs(told.offset_s - a.offset_s) < 1e-9, told


def test_flickering_light_is_no_repeated_frame(filmed, tmp_path):
    """100 Hz light flicker (25 %) at 120 fps: only the two repeated frames are flagged (a brightness
    test flagged a third of the frames)."""
    from rodctl.track import track
    from rodctl.track.calibrate import View
    from rodctl.track.shape import REPEATED

    d = filmed[120]

    def flicker(k, f):
        return np.clip(f * (1.0 + 0.25 * np.sin(2 * np.pi * 100.0 * k / 120.0)), 0, 255).astype(np.uint8)

    video = rewrite(d["video"], tmp_path / "flicker.mp4", change=flicker)
    r = track(video, d["log"], None, view=View.from_checkerboard(d["board"], (9, 6), 0.02))
    flagged = set(np.flatnonzero(r.quality == REPEATED))
    assert flagged and flagged <= set(d["filming"].repeated_frames), sorted(flagged)


def test_a_marker_cut_by_the_image_border_is_not_seen(filmed, tmp_path):
    """The frame cut at x = 300 px: the markers the border cuts are left out, not taken at a shifted
    centroid (their edges were 4 to 6 deg off)."""
    from rodctl.track import track
    from rodctl.track.calibrate import View

    d = filmed[120]
    h = cv2.imread(str(d["board"])).shape[0]
    video = tmp_path / "cut.mp4"
    cap = cv2.VideoCapture(str(d["video"]))
    from rodctl.track.render import write_video

    def frames():
        while True:
            ok, f = cap.read()
            if not ok:
                return
            yield np.ascontiguousarray(f[:, :300])

    write_video(video, 120, frames(), (300, h))
    r = track(video, d["log"], None, view=View.from_checkerboard(d["board"], (9, 6), 0.02))
    ok = np.isfinite(r.theta).all(axis=1)
    err = wrap_deg(r.theta[ok] - truth_angles(d, d["filming"].log_time(np.arange(r.frames))[ok]))
    assert np.percentile(np.abs(err), 99.9) <= 3.0, np.percentile(np.abs(err), 99.9)


def test_still_things_of_the_markers_colour_within_the_rod_s_reach_are_left_out(filmed, tracked, tmp_path):
    """Two pink stickers in the background, where the rod sweeps past them and where the balanced rod stands:
    they join no chain of markers and neither is taken for the axis (one was, and the video was refused; the
    other bent the chain: 5.3 deg RMS, 91 deg at the 99.9th percentile); a marker passing over one is filled in."""
    from rodctl.track import track
    from rodctl.track.calibrate import View
    from rodctl.track.render import MARKER_BGR

    d = filmed[120]
    hub = tracked[120].hub_px
    stickers = [(int(hub[0] + 60), int(hub[1] + 38)), (int(hub[0]), int(hub[1] - 102))]

    def stick(k, frame):
        for c in stickers:
            cv2.circle(frame, c, 6, MARKER_BGR, -1, cv2.LINE_AA)
        return frame

    video = rewrite(d["video"], tmp_path / "stickers.mp4", change=stick)
    r = track(video, d["log"], None, view=View.from_checkerboard(d["board"], (9, 6), 0.02), say=None)
    assert np.linalg.norm(r.hub_px - hub) < 1.0
    ok = np.isfinite(r.theta).all(axis=1)
    assert ok.mean() >= 0.99
    err = wrap_deg(r.theta[ok] - truth_angles(d, d["filming"].log_time(np.arange(r.frames))[ok]))
    assert np.sqrt(np.mean(err**2)) <= 1.0 and np.percentile(np.abs(err), 99.9) <= 3.0  # measured 0.73 / 2.33


def test_a_truncated_video_is_one_line(filmed, tmp_path):
    """FFmpeg's own "moov atom not found" stays off stderr: the user sees rodctl's one line."""
    d = filmed[60]
    bad = tmp_path / "cut.mp4"
    bad.write_bytes(d["video"].read_bytes()[:4096])
    out = tmp_path / "t.parquet"
    r = run_rodctl("track", str(bad), "--log", str(d["log"]), "--out", str(out), "--quiet", timeout=120)
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [f"rodctl: video {bad}: OpenCV cannot read it as a video"]
    assert not out.exists()


def test_the_renderer_has_a_help(tmp_path):
    import subprocess
    import sys

    from host_tools import rodctl_env

    r = subprocess.run([sys.executable, "-m", "rodctl.track.render", "--help"], cwd=tmp_path, capture_output=True,
                       text=True, timeout=120, env=rodctl_env())
    assert r.returncode == 0 and "usage:" in r.stdout and "--fps" in r.stdout
    assert list(tmp_path.iterdir()) == []  # nothing rendered (it rendered into a folder named --help)


def test_a_clip_too_short_to_place_in_the_log_is_refused_not_fitted_a_swing_away(filmed, tmp_path):
    """The first second of the 120 fps clip alone: its best fit was a lag 1.05 s off, mirrored, with a drift of
    +4648 ppm and every edge 13 to 20 deg off, accepted with only a coverage warning. Its residual says so."""
    d = filmed[120]
    video = rewrite(d["video"], tmp_path / "short.mp4", keep=lambda k: k < 120)
    out = tmp_path / "t.parquet"
    r = run_rodctl("track", str(video), "--log", str(d["log"]), "--out", str(out), "--quiet", timeout=300)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "only loosely" in r.stderr and "markers span 1.0 s, too short to place" in r.stderr
    assert not out.exists() and not out.with_suffix(".mcap").exists()


def test_a_frame_left_out_without_a_gap_is_a_drift_no_camera_has_and_is_said(filmed, tmp_path):
    """One frame of 720 left out, the container still at 120 fps: the clock fit takes it as a drift of over
    +1000 ppm (a camera's is a few hundred at most) and the frames' times are off by a few ms: said, not silent."""
    import re

    d = filmed[120]
    video = rewrite(d["video"], tmp_path / "one_dropped.mp4", keep=lambda k: k != 360)
    out = tmp_path / "t.parquet"
    r = run_rodctl("track", str(video), "--log", str(d["log"]), "--out", str(out), "--quiet", timeout=300)
    assert r.returncode == 0, r.stderr
    m = re.search(r"warning: the fitted clock drift ([+-]\d+) ppm \(\+-\d+\) is more than a camera's clock drifts",
                  r.stderr)
    assert m and 1000 < int(m.group(1)) < 4000, r.stderr  # 1 of 720 frames is 1389 ppm of the clip; measured 2215
    assert "frame times may be off by up to" in r.stderr


def test_a_rod_that_never_moves_asks_for_the_axis_instead_of_more_markers(filmed, tmp_path):
    """Every marker holds still, so none can be told as the one the rod turns about. It was "never saw all 8
    markers: pass --markers", with all 8 in every frame (the hub taken at a marker halfway down the rod)."""
    d = filmed[120]
    still = {}

    def frozen(k, frame):
        return still.setdefault("frame", frame)  # the first frame, again and again
    video = rewrite(d["video"], tmp_path / "still.mp4", change=frozen, keep=lambda k: k < 240)
    r = run_rodctl("track", str(video), "--log", str(d["log"]), "--out", str(tmp_path / "t.parquet"), "--quiet",
                   timeout=300)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "the rod hardly moves in this video: 9 of its markers hold still" in r.stderr and "--hub X,Y" in r.stderr


def test_a_short_clip_holds_the_clock_it_cannot_measure_at_the_camera_s(filmed, tmp_path):
    """1.5 s of the 120 fps clip: the fitted drift was -3710 ppm (a camera's: a few hundred), which put the first frame
    4.4 ms off. The drift's own uncertainty says the clip cannot measure it, so the camera's nominal clock is held."""
    import re

    d = filmed[120]
    video = rewrite(d["video"], tmp_path / "short.mp4", keep=lambda k: k < 180)
    r = run_rodctl("track", str(video), "--log", str(d["log"]), "--out", str(tmp_path / "t.parquet"), timeout=300)
    assert r.returncode == 0 and "warning" not in r.stderr, r.stderr
    m = re.search(r"alignment: the video's first frame at ([\d.]+) s of the log, clock drift not measurable over "
                  r"1\.5 s \(\+-\d+ ppm\), held at 0,", r.stdout)
    assert m and abs(float(m.group(1)) - d["filming"].offset_s) <= 1 / 120, r.stdout
