"""The Gymnasium rough edges of issue 31: the registered episode length and its TimeLimit,
the optional normalised action space, and a real-time video at the scenario's frame rate
(:class:`twin.envs.RecordVideo`, no moviepy)."""
from __future__ import annotations

import math
import os
import warnings

import numpy as np
import pytest

if os.environ.get("TWIN_REQUIRE_GYM", "") not in ("", "0"):  # CI: the gym extra must be there, not skipped
    import gymnasium
else:
    gymnasium = pytest.importorskip("gymnasium")

from gymnasium.utils.env_checker import check_env  # noqa: E402

import twin.envs  # noqa: E402,F401  (registers the ids)
from twin.errors import TwinError  # noqa: E402

SHORT = ("duration=0.5",)


def it2_policy(env):
    """The scenario's IT2 cascade on the loop's estimate: (ul, ur) in N·m, keeps the robot up."""
    u = env.unwrapped
    sc = u.scenario
    ctrl = sc.build_controller("it2", sc.build_context())
    targets = u.experiment.targets
    ctrl.reset(targets)
    return lambda: np.array(ctrl(u.loop.estimate, targets)[:2])


def _episode(env):
    """Step ``env`` (reset already) with the IT2 cascade to the episode's end:
    (steps, terminated, truncated, the last info)."""
    policy = it2_policy(env)
    n = 0
    while True:
        _, _, terminated, truncated, info = env.step(policy())
        n += 1
        if terminated or truncated:
            return n, terminated, truncated, info


# ---- max_episode_steps ------------------------------------------------------------------------
@pytest.mark.parametrize("env_id,scenario", [("mtwip/Balance-v0", "paper-exp1"), ("mtwip/Track-v0", "paper-exp3")])
def test_max_episode_steps_is_registered_from_the_default_scenario(env_id, scenario):
    spec = gymnasium.spec(env_id)
    assert type(spec.max_episode_steps) is int and spec.max_episode_steps == 3000  # 15 s / 5 ms
    assert twin.envs.episode_steps(scenario) == spec.max_episode_steps
    env = gymnasium.make(env_id)
    try:
        assert env.spec.max_episode_steps == env.unwrapped.n_steps == 3000
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # a scenario as long as the limit: no warning
            env.reset(seed=0)
    finally:
        env.close()


def test_episode_steps_refuses_a_duration_between_control_instants(tmp_path):
    f = tmp_path / "odd.toml"
    f.write_text('name = "odd"\nduration = 1.0025\n')
    with pytest.raises(TwinError, match=r"duration 1.0025 s is not a whole number of control periods") as exc:
        twin.envs.episode_steps(f)
    assert "\n" not in str(exc.value)


def test_time_limit_truncates_at_max_episode_steps():
    """A 20 s scenario (4000 steps) through gymnasium.make: the registered TimeLimit ends the
    episode at step 3000, and the first reset says so."""
    env = gymnasium.make("mtwip/Balance-v0", overrides=("duration=20",))
    try:
        assert env.unwrapped.n_steps == 4000 and env.spec.max_episode_steps == 3000
        with pytest.warns(UserWarning, match=r"lasts 4000 steps .*max_episode_steps=3000.*max_episode_steps=4000"):
            env.reset(seed=0)
        n, terminated, truncated, info = _episode(env)
        assert (n, terminated, truncated) == (3000, False, True)
        assert info["status"] == "running" and math.isclose(info["t"], 15.0)
        assert env.unwrapped.loop.k == 3000 < env.unwrapped.n_steps  # the TimeLimit, not the environment
    finally:
        env.close()


# ---- normalised actions -----------------------------------------------------------------------
def test_normalized_actions_pass_the_checker_without_a_warning():
    env = gymnasium.make("mtwip/Balance-v0", overrides=SHORT, normalize_actions=True)
    try:
        space = env.action_space
        assert space.low.tolist() == [-1.0, -1.0] and space.high.tolist() == [1.0, 1.0]
        assert space.dtype == np.float32
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            check_env(env.unwrapped, skip_render_check=True)
        assert [str(w.message) for w in caught] == []
    finally:
        env.close()
    default = gymnasium.make("mtwip/Balance-v0", overrides=SHORT)  # unchanged: N·m
    try:
        assert default.action_space.high.tolist() == [np.float32(default.unwrapped.max_torque)] * 2
    finally:
        default.close()


def test_normalized_actions_are_fractions_of_max_torque():
    kw = {"overrides": ("duration=0.5", "initial.theta=0.05")}
    norm = gymnasium.make("mtwip/Balance-v0", normalize_actions=True, **kw)
    newton = gymnasium.make("mtwip/Balance-v0", **kw)
    try:
        tau = norm.unwrapped.max_torque
        assert tau == newton.unwrapped.max_torque == 1.2
        norm.reset(seed=4)
        newton.reset(seed=4)
        for a in ([0.25, -0.5], [0.5, 0.25], [-0.25, 0.125]) * 5:
            o1, r1, _, _, i1 = norm.step(np.array(a, dtype=np.float32))
            o2, r2, _, _, i2 = newton.step(np.array(a) * tau)  # the same torques in N·m
            assert i1["command"] == i2["command"] == (a[0] * tau, a[1] * tau)
            np.testing.assert_array_equal(o1, o2)
            assert r1 == r2 and i1["truth"] == i2["truth"]
        _, _, _, _, info = norm.step(np.array([2.0, -3.0], dtype=np.float32))  # clipped to [-1, 1]
        assert info["command"] == (tau, -tau) and info["cost_torque"] == 1.0
    finally:
        norm.close()
        newton.close()


def test_a_malformed_normalized_action_is_one_line():
    env = gymnasium.make("mtwip/Balance-v0", overrides=SHORT, normalize_actions=True)
    try:
        env.reset(seed=0)
        with pytest.raises(TwinError, match=r"action must be the two wheel torques as fractions of max_torque, "
                                            r"\(ul, ur\) / τ_max in \[-1, 1\], got 'x'") as exc:
            env.unwrapped.step("x")
        assert "\n" not in str(exc.value)
    finally:
        env.close()


@pytest.mark.parametrize("value", ["yes", 1, None])
def test_normalize_actions_must_be_a_bool(value):
    with pytest.raises(TwinError, match="normalize_actions must be True .* or False") as exc:
        gymnasium.make("mtwip/Balance-v0", overrides=SHORT, normalize_actions=value)
    assert "\n" not in str(exc.value)


# ---- video --------------------------------------------------------------------------------------
def _video_frames(path):
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    frames = sum(1 for _ in reader)
    return frames, meta["fps"], meta["size"]


def _count_renders(env):
    raw = env.unwrapped
    calls = []
    render = raw.render

    def counting():
        calls.append(raw.loop.k)
        return render()

    raw.render = counting
    return calls


def test_record_video_is_real_time_at_the_scenario_rate(tmp_path):
    from twin.envs import RecordVideo

    env = gymnasium.make("mtwip/Balance-v0", render_mode="rgb_array", render_size=(160, 120),
                         overrides=("duration=1",))
    assert env.unwrapped.video_fps == 30 and env.metadata["render_fps"] == 200  # one picture per step
    env = RecordVideo(env, tmp_path, episode_trigger=lambda k: k == 0)
    try:
        calls = _count_renders(env)
        env.reset(seed=0)
        steps, _, truncated, _ = _episode(env)
        assert (steps, truncated) == (200, True)
        # 1 s at 30 frames/s: frames at 0, 1/30, ... 1 s, each at the first step at or after its time
        assert len(calls) == 31 and calls[:4] == [0, 7, 14, 20] and calls[-1] == 200
        (info,) = env.videos
        assert info.path == tmp_path / "rl-video-episode-0.mp4" and info.frames == 31 and info.fps == 30.0
        assert info.codec == "avc1" and info.size == (160, 120)
        frames, fps, size = _video_frames(info.path)
        assert (frames, fps, tuple(size)) == (31, 30.0, (160, 120))  # plays 1.03 s: real time
        # the next episode is not recorded (trigger), and nothing else is left in the folder
        env.reset(seed=1)
        env.step(it2_policy(env)())
        assert len(calls) == 31 and not env.recording
    finally:
        env.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["rl-video-episode-0.mp4"]


def test_record_video_ends_on_the_fall_and_shows_it(tmp_path):
    from twin.envs import RecordVideo

    env = RecordVideo(gymnasium.make("mtwip/Balance-v0", render_mode="rgb_array", render_size=(160, 120),
                                     overrides=("duration=2",)), tmp_path, episode_trigger=lambda k: True, fps=10)
    try:
        env.reset(seed=0)
        while True:  # no torque from 0.48 rad: it falls
            _, _, terminated, truncated, info = env.step(np.zeros(2, dtype=np.float32))
            if terminated or truncated:
                break
        assert terminated and not env.recording
        fell = info["t"]
        (video,) = env.videos
        # frames at 0, 0.1, ... up to the fall, then one of the fallen robot
        assert video.frames == math.floor(fell * 10 + 1e-9) + 2
        assert _video_frames(video.path)[:2] == (video.frames, 10.0)
    finally:
        env.close()


def test_record_video_interrupted_leaves_no_partial_file(tmp_path):
    from twin.envs import RecordVideo

    env = RecordVideo(gymnasium.make("mtwip/Balance-v0", render_mode="rgb_array", render_size=(160, 120),
                                     overrides=("duration=1", "initial.theta=0.0")), tmp_path,
                      episode_trigger=lambda k: True)
    try:
        calls = _count_renders(env)
        raw = env.unwrapped
        counting = raw.render

        def interrupted():
            if len(calls) == 5:
                raise KeyboardInterrupt
            return counting()

        raw.render = interrupted
        env.reset(seed=0)
        with pytest.raises(KeyboardInterrupt):
            for _ in range(100):
                env.step(np.zeros(2, dtype=np.float32))
        assert not env.recording and env.videos == []
    finally:
        env.close()
    assert list(tmp_path.iterdir()) == []


def test_record_video_close_finishes_the_running_episode(tmp_path):
    from twin.envs import RecordVideo

    env = RecordVideo(gymnasium.make("mtwip/Balance-v0", render_mode="rgb_array", render_size=(160, 120),
                                     overrides=("duration=1", "initial.theta=0.0")), tmp_path,
                      episode_trigger=lambda k: True, name_prefix="eval")
    env.reset(seed=0)
    for _ in range(20):  # 0.1 s
        env.step(np.zeros(2, dtype=np.float32))
    assert env.recording
    env.close()
    (video,) = env.videos
    assert video.path.name == "eval-episode-0.mp4" and video.frames == 4  # 0, 1/30, 2/30, 3/30 s
    assert [p.name for p in tmp_path.iterdir()] == ["eval-episode-0.mp4"]


@pytest.mark.parametrize("make_kwargs,kwargs,match", [
    ({}, {}, "RecordVideo needs an environment made with render_mode='rgb_array', got render_mode=None"),
    ({"render_mode": "rgb_array"}, {"fps": 0}, "fps must be a number of frames per second in"),
    ({"render_mode": "rgb_array"}, {"episode_trigger": 3}, "episode_trigger must be a callable"),
    ({"render_mode": "rgb_array"}, {"name_prefix": ""}, "name_prefix must be a non-empty"),
    ({"render_mode": "rgb_array"}, {"video_folder": 5}, "video_folder must be a directory path"),
])
def test_record_video_bad_arguments(tmp_path, make_kwargs, kwargs, match):
    from twin.envs import RecordVideo

    env = gymnasium.make("mtwip/Balance-v0", overrides=SHORT, **make_kwargs)
    try:
        with pytest.raises(TwinError, match=match) as exc:
            RecordVideo(env, **{"video_folder": tmp_path, **kwargs})
        assert "\n" not in str(exc.value)
    finally:
        env.close()


def test_record_video_refuses_other_environments(tmp_path):
    from twin.envs import RecordVideo

    env = gymnasium.make("CartPole-v1", render_mode="rgb_array")
    with pytest.raises(TwinError, match="RecordVideo records the mtwip environments .*got CartPoleEnv"):
        RecordVideo(env, tmp_path)
    env.close()


def test_default_trigger_is_gymnasiums_schedule():
    from twin.envs.video import capped_cubic_video_schedule

    assert [k for k in range(1001) if capped_cubic_video_schedule(k)] == [k ** 3 for k in range(10)] + [1000]
    assert capped_cubic_video_schedule(3000) and not capped_cubic_video_schedule(3001)
