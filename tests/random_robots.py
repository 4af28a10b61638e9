"""Random robots for the tests, drawn in stated ranges by a seeded generator (nothing else is
random): a body of 0.3–40 kg whose centre of mass is 0.03–0.6 m above the axle, wheels of
0.02–0.25 m radius, and a drive per side sized to hold the body 0.5 rad from upright (1.2 to
4 times the torque it takes), written as robot files (:func:`robot_text`)."""
from __future__ import annotations

import math

import numpy as np

G = 9.81
RANGES = {"body mass (kg)": (0.3, 40.0), "wheel radius (m)": (0.02, 0.25), "centre of mass above the axle (m)": (0.03, 0.6),
          "drive: holds the body at (rad)": (0.5, 0.5)}


def _loguniform(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(math.exp(rng.uniform(math.log(lo), math.log(hi))))


def random_robot(rng: np.random.Generator, name: str) -> dict:
    """One robot file's tables (SI units), physically consistent: the body a box that holds its
    centre of mass and clears the floor, inertias of a box with its mass concentrated toward the
    centre, wheels between a disc and a ring."""
    m_b = _loguniform(rng, 0.3, 40.0)
    r = _loguniform(rng, 0.02, 0.25)
    l = float(rng.uniform(0.03, 0.6))
    # the box: its bottom above the floor at 0.3 rad of tilt (0.5 r below the axle at most)
    height = float(min(rng.uniform(1.4, 2.4) * l, 2.0 * (l + 0.5 * r)))
    bottom = l - 0.5 * height
    depth = float(rng.uniform(0.3, 0.8)) * min(height, 2 * r + 0.1)
    width = float(rng.uniform(0.4, 1.2)) * height
    k = float(rng.uniform(0.5, 1.0))  # mass toward the centre: a fraction of the uniform box's moments
    pitch, yaw, roll = (k * m_b * (a * a + b * b) / 12.0 for a, b in ((depth, height), (depth, width), (width, height)))
    m_w = float(rng.uniform(0.03, 0.15)) * m_b
    wheel_width = 0.25 * r
    axle = float(rng.uniform(0.5, 0.9)) * m_w * r * r  # between a disc's 0.5 and a ring's 1
    diameter = 0.5 * axle + m_w * wheel_width * wheel_width / 12.0
    track = width + 2.0 * wheel_width + 0.01
    hold = m_b * G * l * math.sin(0.5) / 2.0  # N·m per wheel at 0.5 rad
    stall = float(rng.uniform(1.2, 4.0)) * hold
    top_speed = float(rng.uniform(1.0, 5.0))  # m/s at no load
    return {
        "name": name, "description": f"a random robot ({m_b:.2g} kg, {r * 100:.2g} cm wheels)",
        "body": {"mass": m_b, "com_height": l, "pitch_inertia": pitch, "yaw_inertia": yaw, "roll_inertia": roll,
                 "size": [depth, width, height], "box_bottom": bottom},
        "wheels": {"mass": m_w, "radius": r, "inertia_axle": axle, "inertia_diameter": diameter, "track": track},
        "friction": {"drive": 0.001 * m_b / 2.58, "ground": 0.01 * m_b / 2.58},
        "drive": {"supply_voltage": 24.0, "stall_torque": stall, "no_load_speed": top_speed / r, "gear_ratio": 1.0,
                  "gear_efficiency": 1.0, "rotor_inertia": 0.0, "pwm_bits": 10, "back_emf_compensation": True},
        "imu": {"part": "mpu6050", "position": [0.0, 0.0, l], "rate": 200.0, "latency": 0.005},
        "encoders": {"counts_per_rev": 2048, "on": "wheel"},
        "control": {"rate": 200.0},
    }


def robot_text(robot: dict) -> str:
    """``robot`` as a robot file (TOML): top-level strings, then one table per section."""
    def value(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return '"' + v + '"'
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return repr(float(v)) if isinstance(v, float) else str(v)

    lines = [f"{k} = {value(v)}" for k, v in robot.items() if not isinstance(v, dict)]
    for section, table in robot.items():
        if isinstance(table, dict):
            lines += ["", f"[{section}]"] + [f"{k} = {value(v)}" for k, v in table.items()]
    return "\n".join(lines) + "\n"
