"""The PyBullet digital twin: the robot of :mod:`twin.plant.urdf` on a floor, driven by
DC motors, with disturbances, read out as ground truth.

Physics and time
    One ``BulletClient`` in DIRECT mode per twin (no global connection: two twins in
    one process never interfere). Bullet's Featherstone multibody at ``physics_rate``
    (default 1 kHz); commands are taken every control period (default 200 Hz), which
    must be a whole number of physics steps. Bullet's default velocity motors are
    switched off; the wheel torques go in with TORQUE_CONTROL at every physics step.
    Bullet's default link damping (0.04) is switched off: the only dissipation is the
    paper's.

Equation (1)'s resistances
    d_b (body–wheel) acts on the joint rate ψ̇_i − θ̇ and is Bullet's joint damping, so
    it is applied inside the engine at every physics step. d_w (wheel–ground) acts on
    the absolute wheel rate ψ̇_i, which joint damping cannot express; it enters as a
    joint torque −d_w ψ̇_i plus the torque −d_w (ψ̇_l + ψ̇_r) on the body about the axle,
    which together do exactly the virtual work −d_w ψ̇_i δψ_i of equation (1) and nothing
    on θ. Both are evaluated at the start of each control period and held (a 5 ms hold
    on a term whose time constant is m11 / 2d_w ≈ 0.25 s).

Actuators
    :class:`~twin.actuators.DCMotorParams` per wheel (``motor=None``: an ideal torque
    source). The PWM duty is set at the control rate; the back-EMF slope of the
    speed–torque curve is joint damping, so it acts at the physics rate too.

Ground truth (:class:`GroundTruth`, at the end of each control period)
    The body's orientation is decomposed as R = Rz(α) Rx(φ) Ry(θ): heading α (unwrapped,
    positive turning left), roll φ about the heading, pitch θ about the axle from the
    vertical (positive leaning forward). θ is then the rotation about the wheels' joint
    axis even when the body rolls (across a slope), so ψ_i = q_i + θ are the wheel angles
    from the vertical (q_i the joint angles); distance p = r ψ as in the paper; (x, y) the
    axle midpoint in the world. Rates are the time derivatives of these angles.

Logged per control period (:attr:`BulletTwin.actuation`, :attr:`BulletTwin.push_force`)
    Duties and saturation flags at the PWM update; delivered torques and push forces as
    the period's means. :attr:`BulletTwin.kinematics` holds the body's raw PyBullet pose
    and velocity at the end of the period, for the IMU (:mod:`twin.sensors.imu`).

Termination
    The run ends with status ``"fell"`` when the body's tilt from the vertical (pitch and
    roll together: cos tilt = cos θ cos φ) exceeds ``fall_angle`` (default 1.0 rad; the
    nominal body box touches a level floor at 0.97 rad of pitch), or the body touches the
    floor; and ``"diverged"`` if the physics returns a non-finite state. Neither raises:
    :attr:`BulletTwin.status` and :attr:`BulletTwin.end_reason` say what happened; calling
    :meth:`BulletTwin.step` afterwards is an error.

Limits
    Bullet applies joint damping explicitly, so d_b plus the motor's back-EMF slope must
    satisfy damping · dt / n_wa < 1 (a clear error otherwise, naming the physics rate
    that would do). Bullet's default cap of 100 rad/s on joint rates is lifted to
    :data:`MAX_JOINT_RATE`.
"""
from __future__ import annotations

import contextlib
import math
import os
import sys
import tempfile
from math import asin, atan2, cos, isfinite, remainder, sin

from twin.actuators.dc_motor import MotorDriver
from twin.errors import TwinError
from twin.interrupts import deferred_signals
# the types and start checks every plant shares, importable from here as before
from twin.plant.base import (ACTUATION_UNITS, START_TOLERANCE, TRUTH_UNITS, Actuation, GroundTruth,  # noqa: F401
                             TwinConfig, checked_start, initial_pose, start_clearance, start_problem, touch_angle)
from twin.plant.urdf import robot_urdf

WHEEL_JOINTS = (0, 1)  # left, right: the order of the joints in the URDF
MAX_JOINT_RATE = 1000.0  # rad/s, Bullet's cap on the wheel joint rates (its default is 100)
_ZERO2 = (0.0, 0.0)
_ZERO3 = (0.0, 0.0, 0.0)
_TWO_PI = 2.0 * math.pi
_new = tuple.__new__
_TORQUE_CONTROL = 1  # pybullet.TORQUE_CONTROL, checked at connection
_WORLD_FRAME = 2  # pybullet.WORLD_FRAME, checked at connection

try:  # the optional compiled hot path (setup.py); TWIN_PURE_PYTHON=1 turns it off
    from twin.plant import _fastpath
except ImportError:  # pragma: no cover - no C compiler at install time
    _fastpath = None
if os.environ.get("TWIN_PURE_PYTHON", "") not in ("", "0"):
    _fastpath = None


def compiled_kernel_loaded() -> bool:
    """True if the twin's own per-step arithmetic runs in its compiled fast path here."""
    return _fastpath is not None


@contextlib.contextmanager
def quiet_native_output():
    """Silence what PyBullet's C code prints (its build time on import, ``argv[0]=`` on
    connect) by pointing file descriptors 1 and 2 at /dev/null for the duration."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    saved = []
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
    except OSError:
        yield
        return
    try:
        for fd in (1, 2):
            try:
                saved.append((fd, os.dup(fd)))
                os.dup2(devnull, fd)
            except OSError:
                pass
        yield
    finally:
        for fd, copy in saved:
            os.dup2(copy, fd)
            os.close(copy)
        os.close(devnull)


def _connect():
    """A new DIRECT physics server of its own, and the pybullet module.

    SIGINT and SIGTERM are held meanwhile (:func:`twin.interrupts.deferred_signals`, delivered
    as it returns): an interrupt raised between ``pybullet.connect`` and BulletClient's storing its
    id left a client without one, whose ``__del__`` then printed an AttributeError traceback after
    the command's one line (and the server it had connected was never disconnected)."""
    with deferred_signals(), quiet_native_output():
        import pybullet
        from pybullet_utils.bullet_client import BulletClient

        return BulletClient(connection_mode=pybullet.DIRECT), pybullet


# pybullet_utils' BulletClient keeps its server id in ``_client`` and offers no public way to
# read it or to say it is closed (its __del__ disconnects again unless it is −1): the two
# functions below are the only places that touch it.
def client_id(client) -> int:
    """The physics server id of a ``BulletClient`` (−1 once disconnected)."""
    return client._client


def disconnect(client) -> None:
    """Disconnect a ``BulletClient`` once (idempotent)."""
    if client._client >= 0:
        client.disconnect()
        client._client = -1


def truth_from_states(cls, pose, vel, joints, alpha_prev, com_local, r: float, t: float):
    """Ground truth from PyBullet's base pose, base velocity and wheel joint states.

    Returns ``(cls(...), axle_dir)``, ``axle_dir`` the world direction of the body's y
    axis. ``alpha_prev`` (rad or None) unwraps the heading. ``twin.plant._fastpath.truth``
    is the same arithmetic compiled; the two agree bit for bit.
    """
    (cx, cy, _), (x, y, z, qw) = pose
    w0, w1, w2 = vel[1]
    (ql, ql_d, *_), (qr, qr_d, *_) = joints
    # R = Rz(α) Rx(φ) Ry(θ): heading, roll about the heading, pitch about the axle (the
    # wheels' joint axis), so that ψ_i = q_i + θ also when the body rolls
    r01 = 2 * (x * y - z * qw)
    r11 = 1 - 2 * (x * x + z * z)
    r20 = 2 * (x * z - y * qw)
    r21 = 2 * (y * z + x * qw)
    r22 = 1 - 2 * (x * x + y * y)
    theta = atan2(-r20, r22)
    roll = asin(1.0 if r21 > 1.0 else (-1.0 if r21 < -1.0 else r21))
    yaw = atan2(-r01, r11)
    alpha = yaw if alpha_prev is None else alpha_prev + remainder(yaw - alpha_prev, _TWO_PI)
    ca, sa = cos(alpha), sin(alpha)
    # ω = α̇ ẑ + φ̇ x̂' + θ̇ ŷ'' with x̂' = (cos α, sin α, 0), ŷ'' the body's y axis
    cr = cos(roll)
    theta_dot = (-sa * w0 + ca * w1) / cr if cr > 1e-9 else 0.0
    alpha_dot = w2 - theta_dot * r21
    psi_l, psi_r = ql + theta, qr + theta
    psi_l_dot, psi_r_dot = ql_d + theta_dot, qr_d + theta_dot
    psi = 0.5 * (psi_l + psi_r)
    r00 = 1 - 2 * (y * y + z * z)
    r02 = 2 * (x * z + y * qw)
    r10 = 2 * (x * y + z * qw)
    r12 = 2 * (y * z - x * qw)
    c0, c1, c2 = com_local
    # axle midpoint = centre of mass − R · (centre of mass in the body frame)
    return _new(cls, (t, theta, theta_dot, psi_l, psi_r, psi, 0.5 * (psi_l_dot + psi_r_dot), alpha, alpha_dot,
                      r * psi, cx - (r00 * c0 + r01 * c1 + r02 * c2), cy - (r10 * c0 + r11 * c1 + r12 * c2),
                      roll, psi_l_dot, psi_r_dot)), (r01, r11, r21)


class BulletTwin:
    """One simulated robot in its own PyBullet world (a :class:`twin.protocols.Plant`).

    Parameters
    ----------
    config : TwinConfig
    theta0 : float
        Initial body pitch in rad (wheel angles ψ_i start at 0, all rates at 0).
    alpha0 : float
        Initial heading in rad.
    position : (2,) m
        Initial axle midpoint (x, y); the wheels stand on the floor below it.

    Use as a context manager, or call :meth:`close`, to free the physics server.
    """

    trusted = True  # its truth is finite and well formed by construction: the loop need not check it
    applies_motor = True  # it drives the wheels through config.motor (the controllers may model it)

    def __init__(self, config: TwinConfig | None = None, theta0: float = 0.0, alpha0: float = 0.0,
                 position=(0.0, 0.0)):
        import pybullet_data

        self.config = config = config if config is not None else TwinConfig()
        if not isinstance(config, TwinConfig):
            raise TwinError(f"config must be a TwinConfig, got {type(config).__name__}")
        theta0, alpha0, (x0, y0) = checked_start(theta0, alpha0, position, config.fall_angle)
        self._start = (theta0, alpha0, (x0, y0))
        # a part inside the floor would be thrown out of it by the solver (the body), or carried
        # through it (the payload, a point mass): no robot can start so
        problem = start_problem(config.params, config.ground, theta0, alpha0, (x0, y0), config.disturbances.payload,
                                config.body)
        if problem:
            raise TwinError(problem)
        p = config.params
        self.params = p
        self.k = config.steps_per_control
        self.physics_dt = 1.0 / config.physics_rate
        self.control_dt = self.k * self.physics_dt
        self.control_rate = config.control_rate  # Hz (twin.protocols.Plant)
        self.gravity = p.g  # m/s² (twin.protocols.Plant, for the IMU)
        self.client, pybullet = _connect()
        c = self.client
        c.setPhysicsEngineParameter(fixedTimeStep=self.physics_dt, numSolverIterations=config.solver_iterations,
                                    numSubSteps=0, deterministicOverlappingPairs=1,
                                    solverResidualThreshold=config.solver_residual_threshold)
        c.setGravity(0.0, 0.0, -p.g)

        g = config.ground
        plane_q = c.getQuaternionFromEuler((0.0, 0.0, 0.0))
        if g.slope != 0.0:
            # the floor rises towards slope_direction: rotate about the horizontal axis ⟂ to it
            axis = (-math.sin(g.slope_direction), math.cos(g.slope_direction), 0.0)
            h = -0.5 * g.slope
            plane_q = (axis[0] * math.sin(h), axis[1] * math.sin(h), 0.0, math.cos(h))
        self.plane = c.loadURDF(os.path.join(pybullet_data.getDataPath(), "plane.urdf"), (0.0, 0.0, 0.0), plane_q,
                                useFixedBase=True)
        c.changeDynamics(self.plane, -1, lateralFriction=1.0, rollingFriction=0.0, spinningFriction=0.0,
                         restitution=0.0)

        d = config.disturbances
        self.urdf = robot_urdf(p, d.payload, d.com_offset, body=config.body)
        pos, quat = initial_pose(p, g, theta0, alpha0, x0, y0)
        fd, path = tempfile.mkstemp(suffix=".urdf", prefix="mtwip-")
        try:
            with os.fdopen(fd, "w") as f:
                f.write(self.urdf)
            self.robot = c.loadURDF(path, pos, quat, flags=pybullet.URDF_USE_INERTIA_FROM_FILE)
        finally:
            os.unlink(path)
        rob = self.robot
        self.motor = None if config.motor is None else MotorDriver(config.motor)
        self._duties = None  # the next step's duties from a firmware (step_duties), else None
        self._motor_damping = 0.0 if config.motor is None else config.motor.electrical_damping
        self._lagged = config.motor is not None and config.motor.inductance > 0.0
        for link in range(-1, c.getNumJoints(rob)):
            c.changeDynamics(rob, link, linearDamping=0.0, angularDamping=0.0, restitution=0.0)
        for j in WHEEL_JOINTS:
            c.resetJointState(rob, j, -theta0, 0.0)
            # with inductance the back-EMF is integrated in Python; otherwise it is joint damping
            damping = p.d_b + (0.0 if self._lagged else self._motor_damping)
            # Bullet caps joint rates at 100 rad/s by default (4 m/s here); lift the cap far above
            # anything the motors can reach, so that it never shapes the motion
            c.changeDynamics(rob, j, jointDamping=damping, lateralFriction=g.lateral_friction,
                             rollingFriction=g.rolling_friction, spinningFriction=g.spinning_friction,
                             )
        c.setJointMotorControlArray(rob, WHEEL_JOINTS, pybullet.VELOCITY_CONTROL, forces=(0.0, 0.0))
        for j in WHEEL_JOINTS:
            c.changeDynamics(rob, j, maxJointVelocity=MAX_JOINT_RATE)
        self._friction = {"left": [g.lateral_friction, g.rolling_friction, g.spinning_friction],
                          "right": [g.lateral_friction, g.rolling_friction, g.spinning_friction]}
        self._pending_friction = list(d.friction_changes)
        self._pushes = d.pushes
        self._com_local = (d.com_offset[0], d.com_offset[1], p.l + d.com_offset[2])
        # the body can reach the floor only when tilted this far (pitching on the slope, or rolling)
        self._contact_check_angle = max(0.0, min(touch_angle(p, config.body) - abs(g.slope) - 0.15, 0.6))
        # below this |θ| + |φ| (an upper bound of the tilt) a finite state needs no closer look
        self._quiet_angle = min(self._contact_check_angle, config.fall_angle)

        # the hot path calls pybullet's functions with this client's id: BulletClient
        # builds a new functools.partial on every attribute access
        self._pb = pybullet
        self._cid = client_id(c)
        self._hot = (self.robot, self._cid, pybullet.applyExternalTorque, pybullet.setJointMotorControlArray,
                     pybullet.stepSimulation, pybullet.getBasePositionAndOrientation, pybullet.getBaseVelocity,
                     pybullet.getJointStates, self.k)
        self._r = p.r
        # half the motor's electrical damping (N·m·s/rad), for the period-mean torque; with
        # inductance the back-EMF is integrated per step instead
        self._half_c = 0.0 if self._lagged else 0.5 * self._motor_damping
        self._truth_from_states = _fastpath.truth if _fastpath is not None else truth_from_states
        self._motor_consts = self.motor.constants if _fastpath is not None and self.motor is not None else None
        if (pybullet.TORQUE_CONTROL, pybullet.WORLD_FRAME) != (_TORQUE_CONTROL, _WORLD_FRAME):  # pragma: no cover
            raise TwinError("this PyBullet build numbers TORQUE_CONTROL / WORLD_FRAME differently; please report it")

        self.n_physics = 0
        self.status = "running"
        self.end_reason = ""
        self._alpha = None
        self._current = (0.0, 0.0)
        self._d_w = p.d_w
        self.push_force = (0.0, 0.0, 0.0)
        self.actuation = Actuation(0.0, 0.0, 0.0, 0.0, False, False)
        self.truth = self._read_truth()
        self._check_end()

    # ---- lifecycle ---------------------------------------------------------------------
    def reset(self, theta0: float = 0.0, alpha0: float = 0.0, position=(0.0, 0.0)) -> GroundTruth:
        """A new run on the same config (:class:`twin.protocols.Plant`): the physics server
        is closed and the twin built again at the given initial state; returns the truth at t = 0.
        A twin just built at that state and not stepped is that twin already: it is kept (a
        new physics server costs tens of milliseconds)."""
        if self.status == "running" and self.n_physics == 0 and \
                checked_start(theta0, alpha0, position, self.config.fall_angle) == self._start:
            return self.truth
        self.close()
        self.__init__(self.config, theta0, alpha0, position)
        return self.truth

    def close(self) -> None:
        """Disconnect the physics server (idempotent); a running twin ends as "closed"."""
        client = getattr(self, "client", None)
        if client is not None:
            disconnect(client)
        if getattr(self, "status", None) == "running":
            self.status, self.end_reason = "closed", "the twin was closed"

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass

    @property
    def t(self) -> float:
        """Simulated time in s."""
        return self.n_physics * self.physics_dt

    @property
    def com_local(self) -> tuple[float, float, float]:
        """The body's centre of mass in the body frame (x forward, y left, z up from the axle), m."""
        return self._com_local

    @property
    def motor_current(self) -> tuple[float, float] | None:
        """(i_l, i_r) A: the motors' armature current now, where the twin integrates it (motors with
        inductance); None otherwise, where the current follows the duty and the shaft speed at once
        (:func:`twin.actuators.dc_motor.steady_current`, what a motor-current sensor then reads)."""
        return self._current if self._lagged else None

    # ---- stepping ----------------------------------------------------------------------
    def step_duties(self, duty_l: float, duty_r: float, ul: float, ur: float, saturated=(False, False)) -> GroundTruth:
        """One control period with the PWM duties a firmware computed (in [−1, 1], held as the PWM
        peripheral holds them: clipped and quantised to the drive's resolution), instead of the
        twin's driver turning the torque commands ``ul``, ``ur`` (N·m, still checked and recorded)
        into duties with the true shaft speed; ``saturated`` the firmware's own flags, recorded."""
        if self.motor is None:
            raise TwinError("this twin drives its wheels with ideal torque sources (plant.motor = \"ideal\"): it has "
                            "no PWM duty to set; allowed: DC motors (plant.motor = \"dc\")")
        self._duties = ((float(duty_l), bool(saturated[0])), (float(duty_r), bool(saturated[1])))
        try:
            return self.step(ul, ur)
        finally:
            self._duties = None

    def step(self, ul: float, ur: float) -> GroundTruth:
        """Apply the torque commands ``ul``, ``ur`` (N·m) for one control period.

        Returns the ground truth at the end of the period (also :attr:`truth`);
        :attr:`actuation` holds what the motors delivered, :attr:`push_force` the push
        (N, world frame) that acted. Raises :class:`TwinError` if the run has ended or a
        command is not a finite number.
        """
        if self.status != "running":
            raise TwinError(f"the run has ended ({self.status}: {self.end_reason}); start a new twin")
        try:
            finite = isfinite(ul) and isfinite(ur)
        except TypeError:
            finite = False
        if not finite:
            raise TwinError(f"wheel torque commands must be finite numbers in N·m, got ul={ul!r}, ur={ur!r}")
        # the hot path indexes the truth tuple: 2 = θ̇, 13 = ψ̇_l, 14 = ψ̇_r (see GroundTruth)
        tr = self.truth
        if self._pending_friction:
            self._apply_friction_changes(self.n_physics * self.physics_dt)
        # equation (1)'s d_w: a joint torque per wheel and their sum on the body about the axle
        d_w = self._d_w
        hold_l = -d_w * tr[13]
        hold_r = -d_w * tr[14]
        tb = hold_l + hold_r
        ax, ay, az = self._axle_dir
        body_torque = (tb * ax, tb * ay, tb * az)
        # shaft speeds relative to the body (rad/s)
        w_l = tr[13] - tr[2]
        w_r = tr[14] - tr[2]
        motor = self.motor
        if self._duties is not None:  # a firmware's duties (step_duties): its own driver law ran outside
            (dl, sl), (dr, sr) = self._duties
            self._duties = None
            dl, tau0_l, tq_l = motor.held(dl, w_l)
            dr, tau0_r, tq_r = motor.held(dr, w_r)
        elif motor is None:
            dl = dr = 0.0
            sl = sr = False
            tq_l, tq_r = tau0_l, tau0_r = float(ul), float(ur)
        elif self._motor_consts is not None:
            dl, dr, tq_l, tq_r, sl, sr, tau0_l, tau0_r = _fastpath.motors(ul, ur, w_l, w_r, *self._motor_consts)
        else:
            dl, sl, tau0_l, tq_l = motor.update(ul, w_l)
            dr, sr, tau0_r, tq_r = motor.update(ur, w_r)
        # the speed-dependent part −c ω of the motor torque is the joint damping set at
        # construction, so only τ_0 is sent
        forces = (tau0_l + hold_l, tau0_r + hold_r)
        if self._pushes or self._lagged:
            return self._step_general(dl, dr, sl, sr, tq_l, tq_r, w_l, w_r, forces, hold_l, hold_r, body_torque)
        rob, cid, ext_torque, set_motors, step_sim, base_pose, base_vel, joint_states, k = self._hot
        # positional arguments (targetPositions, targetVelocities, forces, positionGains,
        # velocityGains, physicsClientId): keyword parsing costs PyBullet 0.4 µs a call, and
        # TORQUE_CONTROL reads only the forces
        for _ in range(k):
            ext_torque(rob, -1, body_torque, _WORLD_FRAME, cid)
            set_motors(rob, WHEEL_JOINTS, _TORQUE_CONTROL, _ZERO2, _ZERO2, forces, _ZERO2, _ZERO2, cid)
            step_sim(cid)
        self.push_force = _ZERO3
        self.n_physics = n = self.n_physics + k
        self.kinematics = pose, vel = base_pose(rob, cid), base_vel(rob, cid)
        truth, self._axle_dir = self._truth_from_states(
            GroundTruth, pose, vel, joint_states(rob, WHEEL_JOINTS, cid),
            self._alpha, self._com_local, self._r, n * self.physics_dt)
        self._alpha = truth[7]
        self.truth = truth
        # delivered torque, the period's mean: τ_0 − c ω with ω taken as linear over the period
        half_c = self._half_c
        self.actuation = _new(Actuation, (dl, dr, tq_l - half_c * (truth[13] - truth[2] - w_l),
                                          tq_r - half_c * (truth[14] - truth[2] - w_r), sl, sr))
        # NaN and infinity propagate through the physics and through this sum
        if not (isfinite(truth[1] + truth[2] + truth[5] + truth[6] + truth[7] + truth[8] + truth[10] + truth[11])
                and abs(truth[1]) + abs(truth[12]) <= self._quiet_angle):
            self._check_end()
        return truth

    def _step_general(self, dl, dr, sl, sr, tq_l, tq_r, w_l, w_r, forces, hold_l, hold_r,
                      body_torque) -> GroundTruth:
        """The rest of :meth:`step` with pushes or the motors' electrical lag."""
        t0 = self.n_physics * self.physics_dt
        push = self._push_setup(self.truth, t0) if self._pushes else None
        rob, cid, ext_torque, set_motors, step_sim, *_ = self._hot
        motor, dt, k = self.motor, self.physics_dt, self.k
        fx = fy = fz = 0.0
        sum_l = sum_r = 0.0
        for j in range(k):
            if push is not None:
                f = self._apply_push(push, t0 + j * dt)
                fx, fy, fz = fx + f[0], fy + f[1], fz + f[2]
            if self._lagged:
                # the electrical lag, resolved per physics step: the mean current over the step,
                # exact for a constant voltage and shaft speed
                (_, wl, _, _), (_, wr, _, _) = self._pb.getJointStates(rob, WHEEL_JOINTS, cid)
                il, ir = self._current
                kt = motor.params.k_t
                tl, trq = kt * motor.current_mean(il, dl, wl, dt), kt * motor.current_mean(ir, dr, wr, dt)
                sum_l += tl
                sum_r += trq
                forces = (tl + hold_l, trq + hold_r)
                self._current = (motor.current_step(il, dl, wl, dt), motor.current_step(ir, dr, wr, dt))
            ext_torque(rob, -1, body_torque, _WORLD_FRAME, cid)
            set_motors(rob, WHEEL_JOINTS, _TORQUE_CONTROL, _ZERO2, _ZERO2, forces, _ZERO2, _ZERO2, cid)
            step_sim(cid)
        self.push_force = (fx / k, fy / k, fz / k)
        self.n_physics += k
        self.truth = truth = self._read_truth()
        if self._lagged:
            self.actuation = _new(Actuation, (dl, dr, sum_l / k, sum_r / k, sl, sr))
        else:
            half_c = self._half_c
            self.actuation = _new(Actuation, (dl, dr, tq_l - half_c * (truth[13] - truth[2] - w_l),
                                              tq_r - half_c * (truth[14] - truth[2] - w_r), sl, sr))
        self._check_end()
        return truth

    # ---- disturbances ------------------------------------------------------------------
    def _apply_friction_changes(self, t: float) -> None:
        while self._pending_friction and self._pending_friction[0].time <= t + 1e-12:
            ch = self._pending_friction.pop(0)
            for side, j in (("left", 0), ("right", 1)):
                if ch.wheel not in (side, "both"):
                    continue
                f = self._friction[side]
                for i, v in enumerate((ch.lateral, ch.rolling, ch.spinning)):
                    if v is not None:
                        f[i] = v
                self.client.changeDynamics(self.robot, j, lateralFriction=f[0], rollingFriction=f[1],
                                           spinningFriction=f[2])

    def _push_setup(self, tr: GroundTruth, t0: float):
        """The pushes that overlap this control period, with world force and point (held over it)."""
        t1 = t0 + self.control_dt
        active = [p for p in self._pushes if p.start < t1 and p.start + p.duration > t0]
        if not active:
            return None
        com, R = self._pose()
        cl = self._com_local
        axle = tuple(com[i] - (R[i][0] * cl[0] + R[i][1] * cl[1] + R[i][2] * cl[2]) for i in range(3))
        out = []
        ca, sa = math.cos(tr.alpha), math.sin(tr.alpha)
        for p in active:
            fx, fy, fz = p.force
            if p.frame == "heading":
                f = (fx * ca - fy * sa, fx * sa + fy * ca, fz)
            else:
                f = (fx, fy, fz)
            pt = tuple(axle[i] + R[i][0] * p.point[0] + R[i][1] * p.point[1] + R[i][2] * p.point[2] for i in range(3))
            out.append((p.start, p.start + p.duration, f, pt))
        return out

    def _apply_push(self, push, t: float) -> tuple[float, float, float]:
        """Apply the pushes acting in the physics step starting at ``t``; their total force (N)."""
        fx = fy = fz = 0.0
        eps = 1e-9
        for start, end, f, pt in push:
            if start - eps <= t < end - eps:
                self._pb.applyExternalForce(self.robot, -1, f, pt, _WORLD_FRAME, self._cid)
                fx, fy, fz = fx + f[0], fy + f[1], fz + f[2]
        return fx, fy, fz

    # ---- readout -----------------------------------------------------------------------
    def _pose(self):
        """Centre of mass (m, world) and rotation matrix (rows) of the body."""
        com, (x, y, z, w) = self._pb.getBasePositionAndOrientation(self.robot, self._cid)
        return com, ((1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)),
                     (2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)),
                     (2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)))

    def _read_truth(self) -> GroundTruth:
        pb, cid, rob = self._pb, self._cid, self.robot
        self.kinematics = pose, vel = pb.getBasePositionAndOrientation(rob, cid), pb.getBaseVelocity(rob, cid)
        truth, self._axle_dir = self._truth_from_states(
            GroundTruth, pose, vel, pb.getJointStates(rob, WHEEL_JOINTS, cid), self._alpha, self._com_local,
            self.params.r, self.n_physics * self.physics_dt)
        self._alpha = truth[7]
        return truth

    def _check_end(self) -> None:
        tr = self.truth
        if not math.isfinite(tr.theta + tr.theta_dot + tr.psi + tr.psi_dot + tr.alpha + tr.alpha_dot + tr.x + tr.y):
            self.status, self.end_reason = "diverged", f"the physics returned a non-finite state at t = {tr.t:.3f} s"
            return
        # tilt of the body's axis from the vertical: cos(tilt) = cos θ cos φ
        tilt = math.acos(max(-1.0, min(1.0, math.cos(tr.theta) * math.cos(tr.roll))))
        if tilt > self.config.fall_angle:
            self.status = "fell"
            self.end_reason = (f"the body tilted {tilt:.3f} rad from the vertical (pitch {tr.theta:.3f}, roll "
                               f"{tr.roll:.3f} rad), past the fall limit {self.config.fall_angle:g} rad, "
                               f"at t = {tr.t:.3f} s")
        elif tilt > self._contact_check_angle and self.client.getContactPoints(self.robot, self.plane, -1):
            self.status = "fell"
            self.end_reason = (f"the body touched the floor at t = {tr.t:.3f} s (pitch {tr.theta:.3f}, "
                               f"roll {tr.roll:.3f} rad)")
