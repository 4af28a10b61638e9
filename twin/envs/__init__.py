"""Gymnasium environments on the PyBullet twin (needs ``pip install mtwip-twin[gym]``).

Importing this package registers two environment ids with Gymnasium:

====================  ================================  ================  =================
id                    task                              default scenario  max_episode_steps
====================  ================================  ================  =================
``mtwip/Balance-v0``  keep the robot upright            ``paper-exp1``    3000 (15 s, 200 Hz)
``mtwip/Track-v0``    balance and reach the travel and  ``paper-exp3``    3000 (15 s, 200 Hz)
                      heading targets
====================  ================================  ================  =================

``max_episode_steps`` is the default scenario's duration over its control period (read
from the scenario when the package is imported): ``gymnasium.make`` wraps the
environment in a ``TimeLimit`` that truncates on the step the environment itself
truncates at. For a scenario that lasts longer, pass ``max_episode_steps=`` to
``gymnasium.make`` (the environment warns on its first reset otherwise).

::

    import gymnasium
    import twin.envs  # registers the ids

    env = gymnasium.make("mtwip/Balance-v0", scenario="paper-exp1", overrides=("duration=5",))
    obs, info = env.reset(seed=0)
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())

``gymnasium.make("twin.envs:mtwip/Balance-v0")`` imports the package itself (useful in
the worker processes of a vector environment). Keyword arguments (all optional):
``scenario`` (a built-in name or a ``.toml`` file), ``overrides`` (``"KEY=VALUE"``
strings, as ``twin run --set``), ``obs`` (``"estimate"``, ``"truth"`` or
``"readings"``), ``estimator`` (an estimator kind), ``randomize`` (False, True or a dict
of ``[sweep]`` keys, e.g. ``{"level": 0.3}``), ``render_mode`` (None or
``"rgb_array"``), ``render_size``, ``renderer``, ``hud``, ``max_torque`` (N·m),
``reward_weights``, ``normalize_actions`` (False: the action in N·m; True: Box [−1, 1],
fractions of ``max_torque``). :class:`RecordVideo` records episodes as real-time H.264
video at the scenario's ``video.fps``. The observation, action, reward and episode end of each task are
specified in :mod:`twin.envs.balance` and :mod:`twin.envs.track`; the shared behaviour
in :mod:`twin.envs.base`. Bad arguments raise a one-line :class:`twin.errors.TwinError`.
"""
from __future__ import annotations
from twin.scenarios import load_scenario

try:
    import gymnasium
except ImportError as exc:  # pragma: no cover - the optional dependency is missing
    raise ImportError("twin.envs needs Gymnasium: pip install 'mtwip-twin[gym]' (gymnasium>=1.0)") from exc

from twin.envs.balance import BalanceEnv
from twin.envs.base import OBS_MODES, TwinEnv
from twin.envs.track import TrackEnv
from twin.envs.video import RecordVideo
from twin.errors import TwinError

ENV_IDS = {
    "mtwip/Balance-v0": "twin.envs.balance:BalanceEnv",
    "mtwip/Track-v0": "twin.envs.track:TrackEnv",
}
_CLASSES = {"mtwip/Balance-v0": BalanceEnv, "mtwip/Track-v0": TrackEnv}


def episode_steps(scenario) -> int:
    """Control steps of a whole episode of ``scenario`` (a built-in name or a ``.toml`` file):
    its ``duration`` over its control period, which must be a whole number."""
    sc = load_scenario(str(scenario))
    rate = float(sc.data["rates"]["control"])
    steps = sc.duration * rate
    n = int(round(steps))
    if n < 1 or abs(steps - n) > 1e-6 * max(1.0, steps):
        raise TwinError(f"{sc.source}: duration {sc.duration:g} s is not a whole number of control periods "
                        f"(1/{rate:g} s): {steps:g} steps")
    return n


def register() -> None:
    """Register :data:`ENV_IDS` with Gymnasium (done on import; a second call does nothing),
    each with ``max_episode_steps`` = :func:`episode_steps` of its default scenario."""
    for env_id, entry_point in ENV_IDS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point=entry_point, nondeterministic=False,
                               max_episode_steps=episode_steps(_CLASSES[env_id].default_scenario))


register()

__all__ = ["BalanceEnv", "ENV_IDS", "OBS_MODES", "RecordVideo", "TrackEnv", "TwinEnv", "episode_steps", "register"]
