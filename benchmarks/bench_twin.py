"""Physics steps per second of the PyBullet twin against a bare PyBullet loop over the
same URDF (target: the twin's own overhead at most 15 %).

Run from the repository root::

    python benchmarks/bench_twin.py            # about 10 s
    python benchmarks/bench_twin.py --quick    # smoke run, a few seconds

What is compared
----------------
Both loops run in the same process, on the same PyBullet build, over the same robot:

* **bare** – raw ``pybullet`` module functions on a DIRECT client of its own: the URDF
  text of ``twin.plant.urdf.robot_urdf`` (loaded with ``URDF_USE_INERTIA_FROM_FILE``),
  ``pybullet_data``'s ``plane.urdf`` with a fixed base, and every engine and dynamics
  setting ``BulletTwin.__init__`` makes (time step, solver iterations, deterministic
  overlapping pairs, gravity; no link damping, zero restitution, the joint damping of
  equation (1)'s d_b plus the motor's electrical damping, the ground's friction on the
  wheels and the plane; default velocity motors off). At start-up the script checks
  this mirror against a real twin (URDF text, engine parameters, the dynamics info of
  every link, the initial state) and stops if they differ. Per physics step it sends the wheel
  torques with ``setJointMotorControlArray(..., TORQUE_CONTROL, forces=(0, 0))`` and
  calls ``stepSimulation``: the least any torque-driven loop must do, because Bullet
  clears applied torques after each step. The two calls are written the ordinary way
  (keywords ``forces=`` and ``physicsClientId=``; ``stepSimulation(cid)``), as a user
  writes them. This loop is the reference of the target. Two further bare variants are
  reported for reference: ``stepSimulation`` only (no torques at all), and the torque
  call with all its arguments positional, which has the same effect in TORQUE_CONTROL
  and is the cheapest form (PyBullet parses keyword arguments slowly). The twin uses
  that positional form, so the overhead against this variant is the twin's own work
  with the calling convention taken out of the comparison.
* **twin** – ``BulletTwin(TwinConfig())`` stepped with ``twin.step(0.0, 0.0)``: one
  control period (``twin.k`` = 5 physics steps at the default 1 kHz / 200 Hz) per call,
  with everything the twin does – motor driver, the d_w torque on the body each physics
  step (``applyExternalTorque``), ground truth read once per period, end checks.

**Overhead** = (twin time per physics step) / (bare time per physics step) − 1, i.e.
everything the twin adds on top of the unavoidable torque + step loop.

Windows
-------
The robot starts upright and at rest with zero torque. It balances on its unstable
equilibrium for a while before rounding errors tip it (about 3 s here), and a fallen
robot costs more per step (box–floor contacts). So each measurement is a window of 1 s
of simulated time (1000 physics steps = 200 control periods) starting upright: the bare
loop is reset before each window (base at its URDF-frame pose: PyBullet's base position
is the centre of mass, l above the axle, the axle at z = r; zero velocities; wheel
joints at 0), the twin is a new ``BulletTwin`` per window. Setup and reset are not
timed. The script asserts that every window ends with |θ| < 0.1 rad in every loop.
Windows of all variants are interleaved, in a rotating order, over several rounds, so
drifts of the machine (frequency, other load) hit them alike. Reported: median and best
(minimum) per-physics-step time over all windows, steps per second, overhead from the
medians and from the bests.

Also reported
-------------
* A per-call cost breakdown of one twin control period: ``twin._read_truth()`` (and its
  three PyBullet reads), one ``applyExternalTorque``, one ``setJointMotorControlArray``,
  one ``stepSimulation``. "In situ" times each call where the twin makes it (interleaved
  with physics steps, caches as cold as they are in the twin; the ``perf_counter`` pair
  cost is subtracted); "hot loop" is the same call repeated back to back (the best case).
  The overhead is then split into the calls the bare loop does not make and the rest of
  ``twin.step`` (motor driver, checks, bookkeeping), obtained as the difference.
* The closed-loop real-time factor: the IT2 balance controller on the twin from
  θ0 = 0.2 rad for 10 s (``simulate_twin``, twin construction included), in simulated
  seconds per wall-clock second; the first run in the process is shown separately.

Nothing here is random; ``time.perf_counter`` is the clock.
"""
from __future__ import annotations

import argparse
import contextlib
import gc
import math
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

TARGET_OVERHEAD = 0.15
WINDOW_S = 1.0  # simulated seconds per window
UPRIGHT_LIMIT = 0.1  # rad: |θ| at every window end must stay below this
pc = time.perf_counter


from twin.plant.bullet import WHEEL_JOINTS, BulletTwin, TwinConfig, quiet_native_output  # noqa: E402

with quiet_native_output():
    import pybullet as p
    import pybullet_data

from twin.plant.urdf import robot_urdf  # noqa: E402


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def pybullet_version() -> str:
    try:
        from importlib.metadata import version

        v = version("pybullet")
    except Exception:
        v = "?"
    return f"{v} (API {p.getAPIVersion()})"


def pitch(q) -> float:
    """Body pitch θ (ZYX Euler) from a base quaternion (x, y, z, w), as the twin reads it."""
    x, y, z, w = q
    return math.asin(max(-1.0, min(1.0, -2.0 * (x * z - y * w))))


# ---- the bare loop ------------------------------------------------------------------------
class BareWorld:
    """The twin's world built with raw pybullet calls (mirrors ``BulletTwin.__init__``)."""

    def __init__(self, config: TwinConfig):
        if config.disturbances.payload is not None or any(config.disturbances.com_offset) or config.ground.slope:
            raise SystemExit("the bare loop mirrors the default twin only (no payload, offset or slope)")
        par, g = config.params, config.ground
        with quiet_native_output():
            self.cid = cid = p.connect(p.DIRECT)
        p.setPhysicsEngineParameter(fixedTimeStep=1.0 / config.physics_rate,
                                    numSolverIterations=config.solver_iterations, numSubSteps=0,
                                    deterministicOverlappingPairs=1,
                                    solverResidualThreshold=config.solver_residual_threshold,  # as the twin's
                                    physicsClientId=cid)
        p.setGravity(0.0, 0.0, -par.g, physicsClientId=cid)
        self.plane = p.loadURDF(os.path.join(pybullet_data.getDataPath(), "plane.urdf"), (0.0, 0.0, 0.0),
                                (0.0, 0.0, 0.0, 1.0), useFixedBase=True, physicsClientId=cid)
        p.changeDynamics(self.plane, -1, lateralFriction=1.0, rollingFriction=0.0, spinningFriction=0.0,
                         restitution=0.0, physicsClientId=cid)
        fd, path = tempfile.mkstemp(suffix=".urdf", prefix="bench-twin-")
        try:
            with os.fdopen(fd, "w") as f:
                f.write(robot_urdf(par))
            # the URDF (body) frame at the axle midpoint, axle at z = r, upright
            self.robot = rob = p.loadURDF(path, (0.0, 0.0, par.r), (0.0, 0.0, 0.0, 1.0),
                                          flags=p.URDF_USE_INERTIA_FROM_FILE, physicsClientId=cid)
        finally:
            os.unlink(path)
        motor = config.motor
        lagged = motor is not None and motor.inductance > 0.0
        joint_damping = par.d_b + (0.0 if motor is None or lagged else motor.electrical_damping)
        for link in range(-1, p.getNumJoints(rob, physicsClientId=cid)):
            p.changeDynamics(rob, link, linearDamping=0.0, angularDamping=0.0, restitution=0.0, physicsClientId=cid)
        for j in WHEEL_JOINTS:
            p.resetJointState(rob, j, 0.0, 0.0, physicsClientId=cid)
            p.changeDynamics(rob, j, jointDamping=joint_damping, lateralFriction=g.lateral_friction,
                             rollingFriction=g.rolling_friction, spinningFriction=g.spinning_friction,
                             physicsClientId=cid)
        p.setJointMotorControlArray(rob, WHEEL_JOINTS, p.VELOCITY_CONTROL, forces=(0.0, 0.0), physicsClientId=cid)
        # PyBullet's base position is the centre of mass: l above the axle
        self.com0 = (0.0, 0.0, par.r + par.l)
        com, q = p.getBasePositionAndOrientation(rob, physicsClientId=cid)
        assert max(abs(a - b) for a, b in zip(com, self.com0)) < 1e-12 and q == (0.0, 0.0, 0.0, 1.0), (com, q)

    def reset(self) -> None:
        cid, rob = self.cid, self.robot
        p.resetBasePositionAndOrientation(rob, self.com0, (0.0, 0.0, 0.0, 1.0), physicsClientId=cid)
        p.resetBaseVelocity(rob, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), physicsClientId=cid)
        for j in WHEEL_JOINTS:
            p.resetJointState(rob, j, 0.0, 0.0, physicsClientId=cid)

    def theta(self) -> float:
        return pitch(p.getBasePositionAndOrientation(self.robot, physicsClientId=self.cid)[1])

    def window(self, kind: str, n: int) -> tuple[float, float]:
        """(seconds per physics step, θ at the end) of ``n`` physics steps from upright."""
        self.reset()
        cid, rob, joints = self.cid, self.robot, WHEEL_JOINTS
        step, set_motors, torque = p.stepSimulation, p.setJointMotorControlArray, p.TORQUE_CONTROL
        z = (0.0, 0.0)
        gc.collect()
        if kind == "bare":
            t0 = pc()
            for _ in range(n):
                set_motors(rob, joints, torque, forces=(0.0, 0.0), physicsClientId=cid)
                step(cid)
            dt = pc() - t0
        elif kind == "bare_step":
            t0 = pc()
            for _ in range(n):
                step(cid)
            dt = pc() - t0
        elif kind == "bare_pos":
            # TORQUE_CONTROL reads only `forces`; the other sequences are parsed and ignored
            t0 = pc()
            for _ in range(n):
                set_motors(rob, joints, torque, z, z, z, z, z, cid)
                step(cid)
            dt = pc() - t0
        else:
            raise ValueError(kind)
        return dt / n, self.theta()

    def close(self) -> None:
        p.disconnect(physicsClientId=self.cid)


def twin_window(config: TwinConfig, n_ctrl: int) -> tuple[float, float]:
    """(seconds per physics step, θ at the end) of ``n_ctrl`` twin.step calls on a new twin."""
    twin = BulletTwin(config)
    try:
        step = twin.step
        gc.collect()
        t0 = pc()
        for _ in range(n_ctrl):
            step(0.0, 0.0)
        dt = pc() - t0
        assert twin.status == "running", twin.end_reason
        return dt / (n_ctrl * twin.k), twin.truth.theta
    finally:
        twin.close()


def check_mirror(bare: BareWorld, config: TwinConfig) -> None:
    """The bare world has the twin's URDF, engine parameters, dynamics and initial state."""
    twin = BulletTwin(config)
    try:
        assert getattr(twin, "urdf", None) in (None, robot_urdf(config.params)), "the twin loads another URDF"
        tc = twin.client._client
        a = p.getPhysicsEngineParameters(physicsClientId=tc)
        b = p.getPhysicsEngineParameters(physicsClientId=bare.cid)
        assert a == b, f"engine parameters differ:\n twin {a}\n bare {b}"
        n_links = p.getNumJoints(bare.robot, physicsClientId=bare.cid)
        pairs = [(twin.plane, bare.plane, -1)] + [(twin.robot, bare.robot, link) for link in range(-1, n_links)]
        for tb, bb, link in pairs:
            a = p.getDynamicsInfo(tb, link, physicsClientId=tc)
            b = p.getDynamicsInfo(bb, link, physicsClientId=bare.cid)
            assert a == b, f"dynamics of body {bb} link {link} differ:\n twin {a}\n bare {b}"
        bare.reset()
        for get in (lambda c, r: p.getBasePositionAndOrientation(r, physicsClientId=c),
                    lambda c, r: p.getBaseVelocity(r, physicsClientId=c),
                    lambda c, r: p.getJointStates(r, WHEEL_JOINTS, physicsClientId=c)):
            a, b = get(tc, twin.robot), get(bare.cid, bare.robot)
            assert a == b, f"initial state differs:\n twin {a}\n bare {b}"
    finally:
        twin.close()


# ---- per-call breakdown -------------------------------------------------------------------
def call_breakdown(config: TwinConfig, n_periods: int, periods_per_twin: int) -> dict[str, tuple[float, float]]:
    """{call: (in-situ median s, hot-loop best s)} for the calls of one twin control period.

    In situ: the twin's world is driven period by period as ``twin.step`` drives it (k
    times torque on the body, wheel torques, step; then the truth read), each call
    wrapped in ``perf_counter``. Alternative forms of a call take turns with the twin's
    form at successive physics steps; the truth read and its three PyBullet reads take
    turns at successive periods.
    """
    ext, setm, step = p.applyExternalTorque, p.setJointMotorControlArray, p.stepSimulation
    bpo, bvel, jst = p.getBasePositionAndOrientation, p.getBaseVelocity, p.getJointStates
    T, W, J = p.TORQUE_CONTROL, p.WORLD_FRAME, WHEEL_JOINTS
    bt, z = (0.0, 0.0, 0.0), (0.0, 0.0)
    names = ("ext", "ext_kw", "setm", "setm_pos", "step", "step_kw", "truth", "bpo", "bvel", "jst", "empty")
    s = {k: [] for k in names}
    done = 0
    while done < n_periods:
        twin = BulletTwin(config)
        rob, cid = twin.robot, twin.client._client
        read_truth = twin._read_truth
        gc.collect()
        for i in range(min(periods_per_twin, n_periods - done)):
            for j in range(twin.k):
                if (i + j) % 2 == 0:  # each form gets the first step after the truth read half the time
                    a = pc(); ext(rob, -1, bt, W, cid); b = pc()
                    setm(rob, J, T, forces=z, physicsClientId=cid); c = pc()
                    step(cid); d = pc()
                    s["ext"].append(b - a); s["setm"].append(c - b); s["step"].append(d - c)
                else:
                    a = pc(); ext(rob, -1, bt, W, physicsClientId=cid); b = pc()
                    setm(rob, J, T, z, z, z, z, z, cid); c = pc()
                    step(physicsClientId=cid); d = pc()
                    s["ext_kw"].append(b - a); s["setm_pos"].append(c - b); s["step_kw"].append(d - c)
            if i % 2 == 0:
                a = pc(); read_truth(); b = pc()
                s["truth"].append(b - a)
            else:
                a = pc(); bpo(rob, cid); b = pc(); bvel(rob, cid); c = pc(); jst(rob, J, cid); d = pc()
                s["bpo"].append(b - a); s["bvel"].append(c - b); s["jst"].append(d - c)
            a = pc(); b = pc()
            s["empty"].append(b - a)
        assert abs(twin._read_truth().theta) < UPRIGHT_LIMIT
        twin.close()
        done += periods_per_twin
    timer = statistics.median(s.pop("empty"))
    in_situ = {k: max(0.0, statistics.median(v) - timer) for k, v in s.items()}

    # hot loop: the same call back to back, best of several batches
    twin = BulletTwin(config)
    rob, cid = twin.robot, twin.client._client
    read_truth = twin._read_truth
    hot_calls = {
        "ext": lambda: ext(rob, -1, bt, W, cid),
        "ext_kw": lambda: ext(rob, -1, bt, W, physicsClientId=cid),
        "setm": lambda: setm(rob, J, T, forces=z, physicsClientId=cid),
        "setm_pos": lambda: setm(rob, J, T, z, z, z, z, z, cid),
        "truth": lambda: read_truth(),
        "bpo": lambda: bpo(rob, cid),
        "bvel": lambda: bvel(rob, cid),
        "jst": lambda: jst(rob, J, cid),
        "noop": lambda: None,
    }
    hot = {}
    for name, fn in hot_calls.items():
        best = math.inf
        for _ in range(5):
            t0 = pc()
            for _ in range(400):
                fn()
            best = min(best, (pc() - t0) / 400)
        hot[name] = best
    noop = hot.pop("noop")  # the lambda call around each call
    hot = {k: max(0.0, v - noop) for k, v in hot.items()}
    twin.close()
    # stepSimulation back to back: 300 steps on a new twin each batch (upright all along)
    for name, kw in (("step", False), ("step_kw", True)):
        best = math.inf
        for _ in range(3):
            twin = BulletTwin(config)
            cid = twin.client._client
            gc.collect()
            if kw:
                t0 = pc()
                for _ in range(300):
                    step(physicsClientId=cid)
            else:
                t0 = pc()
                for _ in range(300):
                    step(cid)
            best = min(best, (pc() - t0) / 300)
            twin.close()
        hot[name] = best
    return {k: (in_situ[k], hot[k]) for k in in_situ}


# ---- closed loop --------------------------------------------------------------------------
def closed_loop(runs: int):
    from twin.controllers.cascade import build_cascade
    from twin.experiments import Experiment
    from twin.sim.bullet_loop import simulate_twin
    from twin.controllers.lmi import design_balance_gains

    design = design_balance_gains()
    exp = Experiment("bench", "", theta0=0.2, duration=10.0)
    out = []
    for _ in range(runs + 1):  # the first one is the cold run
        controller = build_cascade("it2", design, exp.targets)
        gc.collect()
        t0 = pc()
        run = simulate_twin(controller, exp, sensors=None)  # the twin and the controller alone (ideal sensing)
        wall = pc() - t0
        assert run.status == "ok", run.end_reason
        out.append((float(run.t[-1]), wall, len(run.t) - 1, float(run.signal("theta")[-1])))
    return out


def construction_time(config: TwinConfig, n: int) -> float:
    times = []
    for _ in range(n):
        t0 = pc()
        twin = BulletTwin(config)
        times.append(pc() - t0)
        twin.close()
    return statistics.median(times)


# ---- main ---------------------------------------------------------------------------------
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="short smoke run (a few seconds)")
    ap.add_argument("--rounds", type=int, help="rounds of interleaved windows (default 5; quick 2)")
    ap.add_argument("--windows", type=int, help="windows per variant per round (default 20; quick 3)")
    args = ap.parse_args(argv)
    rounds = args.rounds or (2 if args.quick else 5)
    per_round = args.windows or (3 if args.quick else 20)
    n_periods = 400 if args.quick else 4000
    cl_runs = 1 if args.quick else 5

    config = TwinConfig()
    n_phys = int(round(WINDOW_S * config.physics_rate))
    k = config.steps_per_control
    assert n_phys % k == 0
    n_ctrl = n_phys // k

    print("PyBullet twin vs bare PyBullet loop: physics steps per second")
    print(f"machine: {cpu_model()}, {os.cpu_count()} logical CPUs; Python {platform.python_version()} "
          f"({platform.python_implementation()}); PyBullet {pybullet_version()}")
    print(f"physics {config.physics_rate:g} Hz, control {config.control_rate:g} Hz (k = {k} physics steps per "
          f"twin.step), {config.solver_iterations} solver iterations")
    print(f"windows: {n_phys} physics steps ({WINDOW_S:g} s simulated) from upright at rest, zero torque; "
          f"{rounds} rounds x {per_round} windows per variant, interleaved")

    bare = BareWorld(config)
    check_mirror(bare, config)
    print("mirror check (URDF, engine parameters, dynamics of every link, initial state): bare world = twin world")

    variants = ("bare", "bare_step", "bare_pos", "twin")
    times = {v: [] for v in variants}
    thetas = {v: [] for v in variants}
    round_overhead = []
    t_start = pc()
    for r in range(rounds):
        rt = {v: [] for v in variants}
        for w in range(per_round):
            shift = (r * per_round + w) % len(variants)
            for v in variants[shift:] + variants[:shift]:
                if v == "twin":
                    dt, th = twin_window(config, n_ctrl)
                else:
                    dt, th = bare.window(v, n_phys)
                assert math.isfinite(th) and abs(th) < UPRIGHT_LIMIT, \
                    f"{v}: window ended with |θ| = {abs(th):.3g} rad (fallen or tipping)"
                times[v].append(dt)
                rt[v].append(dt)
                thetas[v].append(abs(th))
        round_overhead.append(statistics.median(rt["twin"]) / statistics.median(rt["bare"]) - 1.0)
    t_windows = pc() - t_start
    bare.close()

    med = {v: statistics.median(times[v]) for v in variants}
    best = {v: min(times[v]) for v in variants}
    labels = {
        "bare": "bare: torques (forces=) + stepSimulation",
        "bare_step": "bare: stepSimulation only",
        "bare_pos": "bare: torques (positional) + stepSimulation",
        "twin": "twin: BulletTwin.step(0, 0)",
    }
    print()
    print(f"{'loop':46}{'median':>9}{'best':>9}{'steps/s':>10}{'twin overhead vs this':>24}")
    print(f"{'':46}{'[µs/step]':>9}{'[µs/step]':>9}{'(median)':>10}{'median':>12}{'best':>12}")
    print("-" * 101)
    for v in variants:
        ov = "" if v == "twin" else (f"{100 * (med['twin'] / med[v] - 1):11.1f}%"
                                      f"{100 * (best['twin'] / best[v] - 1):11.1f}%")
        print(f"{labels[v]:46}{med[v] * 1e6:9.2f}{best[v] * 1e6:9.2f}{1 / med[v]:10.0f}{ov}")
    print(f"per-round overhead vs bare (medians): {', '.join(f'{100 * o:.1f}%' for o in round_overhead)}")
    print(f"largest |θ| at a window end: bare {max(thetas['bare']):.1e} rad, twin {max(thetas['twin']):.1e} rad "
          f"(limit {UPRIGHT_LIMIT} rad: no window fell); {sum(len(t) for t in times.values())} windows "
          f"in {t_windows:.1f} s wall")

    # ---- per-call breakdown
    bd = call_breakdown(config, n_periods, n_ctrl)
    us = 1e6
    print()
    print(f"Per-call cost in one twin control period (k = {k} physics steps). In situ: median of at least "
          f"{n_periods // 2} samples per call,")
    print("timer cost subtracted; hot loop: the call back to back, best of 5 x 400 (stepSimulation 3 x 300)")
    print(f"{'call':58}{'calls':>6}{'in situ':>10}{'hot loop':>10}{'per period':>12}")
    print(f"{'':58}{'':>6}{'[µs]':>10}{'[µs]':>10}{'[µs]':>12}")
    print("-" * 96)
    rows = [
        ("stepSimulation(cid)", "step", k),
        ("setJointMotorControlArray, all positional", "setm_pos", k),
        ("applyExternalTorque (body d_w torque)", "ext", k),
        ("twin._read_truth()", "truth", 1),
        ("  getBasePositionAndOrientation", "bpo", 1),
        ("  getBaseVelocity", "bvel", 1),
        ("  getJointStates", "jst", 1),
    ]
    for label, key, n in rows:
        ins, hot = bd[key]
        print(f"{label:58}{n:6d}{ins * us:10.3f}{hot * us:10.3f}{n * ins * us:12.2f}")
    reads = bd["bpo"][0] + bd["bvel"][0] + bd["jst"][0]
    py_truth = bd["truth"][0] - reads
    print(f"{'  Python arithmetic + GroundTruth (difference)':58}{1:6d}{py_truth * us:10.3f}"
          f"{(bd['truth'][1] - bd['bpo'][1] - bd['bvel'][1] - bd['jst'][1]) * us:10.3f}{py_truth * us:12.2f}")
    print("same effect, other call forms (not used by the twin):")
    for label, key in (("  stepSimulation(physicsClientId=cid)", "step_kw"),
                       ("  setJointMotorControlArray(..., forces=, physicsClientId=)", "setm"),
                       ("  applyExternalTorque(..., physicsClientId=cid)", "ext_kw")):
        ins, hot = bd[key]
        print(f"{label:58}{k:6d}{ins * us:10.3f}{hot * us:10.3f}{k * ins * us:12.2f}")

    bare_period = k * med["bare"]
    over_period = k * (med["twin"] - med["bare"])
    ext_period = k * bd["ext"][0]
    call_form = k * (bd["setm_pos"][0] - bd["setm"][0])  # the twin's positional torque call vs the bare keywords
    rest = over_period - ext_period - bd["truth"][0] - call_form
    print()
    print(f"Where the overhead goes, per control period (medians; % of the bare loop's {bare_period * us:.1f} µs "
          f"for {k} steps):")
    for label, v in (("measured overhead  k x (twin - bare)", over_period),
                     (f"  {k} x applyExternalTorque", ext_period),
                     ("  _read_truth: 3 PyBullet reads", reads),
                     ("  _read_truth: Python arithmetic + GroundTruth", py_truth),
                     (f"  {k} x torque call, positional (twin) instead of keywords (bare)", call_form),
                     ("  rest of twin.step (motor driver, checks, bookkeeping; difference)", rest)):
        print(f"{label:70}{v * us:8.2f} µs{100 * v / bare_period:8.1f}%")

    # ---- closed loop
    cl = closed_loop(cl_runs)
    t_build = construction_time(config, 3 if args.quick else 10)
    (sim0, wall0, n0, th0), rest_runs = cl[0], cl[1:]
    rtf = [s / w for s, w, _, _ in rest_runs]
    print()
    print("Closed loop: IT2 balance controller on the twin from θ0 = 0.2 rad, 10 s simulated (simulate_twin, ideal sensing)")
    print(f"  first run in process (cold): {wall0:.3f} s wall, real-time factor {sim0 / wall0:.1f}")
    w_med = statistics.median(w for _, w, _, _ in rest_runs)
    print(f"  next {len(rest_runs)} run(s): real-time factor median {statistics.median(rtf):.1f}, best {max(rtf):.1f} "
          f"(median {w_med:.3f} s wall, {w_med / n0 * us:.1f} µs per control period incl. controller and logging)")
    print(f"  of which building the BulletTwin: {t_build * 1e3:.1f} ms (median); final θ {th0:.2e} rad, status ok")

    print()
    overhead, overhead_best = med["twin"] / med["bare"] - 1.0, best["twin"] / best["bare"] - 1.0
    print(f"RESULT: twin {1 / med['twin']:.0f} physics steps/s, bare {1 / med['bare']:.0f} steps/s; overhead "
          f"{100 * overhead:.1f}% (median), {100 * overhead_best:.1f}% (best) vs target "
          f"{100 * TARGET_OVERHEAD:.0f}%: {'PASS' if overhead <= TARGET_OVERHEAD else 'FAIL'}")
    if "bare_pos" in med:
        print(f"        against the bare loop with the same positional torque call: "
              f"{100 * (med['twin'] / med['bare_pos'] - 1.0):.1f}% (median)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
