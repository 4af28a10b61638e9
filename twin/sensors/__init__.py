"""Sensors on the twin: what the robot measures of the ground truth.

``specs``    the IMU's and encoders' datasheet figures, in one place; three IMU presets
``imu``      the IMU's true angular velocity and specific force from the physics, at the
           end of its lever arm from the centre of mass, sample after sample (``ImuMotion``)
``noise``    a 3-axis sensor's noise pipeline (bias, scale, white noise, range, ADC)
``faults``   dropouts, stuck outputs, spikes, latency changes
``suite``    both sensors with faults and latency, read once per control period; more sensors
           (``SensorConfig.extra``) beside them, each on its own random stream
``channels`` a channel (named reading, unit, components), a scenario key of a sensor type
``types``    the table of sensor types (:data:`~twin.sensors.types.SENSOR_TYPES`): what each
           gives, its ``[sensors.<type>]`` keys, how it is built and read
``motor_current`` the drivers' shunt-amplifier current sensor (off unless a scenario turns it on)
"""
from twin.sensors.faults import Dropout, LatencyChange, Spikes, Stuck
from twin.sensors.imu import ImuMotion, imu_kinematics
from twin.sensors.specs import DEFAULT_ENCODERS, DEFAULT_IMU, IMU_PRESETS, EncoderSpec, ImuSpec, TriadSpec
from twin.sensors.motor_current import MotorCurrentSpec
from twin.sensors.suite import Measurement, SensorConfig, SensorSuite

__all__ = ["DEFAULT_ENCODERS", "DEFAULT_IMU", "Dropout", "EncoderSpec", "IMU_PRESETS", "ImuMotion", "ImuSpec",
           "LatencyChange", "Measurement", "MotorCurrentSpec", "SensorConfig", "SensorSuite", "Spikes", "Stuck", "TriadSpec",
           "imu_kinematics"]
