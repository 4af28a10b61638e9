"""Calibration of a robot from its sensor logs: ``twin calibrate``.

Two models, one procedure each (:func:`twin.calibrate.run.model_for` chooses):

* the robot's continuous equations (the default): :mod:`twin.calibrate.physical` (equation (1)
  by RK4 at 1 kHz or more, with the motors, the commands held or sampled) and
  :mod:`twin.calibrate.robot` (several logs of one robot, per-log IMU constants, windows sized in
  seconds, Levenberg–Marquardt with the window states eliminated; the mapping of the robot's
  parameters to the twin's, :func:`~twin.calibrate.robot.to_twin`, and the held-out logs);
* the PyBullet twin's own stepping, for one log the twin wrote itself (its robot's exact
  dynamics), by the modules below.

The twin-stepping path, module by module:

:mod:`twin.calibrate.windows`
    the log on its control instants, cut into 0.1 s windows with their drive, readings and
    the EKF's first guess of each start state (both paths use it);
:mod:`twin.calibrate.model`
    :func:`~twin.calibrate.model.step_windows`: the twin's control-period stepping (physics
    substeps, joint damping, held wheel–ground damping, the motor driver) for all windows at
    once. It steps time as the twin that made such a log does: fitting continuous equation
    (1) to the twin's own states biases the inertias (n_yb ×0.54, the twin's lagging dampings
    acting as inertia), its own stepping does not;
:mod:`twin.calibrate.readings`
    the IMU and encoder readings along stepped states;
:mod:`twin.calibrate.parameters`
    the one registry of what can be fitted (name, SI unit, group);
:mod:`twin.calibrate.fit`
    least squares over the parameters and the windows' start states, outlier windows, the
    covariances and the bootstrap;
:mod:`twin.calibrate.run`
    the staged procedure :func:`~twin.calibrate.run.calibrate`;
:mod:`twin.calibrate.identify`
    intervals, identifiability and the warnings;
:mod:`twin.calibrate.validate`
    the nominal and the calibrated twin's prediction errors on held-out logs;
:mod:`twin.calibrate.output`
    report.json, calibration.toml (for ``twin run --plant``) and figure.png.
"""
