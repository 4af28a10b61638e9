"""The robot's linearised model, the one a controller is designed on (``twin linearize``).

State, input and output (SI units; the twin's conventions of :mod:`twin.plant.analytic`)::

    x = [θ (rad), θ̇ (rad/s), ψ (rad), ψ̇ (rad/s), α (rad), α̇ (rad/s)]
    u = [ul, ur] (N·m, wheel torques)      or, with input="voltage",  u = [vl, vr] (V)
    y = x                                  (C = I, D = 0)

θ is the body pitch (0 upright, positive leaning towards +ψ travel), ψ = (ψl + ψr)/2 the mean
wheel angle, α the heading (positive turning left). x and u are deviations from the
operating point: ẋ = A x + B u (or x[k+1] = A x[k] + B u[k] with a zero-order hold of ``dt``).

The equations linearised are the twin's own: :func:`twin.plant.analytic.rhs` (paper equation (1),
what the analytic plant integrates), differentiated by central differences with one Richardson
step (error O(h⁴), h ≈ 1.2e-4 of the variable's size, a power of two so that x ± h is exact:
the kinematic rows come out exactly 0 and 1). At upright rest the balance block agrees with
:func:`twin.plant.ts_model.local_model` (β = 1) and the yaw block with
:func:`twin.controllers.lqr.yaw_model` to rounding error (about 1e-16 relative; tests/test_linearize.py
holds it to 1e-9).

Voltage input: the twin's DC motor without inductance (:mod:`twin.actuators.dc_motor`), per
wheel τ = k_t (V − k_e ω)/R with k_e = k_t and ω the wheel's speed relative to the body
(ψ̇ ∓ (b/r) α̇ − θ̇, left/right). So B scales by k_t/R and the back-EMF adds the electrical damping
c = k_t k_e/R to the drive's d_b in A. That is the model of a driver that sets the voltage
(duty × supply); a firmware that compensates the back-EMF (``back_emf_compensation``) delivers
torque commands, and the torque model is its model.

Operating points: steady motion only
------------------------------------
A linear model is honest about a point the nonlinear model can stay at. With θ̇ = 0 and
constant ψ̇ and α̇, equation (1) has θ̈ = ψ̈ = α̈ = 0 for constant torques if and only if the
sum of its first two lines vanishes::

    sin θ (g_b + (m12 + n_bla cos θ) α̇²) = 2 d_w ψ̇

i.e. the body leans into the rolling resistance d_w (at the paper's d_w = 0.01 N·m·s/rad,
0.32 rad at 1 m/s). So speed and tilt are not independent: the operating point is given by the
speed (m/s) and the yaw rate (rad/s) and the tilt follows (the smallest one, continuous with
upright at rest); or by the tilt, and the speed follows. A tilt without the speed that holds it
needs a constant acceleration, which is no steady state, and is refused. ψ and α are 0 at the
operating point: they grow at ψ̇ and α̇ along it, and nothing in equation (1) depends on them.
A point the drive cannot hold (a wheel's voltage above the supply or its current above the
limit) or past the robot's fall angle is refused too, naming what is allowed.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass

import control
import numpy as np
from scipy.optimize import brentq

from twin.actuators.dc_motor import DEFAULT_MOTOR, DCMotorParams
from twin.errors import TwinError, shown
from twin.params import RobotParams
from twin.plant.analytic import NO_TAU, rhs

STATES = (  # name, unit, what it is
    ("theta", "rad", "body pitch, 0 upright, positive leaning towards +psi travel"),
    ("theta_dot", "rad/s", "body pitch rate"),
    ("psi", "rad", "mean wheel angle (psi_l + psi_r)/2; distance p = r psi"),
    ("psi_dot", "rad/s", "mean wheel rate; speed v = r psi_dot"),
    ("alpha", "rad", "heading, positive turning left"),
    ("alpha_dot", "rad/s", "yaw rate"),
)
INPUTS = {  # input kind -> (name, unit, what it is) per wheel
    "torque": (("ul", "N·m", "left wheel torque (motor between body and wheel)"),
               ("ur", "N·m", "right wheel torque (motor between body and wheel)")),
    "voltage": (("vl", "V", "left motor voltage (duty × supply voltage)"),
                ("vr", "V", "right motor voltage (duty × supply voltage)")),
}
AT_KEYS = {"theta": "rad", "speed": "m/s", "yaw_rate": "rad/s"}  # what an operating point is given by
AT_EXAMPLE = "speed=0.5,yaw_rate=1"
MAX_DT = 1.0  # s: the longest sampling period of the discrete model (a control period, not a simulation step)
DEFAULT_FALL_ANGLE = 1.0  # rad: a bare RobotParams' fall angle (a robot file's default limits.fall_angle)
THETA_MATCH = 1e-6  # rad: a tilt given with the speed must be the steady one to within this
_STEP_BITS = 13  # difference step h = 2**-13 ≈ 1.2e-4 of the variable's binade
_SCAN = 2000  # grid points over [0, fall angle] where the steady tilt's smallest root is looked for


@dataclass(frozen=True)
class OperatingPoint:
    """A steady motion of equation (1): upright-or-leaning at constant speed and yaw rate.

    ``theta`` (rad), ``speed`` (m/s, r ψ̇), ``yaw_rate`` (rad/s); ``state`` the six states there
    (ψ and α taken as 0); ``torque`` (ul, ur) in N·m and ``voltage`` (vl, vr) in V that hold it,
    ``current`` (il, ir) in A they draw (the twin's motor, no inductance)."""

    theta: float
    speed: float
    yaw_rate: float
    state: tuple
    torque: tuple
    voltage: tuple
    current: tuple

    def as_dict(self) -> dict:
        return {"theta": self.theta, "speed": self.speed, "yaw_rate": self.yaw_rate, "state": list(self.state),
                "torque": list(self.torque), "voltage": list(self.voltage), "current": list(self.current)}


def parse_at(text) -> dict[str, float]:
    """``"speed=0.5,yaw_rate=1"`` → {"speed": 0.5, "yaw_rate": 1.0}: the keys of :data:`AT_KEYS`,
    each at most once, finite numbers in their units; None or "" → {} (upright at rest)."""
    if text is None or not str(text).strip():
        return {}
    allowed = ", ".join(f"{k} ({u})" for k, u in AT_KEYS.items())
    out = {}
    for item in str(text).split(","):
        key, eq, value = item.partition("=")
        key = key.strip()
        if not eq or not key:
            raise TwinError(f"--at must be KEY=VALUE pairs separated by commas with keys {allowed} "
                            f"(e.g. --at {AT_EXAMPLE}), got {shown(text)}")
        if key not in AT_KEYS:
            raise TwinError(f"--at: unknown key {shown(key)}; allowed: {allowed}")
        if key in out:
            raise TwinError(f"--at names {key} twice; allowed: each key once")
        try:
            v = float(value)
        except ValueError:
            v = math.nan
        if not math.isfinite(v):
            raise TwinError(f"--at {key}: must be a finite number in {AT_KEYS[key]}, got {shown(value.strip())}")
        out[key] = v
    return out


def _robot_parts(robot, motor: DCMotorParams | None):
    """(name, source, RobotParams, DCMotorParams, fall angle rad) of a robot: a
    :class:`twin.robots.Robot` (anything with ``params()``, ``motor()`` and ``fall_angle``: this
    module sits below the robots and loads none; :func:`twin.robots.load_robot` does) or a bare
    :class:`~twin.params.RobotParams` (the paper's motor unless ``motor`` is given)."""
    if isinstance(robot, RobotParams):
        return "params", "RobotParams", robot, motor or DEFAULT_MOTOR, DEFAULT_FALL_ANGLE
    if all(hasattr(robot, a) for a in ("params", "motor", "fall_angle")):
        return (getattr(robot, "name", "robot"), getattr(robot, "source", ""), robot.params(),
                motor or robot.motor(), float(robot.fall_angle))
    raise TwinError(f"linearize needs a robot (twin.robots.load_robot(NAME_OR_FILE)) or a RobotParams, "
                    f"got {shown(robot)}")


# ---- the operating point ---------------------------------------------------------------------


def _lean(theta: float, omega: float, p: RobotParams) -> float:
    """sin θ (g_b + (m12 + n_bla cos θ) α̇²), N·m: what gravity and the turn's centrifugal terms give
    along ψ at tilt θ; steady motion balances it against the rolling resistance 2 d_w ψ̇."""
    return math.sin(theta) * (p.g_b + (p.m12 + p.n_bla * math.cos(theta)) * (omega * omega))


def _steady_tilt(psi_d: float, omega: float, p: RobotParams, fall: float) -> float | None:
    """The smallest |θ| < ``fall`` with :func:`_lean` = 2 d_w ψ̇ (signed like ψ̇), None if none."""
    need = 2.0 * p.d_w * abs(psi_d)
    if need == 0.0:
        return 0.0
    grid = np.linspace(0.0, fall, _SCAN + 1)[:-1]  # the fall angle itself is lost
    q = [_lean(s, omega, p) - need for s in grid.tolist()]
    for i in range(1, len(q)):
        if q[i] >= 0.0:
            s = brentq(lambda t: _lean(t, omega, p) - need, grid[i - 1], grid[i], xtol=1e-15)
            return math.copysign(s, psi_d)
    return None


def _max_lean(omega: float, p: RobotParams, fall: float) -> float:
    """The largest |:func:`_lean`| on the smallest-root branch below the fall angle, N·m."""
    grid = np.linspace(0.0, fall, _SCAN + 1)[:-1].tolist()
    return max(_lean(s, omega, p) for s in grid)


def _trim(theta: float, psi_d: float, omega: float, p: RobotParams, m: DCMotorParams) -> OperatingPoint:
    """The torques, voltages and currents that hold the steady motion (θ, ψ̇, α̇): equation (1)'s
    first line gives ul + ur, its third ur − ul (θ̇ = ψ̈ = θ̈ = α̈ = 0)."""
    s = math.sin(theta)
    total = 2.0 * (p.d_w + p.d_b) * psi_d - p.m12 * (omega * omega) * s
    diff = (p.r / p.b) * (p.m12 * omega * psi_d * s + p.yaw_damping * omega)
    torque = (0.5 * (total - diff), 0.5 * (total + diff))
    half = p.b / p.r * omega
    speeds = (psi_d - half, psi_d + half)  # each wheel relative to the body (θ̇ = 0)
    current = tuple(t / m.k_t for t in torque)
    voltage = tuple(m.resistance * i + m.k_t * w for i, w in zip(current, speeds))
    state = (theta, 0.0, 0.0, psi_d, 0.0, omega)
    return OperatingPoint(theta, p.r * psi_d, omega, state, torque, voltage, current)


def _drive_problem(op: OperatingPoint, m: DCMotorParams) -> str | None:
    """What the drive cannot give at ``op`` (one clause naming the motor that needs most), or None."""
    for what, values, limit, unit, bound in (("voltage", op.voltage, m.supply_voltage, "V", "supply"),
                                             ("current", op.current, m.max_current, "A", "current limit")):
        need = [abs(v) for v in values]
        if max(need) > limit:
            who = "both motors need" if need[0] == need[1] else \
                f"the {'left' if need[0] > need[1] else 'right'} motor needs"
            return f"{who} {max(need):.4g} {unit}, above the {limit:.4g} {unit} {bound}"
    return None


def _largest(ok, hi: float) -> float:
    """The largest x in [0, hi] with ok(x), by bisection (ok(0) true, ok monotone)."""
    lo = 0.0
    if ok(hi):
        return hi
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
    return lo


def _speed_point(v: float, omega: float, p: RobotParams, m: DCMotorParams, fall: float):
    """The operating point at speed ``v`` (m/s) and yaw rate ``omega`` (rad/s), or None."""
    theta = _steady_tilt(v / p.r, omega, p, fall)
    return None if theta is None else _trim(theta, v / p.r, omega, p, m)


def _allowed_speed(omega: float, p: RobotParams, m: DCMotorParams, fall: float) -> str:
    """"|speed| ≤ X m/s at yaw_rate=W rad/s" (or the yaw rates allowed at rest): what --at may ask."""
    rest = _trim(0.0, 0.0, omega, p, m)
    if _drive_problem(rest, m) is not None:
        w = _largest(lambda w: _drive_problem(_trim(0.0, 0.0, w, p, m), m) is None, abs(omega))
        return f"|yaw_rate| ≤ {w:.4g} rad/s (at rest)"
    # the tilt's limit: the most lean the fall angle allows, against 2 d_w ψ̇
    v_fall = math.inf if p.d_w == 0.0 else p.r * _max_lean(omega, p, fall) / (2.0 * p.d_w)
    hi = min(v_fall, 1e3)  # m/s: a bracket for the drive's limit (no robot here goes near)

    def ok(v):
        op = _speed_point(v, omega, p, m, fall)
        return op is not None and _drive_problem(op, m) is None

    v = _largest(ok, hi * (1.0 - 1e-12))
    return f"|speed| ≤ {v:.4g} m/s at yaw_rate={omega:g} rad/s"


def operating_point(robot, at=None, motor: DCMotorParams | None = None) -> OperatingPoint:
    """The steady motion ``at`` names (see the module docstring), checked.

    Parameters
    ----------
    robot : twin.robots.Robot or RobotParams
        The robot (a Robot from :func:`twin.robots.load_robot`), or bare parameters (then the
        paper's motor and a fall angle of :data:`DEFAULT_FALL_ANGLE` rad).
    at : dict or str, optional
        ``{"speed": m/s, "yaw_rate": rad/s, "theta": rad}`` (any subset; a str is read by
        :func:`parse_at`). Default: upright at rest. Give the speed (the tilt follows) or the
        tilt (the speed follows); a tilt given with the speed must be the steady one to within
        :data:`THETA_MATCH` rad.
    motor : DCMotorParams, optional
        Replaces the robot's motor.

    Raises TwinError naming what is allowed for a point that is not a steady motion, past the fall
    angle or beyond the drive.
    """
    _, _, p, m, fall = _robot_parts(robot, motor)
    at = parse_at(at) if at is None or isinstance(at, str) else dict(at)
    unknown = [k for k in at if k not in AT_KEYS]
    if unknown:
        raise TwinError(f"operating point: unknown key {shown(unknown[0])}; allowed: "
                        f"{', '.join(f'{k} ({u})' for k, u in AT_KEYS.items())}")
    for k, v in at.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise TwinError(f"operating point {k}: must be a finite number in {AT_KEYS[k]}, got {shown(v)}")
    omega = float(at.get("yaw_rate", 0.0))
    said = ", ".join(f"{k}={v:g} {AT_KEYS[k]}" for k, v in at.items())
    if "theta" in at and not abs(at["theta"]) < fall:
        raise TwinError(f"operating point {said}: theta is past the robot's fall angle; allowed: |theta| < "
                        f"{fall:g} rad")
    if "speed" in at:
        psi_d = at["speed"] / p.r
        theta = _steady_tilt(psi_d, omega, p, fall)
        if theta is None:
            raise TwinError(f"operating point {said}: no steady motion: the lean that balances the rolling "
                            f"resistance passes the fall angle {fall:g} rad; allowed: "
                            f"{_allowed_speed(omega, p, m, fall)}")
        if "theta" in at:
            theta = _refine(at["theta"], psi_d, omega, p)
            if theta is None:
                steady = _steady_tilt(psi_d, omega, p, fall)
                raise TwinError(f"operating point {said}: the tilt is not steady at this speed (it would "
                                f"accelerate); allowed: theta={steady:.10g} rad at this speed and yaw rate, or "
                                f"theta alone (the speed follows), or speed alone (the tilt follows)")
    elif "theta" in at:
        theta = float(at["theta"])
        lean = _lean(theta, omega, p)
        if p.d_w == 0.0:
            if lean != 0.0:
                raise TwinError(f"operating point {said}: a constant tilt is no steady state of this robot "
                                f"(no rolling resistance d_w to lean into: it would accelerate); allowed: theta=0 "
                                f"(steady at any speed)")
            psi_d = 0.0
        else:
            psi_d = lean / (2.0 * p.d_w)
    else:
        theta, psi_d = 0.0, 0.0
    op = _trim(theta, psi_d, omega, p, m)
    problem = _drive_problem(op, m)
    if problem is not None:
        raise TwinError(f"operating point {said}: {problem}; allowed: {_allowed_speed(omega, p, m, fall)}")
    _check_steady(op, p)
    return op


def _refine(theta: float, psi_d: float, omega: float, p: RobotParams) -> float | None:
    """The steady tilt within :data:`THETA_MATCH` of ``theta`` at (ψ̇, α̇), by Newton, or None."""
    need = 2.0 * p.d_w * psi_d
    t = float(theta)
    for _ in range(50):
        slope = math.cos(t) * (p.g_b + p.m12 * omega * omega) + p.n_bla * omega * omega * math.cos(2.0 * t)
        if slope == 0.0:
            return None
        step = (_lean(t, omega, p) - need) / slope
        t -= step
        if abs(t - theta) > THETA_MATCH:
            return None
        if abs(step) <= 1e-16 * max(1.0, abs(t)):
            break
    return t if abs(_lean(t, omega, p) - need) <= 1e-12 * (p.g_b + abs(need)) else None


def _check_steady(op: OperatingPoint, p: RobotParams) -> None:
    """The twin's own equations at the point: the accelerations vanish (a bug otherwise)."""
    x = op.state
    f = rhs(x, op.torque[0], op.torque[1], p, NO_TAU)
    f0 = rhs(x, 0.0, 0.0, p, NO_TAU)
    scale = max(1.0, *(abs(f0[i]) for i in (1, 3, 5)), *(abs(f[i] - f0[i]) for i in (1, 3, 5)))
    if max(abs(f[i]) for i in (1, 3, 5)) > 1e-9 * scale:
        raise RuntimeError(f"operating point {op} is not steady under twin.plant.analytic.rhs: accelerations "
                           f"{f[1]!r}, {f[3]!r}, {f[5]!r}")


# ---- the Jacobians ---------------------------------------------------------------------------


def _step(v: float) -> float:
    """A power of two about 1.2e-4 of max(1, |v|): v ± h and the difference 2h are exact."""
    _, e = math.frexp(max(1.0, abs(v)))
    return math.ldexp(1.0, e - 1 - _STEP_BITS)


def _jacobian(f, z0: np.ndarray) -> np.ndarray:
    """∂f/∂z at z0 by central differences with one Richardson step: (4 D(h/2) − D(h)) / 3."""
    cols = []
    for j in range(z0.size):
        h = _step(float(z0[j]))

        def d(step):
            zp, zm = z0.copy(), z0.copy()
            zp[j] += step
            zm[j] -= step
            return (f(zp) - f(zm)) / (2.0 * step)

        cols.append((4.0 * d(0.5 * h) - d(h)) / 3.0)
    return np.column_stack(cols)


def _field(p: RobotParams, m: DCMotorParams, kind: str):
    """z = [x (6), u (2)] → ẋ (6): the twin's equation (1), with wheel torques or motor voltages."""
    half = p.b / p.r
    kt, R = m.k_t, m.resistance

    def f(z):
        x = z[:6]
        if kind == "torque":
            ul, ur = z[6], z[7]
        else:  # the twin's motor at the wheel: τ = k_t (V − k_e ω)/R, ω relative to the body
            wl = x[3] - half * x[5] - x[1]
            wr = x[3] + half * x[5] - x[1]
            ul, ur = kt * (z[6] - kt * wl) / R, kt * (z[7] - kt * wr) / R
        return np.array(rhs(x, ul, ur, p, NO_TAU)[:6])

    return f


def linearize(robot, at=None, input: str = "torque", dt: float | None = None,
              motor: DCMotorParams | None = None) -> control.StateSpace:
    """The robot's model linearised at a steady motion, as a python-control StateSpace.

    Parameters
    ----------
    robot : twin.robots.Robot or RobotParams
        ``load_robot("paper")``, a robot file's Robot, or bare parameters (the paper's motor).
    at : dict or str, optional
        The operating point (:func:`operating_point`): ``{"speed": m/s, "yaw_rate": rad/s}`` or
        ``{"theta": rad, ...}``, or ``"speed=0.5,yaw_rate=1"``. Default: upright at rest.
    input : {"torque", "voltage"}
        Wheel torques [ul, ur] in N·m, or motor voltages [vl, vr] in V (the twin's DC motor folded in).
    dt : float, optional
        Sampling period in s, in (0, :data:`MAX_DT`]: the zero-order-hold discrete model
        (:func:`control.c2d`). Default: continuous time.
    motor : DCMotorParams, optional
        Replaces the robot's motor.

    Returns
    -------
    control.StateSpace
        States, inputs and outputs named (:data:`STATES`, :data:`INPUTS`; outputs = states, C = I,
        D = 0), in deviations from the operating point. Added attributes: ``units`` (signal name →
        SI unit), ``operating_point`` (:class:`OperatingPoint`) and ``info`` (robot, input kind,
        motor constants, method), which :func:`model_dict` writes out.
    """
    if input not in INPUTS:
        raise TwinError(f"input must be one of {', '.join(INPUTS)}, got {shown(input)}")
    if dt is not None:
        if isinstance(dt, bool) or not isinstance(dt, (int, float)) or not 0.0 < dt <= MAX_DT:
            raise TwinError(f"dt must be a sampling period in (0, {MAX_DT:g}] s, got {shown(dt)}")
        dt = float(dt)
    name, source, p, m, fall = _robot_parts(robot, motor)
    op = operating_point(robot, at, motor)
    u0 = op.torque if input == "torque" else op.voltage
    z0 = np.array([*op.state, *u0], dtype=float)
    J = _jacobian(_field(p, m, input), z0)
    A, B = J[:, :6], J[:, 6:]
    states = [s[0] for s in STATES]
    inputs = [i[0] for i in INPUTS[input]]
    sys_name = f"{name} linearised"
    sys = control.ss(A, B, np.eye(6), np.zeros((6, 2)), states=states, inputs=inputs, outputs=states,
                     name=sys_name)
    if dt is not None:
        sys = control.c2d(sys, dt, method="zoh", name=sys_name)
    sys.units = {**{s[0]: s[1] for s in STATES}, **{i[0]: i[1] for i in INPUTS[input]}}
    sys.operating_point = op
    sys.info = {
        "robot": name, "source": source, "input": input, "dt": dt,
        "motor": {"k_t": m.k_t, "resistance": m.resistance, "electrical_damping": m.electrical_damping,
                  "supply_voltage": m.supply_voltage, "max_current": m.max_current, "inductance": m.inductance,
                  "back_emf_compensation": m.back_emf_compensation},
        "fall_angle": fall,
    }
    return sys


# ---- the model as JSON -----------------------------------------------------------------------


def model_dict(sys: control.StateSpace) -> dict:
    """A model from :func:`linearize` as a JSON-able dict: names, units, the operating point,
    A, B, C, D (rows of floats), the eigenvalues of A as [re, im] pairs (1/s; for a discrete
    model, of the transition matrix), sorted."""
    if not all(hasattr(sys, a) for a in ("units", "operating_point", "info")):
        raise TwinError("model_dict needs a model from twin.plant.linearize.linearize (its units, operating point "
                        "and info), got another system")
    info = sys.info
    signal = {name: meaning for name, _, meaning in (*STATES, *INPUTS[info["input"]])}

    def names(labels):
        return [{"name": n, "unit": sys.units[n], "meaning": signal[n]} for n in labels]

    def rows(M):
        return [[float(v) + 0.0 for v in row] for row in np.asarray(M)]  # + 0.0: no "-0.0" in the text

    eig = sorted((float(e.real) + 0.0, float(e.imag) + 0.0) for e in np.linalg.eigvals(np.asarray(sys.A)))
    discrete = info["dt"] is not None
    notes = [
        "x and u are deviations from operating_point (state: psi and alpha taken as 0 there; they grow at "
        "psi_dot and alpha_dot along it)",
        "y = x: C is the identity and D is zero",
        ("x[k+1] = A x[k] + B u[k], u held over each dt (zero-order hold)" if discrete else "dx/dt = A x + B u"),
        "linearised from twin.plant.analytic.rhs (paper equation (1)) by central differences with a Richardson step",
    ]
    if info["input"] == "voltage":
        motor = info["motor"]
        notes.append("voltage input: the twin's DC motor at the wheel, tau = k_t (V - k_e omega)/R with k_e = k_t and "
                     "omega the wheel's speed relative to the body; inductance left out"
                     + (f" (the robot's L/R = {motor['inductance'] / motor['resistance']:.3g} s)"
                        if motor["inductance"] > 0 else ""))
    return {
        "robot": info["robot"],
        "source": info["source"],
        "time": "discrete" if discrete else "continuous",
        "dt": info["dt"],
        "input": info["input"],
        "operating_point": sys.operating_point.as_dict(),
        "states": names(sys.state_labels),
        "inputs": names(sys.input_labels),
        "outputs": names(sys.output_labels),
        "A": rows(sys.A), "B": rows(sys.B), "C": rows(sys.C), "D": rows(sys.D),
        "eigenvalues": [list(e) for e in eig],
        "motor": info["motor"],
        "fall_angle": info["fall_angle"],
        "notes": notes,
    }


def to_json(d: dict) -> str:
    """The dict of :func:`model_dict` as JSON text: indented, each list of numbers (a matrix row, a
    state) and each signal's entry on one line, floats as Python's shortest round-trip repr, ending in
    a newline: the same model gives the same bytes."""
    def flat(v):
        return json.dumps(v, ensure_ascii=False, allow_nan=False)

    def text(v, indent, in_list=False):
        pad = "  " * (indent + 1)
        end = "\n" + "  " * indent
        if isinstance(v, dict):
            if in_list and all(not isinstance(x, (dict, list, tuple)) for x in v.values()):
                return flat(v)
            return "{\n" + ",\n".join(f"{pad}{flat(k)}: {text(x, indent + 1)}" for k, x in v.items()) + end + "}"
        if isinstance(v, (list, tuple)):
            if all(isinstance(x, (int, float)) or x is None for x in v):
                return flat(list(v))
            return "[\n" + ",\n".join(pad + text(x, indent + 1, True) for x in v) + end + "]"
        return flat(v)

    return text(d, 0) + "\n"


def model_json(robot, at=None, input: str = "torque", dt: float | None = None) -> str:
    """What ``twin linearize`` prints: :func:`to_json` of :func:`model_dict` of :func:`linearize`
    (``at`` a dict or ``--at``'s text)."""
    return to_json(model_dict(linearize(robot, at=at, input=input, dt=dt)))


__all__ = ["AT_KEYS", "INPUTS", "MAX_DT", "OperatingPoint", "STATES", "linearize", "model_dict", "model_json",
           "operating_point", "parse_at", "to_json"]
