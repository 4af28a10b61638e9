"""Calibration of the twin's plant parameters from sensor logs (issue 30; in progress).

The fit compares logged motion with a model of it, and that model must step time the way
the plant that made the log does: fitting continuous equation (1) to the PyBullet twin's
own states biases the inertias (n_yb by ×0.54, n_zb by ×−0.42 in the research for
issue 30), while the twin's own discretisation recovers them within 0.1 %.

Modules
    :mod:`twin.calibrate.model`
        :func:`~twin.calibrate.model.step_windows`: the twin's control-period stepping
        (physics substeps, joint damping, held wheel–ground damping, the motor driver) for
        many windows of a log at once, in plain elementwise numpy.

Still to come: the IMU and encoder measurement models, and the fit itself.
"""
