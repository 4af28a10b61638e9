"""The plant.

- :mod:`twin.plant.analytic`: equation (1) as ODE right-hand sides (the reference model);
- :mod:`twin.plant.analytic_plant`: equation (1) as a :class:`twin.protocols.Plant` (RK4, ideal torque sources);
- :mod:`twin.plant.ts_model`: its IT2 Takagi–Sugeno approximation (for the LMI design);
- :mod:`twin.plant.urdf`: the robot as a URDF generated from a parameter set;
- :mod:`twin.plant.bullet`: the PyBullet twin (contact, friction, motors, ground truth);
- :mod:`twin.plant.disturbances`: pushes, payload, slope, friction changes, true-plant sampling.

:func:`build_plant` makes the plant a scenario's ``plant.model`` names; :func:`check_plant`
is the one check of the :class:`twin.protocols.Plant` contract.
"""
from __future__ import annotations

PLANT_MODELS = ("bullet", "analytic")  # a scenario's plant.model
_PLANT_MEMBERS = ("reset", "step", "close")
_PLANT_ATTRIBUTES = ("control_rate",)
_SENSOR_ATTRIBUTES = ("kinematics", "com_local", "gravity")


def build_plant(model: str, config=None, theta0: float = 0.0, alpha0: float = 0.0, position=(0.0, 0.0)):
    """The plant ``model`` ("bullet": :class:`~twin.plant.bullet.BulletTwin`; "analytic":
    :class:`~twin.plant.analytic_plant.AnalyticPlant`) on ``config`` (a TwinConfig), at the
    given initial state."""
    from twin.errors import TwinError

    if model == "bullet":
        from twin.plant.bullet import BulletTwin

        return BulletTwin(config, theta0, alpha0, position)
    if model == "analytic":
        from twin.plant.analytic_plant import AnalyticPlant

        return AnalyticPlant(config, theta0, alpha0, position)
    raise TwinError(f"plant model must be one of {', '.join(map(repr, PLANT_MODELS))}, got {model!r}")


def check_plant(plant, sensors: bool = False) -> None:
    """A one-line :class:`~twin.errors.PluginError` unless ``plant`` has the members of
    :class:`twin.protocols.Plant` (with ``sensors``, those the simulated IMU reads too)."""
    from twin.errors import PluginError
    from twin.protocols import describe_object

    missing = [f"{m}()" for m in _PLANT_MEMBERS if not callable(getattr(plant, m, None))]
    missing += [m for m in _PLANT_ATTRIBUTES + (_SENSOR_ATTRIBUTES if sensors else ()) if not hasattr(plant, m)]
    if missing:
        why = " (the simulated IMU reads them)" if sensors and set(missing) & set(_SENSOR_ATTRIBUTES) else ""
        raise PluginError(f"plant {describe_object(plant)} has no {', '.join(missing)}{why}; a plant needs "
                          f"reset(theta0, alpha0, position), step(ul, ur), close(), control_rate, truth, status and "
                          f"end_reason, and kinematics, com_local and gravity with sensors (see "
                          f"twin.protocols.Plant)")
    rate = plant.control_rate
    if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not 0 < rate <= 100_000:
        raise PluginError(f"plant {describe_object(plant)}: control_rate must be a frequency in (0, 100000] Hz, got "
                          f"{rate!r} (see twin.protocols.Plant)")


__all__ = ["PLANT_MODELS", "build_plant", "check_plant"]
