"""Sensors on the twin: what the robot measures of the ground truth.

``specs``    the IMU's and encoders' datasheet figures, in one place; three IMU presets
``imu``      the IMU's true angular velocity and specific force from the physics, at the
           end of its lever arm from the centre of mass, sample after sample (``ImuMotion``)
``noise``    a 3-axis sensor's noise pipeline (bias, scale, white noise, range, ADC)
``faults``   dropouts, stuck outputs, spikes, latency changes
``suite``    both sensors with faults and latency, read once per control period
"""
from twin.sensors.faults import Dropout, LatencyChange, Spikes, Stuck
from twin.sensors.imu import ImuMotion, imu_kinematics
from twin.sensors.specs import DEFAULT_ENCODERS, DEFAULT_IMU, IMU_PRESETS, EncoderSpec, ImuSpec, TriadSpec
from twin.sensors.suite import Measurement, SensorConfig, SensorSuite

__all__ = ["DEFAULT_ENCODERS", "DEFAULT_IMU", "Dropout", "EncoderSpec", "IMU_PRESETS", "ImuMotion", "ImuSpec",
           "LatencyChange", "Measurement", "SensorConfig", "SensorSuite", "Spikes", "Stuck", "TriadSpec",
           "imu_kinematics"]
