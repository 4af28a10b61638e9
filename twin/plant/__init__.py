"""The plant.

- :mod:`twin.plant.analytic`: equation (1) as ODE right-hand sides (the reference model);
- :mod:`twin.plant.ts_model`: its IT2 Takagi–Sugeno approximation (for the LMI design);
- :mod:`twin.plant.urdf`: the robot as a URDF generated from a parameter set;
- :mod:`twin.plant.bullet`: the PyBullet twin (contact, friction, motors, ground truth);
- :mod:`twin.plant.disturbances`: pushes, payload, slope, friction changes, true-plant sampling.
"""
