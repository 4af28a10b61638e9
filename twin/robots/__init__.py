"""Robots in absolute units: a robot file (``robot.toml``) describes one robot (body, wheels,
drive, sensors, control rate, the tilt at which it is lost) and every command uses it.

:func:`load_robot` reads a built-in by name (:func:`builtin_robots`) or a file;
:class:`~twin.robots.robot.Robot` is the validated robot and what the twin makes of it (the
model of equation (1), the motors, the IMU and the encoders).
"""
from twin.robots.robot import ROBOT_KEYS, Robot, builtin_names, builtin_robots, load_robot, robot_item, robot_text

__all__ = ["ROBOT_KEYS", "Robot", "builtin_names", "builtin_robots", "load_robot", "robot_item", "robot_text"]
