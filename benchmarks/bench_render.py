"""Frames per second of the offscreen video renderer (twin.render): PyBullet's EGL plugin
against its TinyRenderer, and what encoding the frames costs (target: at least 30
rendered frames per second at 640x480 where EGL loads).

Run from the repository root::

    python benchmarks/bench_render.py            # about a minute
    python benchmarks/bench_render.py --quick    # smoke run, about 20 s

What is measured
----------------
One closed-loop run of the paper's third experiment (IT2, ideal sensing, 3 s: the robot
rises from 0.48 rad, drives and turns, so every frame differs) is replayed in a
:class:`twin.render.Scene` per renderer, at the frame times of a 30 fps video.

* **render** – ``Scene.render``: posing the robot and ``getCameraImage`` (RGB, no
  segmentation mask), the renderer's whole cost per frame; after 3 warm-up frames
  (EGL's first frames compile shaders and are much slower; reported separately).
* **overlay** – RGB → BGR conversion and the heads-up overlay (``draw_hud``).
* **encode** – per frame, for each encoder ``render_video`` may use: H.264 by
  imageio-ffmpeg's ffmpeg (``libx264`` ultrafast, ``libopenh264``) fed through a pipe,
  and OpenCV's ``cv2.VideoWriter`` (``vp09``, ``mp4v``), on the frames the EGL (else
  Tiny) scene rendered, at the panel size and at two panels side by side (the frame of
  ``--controller both``); the writer's whole life (ffmpeg: process start, pipe, finish;
  OpenCV: write and release) over the frames. For ffmpeg also its CPU time (the child
  process's user + system) per frame. And the file size per second of video.
* **end to end** – ``render_video`` on the same run, one panel per renderer and two
  panels side by side: wall time per frame, including setup, rendering, the encoder
  thread (it overlaps rendering) and the final flush.

The renderers take turns in the same process; the numbers are medians of per-frame
times (encode: mean over the video). Setup (plugin load, URDF, the EGL probe picture)
is reported per scene.
"""
from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_twin import cpu_model  # noqa: E402

TARGET_FPS = 30.0
pc = time.perf_counter


def make_run(duration: float):
    from twin.controllers.cascade import build_cascade
    from twin.experiments import PAPER_EXPERIMENTS
    from twin.sim.bullet_loop import simulate_twin
    from twin.controllers.lmi import design_balance_gains

    exp = PAPER_EXPERIMENTS[3]
    run = simulate_twin(build_cascade("it2", design_balance_gains(), exp.targets), exp, duration=duration,
                        controller_name="it2", sensors=None)
    assert run.status == "ok", run.end_reason
    return run


def render_frames(run, renderer: str, size, n_frames: int, warmup: int = 3) -> dict:
    """Time Scene.render and the overlay over ``n_frames`` frames of a 30 fps replay."""
    import cv2

    from twin.render import HudState, Scene, draw_hud
    from twin.render.video import _Track, frame_times

    t0 = pc()
    scene = Scene(run.config, size, renderer)
    setup = pc() - t0
    track = _Track(run, "IT2  paper-exp3")
    times = frame_times(track.duration, 30.0)
    s = track.sample(times)
    k_all = [k % len(times) for k in range(warmup + n_frames)]
    render, overlay, first, frames = [], [], [], []
    try:
        for i, k in enumerate(k_all):
            a = pc()
            rgb = scene.render(s["theta"][k], s["alpha"][k], s["x"][k], s["y"][k], s["psi_l"][k], s["psi_r"][k],
                               s["roll"][k])
            b = pc()
            bgr = cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)
            draw_hud(bgr, HudState(track.label, float(times[k]), s["theta"][k], s["distance"][k], s["alpha"][k],
                                   track.p_d, track.alpha_d))
            c = pc()
            if i < warmup:
                first.append(b - a)
                continue
            render.append(b - a)
            overlay.append(c - b)
            frames.append(bgr)
    finally:
        used = scene.renderer
        scene.close()
    return {"renderer": used, "setup": setup, "first": first, "render": statistics.median(render),
            "overlay": statistics.median(overlay), "frames": frames}


def ffmpeg_version() -> str:
    """imageio-ffmpeg's version and its ffmpeg's first line, or why there is none."""
    import subprocess

    from twin.errors import TwinError
    from twin.render.video import _ffmpeg_exe

    try:
        exe = _ffmpeg_exe()
    except TwinError as exc:
        return str(exc)
    import imageio_ffmpeg

    first = subprocess.run([exe, "-version"], capture_output=True, text=True).stdout.splitlines()[:1]
    return f"imageio-ffmpeg {imageio_ffmpeg.__version__}: {first[0] if first else exe}"


def encode(frames, fourcc: str, fps: float, tmpdir: Path) -> dict | None:
    """OpenCV's ``cv2.VideoWriter`` with ``fourcc``: wall time per frame (None: no such codec)."""
    import cv2

    from twin.plant.bullet import quiet_native_output

    h, w = frames[0].shape[:2]
    path = tmpdir / f"bench_{fourcc}.mp4"
    with quiet_native_output():
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps, (w, h))
    if not writer.isOpened():
        return None
    t0 = pc()
    for f in frames:
        writer.write(f)
    writer.release()
    wall = pc() - t0
    size = path.stat().st_size
    path.unlink()
    return {"per_frame": wall / len(frames), "cpu_per_frame": None, "kib_per_s": size / 1024 / (len(frames) / fps)}


def encode_ffmpeg(frames, encoder: str, fps: float, tmpdir: Path) -> dict | None:
    """H.264 by ffmpeg through render_video's pipe writer: wall and child CPU time per frame
    (None: no ffmpeg, or this ffmpeg lacks ``encoder``)."""
    import resource

    from twin.errors import TwinError
    from twin.render.video import _FfmpegWriter, _ffmpeg_exe, _h264_encoder

    try:
        exe = _ffmpeg_exe()
        _h264_encoder(exe)
    except TwinError:
        return None
    h, w = frames[0].shape[:2]
    path = tmpdir / f"bench_{encoder}.mp4"

    def child_cpu() -> float:
        ru = resource.getrusage(resource.RUSAGE_CHILDREN)  # counts ffmpeg once it has been waited for
        return ru.ru_utime + ru.ru_stime

    c0, t0 = child_cpu(), pc()
    try:
        writer = _FfmpegWriter(exe, encoder, path, fps, (w, h))
        for f in frames:
            writer.write(f)
        writer.release()
    except TwinError as exc:  # e.g. this ffmpeg was built without the encoder
        print(f"  ({encoder}: {exc})")
        return None
    wall, cpu = pc() - t0, child_cpu() - c0
    size = path.stat().st_size
    path.unlink()
    return {"per_frame": wall / len(frames), "cpu_per_frame": cpu / len(frames),
            "kib_per_s": size / 1024 / (len(frames) / fps)}


ENCODERS = ("libx264", "libopenh264", "vp09", "mp4v")  # ffmpeg's H.264 encoders (pipe), then OpenCV's


def encode_table(frames, n_encode: int, tmpdir: Path) -> dict:
    """Encode cost per encoder at the panel size and at two panels side by side."""
    base = frames[:n_encode]
    h, w = base[0].shape[:2]
    wide = [np.ascontiguousarray(np.hstack([f, base[(i + len(base) // 2) % len(base)]])) for i, f in enumerate(base)]
    print(f"{'encoder':14}{'frame':>10}{'encode wall':>13}{'ffmpeg CPU':>12}{'encode':>12}{'size':>16}")
    print(f"{'':14}{'[px]':>10}{'[ms/frame]':>13}{'[ms/frame]':>12}{'[frames/s]':>12}{'[KiB/s video]':>16}")
    print("-" * 77)
    out = {}
    for name in ENCODERS:
        for fr in (base, wide):
            size = f"{fr[0].shape[1]}x{fr[0].shape[0]}"
            e = (encode_ffmpeg(fr, name, 30.0, tmpdir) if name.startswith("lib")
                 else encode(fr, name, 30.0, tmpdir))
            out[(name, size)] = e
            if e is None:
                print(f"{name:14}{size:>10}{'not available here':>30}")
                continue
            cpu = "" if e["cpu_per_frame"] is None else f"{1e3 * e['cpu_per_frame']:.1f}"
            print(f"{name:14}{size:>10}{1e3 * e['per_frame']:13.1f}{cpu:>12}{1 / e['per_frame']:12.1f}"
                  f"{e['kib_per_s']:16.0f}")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="short smoke run")
    ap.add_argument("--size", default="640x480", help="panel size WxH (default 640x480)")
    args = ap.parse_args(argv)
    try:
        size = tuple(int(v) for v in args.size.lower().split("x"))
        assert len(size) == 2
    except (ValueError, AssertionError):
        ap.error(f"--size must be WxH, got {args.size!r}")
    n_egl, n_tiny = (30, 10) if args.quick else (150, 45)
    video_s = 1.0 if args.quick else 3.0

    import cv2

    from twin.plant.bullet import quiet_native_output

    with quiet_native_output():  # PyBullet prints its build time on import
        import pybullet
    from twin.render import Scene, render_video

    print("Offscreen video renderer: frames per second at "
          f"{size[0]}x{size[1]}, PyBullet EGL plugin vs TinyRenderer, and the encode cost")
    print(f"machine: {cpu_model()}, {os.cpu_count()} logical CPUs; Python {platform.python_version()}; "
          f"PyBullet API {pybullet.getAPIVersion()}; OpenCV {cv2.__version__}; numpy {np.__version__}")
    print(f"ffmpeg: {ffmpeg_version()}")
    run = make_run(3.0)
    print(f"run: paper experiment 3, IT2, ideal sensing, {run.t[-1]:g} s simulated; frames at 30 fps")

    with Scene(run.config, (64, 48), "auto") as probe:
        egl = probe.renderer == "egl"
    renderers = (["egl"] if egl else []) + ["tiny"]
    if not egl:
        print("EGL: the plugin does not load here; TinyRenderer only")

    results = {}
    for r in renderers:
        results[r] = render_frames(run, r, size, n_egl if r == "egl" else n_tiny)

    print()
    print(f"{'renderer':10}{'setup':>9}{'first 3 frames':>22}{'render':>10}{'overlay':>10}{'render only':>13}"
          f"{'with overlay':>14}")
    print(f"{'':10}{'[ms]':>9}{'[ms]':>22}{'[ms/fr]':>10}{'[ms/fr]':>10}{'[frames/s]':>13}{'[frames/s]':>14}")
    print("-" * 88)
    for r, d in results.items():
        first = " ".join(f"{1e3 * v:.0f}" for v in d["first"])
        print(f"{r:10}{1e3 * d['setup']:9.0f}{first:>22}{1e3 * d['render']:10.1f}{1e3 * d['overlay']:10.2f}"
              f"{1 / d['render']:13.1f}{1 / (d['render'] + d['overlay']):14.1f}    ({len(d['frames'])} frames)")

    frames = results[renderers[0]]["frames"]
    n_encode = min(len(frames), 30 if args.quick else 60)  # VP9 at 1280x480 costs ~0.25 s a frame
    print()
    print(f"Encoding {n_encode} frames ({renderers[0]} pictures, 30 fps, MP4), alone and two side by side:")
    with tempfile.TemporaryDirectory() as tmp:
        enc = encode_table(frames, n_encode, Path(tmp))

        print()
        print(f"End to end: render_video on the first {video_s:g} s of the run ({size[0]}x{size[1]} per panel)")
        print(f"{'case':30}{'frames':>8}{'codec':>7}{'wall':>9}{'per frame':>11}{'frames/s':>10}{'render':>9}"
              f"{'encode':>9}")
        print(f"{'':30}{'':>8}{'':>7}{'[s]':>9}{'[ms]':>11}{'':>10}{'[s]':>9}{'[s]':>9}")
        print("-" * 93)
        short = _truncate(run, video_s)
        cases = [(f"{r}, 1 panel", [short], r) for r in renderers]
        cases.append((f"{renderers[0]}, 2 panels side by side", [short, short], renderers[0]))
        for label, runs, r in cases:
            info = render_video(runs, Path(tmp) / "v.mp4", size=size, renderer=r)
            per_frame = 1e3 * info.seconds / info.frames
            print(f"{label:30}{info.frames:8d}{info.codec:>7}{info.seconds:9.2f}{per_frame:11.1f}"
                  f"{info.frames / info.seconds:10.1f}{info.render_seconds:9.2f}{info.encode_seconds:9.2f}")
        last_codec, last_encoder, last_note = info.codec, info.encoder, info.note

    print()
    if egl:
        fps = 1 / results["egl"]["render"]
        verdict = "PASS" if fps >= TARGET_FPS else "FAIL"
        print(f"RESULT: EGL renders {fps:.1f} frames/s at {size[0]}x{size[1]} (TinyRenderer "
              f"{1 / results['tiny']['render']:.1f}) vs target {TARGET_FPS:g}: {verdict}")
    else:
        print(f"RESULT: no EGL here; TinyRenderer renders {1 / results['tiny']['render']:.1f} frames/s "
              f"(the {TARGET_FPS:g} fps target applies where EGL loads)")
    costs = ", ".join(f"{c} {1e3 * e['per_frame']:.1f}" for (c, px), e in enc.items() if e and px == f"{size[0]}x{size[1]}")
    print(f"        encoding, ms per {size[0]}x{size[1]} frame: {costs}; render_video used {last_codec} "
          f"({last_encoder}){'; ' + last_note if last_note else ''}")
    return 0


def _truncate(run, seconds: float):
    """The run's first ``seconds`` s (rows up to that time), as a TwinRun."""
    import dataclasses

    n = int(np.searchsorted(run.t, seconds + 1e-9))
    return dataclasses.replace(run, t=run.t[:n], truth=run.truth[:n], commands=run.commands[:n],
                               actuation=run.actuation[:n], push=run.push[:n],
                               estimates=None if run.estimates is None else run.estimates[:n])


if __name__ == "__main__":
    sys.exit(main())
