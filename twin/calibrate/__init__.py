"""Calibration of the twin from a robot's sensor log: ``twin calibrate``.

The data flow, module by module:

:mod:`twin.calibrate.windows`
    the log on its control instants, cut into 0.1 s windows with their drive, readings and
    the EKF's first guess of each start state;
:mod:`twin.calibrate.model`
    :func:`~twin.calibrate.model.step_windows`: the twin's control-period stepping (physics
    substeps, joint damping, held wheel–ground damping, the motor driver) for all windows at
    once. It must step time as the plant that made the log does: fitting continuous equation
    (1) to the twin's own states biases the inertias (n_yb ×0.54), its own stepping does not;
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
