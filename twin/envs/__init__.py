"""Gymnasium environments on the PyBullet twin (needs ``pip install mtwip-twin[gym]``).

Importing this package registers two environment ids with Gymnasium:

============================  ===================================  ======================
id                            task                                 default scenario
============================  ===================================  ======================
``mtwip/Balance-v0``          keep the robot upright               ``paper-exp1``
``mtwip/Track-v0``            balance and reach the travel and     ``paper-exp3``
                              heading targets
============================  ===================================  ======================

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
``reward_weights``. The observation, action, reward and episode end of each task are
specified in :mod:`twin.envs.balance` and :mod:`twin.envs.track`; the shared behaviour
in :mod:`twin.envs.base`. Bad arguments raise a one-line :class:`twin.errors.TwinError`.
"""
from __future__ import annotations

try:
    import gymnasium
except ImportError as exc:  # pragma: no cover - the optional dependency is missing
    raise ImportError("twin.envs needs Gymnasium: pip install 'mtwip-twin[gym]' (gymnasium>=1.0)") from exc

from twin.envs.balance import BalanceEnv
from twin.envs.base import OBS_MODES, TwinEnv
from twin.envs.track import TrackEnv

ENV_IDS = {
    "mtwip/Balance-v0": "twin.envs.balance:BalanceEnv",
    "mtwip/Track-v0": "twin.envs.track:TrackEnv",
}


def register() -> None:
    """Register :data:`ENV_IDS` with Gymnasium (done on import; a second call does nothing)."""
    for env_id, entry_point in ENV_IDS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point=entry_point, nondeterministic=False)


register()

__all__ = ["BalanceEnv", "ENV_IDS", "OBS_MODES", "TrackEnv", "TwinEnv", "register"]
