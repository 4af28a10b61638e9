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
* **encode** – ``cv2.VideoWriter.write`` per frame, for each codec ``render_video`` may
  use (``vp09`` first, ``mp4v`` as fallback), on the frames the EGL (else Tiny) scene
  rendered; release included. Also the file size per second of video.
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
    from twin.bullet_loop import simulate_twin
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


def encode(frames, fourcc: str, fps: float, tmpdir: Path) -> dict | None:
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
    return {"per_frame": wall / len(frames), "kib_per_s": size / 1024 / (len(frames) / fps)}


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
    from twin.render.video import CODECS

    print("Offscreen video renderer: frames per second at "
          f"{size[0]}x{size[1]}, PyBullet EGL plugin vs TinyRenderer, and the encode cost")
    print(f"machine: {cpu_model()}, {os.cpu_count()} logical CPUs; Python {platform.python_version()}; "
          f"PyBullet API {pybullet.getAPIVersion()}; OpenCV {cv2.__version__}; numpy {np.__version__}")
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
    print()
    print(f"Encoding {len(frames)} frames of {size[0]}x{size[1]} ({renderers[0]} pictures), cv2.VideoWriter, "
          f"30 fps, MP4:")
    print(f"{'codec':10}{'encode':>12}{'encode':>12}{'size':>16}")
    print(f"{'':10}{'[ms/frame]':>12}{'[frames/s]':>12}{'[KiB/s video]':>16}")
    print("-" * 50)
    enc = {}
    with tempfile.TemporaryDirectory() as tmp:
        for fourcc in CODECS:
            e = encode(frames, fourcc, 30.0, Path(tmp))
            enc[fourcc] = e
            if e is None:
                print(f"{fourcc:10}{'not available in this OpenCV':>40}")
            else:
                print(f"{fourcc:10}{1e3 * e['per_frame']:12.1f}{1 / e['per_frame']:12.1f}{e['kib_per_s']:16.0f}")

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

    print()
    if egl:
        fps = 1 / results["egl"]["render"]
        verdict = "PASS" if fps >= TARGET_FPS else "FAIL"
        print(f"RESULT: EGL renders {fps:.1f} frames/s at {size[0]}x{size[1]} (TinyRenderer "
              f"{1 / results['tiny']['render']:.1f}) vs target {TARGET_FPS:g}: {verdict}")
    else:
        print(f"RESULT: no EGL here; TinyRenderer renders {1 / results['tiny']['render']:.1f} frames/s "
              f"(the {TARGET_FPS:g} fps target applies where EGL loads)")
    best = min((e["per_frame"], c) for c, e in enc.items() if e is not None)
    costs = ", ".join(f"{c} {1e3 * e['per_frame']:.1f} ms/frame" for c, e in enc.items() if e)
    print(f"        encoding: {costs} (render_video uses {next(c for c in CODECS if enc[c])}; "
          f"fastest here {best[1]})")
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
