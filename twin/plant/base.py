"""What every plant shares: the ground truth and actuation it reports, the configuration of a
twin of the robot, and the checks of a starting pose.

A plant (:class:`twin.protocols.Plant`) reports :class:`GroundTruth` at the end of each
control period and :class:`Actuation`, what its motors did; :class:`TwinConfig` says which
robot, rates, motors, floor and disturbances a twin has. :func:`checked_start` checks a
starting pose; :func:`initial_pose` places the robot with both wheels on the floor, and
:func:`start_problem` says which part of it would start in the floor. None of this needs
PyBullet: the PyBullet twin (:mod:`twin.plant.bullet`), the analytic plant
(:mod:`twin.plant.analytic_plant`) and users' plants build on it alike.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

from twin.actuators.dc_motor import DEFAULT_MOTOR, DCMotorParams
from twin.errors import TwinError
from twin.params import NOMINAL, RobotParams
from twin.plant.disturbances import Disturbances, Ground
from twin.plant.urdf import BODY_DEPTH, PAYLOAD_SIZE, Payload, body_box, body_height
from twin.rotations import cross, dot, quat_from_matrix, unit
from twin.timing import steps_per_control


class GroundTruth(NamedTuple):
    """The true state at one instant (SI units)."""

    t: float  # s
    theta: float  # rad, body pitch from the vertical, positive forward
    theta_dot: float  # rad/s
    psi_l: float  # rad, left wheel angle from the vertical
    psi_r: float  # rad
    psi: float  # rad, (ψl + ψr) / 2
    psi_dot: float  # rad/s
    alpha: float  # rad, heading, unwrapped, positive turning left
    alpha_dot: float  # rad/s
    distance: float  # m, p = r ψ
    x: float  # m, axle midpoint in the world
    y: float  # m
    roll: float  # rad, body roll (0 with both wheels on a level floor)
    psi_l_dot: float  # rad/s
    psi_r_dot: float  # rad/s

    def state6(self) -> tuple[float, float, float, float, float, float]:
        """[θ, θ̇, ψ, ψ̇, α, α̇], the controllers' state."""
        return (self.theta, self.theta_dot, self.psi, self.psi_dot, self.alpha, self.alpha_dot)


TRUTH_UNITS = dict(t="s", theta="rad", theta_dot="rad/s", psi_l="rad", psi_r="rad", psi="rad", psi_dot="rad/s",
                   alpha="rad", alpha_dot="rad/s", distance="m", x="m", y="m", roll="rad",
                   psi_l_dot="rad/s", psi_r_dot="rad/s")


class Actuation(NamedTuple):
    """What the motors did over one control period."""

    duty_l: float  # PWM duty in [−1, 1] (0 for an ideal torque source)
    duty_r: float
    torque_l: float  # N·m delivered by the motor (at the PWM update; mean over the period with inductance)
    torque_r: float
    saturated_l: bool  # the current limit or the supply voltage cut the command
    saturated_r: bool


ACTUATION_UNITS = dict(duty_l="1", duty_r="1", torque_l="N·m", torque_r="N·m", saturated_l="bool", saturated_r="bool")


@dataclass(frozen=True)
class TwinConfig:
    """Everything that defines a twin (all deterministic; sample random parts beforehand).

    Parameters
    ----------
    params : RobotParams
        The true plant (the controllers may be designed on another set).
    physics_rate, control_rate : Hz
        The control period must be a whole number of physics steps.
    motor : DCMotorParams or None
        Motor and driver of each wheel; None is an ideal torque source.
    ground : Ground
        Friction coefficients and slope of the floor.
    disturbances : Disturbances
        Pushes, payload, centre-of-mass offset, friction changes.
    fall_angle : rad
        |θ| beyond this ends the run as ``"fell"``.
    solver_iterations : int
        Bullet's constraint-solver iterations per step.
    solver_residual_threshold : float
        The solver stops early once its residual falls below this (Bullet's default is
        1e-7). At 1e-7 a wheel not aligned with the world axes slips by what the solver
        leaves unresolved, and the robot's rocking rectifies that slip into a yaw and
        position creep (0.08 rad per 100 s at α = 0.1 rad; see
        docs/investigations/yaw-creep.md); 1e-14 removes it for about 20 % more time.
    body : ((x, y, z), (x, y, z)) m, or None
        The body box's lowest and highest corners from the axle midpoint (body frame), drawn
        and collided with (a robot file's ``size`` and ``box_bottom``); None: Table III's drawing
        rule (:func:`twin.plant.urdf.body_box`).
    """

    params: RobotParams = NOMINAL
    physics_rate: float = 1000.0
    control_rate: float = 200.0
    motor: DCMotorParams | None = DEFAULT_MOTOR
    ground: Ground = field(default_factory=Ground)
    disturbances: Disturbances = field(default_factory=Disturbances)
    fall_angle: float = 1.0
    solver_iterations: int = 50
    solver_residual_threshold: float = 1e-14
    body: tuple | None = None

    def __post_init__(self):
        if not isinstance(self.params, RobotParams):
            raise TwinError(f"params must be a RobotParams, got {type(self.params).__name__}")
        if self.motor is not None and not isinstance(self.motor, DCMotorParams):
            raise TwinError(f"motor must be DCMotorParams or None (ideal torque source), got {self.motor!r}")
        if not isinstance(self.ground, Ground):
            raise TwinError(f"ground must be a Ground, got {self.ground!r}")
        if not isinstance(self.disturbances, Disturbances):
            raise TwinError(f"disturbances must be a Disturbances, got {self.disturbances!r}")
        for name, lo in (("physics_rate", 10.0), ("control_rate", 1.0)):
            v = getattr(self, name)
            if not (_is_number(v) and lo <= v <= 100_000):
                raise TwinError(f"{name} must be a frequency in [{lo:g}, 100000] Hz, got {v!r}")
        k = steps_per_control(1.0 / self.physics_rate, 1.0 / self.control_rate)
        if k > 1000:
            raise TwinError(f"the control period is {k} physics steps; at most 1000 are allowed "
                            f"(raise control_rate or lower physics_rate)")
        if self.body is not None:
            ok = isinstance(self.body, (tuple, list)) and len(self.body) == 2 and all(
                isinstance(c, (tuple, list)) and len(c) == 3 and all(_is_number(v) and abs(v) <= 10.0 for v in c)
                for c in self.body)
            if not ok or not all(self.body[0][i] < self.body[1][i] for i in range(3)):
                raise TwinError(f"body must be the box's (lowest, highest) corners, 3 numbers each in m within ±10 m, "
                                f"the lowest below the highest, or None, got {self.body!r}")
            object.__setattr__(self, "body", tuple(tuple(float(v) for v in c) for c in self.body))
        if not (_is_number(self.fall_angle) and 0.05 <= self.fall_angle <= 1.5):
            raise TwinError(f"fall_angle must be in [0.05, 1.5] rad, got {self.fall_angle!r}")
        if not (isinstance(self.solver_iterations, int) and not isinstance(self.solver_iterations, bool)
                and 1 <= self.solver_iterations <= 1000):
            raise TwinError(f"solver_iterations must be an integer from 1 to 1000, got {self.solver_iterations!r}")
        if not (_is_number(self.solver_residual_threshold) and 0.0 <= self.solver_residual_threshold <= 1e-3):
            raise TwinError(f"solver_residual_threshold must be a number in [0, 1e-3], got "
                            f"{self.solver_residual_threshold!r}")
        # Bullet applies joint damping explicitly: a lifted wheel (inertia n_wa about its
        # axle) is stable only for D dt / n_wa < 2; keep well inside that
        damping = self.params.d_b + (0.0 if self.motor is None else self.motor.electrical_damping)
        ratio = damping / (self.physics_rate * self.params.n_wa)
        if ratio >= 1.0:
            needed = math.ceil(damping / self.params.n_wa)
            raise TwinError(
                f"the wheel joint damping d_b + k_t²/R = {damping:.4g} N·m·s/rad is too stiff for "
                f"{self.physics_rate:g} Hz physics (damping · dt / n_wa = {ratio:.2f}, must be < 1): "
                f"raise physics_rate to at least {needed} Hz or choose a motor with a flatter speed–torque curve")

    @property
    def steps_per_control(self) -> int:
        return steps_per_control(1.0 / self.physics_rate, 1.0 / self.control_rate)


def _is_number(v) -> bool:
    """A finite real number (not a bool)."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def initial_pose(params: RobotParams, ground: Ground, theta0: float, alpha0: float, x0: float, y0: float):
    """Axle-midpoint position and orientation quaternion with both wheels on the floor.

    The axle midpoint is above (x0, y0) (m), the axle lies in the floor plane with the
    robot heading ``alpha0``, and the body is pitched ``theta0`` from the vertical about
    the axle (rad).
    """
    pos, R = _initial_frame(params, ground, theta0, alpha0, x0, y0)
    return pos, quat_from_matrix(R)


def _initial_frame(params: RobotParams, ground: Ground, theta0: float, alpha0: float, x0: float, y0: float):
    """(axle midpoint (m, world), body rotation R as rows) of :func:`initial_pose`."""
    n = ground.normal()
    a_h = (-math.sin(alpha0), math.cos(alpha0), 0.0)
    k = dot(a_h, n)
    a = unit((a_h[0] - k * n[0], a_h[1] - k * n[1], a_h[2] - k * n[2]))
    up = (0.0, 0.0, 1.0)
    k = dot(up, a)
    z_u = unit((up[0] - k * a[0], up[1] - k * a[1], up[2] - k * a[2]))
    x_u = cross(a, z_u)
    c, s = math.cos(theta0), math.sin(theta0)
    x_b = tuple(c * xu - s * zu for xu, zu in zip(x_u, z_u))
    z_b = tuple(c * zu + s * xu for xu, zu in zip(x_u, z_u))
    R = tuple((x_b[i], a[i], z_b[i]) for i in range(3))
    # the wheels touch the floor r from the axle against the normal
    cx, cy = x0 - params.r * n[0], y0 - params.r * n[1]
    pos = (x0, y0, ground.height(cx, cy) + params.r * n[2])
    return pos, R


def checked_start(theta0, alpha0, position, fall_angle: float) -> tuple[float, float, tuple[float, float]]:
    """A plant's starting pose, checked: (θ0 rad, α0 rad, (x0, y0) m) as floats, or a one-line
    TwinError naming what is wrong (not numbers, not finite, past the fall limit, beyond ±10 km)."""
    try:
        theta0, alpha0 = float(theta0), float(alpha0)
        x0, y0 = (float(v) for v in position)
    except (TypeError, ValueError):
        raise TwinError(f"theta0 and alpha0 must be angles in rad and position 2 coordinates in m, got "
                        f"theta0={theta0!r}, alpha0={alpha0!r}, position={position!r}") from None
    for name, v in (("theta0", theta0), ("alpha0", alpha0)):
        if not math.isfinite(v):
            raise TwinError(f"{name} must be a finite angle in rad, got {v!r}")
    if not abs(theta0) < fall_angle:
        raise TwinError(f"theta0 must be inside the fall limit ±{fall_angle:g} rad, got {theta0!r}")
    if not (abs(x0) <= 1e4 and abs(y0) <= 1e4):
        raise TwinError(f"position must be 2 finite coordinates within ±10 km, got {position!r}")
    return theta0, alpha0, (x0, y0)


START_TOLERANCE = 1e-9  # m: a part this far into the floor at the start is on it (rounding)


def start_clearance(params: RobotParams, ground: Ground, theta0: float, alpha0: float = 0.0, position=(0.0, 0.0),
                    payload: Payload | None = None, body=None) -> dict[str, float]:
    """How far each part of the robot starts above the floor, along its normal, in m.

    ``"wheels"``: the lower wheel's lowest point (0 by construction: they stand on the
    floor); ``"body"``: the body box's lowest corner; ``"payload"`` (with one): the
    payload's centre less half its cube (:data:`~twin.plant.urdf.PAYLOAD_SIZE`). The robot
    stands as :func:`initial_pose` places it. A part starts above the floor if its
    clearance is at least −:data:`START_TOLERANCE`. Nothing here keeps a part from reaching
    the floor later: the body and the wheels collide with it (and a body that touches it
    ends the run), the payload is a point mass."""
    x0, y0 = position
    pos, R = _initial_frame(params, ground, theta0, alpha0, x0, y0)
    n = ground.normal()

    def height(p) -> float:  # the floor plane passes through the origin
        return dot(tuple(pos[i] + R[i][0] * p[0] + R[i][1] * p[1] + R[i][2] * p[2] for i in range(3)), n)

    lo, hi = body_box(params, body)
    out = {"wheels": min(height((0.0, s * params.b, 0.0)) for s in (-1.0, 1.0)) - params.r,
           "body": min(height((x, y, z)) for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2]))}
    if payload is not None:
        out["payload"] = height(payload.position) - 0.5 * PAYLOAD_SIZE
    return out


def start_problem(params: RobotParams, ground: Ground, theta0: float, alpha0: float = 0.0, position=(0.0, 0.0),
                  payload: Payload | None = None, body=None) -> str | None:
    """The first part of :func:`start_clearance` that starts in the floor, as one line, or None."""
    for part, clearance in start_clearance(params, ground, theta0, alpha0, position, payload, body).items():
        if clearance < -START_TOLERANCE:
            what = {"wheels": "the wheels reach", "body": "the body's box reaches",
                    "payload": f"the payload (a {100 * PAYLOAD_SIZE:g} cm cube at {_point(payload.position)} m, body "
                               f"frame) reaches"}[part]
            return (f"{what} {-clearance:.3g} m into the floor at the start (pitch {theta0:g} rad, floor slope "
                    f"{ground.slope:g} rad); every part must start above the floor")
    return None


def _point(p) -> str:
    return "(" + ", ".join(f"{v:g}" for v in p) + ")"


def touch_angle(params: RobotParams, body=None) -> float:
    """Smallest pitch (rad) at which the body box (``body``: the robot's own corners, see
    :class:`TwinConfig`; None: Table III's rule) can reach a level floor."""
    if body is None:  # as it always was computed
        h = body_height(params)
        corners = [(sx * 0.5 * BODY_DEPTH, params.l + sz * 0.5 * h) for sx in (-1, 1) for sz in (-1, 1)]
    else:
        lo, hi = body_box(params, body)
        corners = [(x, z) for x in (lo[0], hi[0]) for z in (lo[2], hi[2])]
    for i in range(1, 158):
        th = 0.01 * i
        if any(params.r + (-x * math.sin(th) + z * math.cos(th)) <= 0.0 for x, z in corners):
            return th
    return math.pi / 2
