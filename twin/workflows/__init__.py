"""The workflows: what each ``twin`` command does, above the engine (:mod:`twin.sim`), the
outputs (:mod:`twin.outputs`), the checks (:mod:`twin.verify`), the logs (:mod:`twin.logs`)
and calibration (:mod:`twin.calibrate`). A command of :mod:`twin.commands` parses its
arguments, calls one of these and prints what it returns; a program calls them the same way.

=================================  ====================================================
:mod:`twin.workflows.run`          a scenario's runs into a run directory (``twin run``)
:mod:`twin.workflows.check`        scenarios and sensor logs against their bounds (``twin check``)
:mod:`twin.workflows.sweep`        a Monte Carlo sweep into its directory (``twin sweep``)
:mod:`twin.workflows.replay`       estimators replayed on sensor logs (``twin replay``)
:mod:`twin.workflows.calibrate`    a robot calibrated from its logs (``twin calibrate``)
:mod:`twin.workflows.compare`      two results side by side (``twin compare``)
:mod:`twin.workflows.linearize`    a robot's linearised model as JSON (``twin linearize``)
=================================  ====================================================

Each module is imported only by the command that uses it (they import the engine, NumPy and
PyBullet): this package's ``__init__`` imports none of them.
"""
