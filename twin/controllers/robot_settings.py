"""The controllers' settings a robot implies: the LMI design's torque bound and decay rate, the
LQR's input scale, and the Mamdani position and direction controllers' universes.

The paper gives its settings for its own robot only (Table I's ranges, a decay rate and a torque
bound chosen for a 2.6 kg body); it leaves open how they carry to another robot. The twin's
rule is that every setting keeps its meaning, and so its value, where the meaning is free of
the robot's size, and is scaled by the one figure of the robot it depends on where it is not.
Each rule gives the paper's values for the paper's robot exactly (a ratio of a figure to
itself is 1), so a paper run is what it was, bit for bit.

Two figures of the robot carry the scaling:

* its **time scale**, the rate λ = √(m11 g_b / (m11 m22 − m12²)) (1/s) at which the upright
  body falls with its wheels free (the open-loop unstable pole of the balance model without
  friction: 23.8 1/s for the paper's robot, 12.5 for the Balboa, 4.1 for the RMP 220);
* its **drive**, the peak torque per wheel τ = k_t · i_max (N·m: the stall torque, or less
  where the driver limits the current), and the accelerations it gives.

The rules (the paper's value × the ratio of the robot's figure to the paper robot's):

* ``design.decay_rate`` × λ / λ_paper: a guaranteed decay is a speed, and a slow (large)
  robot cannot be asked to recover as fast as a small one; the design would be infeasible
  (the RMP 220 at the paper's 2 1/s) or needlessly aggressive;
* ``design.rho`` × τ / τ_paper: the bound on the total wheel torque is a share of what the
  drive gives (2 N·m of the paper's 2.4);
* the LQR's Bryson input scale is ``design.rho`` (as it always was: "the input bound of the LMI
  design");
* position controller: the lean θ_off (rad) asks for the acceleration g tan θ_off on any robot,
  and the position error p_e (m) is a distance of the task: both keep Table I's ranges, so the
  position loop behaves as the paper's does on every robot, unless the drive cannot give
  that acceleration with room to spare: θ_off is capped where g tan θ_off reaches a quarter
  of the drive's acceleration 2τ / (r M) (M the mass with the wheels' rotation);
* the body's pitch rate θ̇ (rad/s) is a rate of the body's own fall: × λ / λ_paper;
* direction controller: the heading error α_e and its rate α̇_e are the task's (Table I's
  ranges kept); the turning torque u_α (N·m per wheel) is scaled so that it gives the same
  yaw acceleration 2 b u_α / (r m33) as on the paper's robot (× (r m33 / b) / (r m33 / b)_paper),
  capped at a quarter of the wheel's peak torque (the balance loop keeps the rest).

Values are rounded to 3 significant digits (the robot's figures are not known better, and a
scenario's record shows them). See ``docs/explanation/paper-method.md``, "Another robot".
"""
from __future__ import annotations

import math

from twin.controllers.lmi import DEFAULT_DECAY_RATE, DEFAULT_RHO
from twin.controllers.mamdani import (ALPHA_DOT_E_RANGE, ALPHA_E_RANGE, DEFAULT_U_ALPHA_MAX, P_E_RANGE,
                                      THETA_DOT_RANGE, THETA_OFF_RANGE)
from twin.params import RobotParams
from twin.plant.ts_model import local_model
from twin.robots import load_robot

# the Mamdani controllers' universes: scenario key (controller.universes.NAME) → (Table I's value, unit)
UNIVERSES = {
    "position_error": (P_E_RANGE, "m"),
    "pitch_rate": (THETA_DOT_RANGE, "rad/s"),
    "lean": (THETA_OFF_RANGE, "rad"),
    "heading_error": (ALPHA_E_RANGE, "rad"),
    "turn_rate": (ALPHA_DOT_E_RANGE, "rad/s"),
    "turn_torque": (DEFAULT_U_ALPHA_MAX, "N·m"),
}
DRIVE_SHARE = 0.25  # of the drive's acceleration (lean) and of a wheel's peak torque (turning torque)


def fall_rate(params: RobotParams) -> float:
    """λ in 1/s: the rate at which the upright body falls with its wheels free, without friction
    (√A[1, 0] of the upright rule of the balance model)."""
    return math.sqrt(float(local_model(params, 1.0)[0][1, 0]))


def peak_torque(robot) -> float:
    """N·m per wheel: the drive's torque at its current limit (the stall torque when it has none)."""
    m = robot.motor()
    return min(m.stall_torque, m.k_t * m.max_current)


def drive_acceleration(robot) -> float:
    """m/s²: the acceleration both wheels' peak torque gives the whole robot on level ground."""
    p = robot.params()
    mass = p.m_b + 2.0 * p.m_w + 2.0 * p.n_wa / (p.r * p.r)
    return 2.0 * peak_torque(robot) / (p.r * mass)


def _rounded(value: float) -> float:
    return float(f"{value:.3g}")


def _paper():
    return load_robot("paper")  # read once per process (a built-in)


_MEMO: dict = {}  # (rule, robot digest) → settings: a scenario asks for each key of them apart


def _once(rule):
    def settings(robot) -> dict[str, float]:
        key = (rule.__name__, robot.digest)
        if key not in _MEMO:
            _MEMO[key] = rule(robot)
        return dict(_MEMO[key])

    settings.__name__, settings.__doc__ = rule.__name__, rule.__doc__
    return settings


@_once
def design_settings(robot) -> dict[str, float]:
    """``design.rho`` (N·m) and ``design.decay_rate`` (1/s) for ``robot`` (see the module's rules)."""
    paper = _paper()
    return {"rho": _rounded(DEFAULT_RHO * (peak_torque(robot) / peak_torque(paper))),
            "decay_rate": _rounded(DEFAULT_DECAY_RATE * (fall_rate(robot.params()) / fall_rate(paper.params())))}


@_once
def universes(robot) -> dict[str, float]:
    """``controller.universes``: each of :data:`UNIVERSES` for ``robot`` (see the module's rules)."""
    paper = _paper()
    p, pp = robot.params(), paper.params()
    lean = min(THETA_OFF_RANGE, math.atan(DRIVE_SHARE * drive_acceleration(robot) / p.g))
    yaw = (p.r * p.m33 / p.b) / (pp.r * pp.m33 / pp.b)
    turn_torque = min(DEFAULT_U_ALPHA_MAX * yaw, DRIVE_SHARE * peak_torque(robot))
    out = {"position_error": P_E_RANGE, "pitch_rate": THETA_DOT_RANGE * (fall_rate(p) / fall_rate(pp)),
           "lean": lean, "heading_error": ALPHA_E_RANGE, "turn_rate": ALPHA_DOT_E_RANGE, "turn_torque": turn_torque}
    return {k: (v if v == UNIVERSES[k][0] else _rounded(v)) for k, v in out.items()}


__all__ = ["DRIVE_SHARE", "UNIVERSES", "design_settings", "drive_acceleration", "fall_rate", "peak_torque",
           "universes"]
