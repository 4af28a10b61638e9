"""Offscreen MP4 videos of twin runs (twin.render): decoded back with OpenCV and looked at."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")

from twin.controllers.cascade import build_cascade  # noqa: E402
from twin.experiments import PAPER_EXPERIMENTS, Experiment  # noqa: E402
from twin.sim.bullet_loop import simulate_twin  # noqa: E402
from twin.errors import TwinError  # noqa: E402
from twin.plant.bullet import WHEEL_JOINTS, BulletTwin, GroundTruth, TwinConfig, truth_from_states  # noqa: E402
from twin.plant.disturbances import Disturbances, Ground, Push  # noqa: E402
from twin.render import (CODECS, Camera, HudState, Scene, draw_hud, frame_count, frame_times,  # noqa: E402
                         render_video, resolve_renderer)
from twin.render import hud  # noqa: E402
from twin.render.hud import RED, hud_lines  # noqa: E402
from twin.render.scene import egl_available  # noqa: E402

SIZE = (320, 240)  # small panels keep the encoder quick
FPS = 30


# ---- runs -------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def run_exp1(design):
    """Paper experiment 1 (balance from θ0 = 0.48 rad), its first second, IT2, ideal sensing."""
    exp = PAPER_EXPERIMENTS[1]
    run = simulate_twin(build_cascade("it2", design, exp.targets), exp, duration=1.0, controller_name="it2",
                        sensors=None)
    assert run.status == "ok" and abs(run.signal("theta")[-1]) < 0.1
    return run


@pytest.fixture(scope="module")
def run_fell(design):
    """Type-1 balance only, pushed over by 28 N for 0.1 s: falls after about 0.55 s (the default
    design rides out 24 N)."""
    exp = Experiment("push", "pushed over", theta0=0.0, duration=1.0)
    config = TwinConfig(disturbances=Disturbances(pushes=(Push((28.0, 0.0, 0.0), 0.2, 0.1),)))
    run = simulate_twin(build_cascade("t1", design, exp.targets), exp, config, controller_name="t1", sensors=None)
    assert run.status == "fell" and 0.3 < run.t[-1] < 0.9
    return run


@pytest.fixture(scope="module")
def egl_loads():
    try:
        with Scene(TwinConfig(), (64, 48), "auto") as scene:
            return scene.renderer == "egl"
    except TwinError:
        return False


@pytest.fixture(params=["tiny", "egl"])
def renderer(request, egl_loads):
    if request.param == "egl" and not egl_loads:
        pytest.skip("PyBullet's EGL renderer plugin does not load on this machine")
    return request.param


# ---- helpers ----------------------------------------------------------------------------------
def read_video(path) -> list[np.ndarray]:
    cap = cv2.VideoCapture(str(path))
    assert cap.isOpened(), f"OpenCV cannot open {path}"
    frames = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        frames.append(frame)
    cap.release()
    return frames


def orange(bgr: np.ndarray) -> np.ndarray:
    """Pixels of the robot's body colour (orange; the floor is blue and white, the sky grey)."""
    hsv = cv2.cvtColor(bgr, cv2.COLOR_BGR2HSV)
    h, s, v = hsv[..., 0].astype(int), hsv[..., 1].astype(int), hsv[..., 2].astype(int)
    return (h >= 5) & (h <= 20) & (s >= 120) & (v >= 60)


def lean(bgr: np.ndarray) -> float:
    """How the robot's body leans in the picture: the slope dx/dy (px/px) of its pixels,
    positive with the top to the right of the bottom."""
    ys, xs = np.nonzero(orange(bgr))
    return float(-np.cov(xs, ys)[0, 1] / np.var(ys))


def changed(a: np.ndarray, b: np.ndarray) -> float:
    """Fraction of the pixels that differ clearly (by more than 40 levels in a channel)."""
    return float((np.abs(a.astype(int) - b.astype(int)).max(axis=2) > 40).mean())


def hud_rows(size=SIZE) -> int:
    """How far down the overlay's box reaches in a panel of ``size``."""
    img = np.full((size[1], size[0], 3), 255, np.uint8)
    draw_hud(img, HudState("IT2  paper-exp1", 1.0, 0.1, 0.2, 0.3, 1.0, 1.5, "FELL at 1.00 s", True))
    return int(np.nonzero((img < 255).any(axis=(1, 2)))[0].max()) + 1


def pose_args(run, i: int):
    tr = run.truth[i]
    names = GroundTruth._fields
    return tuple(float(tr[names.index(n)]) for n in ("theta", "alpha", "x", "y", "psi_l", "psi_r", "roll"))


# ---- timing -----------------------------------------------------------------------------------
def test_frame_count_is_real_time_at_fps():
    assert frame_count(2.0, 30) == 61
    assert frame_count(0.0, 30) == 1
    assert frame_count(0.1, 30) == 4  # 0.1 · 30 = 3.0000000000000004: not 5 frames, not 3
    assert frame_count(0.0999, 30) == 3
    t = frame_times(1.0, 30)
    assert len(t) == 31 and t[0] == 0.0 and t[-1] == pytest.approx(1.0) and np.allclose(np.diff(t), 1 / 30)


# ---- the scene --------------------------------------------------------------------------------
def test_scene_poses_the_robot_as_the_twin_does():
    """The replayed pose reads back, through the twin's own readout, as the logged state; and
    the twin's state at spawn replays exactly where BulletTwin put the robot (on a slope,
    with a centre-of-mass offset)."""
    config = TwinConfig(ground=Ground(slope=0.12, slope_direction=0.7),
                        disturbances=Disturbances(com_offset=(0.01, -0.005, 0.008)))
    com_local = (0.01, -0.005, config.params.l + 0.008)
    with BulletTwin(config, theta0=0.3, alpha0=0.5, position=(0.2, -0.1)) as twin:
        spawned = twin.client.getBasePositionAndOrientation(twin.robot)
        t0 = twin.truth
    assert abs(t0.roll) > 0.01, "the slope rolls the robot: the test covers roll"
    with Scene(config, (64, 48), "tiny") as scene:
        c, rob = scene.client, scene.robot
        for theta, alpha, x, y, pl, pr, roll in ((0.48, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
                                                 (-0.3, 1.2, 0.4, -0.7, 5.0, -2.5, 0.05),
                                                 (0.05, -2.9, -1.5, 2.0, 40.0, 41.0, -0.1)):
            scene.pose(theta, alpha, x, y, pl, pr, roll)
            pose = c.getBasePositionAndOrientation(rob)
            joints = c.getJointStates(rob, WHEEL_JOINTS)
            tr, _ = truth_from_states(GroundTruth, pose, ((0.0,) * 3, (0.0,) * 3), joints, alpha, com_local,
                                      config.params.r, 0.0)
            got = (tr.theta, tr.alpha, tr.roll, tr.x, tr.y, tr.psi_l, tr.psi_r)
            assert got == pytest.approx((theta, alpha, roll, x, y, pl, pr), abs=1e-9)
        scene.pose(t0.theta, t0.alpha, t0.x, t0.y, t0.psi_l, t0.psi_r, t0.roll)
        mine = c.getBasePositionAndOrientation(rob)
    assert np.allclose(mine[0], spawned[0], atol=1e-7) and np.allclose(mine[1], spawned[1], atol=1e-7)


def test_scene_shows_the_robot_leaning_the_logged_way(renderer, run_exp1):
    side = Camera(distance=0.5, yaw=0.0, pitch=-5.0)  # at the robot's right side: forward is to the right
    with Scene(run_exp1.config, SIZE, renderer, side) as scene:
        assert scene.renderer == renderer
        start = cv2.cvtColor(scene.render(*pose_args(run_exp1, 0)), cv2.COLOR_RGB2BGR)
        empty = cv2.cvtColor(scene.render(*pose_args(run_exp1, 0), show_robot=False), cv2.COLOR_RGB2BGR)
        end = cv2.cvtColor(scene.render(*pose_args(run_exp1, -1)), cv2.COLOR_RGB2BGR)
    assert start.shape == (SIZE[1], SIZE[0], 3)
    n_pixels = SIZE[0] * SIZE[1]
    assert orange(start).sum() > 0.03 * n_pixels and orange(end).sum() > 0.03 * n_pixels
    assert orange(empty).sum() == 0, "the floor and sky have no orange: the detector sees the robot only"
    # the robot is where it is projected: in the middle of the picture
    ys, xs = np.nonzero(orange(start))
    assert SIZE[0] * 0.25 < xs.mean() < SIZE[0] * 0.75 and SIZE[1] * 0.2 < ys.mean() < SIZE[1] * 0.8
    # θ0 = 0.48 rad leans forward (to the right); at the end it stands upright
    assert lean(start) > 0.12 and abs(lean(end)) < 0.04, (lean(start), lean(end))
    # with the robot gone, what changes is where it stood
    changed = np.abs(start.astype(int) - empty.astype(int)).max(axis=2) > 30
    assert changed.sum() > 0.03 * n_pixels


def test_renderer_choice(monkeypatch):
    monkeypatch.setenv("TWIN_RENDERER", "tiny")
    assert resolve_renderer() == "tiny"
    with Scene(TwinConfig(), (64, 48)) as scene:
        assert scene.renderer == "tiny"
    assert resolve_renderer("EGL") == "egl"
    monkeypatch.setenv("TWIN_RENDERER", "vulkan")
    with pytest.raises(TwinError, match="TWIN_RENDERER must be one of auto, egl, tiny, got 'vulkan'"):
        resolve_renderer()
    with pytest.raises(TwinError, match="renderer must be one of auto, egl, tiny"):
        Scene(TwinConfig(), (64, 48), renderer="opengl")


def test_without_egl_auto_takes_tiny_and_egl_says_so(monkeypatch):
    import twin.render.scene as scene_module

    monkeypatch.delenv("TWIN_RENDERER", raising=False)
    monkeypatch.setattr(scene_module, "_egl_works", False)  # as the child process found on a machine without EGL
    with Scene(TwinConfig(), (64, 48)) as scene:
        assert scene.renderer == "tiny"
    with pytest.raises(TwinError, match="the EGL renderer plugin does not work here .*use renderer 'tiny' or 'auto'"):
        Scene(TwinConfig(), (64, 48), "egl")


# ---- videos -----------------------------------------------------------------------------------
def test_video_of_one_run(renderer, run_exp1, tmp_path):
    path = tmp_path / "exp1.mp4"
    calls = []
    info = render_video(run_exp1, path, fps=FPS, size=SIZE, renderer=renderer,
                        progress=lambda done, total: calls.append((done, total)))
    n = 31  # floor(1.0 s · 30) + 1
    assert (info.frames, info.size, info.fps, info.panels, info.renderer) == (n, SIZE, 30.0, 1, renderer)
    assert info.codec in CODECS and info.path == path and info.duration == pytest.approx(n / 30)
    assert info.seconds > 0 and info.render_seconds > 0 and info.encode_seconds > 0
    assert calls == [(k, n) for k in range(1, n + 1)]
    assert [p.name for p in tmp_path.iterdir()] == ["exp1.mp4"], "no partial file left behind"

    frames = read_video(path)
    assert abs(len(frames) - n) <= 1
    assert all(f.shape == (SIZE[1], SIZE[0], 3) for f in frames)
    below = hud_rows()
    first, last = frames[0][below:], frames[-1][below:]
    # the robot swings up from 0.48 rad and rolls forward: the pictures differ where it is
    assert changed(first, last) > 0.015
    # frames keep changing as it moves: early frames 0.1 s apart differ
    assert changed(frames[3][below:], frames[6][below:]) > 0.02
    for f in (first, last):
        assert orange(f).mean() > 0.03, "the robot is in the picture"
    assert lean(first) > lean(last) + 0.2, "leaning forward (to the right) at the start"


def test_video_side_by_side_holds_the_shorter_run(run_exp1, run_fell, tmp_path):
    info = render_video([run_exp1, run_fell], tmp_path / "both.mp4", size=SIZE)
    w, h = SIZE
    assert info.panels == 2 and info.size == (2 * w, h) and info.frames == 31
    frames = read_video(info.path)
    assert abs(len(frames) - 31) <= 1
    assert all(f.shape == (h, 2 * w, 3) for f in frames)
    k_held = int(math.ceil(float(run_fell.t[-1]) * FPS)) + 1  # the first frame after the fall
    # the fallen run's panel stands still once its log has ended; the other goes on
    below = hud_rows()
    right = [f[below:, w + 2:] for f in frames]
    left = [f[below:, :w - 2] for f in frames]
    assert changed(right[k_held], right[-1]) < 0.002
    assert np.abs(right[k_held].astype(int) - right[-1].astype(int)).mean() < 1.5
    assert changed(right[0], right[k_held]) > 0.05
    assert changed(left[0], left[-1]) > 0.015
    for f in (frames[0], frames[-1]):  # both robots in their panels
        assert orange(f[below:, :w]).mean() > 0.03 and orange(f[below:, w:]).mean() > 0.03


def test_panels_rendered_in_worker_processes_are_the_same_frames(run_exp1, run_fell, tmp_path):
    """The parallel path (one worker process per panel) gives the serial path's frames, bit
    for bit, and the same file."""
    a = render_video([run_exp1, run_fell], tmp_path / "serial.mp4", size=SIZE, parallel=False)
    b = render_video([run_exp1, run_fell], tmp_path / "parallel.mp4", size=SIZE, parallel=True)
    assert a.renderer == b.renderer and a.frames == b.frames == 31
    fa, fb = read_video(a.path), read_video(b.path)
    assert len(fa) == len(fb) == 31 and all(np.array_equal(x, y) for x, y in zip(fa, fb))
    assert a.path.read_bytes() == b.path.read_bytes()


def test_a_worker_that_fails_is_one_line_and_leaves_no_video(run_exp1, run_fell, tmp_path, monkeypatch):
    import sys

    # the worker exits at once without a word (an interpreter that is /bin/false): the
    # parent must say so in one line, not hang or write a video
    monkeypatch.setattr(sys, "executable", "/bin/false")
    with pytest.raises(TwinError, match=r"the renderer process of video panel 1 ended without a word \(exit status 1\)"):
        render_video([run_exp1, run_fell], tmp_path / "v.mp4", size=SIZE, parallel=True)
    assert list(tmp_path.iterdir()) == []


def test_hud_is_drawn(run_exp1, tmp_path):
    with_hud = read_video(render_video(run_exp1, tmp_path / "hud.mp4", fps=5, size=SIZE).path)
    without = read_video(render_video(run_exp1, tmp_path / "plain.mp4", fps=5, size=SIZE, hud=False).path)
    assert len(with_hud) == len(without) == 6
    rows = hud_rows()
    a, b = with_hud[0].astype(int), without[0].astype(int)
    box_diff = np.abs(a[:rows, :SIZE[0] // 2] - b[:rows, :SIZE[0] // 2]).mean()
    rest_diff = np.abs(a[rows + 8:] - b[rows + 8:]).mean()
    assert box_diff > 20 and rest_diff < 2, (box_diff, rest_diff)
    # white text on the darkened box
    assert (a[:rows, :SIZE[0] // 2].min(axis=2) > 200).sum() > 100


def test_hud_says_what_it_shows():
    s = HudState("IT2  paper-exp3", 1.234, math.radians(-5.0), 0.4567, 1.0, p_d=1.0, alpha_d=1.5,
                 ended="FELL at 1.23 s", alarm=True)
    lines = hud_lines(s)
    text = [t for t, _ in lines]
    assert text[0] == "IT2  paper-exp3"
    assert "1.23 s" in text[1] and "-0.087 rad" in text[2]  # SI, as everywhere: no degrees
    assert "+0.457 m" in text[3] and "(target 1.00 m)" in text[3]
    assert "+1.000 rad" in text[4] and "(target 1.50 rad)" in text[4]
    assert lines[-1] == ("FELL at 1.23 s", RED)
    quiet = [t for t, _ in hud_lines(HudState("T1", 0.0, -1e-9, -1e-9, -1e-9))]
    assert len(quiet) == 5 and not any("target" in t or "-0.0" in t for t in quiet)
    img = np.full((240, 320, 3), 128, np.uint8)
    draw_hud(img, s)
    assert (img[:20, :20] != 128).any() and (img[-40:, -40:] == 128).all()


def test_rendering_leaves_the_run_alone(run_fell, tmp_path):
    before = run_fell.truth.copy(), run_fell.t.copy()
    render_video(run_fell, tmp_path / "fell.mp4", fps=5, size=(64, 48))
    assert np.array_equal(run_fell.truth, before[0]) and np.array_equal(run_fell.t, before[1])


@pytest.mark.parametrize("kwargs, message", [
    (dict(runs=[]), "runs is empty: give a TwinRun or a sequence of at least one"),
    (dict(runs="run.csv"), "runs must be a TwinRun or a sequence of TwinRun, got str"),
    (dict(runs=[None]), r"runs\[0\] must be a TwinRun"),
    (dict(fps=0), r"fps must be a number of frames per second in \[1, 240\], got 0"),
    (dict(fps=-30), "fps must be a number of frames per second"),
    (dict(fps=float("nan")), "fps must be a number of frames per second"),
    (dict(fps=True), "fps must be a number of frames per second"),
    (dict(size=(0, 0)),
     r"size must be \(width, height\) in pixels, even integers from 32x24 to 3840x2160, got \(0, 0\)"),
    (dict(size=(641, 480)), "size must be .*got \\(641, 480\\)"),
    (dict(size=(100000, 480)), "size must be"),
    (dict(size=(640.0, 480)), "size must be"),
    (dict(size="640x480"), "size must be"),
    (dict(size=(640,)), "size must be"),
    (dict(path="video.avi"), r"path must end in \.mp4 \(the video is an MP4 file\), got 'video.avi'"),
    (dict(path=3), "path must be a file path ending in .mp4, got 3"),
    (dict(labels=["only one", "too many"]), "labels must be a sequence of 1 strings, one per run"),
    (dict(progress="yes"), "progress must be a callable"),
    (dict(renderer="vulkan"), "renderer must be one of auto, egl, tiny, got 'vulkan'"),
    (dict(camera="side"), "camera must be a twin.render.Camera"),
    (dict(parallel="yes"), "parallel must be True, False or None"),
])
def test_bad_input_is_a_twin_error(kwargs, message, run_exp1, tmp_path):
    args = dict(runs=run_exp1, path=tmp_path / "v.mp4", size=(64, 48))
    args.update(kwargs)
    with pytest.raises(TwinError, match=message):
        render_video(args.pop("runs"), args.pop("path"), **args)
    assert list(tmp_path.iterdir()) == [], "nothing written"


def test_bad_paths_are_twin_errors(run_exp1, tmp_path):
    (tmp_path / "dir.mp4").mkdir()
    with pytest.raises(TwinError, match="is a directory; give a file name ending in .mp4"):
        render_video(run_exp1, tmp_path / "dir.mp4", size=(64, 48))
    (tmp_path / "file").write_text("not a directory")
    with pytest.raises(TwinError, match="cannot write the video .*file/v.mp4"):
        render_video(run_exp1, tmp_path / "file" / "v.mp4", size=(64, 48))
    with pytest.raises(TwinError, match="panels of 3840 px make the video 11520 px wide; at most 7680"):
        render_video([run_exp1] * 3, tmp_path / "wide.mp4", size=(3840, 480))
    with pytest.raises(TwinError, match=r"camera distance must be a number in \[0.05, 100\], got -1"):
        Camera(distance=-1)
    # a missing directory is made
    info = render_video(run_exp1, tmp_path / "new" / "dir" / "v.mp4", fps=2, size=(64, 48))
    assert info.path.is_file() and info.frames == 3


def test_closing_one_egl_scene_leaves_the_others_working(tmp_path):
    """PyBullet's EGL plugin tears down process-wide state when one client unloads it or
    disconnects: another EGL scene then crashed (SIGSEGV) on its next picture. A closed EGL
    scene is now parked until the last one closes. In a child process, so a crash fails the
    test instead of killing the run."""
    import subprocess
    import sys

    if not egl_available():
        pytest.skip("the EGL renderer plugin does not work here")
    script = tmp_path / "egl.py"
    script.write_text(
        "from twin.plant.bullet import TwinConfig\n"
        "from twin.render import scene\n"
        "a = scene.Scene(TwinConfig(), (160, 120), 'egl'); a.render(0.1, 0, 0, 0, 0, 0)\n"
        "b = scene.Scene(TwinConfig(), (160, 120), 'egl'); b.render(0.1, 0, 0, 0, 0, 0); b.close()\n"
        "first = a.render(0.1, 0, 0, 0, 0, 0)\n"
        "c = scene.Scene(TwinConfig(), (160, 120), 'egl'); a.close()\n"
        "second = c.render(0.2, 0, 0, 0, 0, 0); c.close()\n"
        "assert first.std() > 0 and second.std() > 0\n"
        "assert not scene._EGL_OPEN and not scene._EGL_PARKED\n"
        "print('ok')\n", encoding="utf-8")
    r = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and r.stdout.strip() == "ok", (r.returncode, r.stderr[-2000:])


# ---- encoders ---------------------------------------------------------------------------------
def fourcc_of(path) -> str:
    """The codec OpenCV's decoder reports for ``path`` (FourCC, lower case)."""
    cap = cv2.VideoCapture(str(path))
    code = int(cap.get(cv2.CAP_PROP_FOURCC))
    cap.release()
    return "".join(chr((code >> 8 * i) & 0xFF) for i in range(4)).lower()


def ffmpeg_says(path) -> str:
    """ffmpeg's description of the video stream of ``path`` (it has no ffprobe beside it)."""
    import subprocess

    import imageio_ffmpeg

    err = subprocess.run([imageio_ffmpeg.get_ffmpeg_exe(), "-hide_banner", "-i", str(path)],
                         capture_output=True, text=True).stderr
    return next(line for line in err.splitlines() if "Video:" in line)


def test_video_is_h264_by_ffmpeg(run_exp1, tmp_path):
    pytest.importorskip("imageio_ffmpeg")
    info = render_video(run_exp1, tmp_path / "h264.mp4", fps=FPS, size=SIZE)
    assert (info.codec, info.encoder, info.note) == ("avc1", "ffmpeg libx264", "")
    assert fourcc_of(info.path) in ("avc1", "h264")
    stream = ffmpeg_says(info.path)
    assert "h264" in stream and "yuv420p" in stream and f"{SIZE[0]}x{SIZE[1]}" in stream, stream
    data = info.path.read_bytes()
    assert data.index(b"moov") < data.index(b"mdat"), "+faststart: the index comes before the frames"
    frames = read_video(info.path)
    assert len(frames) == info.frames == 31  # exactly: H.264 by ffmpeg neither drops nor adds frames
    assert all(f.shape == (SIZE[1], SIZE[0], 3) for f in frames)
    below = hud_rows()
    assert changed(frames[3][below:], frames[6][below:]) > 0.02, "frames change as the robot moves"
    assert orange(frames[-1][below:]).mean() > 0.03, "the robot is in the picture"


def test_libopenh264_where_ffmpeg_has_no_libx264(run_exp1, tmp_path, monkeypatch):
    pytest.importorskip("imageio_ffmpeg")
    import twin.render.video as video

    monkeypatch.setattr(video, "_h264_encoder", lambda exe: "libopenh264")
    info = render_video(run_exp1, tmp_path / "openh264.mp4", fps=10, size=SIZE)
    assert (info.codec, info.encoder, info.note) == ("avc1", "ffmpeg libopenh264", "")
    assert fourcc_of(info.path) in ("avc1", "h264") and len(read_video(info.path)) == info.frames == 11


def test_without_ffmpeg_opencv_writes_the_video_and_says_why(run_exp1, tmp_path, monkeypatch):
    import sys

    monkeypatch.setenv("IMAGEIO_FFMPEG_EXE", str(tmp_path / "no-such-ffmpeg"))  # imageio-ffmpeg's override
    info = render_video(run_exp1, tmp_path / "missing.mp4", fps=5, size=(64, 48))
    assert info.codec in CODECS[1:] and info.encoder == f"opencv {info.codec}"
    assert info.note.startswith(f"video encoded by OpenCV as {info.codec}, not H.264: ffmpeg ")
    assert "no-such-ffmpeg" in info.note and "does not run" in info.note and "\n" not in info.note
    assert fourcc_of(info.path) not in ("avc1", "h264") and len(read_video(info.path)) == info.frames == 6

    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # as if the package were not installed
    info = render_video(run_exp1, tmp_path / "no-package.mp4", fps=5, size=(64, 48))
    assert info.codec in CODECS[1:]
    assert info.note.endswith("not H.264: the package imageio-ffmpeg is not installed")


def test_twin_run_notes_the_fallback_encoder(tmp_path, monkeypatch):
    from twin.scenarios import load_scenario
    from twin.workflows.run import run_scenario

    monkeypatch.setenv("IMAGEIO_FFMPEG_EXE", str(tmp_path / "no-such-ffmpeg"))
    sc = load_scenario("paper-exp2", ["duration=0.2", "video.width=64", "video.height=48"])
    res = run_scenario(sc, ("it2",), out=tmp_path / "run", video=True)
    assert res.video.codec in CODECS[1:]
    assert [n for n in res.notes if "not H.264" in n] == [res.video.note]


FAKE_FFMPEG = """#!/bin/sh
case "$*" in *-encoders*) echo " V....D libx264  H.264 (a stand-in)"; exit 0;; esac
{read}
echo "[libx264 @ 0x1] starting" >&2
echo "{message}" >&2
exit 1
"""


@pytest.mark.parametrize("read, message, when", [
    ("head -c 1000 > /dev/null", "x264 [error]: malloc of size 123 failed", "while encoding"),  # dies early
    ("cat > /dev/null", "[out#0/mp4 @ 0x2] Error writing trailer: No space left on device", "writing the video"),
])
def test_ffmpeg_failing_is_a_twin_error_with_its_last_line(read, message, when, run_exp1, tmp_path, monkeypatch):
    fake = tmp_path / "fake-ffmpeg"
    fake.write_text(FAKE_FFMPEG.format(read=read, message=message))
    fake.chmod(0o755)
    monkeypatch.setenv("IMAGEIO_FFMPEG_EXE", str(fake))
    out = tmp_path / "out"
    with pytest.raises(TwinError) as err:
        render_video(run_exp1, out / "v.mp4", fps=FPS, size=SIZE)
    assert str(err.value) == f"ffmpeg failed {when} (exit status 1): {message}"
    assert list(out.iterdir()) == [], "no partial video left behind"


def test_camera_modes():
    """video.camera: the follow camera keeps its world bearing (the turning camera's at the
    start), the fixed one aims at the middle of the run whatever the robot does, the top
    one looks straight down; an unknown mode is one line naming the allowed ones."""
    from twin.plant.bullet import TwinConfig
    from twin.render.scene import CAMERA_MODES, camera_mode

    # with a heading target the follow camera looks from the side of the heading halfway to it
    assert camera_mode("follow", 0.2, alpha_d=1.5).yaw == pytest.approx(25.0 + math.degrees(0.85))
    assert camera_mode("follow", 0.2).yaw == pytest.approx(25.0 + math.degrees(0.2))

    assert CAMERA_MODES == ("follow", "turning", "fixed", "top")
    follow = camera_mode("follow", alpha0=0.5)
    assert not follow.follow_heading and follow.yaw == pytest.approx(25.0 + math.degrees(0.5))
    assert camera_mode("turning") == Camera()
    assert camera_mode("top").pitch == -89.0
    fixed = camera_mode("fixed", 0.0, (0.0, 1.0, -0.2, 0.2))
    assert fixed.aim == (0.5, 0.0, 0.0) and fixed.distance > 0.85
    with pytest.raises(TwinError, match="video camera must be one of follow, turning, fixed, top, got 'side'"):
        camera_mode("side")
    with pytest.raises(TwinError, match="camera aim must be a world point"):
        Camera(aim=(0.0, float("nan"), 0.0))
    with Scene(TwinConfig(), (64, 48), "tiny", fixed) as still, Scene(TwinConfig(), (64, 48), "tiny", follow) as moving:
        assert still.view_matrix((0.0, 0.0, 0.0), 0.3) == still.view_matrix((2.0, 1.0, 0.0), -1.0)
        assert moving.view_matrix((0.0, 0.0, 0.0), 0.3) != moving.view_matrix((2.0, 1.0, 0.0), 0.3)
        assert moving.view_matrix((0.0, 0.0, 0.0), 0.3) == moving.view_matrix((0.0, 0.0, 0.0), -1.0)


def _magenta(bgr: np.ndarray) -> int:
    b, g, r = (bgr[..., i].astype(int) for i in range(3))
    return int(((b > 180) & (r > 180) & (g < 90)).sum())


def _green(bgr: np.ndarray) -> int:
    b, g, r = (bgr[..., i].astype(int) for i in range(3))
    return int(((g > 150) & (b < 110) & (r < 110)).sum())


def test_push_arrow_is_drawn_while_a_push_acts_and_only_then(tmp_path):
    from twin.scenarios import load_scenario
    from twin.workflows.run import run_scenario

    run = run_scenario(load_scenario("push-recovery", ["duration=9"]), controllers="it2").runs[0]
    info = render_video(run, tmp_path / "push.mp4", fps=20, size=(320, 240))
    frames = read_video(info.path)
    t = np.arange(len(frames)) / 20.0
    pushing = [(3.0 <= tk < 3.1) or (8.0 <= tk < 8.1) for tk in t]  # the scenario's two 0.1 s shoves
    during = [_magenta(f) for f, p in zip(frames, pushing) if p]
    outside = [_magenta(f) for f, p in zip(frames, pushing) if not p]
    assert len(during) == 4 and min(during) > 40, during
    assert max(outside) == 0, max(outside)


def test_position_target_is_marked_on_the_floor_in_experiment_2(tmp_path):
    from twin.scenarios import load_scenario
    from twin.workflows.run import run_scenario

    run = run_scenario(load_scenario("paper-exp2", ["duration=4"]), controllers="it2").runs[0]
    # no estimator ghost: H.264's shared chroma turns its thin cyan lines beside orange greenish
    run = dataclasses.replace(run, sensing="ideal")
    with_marker = read_video(render_video(run, tmp_path / "a.mp4", fps=5, size=(320, 240)).path)
    # the ring 0.7 m ahead of the start comes into the follow camera's view as the robot nears it
    assert min(_green(f) for f in with_marker[10:]) > 100, [_green(f) for f in with_marker]
    bare = dataclasses.replace(run, experiment=dataclasses.replace(run.experiment, p_d=None))
    without = read_video(render_video(bare, tmp_path / "b.mp4", fps=5, size=(320, 240)).path)
    assert max(_green(f) for f in without) == 0


def test_hud_names_the_faults_acting():
    s = HudState("IT2", 2.1, 0.0, 0.0, 0.0, fault="IMU dropout")
    assert ("fault: IMU dropout", hud.VIOLET) in hud_lines(s)
    assert not any(t.startswith("fault") for t, _ in hud_lines(HudState("IT2", 2.1, 0.0, 0.0, 0.0)))


def _cyan(bgr: np.ndarray) -> int:
    b, g, r = (bgr[..., i].astype(int) for i in range(3))
    return int(((b > 200) & (g > 200) & (r < 90)).sum())


def _cyan_column(bgr: np.ndarray) -> float:
    """Mean column (px) of the cyan pixels: where the ghost's outline sits across the picture."""
    b, g, r = (bgr[..., i].astype(int) for i in range(3))
    _, cols = np.nonzero((b > 200) & (g > 200) & (r < 90))
    return float(cols.mean())


@pytest.fixture(scope="module")
def run_ekf():
    """Paper experiment 1 with the EKF in the loop (the scenario's sensing), its first 1.5 s."""
    from twin.scenarios import load_scenario
    from twin.workflows.run import run_scenario

    run = run_scenario(load_scenario("paper-exp1", ["duration=1.5"]), controllers="it2").runs[0]
    assert run.sensing != "ideal" and run.status == "ok"
    return run


def test_ghost_of_the_body_is_drawn_at_the_estimate(run_ekf, tmp_path):
    """A cyan ghost box is drawn where the estimator puts the body, on every frame of a run
    with an estimator and on none with ideal sensing; an estimate leaning further forward
    moves it (the camera looks at the robot's right side, forward to the right)."""
    frames = read_video(render_video(run_ekf, tmp_path / "a.mp4", fps=10, size=SIZE, hud=False).path)
    assert min(_cyan(f) for f in frames) > 50, [_cyan(f) for f in frames]
    ideal = dataclasses.replace(run_ekf, sensing="ideal")
    assert max(_cyan(f) for f in read_video(render_video(ideal, tmp_path / "b.mp4", fps=10, size=SIZE,
                                                         hud=False).path)) == 0
    est = run_ekf.estimates.copy()
    est[:, 0] += 0.4  # θ̂ 0.4 rad further forward than the filter had it
    leaning = dataclasses.replace(run_ekf, estimates=est)
    moved = read_video(render_video(leaning, tmp_path / "c.mp4", fps=10, size=SIZE, hud=False).path)
    # at the end the body is upright: the ghost leaning 0.4 rad forward is further right
    assert _cyan_column(moved[-1]) > _cyan_column(frames[-1]) + 8, (_cyan_column(moved[-1]),
                                                                     _cyan_column(frames[-1]))


def test_hud_shows_the_estimated_pitch_in_the_ghosts_colour():
    s = HudState("IT2", 2.1, 0.1, 0.0, 0.0, theta_est=0.125)
    assert ("  est.  +0.125 rad", hud.CYAN) in hud_lines(s)
    assert not any("est." in t for t, _ in hud_lines(HudState("IT2", 2.1, 0.1, 0.0, 0.0)))


def test_markers_follow_a_sloped_floor_and_the_posed_body():
    """Floor markers lie on the floor's plane, and a point in the body frame lands where
    PyBullet has the posed body (its base is the centre of mass)."""
    config = TwinConfig(ground=Ground(slope=0.1, slope_direction=0.4),
                        disturbances=Disturbances(com_offset=(0.01, -0.005, 0.008)))
    with Scene(config, (64, 48), "tiny") as scene:
        pts = scene.floor_points([(1.0, 0.5), (-2.0, 0.3)], lift=0.0)
        assert pts[:, 2] == pytest.approx([config.ground.height(1.0, 0.5), config.ground.height(-2.0, 0.3)])
        assert abs(pts[0, 2]) > 0.05
        for pose in ((0.3, 0.7, 0.4, -0.2, 0.02), (-0.2, -2.0, -1.0, 1.5, -0.03)):
            scene.pose(*pose[:4], 0.0, 0.0, pose[4])
            com = scene.client.getBasePositionAndOrientation(scene.robot)[0]
            got = scene.body_points([(0.01, -0.005, config.params.l + 0.008)], *pose[:4], pose[4])[0]
            assert got == pytest.approx(com, abs=1e-9)


def test_body_faces_are_evenly_shaded(egl_loads):
    """The body's side seen squarely is one colour under EGL: PyBullet's box primitive left a
    dark triangle across each face (the body is drawn from a flat-shaded cube mesh)."""
    if not egl_loads:
        pytest.skip("PyBullet's EGL renderer plugin does not load on this machine")
    with Scene(TwinConfig(), (320, 240), "egl", Camera(yaw=0.0, pitch=-5.0)) as scene:
        hsv = cv2.cvtColor(scene.render(0.0, 0.8, 0.0, 0.0, 0.0, 0.0), cv2.COLOR_RGB2HSV)
    body = (hsv[..., 0] > 5) & (hsv[..., 0] < 25) & (hsv[..., 1] > 150)
    v = hsv[..., 2][body].astype(float)
    assert body.sum() > 500
    assert np.percentile(v, 95) - np.percentile(v, 5) <= 8, np.percentile(v, [5, 50, 95])


def test_floor_markers_are_hidden_where_the_robot_stands_in_front(egl_loads):
    """The heading arrow pointing away from the camera runs behind the body: with the robot
    in the picture most of it is hidden, without the robot all of it shows."""
    from types import SimpleNamespace

    from twin.plant.urdf import body_box
    from twin.render.panels import draw_markers

    config = TwinConfig()
    track = SimpleNamespace(p_d=None, alpha_d=math.pi / 2, start=(0.0, 0.0, 0.0), r=config.params.r,
                            box=body_box(config.params), body_top=body_box(config.params)[1][2])
    s = {k: np.zeros(1) for k in ("x", "y", "alpha", "roll", "theta", "push_fx", "push_fy", "push_fz")}
    counts = []
    with Scene(config, (320, 240), "egl" if egl_loads else "tiny", Camera(yaw=0.0, follow_heading=False)) as scene:
        for show in (True, False):
            img = cv2.cvtColor(scene.render(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, show_robot=show), cv2.COLOR_RGB2BGR)
            draw_markers(img, scene, track, s, 0)
            counts.append(_green(img))
    with_robot, without = counts
    assert without > 60 and with_robot < 0.5 * without, counts


def _orange(bgr: np.ndarray) -> int:
    """Pixels of the start's cross and the path (PATH_BGR (0, 140, 255): red high, blue low)."""
    b, g, r = (bgr[..., i].astype(int) for i in range(3))
    return int(((r > 200) & (g > 90) & (g < 190) & (b < 80)).sum())


def test_the_start_the_path_and_the_target_ahead_are_drawn_on_the_floor(egl_loads):
    """The camera follows the robot, so the travel shows on the floor: the start's cross and the
    path since once the robot is 5 cm or more from the start (none before), and with a heading
    target the position target's ring p_d − p ahead on the present heading."""
    from types import SimpleNamespace

    from twin.plant.urdf import body_box
    from twin.render.hud import START_SHOWN_M
    from twin.render.panels import draw_markers

    config = TwinConfig()
    box = body_box(config.params)
    cam = Camera(yaw=0.0, pitch=-35.0, distance=1.6, follow_heading=False)

    def drawn(xs, p_d=None, alpha_d=None, distance=0.0, robot=False):
        track = SimpleNamespace(p_d=p_d, alpha_d=alpha_d, start=(0.0, 0.0, 0.0), r=config.params.r, box=box,
                                body_top=box[1][2])
        n = len(xs)
        s = {k: np.zeros(n) for k in ("y", "alpha", "roll", "theta", "push_fx", "push_fy", "push_fz")}
        s["x"], s["distance"] = np.asarray(xs, float), np.full(n, distance)
        with Scene(config, (320, 240), "egl" if egl_loads else "tiny", cam) as scene:
            img = cv2.cvtColor(scene.render(0.0, 0.0, s["x"][-1], 0.0, 0.0, 0.0, show_robot=robot),
                               cv2.COLOR_RGB2BGR)
            plain = img.copy()
            draw_markers(img, scene, track, s, n - 1)
        return img, plain

    img, plain = drawn(np.linspace(0.0, 0.4, 9))
    assert _orange(img) > 150 and _orange(plain) == 0, _orange(img)  # the cross at 0, the path to 0.4 m
    img, _ = drawn([0.0, 0.5 * START_SHOWN_M])
    assert _orange(img) == 0  # still at the start: nothing drawn
    # the ring p_d − p = 0.4 m ahead of the axle at x = 0.2 m: around x = 0.6 m
    with_ring, _ = drawn([0.0, 0.2], p_d=0.6, alpha_d=0.0, distance=0.2)
    no_ring, _ = drawn([0.0, 0.2], p_d=None, alpha_d=0.0, distance=0.2)
    assert _green(with_ring) > _green(no_ring) + 40, (_green(with_ring), _green(no_ring))


def test_hud_names_the_plant_when_it_is_not_the_pybullet_twin(design, run_exp1):
    """A video of the analytic model (equation (1)) or of a user's plant says so under the
    label; the PyBullet twin's overlay is as it was (no plant line)."""
    from twin.sim.analytic_loop import simulate
    from twin.render.video import _Track

    exp = PAPER_EXPERIMENTS[1]
    analytic = simulate(build_cascade("it2", design, exp.targets), exp, duration=0.05, controller_name="it2")
    assert analytic.plant == "analytic"
    track = _Track(analytic, "IT2  paper-exp1")
    assert track.plant == "analytic model (eq. 1)"
    lines = hud_lines(HudState(track.label, 0.0, 0.1, 0.0, 0.0, plant=track.plant))
    assert lines[:2] == [("IT2  paper-exp1", hud.YELLOW), ("plant: analytic model (eq. 1)", hud.ORANGE)]
    assert lines[2][0].startswith("t ")

    twin_track = _Track(run_exp1, "IT2  paper-exp1")
    assert run_exp1.plant == "twin" and twin_track.plant == ""
    assert not any("plant" in t for t, _ in hud_lines(HudState("IT2", 0.0, 0.1, 0.0, 0.0, plant=twin_track.plant)))

    # a user's plant by the name the run gives it; ASCII only (Hershey fonts), its end kept when long
    assert hud.plant_caption("my_plants.Spring") == "my_plants.Spring"
    assert hud.plant_caption("modèle.Pendule\n") == "mod?le.Pendule"
    long = hud.plant_caption("a_very.long.package.path.of.plugins.SpringPlant")
    assert len(long) == hud.PLANT_NAME_MAX and long.startswith("...") and long.endswith(".SpringPlant")


def test_the_path_is_drawn_through_thinned_points_and_survives_points_at_the_eye(egl_loads):
    """A frame draws the path since the start: through points a centimetre apart at most 400
    of them (its cost does not grow with the frames before), the last point kept; a point that
    projects far outside the picture (just in front of the eye, where a following camera
    crosses an old path) breaks the line instead of breaking OpenCV."""
    from types import SimpleNamespace

    from twin.plant.urdf import body_box
    from twin.render.panels import PATH_POINTS, draw_markers, path_points

    x = np.linspace(0.0, 0.5, 5001)  # 0.1 mm apart
    pts = path_points(x, np.zeros_like(x))
    assert len(pts) == 51 and pts[-1][0] == 0.5 and np.all(np.diff(pts[:, 0]) >= 0.0099)
    far = np.linspace(0.0, 100.0, 100001)
    assert len(path_points(far, far)) <= PATH_POINTS + 1
    assert len(path_points([0.0, np.nan, 0.2, 0.3], [0.0, 0.0, 0.0, 0.0])) == 3  # non-finite rows dropped

    config = TwinConfig()
    box = body_box(config.params)
    track = SimpleNamespace(p_d=None, alpha_d=None, start=(-3.0, 0.0, 0.0), r=config.params.r, box=box,
                            body_top=box[1][2])
    s = {k: np.zeros(301) for k in ("y", "alpha", "roll", "theta", "push_fx", "push_fy", "push_fz", "distance")}
    s["x"] = np.linspace(-3.0, 0.0, 301)
    with Scene(config, (320, 240), "egl" if egl_loads else "tiny", Camera(yaw=0.0, follow_heading=False)) as scene:
        img = cv2.cvtColor(scene.render(0.0, 0.0, 0.0, 0.0, 0.0, 0.0), cv2.COLOR_RGB2BGR)
        real = scene.project

        def project(points):  # one point as if a hair in front of the eye
            uv = real(points)
            if len(uv) > 3:
                uv[len(uv) // 2] = (3e12, -2e12)
            return uv

        scene.project = project
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("error")  # no pixel coordinate cast out of range, no OpenCV error
            draw_markers(img, scene, track, s, 300)
    assert _orange(img) > 50
