"""Actuators: what stands between a controller's torque command and the wheel."""
from twin.actuators.dc_motor import DEFAULT_MOTOR, DCMotorParams, MotorDriver, steady_current

__all__ = ["DEFAULT_MOTOR", "DCMotorParams", "MotorDriver", "steady_current"]
