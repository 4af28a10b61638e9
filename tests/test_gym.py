"""The Gymnasium environments (twin.envs): API conformance, seeding, spaces, episode ends, errors."""
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
from twin.envs import BalanceEnv, TrackEnv  # noqa: E402
from twin.errors import TwinError  # noqa: E402

SHORT = ("duration=0.5",)
ACTION_WARNING = "For Box action spaces, we recommend using a symmetric and normalized space"


def make(env_id="mtwip/Balance-v0", **kwargs):
    return gymnasium.make(env_id, **kwargs)


def rollout(env, seed, actions):
    """Observations, rewards and infos of reset(seed) followed by ``actions`` (stops at the end)."""
    obs, info = env.reset(seed=seed)
    out, rewards, infos = [obs], [], [info]
    for a in actions:
        obs, r, term, trunc, info = env.step(a)
        out.append(obs)
        rewards.append(r)
        infos.append(info)
        if term or trunc:
            break
    return np.array(out), np.array(rewards), infos


# ---- registration and Gymnasium's own checker -------------------------------------------------
def test_ids_are_registered_with_their_defaults():
    for env_id, cls, scenario in (("mtwip/Balance-v0", BalanceEnv, "paper-exp1"),
                                  ("mtwip/Track-v0", TrackEnv, "paper-exp3")):
        assert env_id in gymnasium.registry
        env = make(env_id)
        try:
            assert type(env.unwrapped) is cls
            assert env.unwrapped.scenario.name == scenario
            assert env.unwrapped.n_steps == 3000  # 15 s at 200 Hz
        finally:
            env.close()


@pytest.mark.parametrize("env_id", ["mtwip/Balance-v0", "mtwip/Track-v0"])
def test_check_env_passes(env_id):
    env = make(env_id, overrides=SHORT)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            check_env(env.unwrapped, skip_render_check=True)
        # the only remark allowed: the action space is in N·m, not normalised to [-1, 1]
        others = [str(w.message) for w in caught if ACTION_WARNING not in str(w.message)]
        assert others == []
    finally:
        env.close()


@pytest.mark.filterwarnings("ignore:.*For Box action spaces")
def test_check_env_with_rendering_and_one_frame():
    env = make(overrides=SHORT, render_mode="rgb_array", render_size=(160, 120))
    try:
        check_env(env.unwrapped)  # renders through spec.make(render_mode=...) too
        env.reset(seed=1)
        env.step(np.zeros(2, dtype=np.float32))
        frame = env.render()
        assert frame.shape == (120, 160, 3) and frame.dtype == np.uint8
        assert frame.std() > 5.0  # a picture, not a blank
        assert env.unwrapped._scene.renderer in ("egl", "tiny")
    finally:
        env.close()
    assert env.unwrapped._scene is None


def test_no_renderer_without_render_mode():
    env = make(overrides=SHORT)
    try:
        env.reset(seed=0)
        env.step(np.zeros(2, dtype=np.float32))
        assert env.unwrapped._scene is None
    finally:
        env.close()


# ---- seeding ----------------------------------------------------------------------------------
def test_same_seed_same_episode_other_seed_differs():
    env = make(overrides=("duration=0.5", "initial.theta=0.05"))
    try:
        actions = np.random.default_rng(5).uniform(-0.05, 0.05, size=(40, 2)).astype(np.float32)
        o1, r1, i1 = rollout(env, 11, actions)
        o2, r2, i2 = rollout(env, 11, actions)
        o3, _, _ = rollout(env, 12, actions)
        assert len(o1) == len(o2) == 41
        np.testing.assert_array_equal(o1, o2)
        np.testing.assert_array_equal(r1, r2)
        assert [i["truth"] for i in i1] == [i["truth"] for i in i2]
        assert i1[0]["seed"] == i2[0]["seed"] != None  # noqa: E711
        assert not np.array_equal(o1[:len(o3)], o3[:len(o1)])  # other sensor noise, another estimate
        # reset() without a seed continues the generator: a new sensor seed, deterministically
        env.reset(seed=11)
        a = env.reset()[1]["seed"]
        env.reset(seed=11)
        b = env.reset()[1]["seed"]
        assert a == b != i1[0]["seed"]
    finally:
        env.close()


def test_randomized_episodes_replay_from_their_seed():
    from twin.sweep.sampling import sample_scenario

    env = make(overrides=SHORT, randomize={"level": 0.3, "initial_theta": [-0.2, 0.2]})
    try:
        u = env.unwrapped
        obs1, info1 = env.reset(seed=3)
        params1 = u.loop.config.params
        obs2, info2 = env.reset(seed=3)
        np.testing.assert_array_equal(obs1, obs2)
        assert info1["sample_values"] == info2["sample_values"] and u.loop.config.params == params1
        assert info1["level"] == 0.3 and "--sample 0 --seed" in info1["replay"]
        _, info3 = env.reset(seed=4)
        assert info3["sample_values"] != info1["sample_values"]
        theta0 = info3["sample_values"]["initial_theta_rad"]
        assert -0.2 <= theta0 <= 0.2 and abs(info3["truth"].theta - theta0) < 1e-9
        # the episode is the sweep's sample: the same plant and sensor seed from (root seed, sample)
        s = sample_scenario(u.scenario, info3["root_seed"], info3["sample"])
        assert s.scenario.twin_config() == u.loop.config and s.seed == info3["seed"]
        factors = [v for k, v in info3["sample_values"].items() if k.startswith("factor_")]
        base = u.scenario.data["plant"]["scale"]
        assert any(abs(f - base.get(k[7:], 1.0)) > 1e-3 for k, f in info3["sample_values"].items()
                   if k.startswith("factor_")) and len(factors) > 5
    finally:
        env.close()
    # randomize=True draws the level from the scenario's sweep.levels
    env = make(overrides=SHORT, randomize=True)
    try:
        levels = {env.reset(seed=s)[1]["level"] for s in range(8)}
        assert levels <= set(env.unwrapped.scenario.data["sweep"]["levels"]) and len(levels) > 1
    finally:
        env.close()


def test_async_vector_env_runs():
    envs = gymnasium.vector.AsyncVectorEnv(
        [lambda: gymnasium.make("mtwip/Balance-v0", overrides=SHORT) for _ in range(2)])
    try:
        obs, infos = envs.reset(seed=[1, 2])
        assert obs.shape == (2, 6) and obs.dtype == np.float32
        for _ in range(5):
            obs, rewards, term, trunc, infos = envs.step(np.zeros((2, 2), dtype=np.float32))
        assert obs.shape == (2, 6) and rewards.shape == (2,) and np.isfinite(obs).all()
        assert not (term.any() or trunc.any())
        assert not np.array_equal(obs[0], obs[1])  # two seeds, two noise streams
    finally:
        envs.close()


# ---- episode ends -----------------------------------------------------------------------------
def test_random_torques_fall_and_terminate():
    env = make()  # paper-exp1: from 0.48 rad, 15 s
    try:
        env.action_space.seed(0)
        env.reset(seed=0)
        for k in range(env.unwrapped.n_steps):
            obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
            if terminated or truncated:
                break
        assert terminated is True and truncated is False
        assert k + 1 < env.unwrapped.n_steps and info["status"] == "fell" and info["reason"]
        assert info["alive"] == 0.0 and reward <= 0.0
        with pytest.raises(TwinError, match="call reset"):
            env.unwrapped.step(np.zeros(2))
    finally:
        env.close()


def test_truncated_at_the_duration():
    env = make(overrides=("duration=0.5", "initial.theta=0.0"))
    try:
        env.reset(seed=0)
        n = 0
        while True:
            obs, reward, terminated, truncated, info = env.step(np.zeros(2, dtype=np.float32))
            n += 1
            if terminated or truncated:
                break
        assert (n, terminated, truncated) == (100, False, True)  # 0.5 s at 200 Hz
        assert math.isclose(info["t"], 0.5) and info["status"] == "running" and reward > 0.9
    finally:
        env.close()


# ---- spaces -----------------------------------------------------------------------------------
@pytest.mark.parametrize("env_id,size", [("mtwip/Balance-v0", 0), ("mtwip/Track-v0", 2)])
@pytest.mark.parametrize("mode,n", [("estimate", 6), ("truth", 6), ("readings", 11)])
def test_observations_stay_in_their_space(env_id, size, mode, n):
    env = make(env_id, obs=mode, overrides=("duration=2",))
    try:
        u = env.unwrapped
        assert env.observation_space.shape == (n + size,) and len(u.obs_names) == n + size
        assert env.observation_space.dtype == np.float32
        env.action_space.seed(1)
        obs, _ = env.reset(seed=1)
        seen = [obs]
        for _ in range(400):  # random torques until it falls (or the 2 s end)
            obs, _, term, trunc, _ = env.step(env.action_space.sample())
            seen.append(obs)
            if term or trunc:
                break
        for o in seen:
            assert o.dtype == np.float32 and np.isfinite(o).all() and o in env.observation_space
        assert np.ptp(np.array(seen), axis=0)[:3].min() > 0  # it moved
    finally:
        env.close()


def test_out_of_range_values_are_clipped_to_the_space():
    env = make(overrides=SHORT)
    try:
        env.reset(seed=0)
        u = env.unwrapped
        u.loop.estimate = (5.0, 1e3, -1e5, 0.25, 2e4, float("nan"))  # as if the estimator ran away
        obs = u._observe()
        assert obs.tolist() == [np.float32(math.pi), 100.0, -1e4, 0.25, 1e4, 0.0] and obs in env.observation_space
    finally:
        env.close()


def test_readings_hold_missing_samples_with_a_flag():
    env = make(obs="readings", overrides=("duration=0.5", 'faults=[{kind="dropout", sensor="imu", start=0.0, '
                                          'duration=0.05}]'))
    try:
        first, _ = env.reset(seed=2)
        assert first[8:].tolist() == [1.0, 1.0, 1.0]  # the sample taken before t = 0 arrives at t = 0
        held = []
        for _ in range(15):
            obs = env.step(np.full(2, 0.2, dtype=np.float32))[0]
            held.append(obs)
        dropped = [o for o in held if o[8] == 0.0]
        assert len(dropped) >= 9  # 0.05 s of IMU samples lost, at 200 Hz
        for o in dropped:
            assert o[9] == 0.0 and o[10] == 1.0
            np.testing.assert_array_equal(o[:6], first[:6])  # the last IMU values held
        assert held[-1][8] == 1.0 and not np.array_equal(held[-1][:6], first[:6])  # and fresh ones after
    finally:
        env.close()


def test_action_bound_from_the_motor_and_clipping():
    from twin.actuators.dc_motor import DEFAULT_MOTOR

    env = make(overrides=SHORT)
    try:
        assert env.action_space.high.tolist() == [np.float32(DEFAULT_MOTOR.stall_torque)] * 2
        assert env.action_space.low.tolist() == [-np.float32(DEFAULT_MOTOR.stall_torque)] * 2
        env.reset(seed=0)
        _, _, _, _, info = env.step(np.array([10.0, -10.0]))
        assert info["command"] == (DEFAULT_MOTOR.stall_torque, -DEFAULT_MOTOR.stall_torque)
        assert info["cost_torque"] == 1.0
    finally:
        env.close()
    for kwargs, bound in (({"overrides": ('plant.motor="ideal"',)}, DEFAULT_MOTOR.stall_torque),
                          ({"max_torque": 0.5}, 0.5)):
        env = make(**kwargs)
        try:
            assert env.action_space.high[0] == np.float32(bound)
        finally:
            env.close()


# ---- what the environment drives: the loop, the reward --------------------------------------
def test_same_trajectory_as_simulate_twin():
    """Driven by the IT2 cascade on the loop's estimate, the environment runs exactly the
    loop that simulate_twin runs (same scenario, same sensor seed)."""
    from twin.sim.bullet_loop import simulate_twin

    env = make("mtwip/Track-v0", overrides=("duration=1",))
    try:
        u = env.unwrapped
        sc = u.scenario
        ctrl = sc.build_controller("it2", sc.build_context())
        _, info = env.reset(seed=9)
        seed = info["seed"]
        ctrl.reset(u.experiment.targets)
        truths = [info["truth"]]
        while True:
            c = ctrl(u.loop.estimate, u.experiment.targets)
            _, _, term, trunc, info = env.step(np.array(c[:2]))
            truths.append(info["truth"])
            if term or trunc:
                break
        run = simulate_twin(sc.build_controller("it2", sc.build_context()), u.experiment, sc.twin_config(),
                            sensors=sc.sensor_config(), seed=seed)
        np.testing.assert_array_equal(np.array(truths), run.truth)
    finally:
        env.close()


@pytest.mark.parametrize("env_id", ["mtwip/Balance-v0", "mtwip/Track-v0"])
def test_reward_is_the_weighted_sum_of_its_terms(env_id):
    env = make(env_id, overrides=SHORT, reward_weights={"theta": 2.0})
    try:
        u = env.unwrapped
        assert u.weights["theta"] == 2.0
        env.reset(seed=0)
        for _ in range(10):
            _, r, _, _, info = env.step(np.array([0.3, 0.2], dtype=np.float32))
            total = info["alive"] - sum(w * info["cost_" + k] for k, w in u.weights.items())
            assert math.isclose(r, total, abs_tol=1e-12)
            assert all(0.0 <= info["cost_" + k] <= 1.0 for k in u.weights)
        assert math.isclose(info["cost_theta"], min(info["truth"].theta ** 2, 1.0))
    finally:
        env.close()


def test_track_observes_its_errors():
    env = make("mtwip/Track-v0", obs="truth", overrides=SHORT)
    try:
        obs, info = env.reset(seed=0)
        assert obs[6:].tolist() == [-1.0, -1.5]  # p − p_d = −1 m, α − α_d = −1.5 rad at the start
    finally:
        env.close()
    env = make("mtwip/Track-v0", scenario="paper-exp2", overrides=SHORT)  # no heading target
    try:
        obs, _ = env.reset(seed=0)
        assert obs[7] == 0.0 and obs[6] == pytest.approx(-0.7, abs=1e-3)
    finally:
        env.close()


def test_estimator_override_and_ideal_estimate():
    env = make(estimator="ideal", overrides=SHORT)
    truth = make(obs="truth", overrides=SHORT)
    try:
        a, _ = env.reset(seed=0)
        b, _ = truth.reset(seed=0)
        np.testing.assert_array_equal(a, b)
        assert type(env.unwrapped.loop.estimator).__name__ == "IdealEstimator"
    finally:
        env.close()
        truth.close()


def test_close_releases_the_physics_client():
    env = make(overrides=SHORT)
    env.reset(seed=0)
    twin = env.unwrapped.loop.twin
    assert twin.client._client >= 0
    env.close()
    assert twin.client._client == -1 and env.unwrapped.loop is None
    env.close()  # twice is fine


# ---- bad arguments ----------------------------------------------------------------------------
@pytest.mark.parametrize("kwargs,match", [
    ({"obs": "pixels"}, "obs must be one of estimate, truth, readings"),
    ({"scenario": "no-such-scenario"}, "neither a built-in scenario"),
    ({"scenario": "missing.toml"}, "no such scenario file"),
    ({"overrides": ("plant.bogus=1",)}, "unknown key 'bogus'"),
    ({"randomize": {"bogus": 1}}, "randomize: unknown key 'bogus'"),
    ({"randomize": {"level": 5.0}}, "sweep.levels"),
    ({"render_mode": "rgb_array", "render_size": (161, 120)}, "render_size must be"),
    ({"estimator": "nope"}, "estimator 'nope' is neither a built-in"),
    ({"obs": "readings", "overrides": ("sensors.sensing=ideal",)}, "obs='readings' needs simulated sensors"),
    ({"max_torque": -1.0}, "max_torque must be a positive number"),
    ({"reward_weights": {"speed": 1.0}}, "reward_weights: unknown term 'speed'"),
])
def test_bad_arguments_are_one_line_errors(kwargs, match):
    with pytest.raises(TwinError, match=match) as exc:
        make(**kwargs)
    assert "\n" not in str(exc.value)


def test_unsupported_render_mode():
    # (gymnasium.make turns "human" into rgb_array under its HumanRendering wrapper)
    with pytest.raises(TwinError, match="render_mode must be None or one of rgb_array"):
        BalanceEnv(render_mode="human")


def test_track_needs_a_target():
    with pytest.raises(TwinError, match="needs a target") as exc:
        make("mtwip/Track-v0", scenario="paper-exp1")
    assert "\n" not in str(exc.value)


def test_an_episode_pictured_shows_the_start_the_path_and_the_targets_as_a_video_does():
    """render() draws the floor markers a twin run video draws and its key names: the heading
    target's arrow and the position target's ring (green), and once the robot has moved 5 cm
    the start's cross and the path since (orange); the key's entries match what is drawn."""
    from twin.render import hud

    env = make("mtwip/Track-v0", overrides=("duration=1.5",), render_mode="rgb_array", render_size=(320, 240))
    u = env.unwrapped
    ctrl = u.scenario.build_controller("it2", u.scenario.build_context())
    obs, _ = env.reset(seed=0)
    ctrl.reset(u.experiment.targets)
    first = env.render()
    done = False
    while not done:
        ul, ur, *_ = ctrl(obs[:6], u.experiment.targets)
        obs, _, terminated, truncated, _ = env.step(np.array([ul, ur], dtype=np.float32))
        done = terminated or truncated
        if u.loop.k % 20 == 0:
            last = env.render()
    env.close()

    def count(rgb, colour):
        return int((np.abs(rgb[:, :, ::-1].astype(int) - colour).max(axis=2) < 40).sum())

    below_key = slice(110, None)  # rows under the text box and its key
    # (the body's lit side comes near the path's orange in a few pixels)
    assert count(last[below_key], hud.PATH) > count(first[below_key], hud.PATH) + 30  # moved: cross and path
    assert count(last[below_key], hud.GREEN) > 30  # the targets on the floor (the arrow, the ring)
