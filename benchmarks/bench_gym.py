"""Steps per second of the Gymnasium environment against ``simulate_twin`` on the same
scenario (target: the environment's overhead at most 10 %).

Run from the repository root::

    python benchmarks/bench_gym.py                 # mtwip/Track-v0 on paper-exp3, about 30 s
    python benchmarks/bench_gym.py --env balance   # mtwip/Balance-v0 on paper-exp1
    python benchmarks/bench_gym.py --quick         # a few seconds
    python benchmarks/bench_gym.py --video         # time to record a 15 s episode (below)
    python benchmarks/bench_gym.py --video --gymnasium-video   # and with Gymnasium's RecordVideo

What is measured, in one process, rounds interleaved (round 0 warms up and is dropped):

* **simulate_twin** – the scenario's run with the built-in IT2 cascade (1 kHz physics,
  200 Hz control, DC motors, the mismatched true plant, simulated IMU and encoders, the
  EKF), everything logged: wall time per control period, twin construction included.
* **environment** – an episode of the same scenario and duration: ``reset`` (a new twin
  and EKF) and ``step`` until it is truncated, the action the same IT2 cascade's two
  torques; wall time per step. Three variants:

  - ``gymnasium.make`` (with Gymnasium's order-enforcing and passive-checker wrappers),
    the cascade called on the observation (float32, its first six entries are the
    estimate): what an agent's loop costs. The target applies to this one.
  - the unwrapped environment, the cascade on the observation;
  - the unwrapped environment, the cascade on ``env.unwrapped.loop.estimate``: the
    cascade sees exactly what it sees in ``simulate_twin`` and the trajectory is
    identical (checked), so the difference is the environment's own work
    (observation, reward, info) minus ``simulate_twin``'s logging.

  Each round uses one sensor seed for all four (the seed the environment's
  ``reset(seed=round)`` draws), so every variant simulates the same noise.

**Overhead** = (time per environment step) / (``simulate_twin``'s time per control
period) − 1, from the medians over the rounds.

``--video``: the wall time to record one whole episode (``mtwip/Balance-v0`` on
paper-exp1, 15 s, the IT2 cascade on the estimate, 640x480 pictures with the overlay)
with :class:`twin.envs.RecordVideo` at the scenario's 30 frames/s, from ``reset`` to the
finished MP4, and the video's frames, frame rate and length (read back with
imageio-ffmpeg). ``--gymnasium-video`` also records it with
``gymnasium.wrappers.RecordVideo`` (needs moviepy: one picture per step, 3001 of them,
kept in memory and encoded at ``render_fps`` = 200 when the episode ends) and reports
the peak resident memory of the process after each.
"""
from __future__ import annotations

import argparse
import gc
import os
import statistics
import sys
from pathlib import Path
from time import perf_counter as pc

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_twin import cpu_model, pybullet_version  # noqa: E402

TARGET_OVERHEAD = 0.10
ENVS = {"track": ("mtwip/Track-v0", "paper-exp3"), "balance": ("mtwip/Balance-v0", "paper-exp1")}


def env_episode(env, loop_env, scenario, targets, seed: int, on_estimate: bool):
    """(wall s per step, steps, truth rows) of reset(seed) and IT2-driven steps until the episode ends."""
    ctrl = scenario.build_controller("it2", scenario.build_context())
    truths = []
    gc.collect()
    t0 = pc()
    obs, info = env.reset(seed=seed)
    ctrl.reset(targets)
    n = 0
    if on_estimate:
        while True:
            c = ctrl(loop_env.loop.estimate, targets)
            obs, reward, terminated, truncated, info = env.step(c[:2])
            n += 1
            if terminated or truncated:
                break
    else:
        while True:
            c = ctrl(obs, targets)
            obs, reward, terminated, truncated, info = env.step(c[:2])
            n += 1
            if terminated or truncated:
                break
    wall = pc() - t0
    if terminated:
        raise SystemExit(f"the IT2 cascade fell in the environment ({info['reason']}); nothing to compare")
    return wall / n, n


def sim_run(scenario, seed: int):
    """(wall s per control period, periods, the run) of simulate_twin on ``scenario``."""
    from twin.sim.bullet_loop import simulate_twin

    ctrl = scenario.build_controller("it2", scenario.build_context())
    exp = scenario.experiment()
    config, sensors = scenario.twin_config(), scenario.sensor_config()
    gc.collect()
    t0 = pc()
    run = simulate_twin(ctrl, exp, config, sensors=sensors, seed=seed, controller_name="it2")
    wall = pc() - t0
    if run.status != "ok":
        raise SystemExit(f"simulate_twin's run fell ({run.end_reason}); nothing to compare")
    n = len(run.t) - 1
    return wall / n, n, run


def record_episode(wrapper: str, folder: str, size=(640, 480)) -> dict:
    """Record one paper-exp1 episode with ``wrapper`` ("twin" or "gymnasium"); timings and the file read back."""
    import resource
    import shutil

    import gymnasium
    import imageio_ffmpeg

    import twin.envs  # noqa: F401

    shutil.rmtree(folder, ignore_errors=True)
    env = gymnasium.make("mtwip/Balance-v0", render_mode="rgb_array", render_size=size)
    raw = env.unwrapped
    if wrapper == "twin":
        env = twin.envs.RecordVideo(env, folder, episode_trigger=lambda k: True)
    else:
        env = gymnasium.wrappers.RecordVideo(env, folder, episode_trigger=lambda k: True)
    renders = []
    render = raw.render
    raw.render = lambda: renders.append(1) or render()
    sc, targets = raw.scenario, raw.experiment.targets
    ctrl = sc.build_controller("it2", sc.build_context())
    gc.collect()
    t0 = pc()
    env.reset(seed=0)
    ctrl.reset(targets)
    steps = 0
    while True:
        _, _, terminated, truncated, info = env.step(ctrl(raw.loop.estimate, targets)[:2])
        steps += 1
        if terminated or truncated:
            break
    t1 = pc()
    renderer = raw._scene.renderer if raw._scene is not None else "?"
    env.close()  # Gymnasium's wrapper encodes here; the twin's has already finished at the episode's end
    t2 = pc()
    (path,) = Path(folder).glob("*.mp4")
    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    frames = sum(1 for _ in reader)
    return {"wrapper": wrapper, "steps": steps, "status": info["status"], "renders": len(renders),
            "episode_s": t1 - t0, "close_s": t2 - t1, "total_s": t2 - t0, "frames": frames, "fps": meta["fps"],
            "video_s": frames / meta["fps"], "renderer": renderer, "size": size,
            "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}


def video_main(args) -> int:
    import gymnasium

    print("Recording one 15 s episode of mtwip/Balance-v0 (paper-exp1, IT2 cascade on the estimate, 640x480)")
    print(f"machine: {cpu_model()}; Python {sys.version.split()[0]}; PyBullet {pybullet_version()}; "
          f"Gymnasium {gymnasium.__version__}; os.getloadavg() at start {os.getloadavg()[0]:.1f}\n")
    rows = [record_episode("twin", "/tmp/bench-gym-video-twin")]
    if args.gymnasium_video:
        try:
            import moviepy  # noqa: F401
        except ImportError:
            print("gymnasium.wrappers.RecordVideo skipped: moviepy is not installed (pip install moviepy)\n")
        else:
            rows.append(record_episode("gymnasium", "/tmp/bench-gym-video-gymnasium"))
    print(f"{'wrapper':12}{'steps':>7}{'pictures':>10}{'episode s':>11}{'close s':>9}{'total s':>9}"
          f"{'frames':>8}{'fps':>6}{'video s':>9}{'peak RSS MB':>13}  renderer")
    for r in rows:
        print(f"{r['wrapper']:12}{r['steps']:7d}{r['renders']:10d}{r['episode_s']:11.1f}{r['close_s']:9.1f}"
              f"{r['total_s']:9.1f}{r['frames']:8d}{r['fps']:6g}{r['video_s']:9.2f}{r['peak_rss_mb']:13.0f}  "
              f"{r['renderer']}")
    print("\n(episode s: reset to the episode's end, pictures and, for the twin's wrapper, encoding included; "
          "close s: Gymnasium's wrapper encodes with moviepy there; peak RSS is the process's, cumulative)")
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="short smoke run (5 s episodes, 2 rounds)")
    ap.add_argument("--env", choices=sorted(ENVS), default="track", help="which environment (default: track)")
    ap.add_argument("--rounds", type=int, default=None, help="timed rounds (default 7; 2 with --quick)")
    ap.add_argument("--video", action="store_true", help="time recording a 15 s episode with twin.envs.RecordVideo")
    ap.add_argument("--gymnasium-video", action="store_true",
                    help="with --video: also with gymnasium.wrappers.RecordVideo (needs moviepy; minutes)")
    args = ap.parse_args(argv)
    if args.video:
        return video_main(args)

    import gymnasium
    import numpy as np

    import twin.envs  # noqa: F401  (registers the ids)

    env_id, scenario_name = ENVS[args.env]
    rounds = args.rounds or (2 if args.quick else 7)
    overrides = ("duration=5",) if args.quick else ()
    env = gymnasium.make(env_id, scenario=scenario_name, overrides=overrides)
    raw = env.unwrapped
    sc = raw.scenario
    targets = raw.experiment.targets
    print("Gymnasium environment against simulate_twin, IT2 cascade in the loop")
    print(f"machine: {cpu_model()}; Python {sys.version.split()[0]}; PyBullet {pybullet_version()}; "
          f"Gymnasium {gymnasium.__version__}")
    print(f"{env_id} on {sc.name}: {sc.duration:g} s ({raw.n_steps} steps), {raw.config.physics_rate:g} Hz physics, "
          f"{raw.control_rate:g} Hz control, estimator {raw.estimator_kind}, obs {raw.obs_mode} "
          f"{raw.observation_space.shape}\n")

    variants = ("simulate_twin", "make, IT2 on obs", "unwrapped, IT2 on obs", "unwrapped, IT2 on estimate")
    times = {v: [] for v in variants}
    for r in range(rounds + 1):  # round 0 warms up
        seed = raw.reset(seed=r)[1]["seed"]  # the sensor seed the environment draws from reset(seed=r)
        sim, n_sim, run = sim_run(sc, seed)
        a, n_a = env_episode(env, raw, sc, targets, r, on_estimate=False)
        b, n_b = env_episode(raw, raw, sc, targets, r, on_estimate=False)
        c, n_c = env_episode(raw, raw, sc, targets, r, on_estimate=True)
        assert n_sim == n_a == n_b == n_c == raw.n_steps, (n_sim, n_a, n_b, n_c)
        if r == 0:  # the same loop: with the cascade on the same estimate, the same trajectory
            truths = [raw.reset(seed=r)[1]["truth"]]
            ctrl = sc.build_controller("it2", sc.build_context())
            ctrl.reset(targets)
            while True:
                out = raw.step(ctrl(raw.loop.estimate, targets)[:2])
                truths.append(out[4]["truth"])
                if out[2] or out[3]:
                    break
            same = np.array_equal(np.array(truths), run.truth)
            print(f"trajectory of the environment (IT2 on the estimate) identical to simulate_twin's: {same}\n")
            continue
        for v, t in zip(variants, (sim, a, b, c)):
            times[v].append(t)
    env.close()

    med = statistics.median
    ref = med(times["simulate_twin"])
    print(f"{'variant':34}{'µs per step':>13}{'steps/s':>10}{'real-time':>11}{'overhead':>10}   range µs")
    for v in variants:
        m = med(times[v])
        lo, hi = min(times[v]), max(times[v])
        over = "" if v == "simulate_twin" else f"{100 * (m / ref - 1):+9.1f}%"
        print(f"{v:34}{m * 1e6:13.1f}{1 / m:10.0f}{1 / (m * raw.control_rate):10.1f}×{over:>10}   "
              f"{lo * 1e6:.1f}–{hi * 1e6:.1f}")
    head = med(times["make, IT2 on obs"]) / ref - 1
    own = med(times["unwrapped, IT2 on estimate"]) / ref - 1
    print(f"\n({rounds} rounds after a warm-up; medians; per step = per control period of "
          f"{1e3 / raw.control_rate:g} ms simulated, reset and twin construction included)")
    print(f"environment overhead {100 * head:+.1f} % (gymnasium.make, IT2 on the observation; target ≤ "
          f"{100 * TARGET_OVERHEAD:.0f} %: {'met' if head <= TARGET_OVERHEAD else 'missed'}); the environment's "
          f"own work alone {100 * own:+.1f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
