"""The run figures the documentation shows, drawn by the commands the pages name.

* ``docs/paper-exp3-twin.png``: ``twin run paper-exp3 --no-video`` (the tutorial's command: IT2
  and type-1, the twin with the EKF);
* ``docs/paper-exp3-twin-lqr.png``: the same with ``--controller it2,t1,lqr`` (the paper-claim
  page, LQR beside the fuzzy cascades);
* ``docs/paper-exp3-analytic.png``: ``twin run paper-exp3 --set plant.model=analytic --set
  plant.scale={} --set sensors.sensing=ideal --no-video`` (equation (1) itself, the method page);
* ``docs/paper-exp3-video-frame.png``: the frame at t = 5 s of ``twin run paper-exp3``'s video (the
  README's picture);
* ``docs/reference/envs/_media/balance-v0.gif`` and ``track-v0.gif``: the Gymnasium environments'
  pages' animations, the first seconds of an episode (``render_mode="rgb_array"``) driven by the
  built-in IT2 cascade on the observation, as the Gymnasium how-to does.

Run from the repository root after a change to the figure or to the runs::

    python benchmarks/docs_figures.py

Each command runs in a subprocess (``python -m twin.cli``) in a temporary directory; its
``figure.png`` is copied over the page's image. Look at them before committing.
"""
from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FIGURES = {
    "paper-exp3-twin.png": ["run", "paper-exp3", "--no-video"],
    "paper-exp3-twin-lqr.png": ["run", "paper-exp3", "--controller", "it2,t1,lqr", "--no-video"],
    "paper-exp3-analytic.png": ["run", "paper-exp3", "--set", "plant.model=analytic", "--set", "plant.scale={}",
                                "--set", "sensors.sensing=ideal", "--no-video"],
}


ANIMATIONS = {"balance-v0.gif": "mtwip/Balance-v0", "track-v0.gif": "mtwip/Track-v0"}
ANIMATION_S = 3.0  # s of the episode shown
ANIMATION_FPS = 20  # pictures per simulated second (and per second of the GIF: real time)
ANIMATION_SIZE = (320, 240)  # px


def animation(env_id: str, path: Path) -> int:
    """The first :data:`ANIMATION_S` s of an episode of ``env_id`` as a GIF at ``path``, the agent
    the built-in IT2 cascade on the estimate; returns the number of pictures."""
    import gymnasium
    import numpy as np
    from PIL import Image

    import twin.envs  # noqa: F401 - registers the ids

    env = gymnasium.make(env_id, render_mode="rgb_array", render_size=ANIMATION_SIZE,
                         overrides=(f"duration={ANIMATION_S}",))
    u = env.unwrapped
    ctrl = u.scenario.build_controller("it2", u.scenario.build_context())
    obs, _ = env.reset(seed=0)
    ctrl.reset(u.experiment.targets)
    every = max(1, round(u.scenario.data["rates"]["control"] / ANIMATION_FPS))
    frames, k = [Image.fromarray(env.render())], 0
    while True:
        ul, ur, *_ = ctrl(obs[:6], u.experiment.targets)
        obs, _, terminated, truncated, _ = env.step(np.array([ul, ur], dtype=np.float32))
        k += 1
        if k % every == 0:
            frames.append(Image.fromarray(env.render()))
        if terminated or truncated:
            break
    env.close()
    path.parent.mkdir(parents=True, exist_ok=True)
    frames[0].save(path, save_all=True, append_images=frames[1:], duration=round(1000 / ANIMATION_FPS), loop=0,
                   optimize=True)
    return len(frames)


VIDEO_FRAME_S = 5.0  # s: the README's video frame


def video_frame(path: Path) -> float:
    """The frame at :data:`VIDEO_FRAME_S` of ``twin run paper-exp3``'s video (its catch slowed:
    the frame's index from the video's own frame times) as a PNG at ``path``; returns its time."""
    import cv2

    from twin.render.video import frame_times
    from twin.scenarios import load_scenario
    from twin.outputs.run_directory import SLOW_CATCH, catch_end as _catch_end
    from twin.workflows.run import run_scenario

    with tempfile.TemporaryDirectory() as tmp:
        sc = load_scenario("paper-exp3")
        result = run_scenario(sc, ("it2", "t1"), out=Path(tmp) / "run", video=True)
        catch = _catch_end(result.runs)
        v = sc.data["video"]
        times = frame_times(max(float(r.t[-1] - r.t[0]) for r in result.runs), v["fps"],
                            None if catch is None else (catch, SLOW_CATCH))
        k = int(abs(times - VIDEO_FRAME_S).argmin())
        cap = cv2.VideoCapture(str(Path(tmp) / "run" / "video.mp4"))
        cap.set(cv2.CAP_PROP_POS_FRAMES, k)
        ok, frame = cap.read()
        cap.release()
        if not ok:
            raise SystemExit(f"could not read frame {k} of the video")
        cv2.imwrite(str(path), frame)
        return float(times[k])


def main() -> int:
    t = video_frame(ROOT / "docs" / "paper-exp3-video-frame.png")
    print(f"docs/paper-exp3-video-frame.png: twin run paper-exp3, the video's frame at t = {t:g} s")
    for name, env_id in ANIMATIONS.items():
        path = ROOT / "docs" / "reference" / "envs" / "_media" / name
        n = animation(env_id, path)
        print(f"{path.relative_to(ROOT)}: {env_id}, {n} pictures, {path.stat().st_size / 1e3:.0f} kB")
    with tempfile.TemporaryDirectory() as tmp:
        for name, args in FIGURES.items():
            out = Path(tmp) / name.removesuffix(".png")
            subprocess.run([sys.executable, "-m", "twin.cli", *args, "--out", str(out)], check=True, cwd=tmp,
                           stdout=subprocess.DEVNULL)
            shutil.copyfile(out / "figure.png", ROOT / "docs" / name)
            print(f"docs/{name}: twin {' '.join(args)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
