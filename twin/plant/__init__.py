"""The plant.

- :mod:`twin.plant.base`: what every plant shares (ground truth, actuation, the twin's
  configuration, the start checks);
- :mod:`twin.plant.analytic`: equation (1) as ODE right-hand sides (the reference model);
- :mod:`twin.plant.analytic_plant`: equation (1) as a :class:`twin.protocols.Plant` (RK4, ideal torque sources);
- :mod:`twin.plant.ts_model`: its IT2 Takagi–Sugeno approximation (for the LMI design);
- :mod:`twin.plant.urdf`: the robot as a URDF generated from a parameter set;
- :mod:`twin.plant.bullet`: the PyBullet twin (contact, friction, motors, ground truth);
- :mod:`twin.plant.disturbances`: pushes, payload, slope, friction changes, true-plant sampling.

Plants are kinds of :mod:`twin.registry` (``"bullet"``, ``"analytic"`` or one's own
``"package.module:attribute"``), built by :func:`twin.registry.build_plant` and checked by
:func:`twin.registry.check_plant`.
"""
