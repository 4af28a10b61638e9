"""Data the twin did not write: an independent simulator of a two-wheeled inverted pendulum
(:mod:`foreign.robot_sim`) that shares no code with ``twin`` or ``estimation``, kept as a test
fixture (issue 40)."""
