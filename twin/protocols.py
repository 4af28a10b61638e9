"""The data that flows around the closed loop, and the contracts a user's code meets.

One control period of :class:`twin.sim.loop.ClosedLoop`::

    plant (GroundTruth) → sensors (Measurement) → Estimator (Estimate)
        → Controller (command: ul, ur [, signals]) → actuators → plant

Everything is in SI units. The controllers' state is the 6-vector of the paper,

    estimate = [θ, θ̇, ψ, ψ̇, α, α̇]   (rad, rad/s, rad, rad/s, rad, rad/s)

θ the body's pitch from the vertical (positive leaning forward), ψ = (ψ_l + ψ_r) / 2 the
mean wheel angle from the vertical (travelled distance p = r ψ), α the heading
(positive turning left). The command is the two wheel torques (ul, ur) in N·m, positive
driving the robot forward; the motors may deliver less (see :mod:`twin.actuators`).

A controller or an estimator is any object with the methods of :class:`Controller` or
:class:`Estimator` (structural typing: no base class to inherit). Built-in ones and
one's own are named the same way, by :mod:`twin.registry`: a built-in name (``"it2"``,
``"ekf"``, ...) or an import path ``"package.module:attribute"``. The loop checks the
contract at every step and stops with a one-line :class:`twin.errors.PluginError` naming
the object and what was expected.

The plant is one more such object (:class:`Plant`): the PyBullet twin, equation (1) or
one's own, chosen by a scenario's ``plant.model`` (a kind of :mod:`twin.registry`:
``"bullet"``, ``"analytic"`` or ``"package.module:attribute"``, built by
:func:`twin.registry.build_plant`) or handed to :class:`twin.sim.loop.ClosedLoop` directly.
"""
from __future__ import annotations

from typing import Any, NamedTuple, Protocol, Sequence, runtime_checkable

from twin.errors import shown  # re-exported: twin.registry quotes values with twin.protocols.shown
from twin.plant.base import Actuation, GroundTruth
from twin.sensors.suite import Measurement

ESTIMATE_NAMES = ("theta", "theta_dot", "psi", "psi_dot", "alpha", "alpha_dot")
ESTIMATE_UNITS = ("rad", "rad/s", "rad", "rad/s", "rad", "rad/s")



# the names of the columns a run logs of each part (twin.sim.runs): what a controller's own
# signals may not be called
TRUTH_NAMES = GroundTruth._fields
ESTIMATE_NAMES = ("theta_est", "theta_dot_est", "psi_est", "psi_dot_est", "alpha_est", "alpha_dot_est")
ESTIMATE_UNITS = dict(theta_est="rad", theta_dot_est="rad/s", psi_est="rad", psi_dot_est="rad/s", alpha_est="rad",
                      alpha_dot_est="rad/s")
COMMAND_NAMES = ("ul_cmd", "ur_cmd", "u", "theta_off", "u_alpha")  # the fuzzy cascade's (and LQR's)
COMMAND_UNITS = dict(ul_cmd="N·m", ur_cmd="N·m", u="N·m", theta_off="rad", u_alpha="N·m")
ACTUATION_NAMES = Actuation._fields
PUSH_NAMES = ("push_fx", "push_fy", "push_fz")
PUSH_UNITS = dict(push_fx="N", push_fy="N", push_fz="N")

class Estimate(NamedTuple):
    """The controllers' state [θ, θ̇, ψ, ψ̇, α, α̇] (rad, rad/s, rad, rad/s, rad, rad/s) at one
    control instant. Estimators may return any sequence of six floats instead."""

    theta: float
    theta_dot: float
    psi: float
    psi_dot: float
    alpha: float
    alpha_dot: float


class Targets(NamedTuple):
    """What the robot is asked to do: ``position`` p_d (m of travel, p = r ψ, from where it
    started) and ``heading`` α_d (rad); None where that loop is off (balance only)."""

    position: float | None = None
    heading: float | None = None


@runtime_checkable
class Controller(Protocol):
    """Turns the estimate into the two wheel torques, once per control period.

    Attributes
    ----------
    signals : tuple of str, optional
        Names of extra signals the call returns after the two torques, logged with the
        run (for example the fuzzy cascade's ``("u", "theta_off", "u_alpha")``). Absent
        means none.
    signal_units : dict of str to str, optional
        The unit of each extra signal (for CSV headers); absent means "1".
    drives_duty : bool, optional
        True for a controller that also computes the motors' PWM duties itself (a firmware's
        driver law, as an export's C does): its ``signals`` then end with ``duty_cmd_l``,
        ``duty_cmd_r`` (each in [−1, 1]), ``saturated_cmd_l``, ``saturated_cmd_r`` (1.0 or 0.0),
        and the loop hands those duties to the plant (``step_duties``) instead of its driver
        turning the torques into duties. Absent or False: the torques are the command.

    Methods
    -------
    reset(targets)
        Called once before the first step of a run (and again for every new run or
        episode). Clear any internal state (integrators, filters, previous inputs).
    __call__(estimate, targets) -> sequence of float
        ``estimate`` (6,) as in the module docstring; ``targets`` a :class:`Targets`.
        Returns ``(ul, ur, *signals)``: the left and right wheel torque commands in N·m
        followed by one finite value per entry of ``signals``. Anything else (another
        length, a non-number, NaN or inf) stops the run with a one-line error.
    """

    def reset(self, targets: Targets) -> None: ...

    def __call__(self, estimate: Sequence[float], targets: Targets) -> Sequence[float]: ...


@runtime_checkable
class Estimator(Protocol):
    """Turns the sensor readings into the controllers' state, once per control period.

    Methods
    -------
    start(measurement) -> sequence of 6 floats
        The first readings (control step 0, the robot at rest on its wheels, tilted by
        the initial θ); returns the first estimate [θ, θ̇, ψ, ψ̇, α, α̇]. It begins a
        run: an estimator reused by :meth:`twin.sim.loop.ClosedLoop.reset` must forget any
        previous run here (the built-in ones do).
    step(measurement, command) -> sequence of 6 floats
        The readings that arrived at this control instant (a
        :class:`~twin.sensors.Measurement`: ``t`` s; ``gyro`` (3,) rad/s and ``accel``
        (3,) m/s² in body axes, x forward, y left along the axle, z up the body;
        ``encoders`` (2,) rad, each wheel's angle relative to the body since power-up,
        quantised; a field is None when no new sample arrived, and may be NaN or stale
        under faults) and ``command`` (ul, ur) in N·m, the torques commanded over the
        period that just ended. Returns the estimate at this instant. A non-finite
        value stops the run with a one-line error.

    Optional hooks (the loop calls them only if they exist)
    -------------------------------------------------------
    covariance() -> ndarray (6, 6)
        Covariance of the last estimate, in the units of the estimate squared.
    stats() -> dict
        Counts over the run so far, JSON-serialisable; ``"rejected_total"`` (int), if
        present, is reported as the run's ``rejected_measurements``.
    set_sampling(imu: str, commands: str, periods: str = "constant") -> None
        Called by ``twin replay`` before ``start`` where a log's rows are not the twin's:
        ``imu`` is ``"mean"`` (each reading the mean over the interval since the previous
        sample) or ``"point"`` (the value at its instant), ``commands`` is ``"held"`` (from
        each row's t) or ``"sampled"`` (a faster loop's value at that instant; each period's
        command is then the mean of the samples joined by straight lines). ``periods`` (passed
        by keyword, only to a hook that takes it) is ``"rows"`` for a log whose command rows
        are off the regular grid: the instants are then those rows, and each step spans the
        time from the previous measurement's ``t`` to this one's (s), not 1 / control rate;
        a hook without it is replayed as if every period were the nominal one.
    diagnostics() -> dict
        What the last ``start``/``step`` did (for example the EKF's state, covariance and
        normalised innovation). Asked for after every step when a run logs them, and by
        ``twin replay``; the estimator owns and resets these values itself. Keys the twin
        reads, all optional, each about the last ``start``/``step`` alone:

        ``nis`` float and ``nis_dof`` int
            The normalised innovation squared yᵀ S⁻¹ y of the update made at this step and
            its degrees of freedom (the measurement's dimension m); NaN and 0 where no update
            was made. ``twin replay`` reports NIS per degree of freedom (1 if consistent).
        ``innovation`` (m,) and ``innovation_cov`` (m, m)
            That update's innovation y (measured less predicted) and its covariance S as the
            estimator believes it, in the measurement's units and their square (rad and rad²
            for encoder angles or an accelerometer angle, m/s² and m²/s⁴ for a specific
            force); absent where no update was made. ``twin replay`` whitens each with S and
            tests the sequence for whiteness (:mod:`twin.logs.replay`); no truth is needed,
            so this works on a real robot's log.
        ``x`` (n,), ``P`` (n, n) and ``lag`` int (the EKF's own)
            The built-in EKF's 12 states, their covariance and the periods its state lags
            the instant; with a log's state truth, ``twin replay`` reports NEES from them.

        The built-in EKF gives all of these (its encoder update); the two-state Kalman
        filter (``kalman2``) its accelerometer-angle update's; the complementary filter has
        no covariance and no hook.

    Sensor channels beyond the IMU and encoders (:mod:`twin.sensors.types`: the motor current,
    ``measurement["motor_current"]`` (left, right) A, or ``measurement.channels``) reach every
    estimator in ``measurement.extra`` when the run or the log has them; an estimator that does
    not read them is unaffected, one that reads a channel the run lacks gets None.

    Attributes
    ----------
    reads_truth : bool, optional
        True only for reference estimators that read ``measurement.truth`` (the ground
        truth, attached for them alone); a real estimator never sees it.
    channels : tuple of str, optional
        The channels it cannot do without beyond gyro, accel and encoders (e.g.
        ``("motor_current",)``): a run whose sensors, or a log that, lack one is refused in one
        line naming it.
    """

    def start(self, measurement: Measurement) -> Sequence[float]: ...

    def step(self, measurement: Measurement, command: Sequence[float]) -> Sequence[float]: ...


@runtime_checkable
class Plant(Protocol):
    """The robot being controlled: steps one control period with the two wheel torques and
    reports the ground truth. :class:`twin.sim.loop.ClosedLoop` runs any object with these
    members (structural typing: no base class to inherit); built in are the PyBullet twin
    (:class:`twin.plant.bullet.BulletTwin`, ``plant.model = "bullet"``) and equation (1)
    (:class:`twin.plant.analytic_plant.AnalyticPlant`, ``plant.model = "analytic"``).
    One's own is named in a scenario as ``plant.model = "package.module:attribute"``: the
    attribute (a class or a function) is called as ``attribute(config, theta0, alpha0,
    position, **params)`` with the scenario's :class:`~twin.plant.base.TwinConfig` (the true
    robot, rates, floor, disturbances), the start (rad, rad, (m, m)) and ``[plant.params]``,
    as the built-ins are.

    Attributes
    ----------
    control_rate : float
        Hz: one :meth:`step` advances 1 / control_rate s.
    truth : GroundTruth
        The ground truth now (after the last :meth:`reset` or :meth:`step`), SI units:
        ``t`` s, θ, ψ_l, ψ_r, ψ, α, roll in rad, their rates in rad/s, ``distance`` p = r ψ
        and the axle midpoint ``x``, ``y`` in m (see :class:`~twin.plant.base.GroundTruth`).
    status : str
        ``"running"``, ``"fell"`` or ``"diverged"`` (a non-finite state); ``"closed"`` after
        :meth:`close` mid-run. Only a running plant is stepped.
    end_reason : str
        One line saying why the run ended ("" while running).

    Methods
    -------
    reset(theta0, alpha0, position) -> GroundTruth
        Start a new run at rest: body pitch ``theta0`` and heading ``alpha0`` in rad, axle
        midpoint ``position`` (x, y) in m, all rates 0, wheel angles ψ_i = 0 at t = 0.
        Returns the truth at t = 0. Called by every :meth:`twin.sim.loop.ClosedLoop.reset`,
        also after :meth:`close` (a plant is reused run after run).
    step(ul, ur) -> GroundTruth
        Apply the left and right wheel torque commands ``ul``, ``ur`` (N·m, each acting
        between body and wheel, positive driving forward) for one control period; returns
        the truth at its end (also :attr:`truth`) and updates :attr:`status`.
    close()
        Free what the plant holds (a physics server, say); safe to call twice.

    For the simulated IMU (a loop with ``sensors``; the encoders read ψ_i − θ from the truth)
    -----------------------------------------------------------------------------------
    kinematics : ((x, y, z), (qx, qy, qz, qw)), ((vx, vy, vz), (ωx, ωy, ωz))
        The body's pose and velocity at :attr:`truth`'s instant, PyBullet's layout: its
        centre of mass in m and orientation quaternion (body → world; body axes x forward,
        y left along the axle, z up the body), then the centre of mass's velocity in m/s
        and the angular velocity in rad/s, both in world axes (z up). For a planar plant
        :func:`twin.plant.analytic_plant.planar_kinematics` builds it from θ, α and rates.
    com_local : (3,) m
        The body's centre of mass in body axes from the axle midpoint.
    gravity : float
        m/s², what the accelerometer adds.

    Optional (read by the loop when present)
    ----------------------------------------
    actuation : Actuation
        What the motors delivered over the last period (duties, torques N·m, saturation);
        absent: the commands, delivered exactly.
    push_force : (3,) N
        Mean external push force over the last period, world axes; absent: none.
    motor_current : (2,) A
        The motors' armature current (left, right) at :attr:`truth`'s instant, what the
        ``motor_current`` sensor samples; absent: the drive model's current for the duty
        held over the last period and the shaft speed now
        (:func:`twin.actuators.dc_motor.steady_current`, exact without inductance).
    trusted : bool
        True: the loop does not check the truth this plant returns at every step (the
        built-ins', finite and well formed by construction; a check costs a few µs a step);
        absent or False: it is checked, and a wrong one stops the run in one line.
    step_duties(duty_l, duty_r, ul, ur, saturated) -> GroundTruth
        One period with PWM duties (in [−1, 1]) a controller computed itself (``drives_duty``),
        the torque commands ``ul``, ``ur`` (N·m) and the controller's ``saturated`` flags kept
        for the record; the built-in PyBullet twin with DC motors has it. A controller that
        drives duties on a plant without it is refused in one line.
    applies_motor : bool
        True: the plant drives its wheels through its configuration's ``motor``
        (:class:`~twin.actuators.DCMotorParams`), so the controllers and the estimator are
        told of it (back-EMF compensation); absent or False: they see ideal torque sources.

    A plant that lacks a member, or returns something other than a GroundTruth (15 numbers)
    from ``reset``/``step``, stops the run with a one-line :class:`twin.errors.PluginError`
    naming it and this contract.
    """

    control_rate: float
    truth: GroundTruth
    status: str
    end_reason: str

    def reset(self, theta0: float = 0.0, alpha0: float = 0.0, position=(0.0, 0.0)) -> GroundTruth: ...

    def step(self, ul: float, ur: float) -> GroundTruth: ...

    def close(self) -> None: ...


class StepResult(NamedTuple):
    """What one control instant of :class:`twin.sim.loop.ClosedLoop` holds.

    ``truth`` the plant's ground truth; ``measurement`` what reached the estimator;
    ``estimate`` (6,) what the controller is given; ``status`` "running", "fell" or
    "diverged"; ``reason`` why it ended ("" while running).

    Published with them, for loggers (:class:`twin.sim.recorder.Recorder`, one's own):
    ``gyro_bias`` (3,) rad/s the gyro's true bias in the sample taken at this instant (None
    without one: no sensors, or no IMU sample due); ``actuation``
    (:class:`~twin.plant.bullet.Actuation`) and ``push_force`` (3,) N, world axes, what the
    motors delivered and the pushes did over the control period that ended at this instant
    (None at instant 0, from :meth:`~twin.sim.loop.ClosedLoop.reset`)."""

    truth: GroundTruth
    measurement: Measurement
    estimate: tuple
    status: str
    reason: str
    gyro_bias: tuple | None = None
    actuation: Any = None
    push_force: tuple | None = None


def one_line(text: str, limit: int = 500) -> str:
    """``text`` (a plugin's exception message, say) on one line, at most ``limit`` characters."""
    text = " ".join(str(text).split())
    return text if len(text) <= limit else text[:limit - 1] + "…"


def describe_object(obj: Any) -> str:
    """A short name for messages: the class's (or function's) qualified name."""
    target = obj if isinstance(obj, type) or callable(obj) and hasattr(obj, "__qualname__") else type(obj)
    return f"{getattr(target, '__module__', '?')}.{getattr(target, '__qualname__', repr(target))}"


__all__ = ["Controller", "ESTIMATE_NAMES", "ESTIMATE_UNITS", "Estimate", "Estimator", "GroundTruth", "Measurement",
           "Plant", "StepResult", "Targets", "describe_object", "one_line", "shown"]
