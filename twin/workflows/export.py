"""What ``twin export`` does: a scenario's controller, estimator and drive, designed as the twin
runs them, written as a C99 library (:mod:`twin.export`), with a host test whose vectors are a
short run of the twin recorded through the same interface."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from twin.errors import TwinError
from twin.export import generate as gen
from twin.export.ekf import check_arithmetic, default_arithmetic
from twin.export.literals import check_precision, literal
from twin.export.vectors import host_test_files
from twin.rotations import mounting_matrix
from twin.sim.simulate import build_loop
from twin.registry import is_import_path
from twin.scenarios import load_scenario

VECTOR_SECONDS = 1.0  # s of the scenario's run recorded for the host test


def exportable(role: str, kind: str, allowed: tuple) -> str:
    if kind not in allowed:
        why = " (a Python plugin: only the built-ins have C)" if is_import_path(kind) else ""
        raise TwinError(f"{role} {kind!r} cannot be exported to C{why}; allowed: {', '.join(allowed)}")
    return kind


CONTROLLERS = ("it2", "t1", "lqr")
# the host test's tolerances (absolute): float64 is the twin's arithmetic, operation for operation;
# float32 rounds every operation to 24 bits: measured on the built-ins' first second with it2, t1 and
# lqr, the estimate within 3e-5 (rad, rad/s) while the gyro is read, up to 1.1e-2 rad/s where the
# model stands in for a gyro at its rail (paper-exp1 from 0.48 rad: the model's finite differences in
# float32), the torques within 5e-4 N·m, the duties a PWM step apart where a torque lies at a step's edge
TOLERANCES = {"float64": {"estimate": 1e-9, "torque": 1e-9, "duty": 1e-9},
              "float32": {"estimate": 3e-2, "torque": 1e-2, "duty": None}}  # duty: two PWM steps
# float64 with the EKF's lean arithmetic: the same filter, within 6e-8 of the twin's estimates where it
# coasts (tests/test_export_ekf.py); the torques follow through the gains
LEAN_FLOAT64 = {"estimate": 1e-6, "torque": 1e-5, "duty": 1e-5}
PWM_STEPS_ALLOWED = 2
ESTIMATORS = ("ekf", "complementary", "kalman2")


def export(scenario: str, controller: str, estimator: str | None, precision: str, out: Path, overrides=(),
           seconds: float = VECTOR_SECONDS, arithmetic: str | None = None) -> dict:
    """Write the export of ``scenario`` (name or file, with ``overrides``) into ``out``: the
    library, the host test, CMakeLists.txt, README.md and export.json. ``arithmetic``: the EKF's,
    "exact" or "lean" (None: exact for float64, lean for float32). Returns the manifest's
    identity and the files written."""
    # only: the twin's version, named in every generated file
    from twin import __version__

    check_precision(precision)
    arithmetic = default_arithmetic(precision) if arithmetic is None else arithmetic
    check_arithmetic(arithmetic)
    exportable("controller", controller, CONTROLLERS)
    extra = tuple(overrides)
    if estimator is not None:
        exportable("estimator", estimator, ESTIMATORS)
        extra += (f"sensors.estimator={estimator}",)
    sc = load_scenario(scenario, extra)
    if sc.estimator == "ideal":
        raise TwinError(f"scenario {sc.name!r} has ideal sensing: a firmware estimates from its sensors; export "
                        "one with sensors (sensors.sensing = \"simulated\")")
    exportable("estimator", sc.estimator, ESTIMATORS)
    context = sc.build_context()
    ctrl = sc.build_controller(controller, context)
    est = sc.build_estimator(context)
    model = context.model
    cpr = context.sensors.encoders.counts_per_rev
    rad_per_count = 1.0 / (cpr / (2.0 * math.pi))  # the sensor suite's quantum, to the bit
    if controller == "lqr":
        design = ctrl.design_digest()
    else:
        design = context.balance_design().digest()
    identity = {"version": __version__, "controller": controller, "estimator": sc.estimator,
                "precision": precision, "arithmetic": arithmetic, "design_digest": design, "robot": sc.robot.name,
                "robot_digest": sc.robot.digest, "scenario": sc.name}
    mount = imu_mount(context)
    files = gen.library_files(ctrl, est, context.motor, identity, precision, rad_per_count, model.b / model.r,
                              context.control_rate, mount)
    targets = context.targets
    loops = {"position": getattr(ctrl, "position", None) is not None or (controller == "lqr"),
             "heading": getattr(ctrl, "direction", None) is not None or (controller == "lqr")}
    rec = record_run(sc, controller, seconds, context.motor, rad_per_count, model.b / model.r, mount)
    tol = dict(LEAN_FLOAT64 if (precision, arithmetic) == ("float64", "lean") else TOLERANCES[precision])
    if tol["duty"] is None:
        tol["duty"] = PWM_STEPS_ALLOWED / context.motor.pwm_steps if context.motor is not None else 1e-2
    files.update(host_test_files(rec, tol))
    files["CMakeLists.txt"] = gen.cmake_text(identity)
    files["README.md"] = gen.readme_text(identity, targets, loops, context.control_rate)
    record = {**identity, "loops": loops, "control_rate_hz": float(context.control_rate),
              "encoder_rad_per_count": literal(rad_per_count)}
    files[gen.MANIFEST] = gen.manifest(record, files)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise TwinError(f"--out {str(out)!r} is a file; give a directory")
    written = gen.write(out, files)
    return {"identity": identity, "files": written, "out": out}


def imu_mount(context) -> tuple:
    """The IMU's axes into the body's (3 rows, :func:`twin.rotations.mounting_matrix`) for the
    scenario's robot: the identity unless its ``imu.orientation`` turns the IMU."""
    o = tuple(context.sensors.imu.orientation)
    return gen.IDENTITY3 if o == (0.0, 0.0, 0.0) else tuple(tuple(r) for r in mounting_matrix(*o))


def record_run(sc, controller: str, seconds: float, motor, rad_per_count: float, b_over_r: float,
               imu_to_body=None) -> dict:
    """The first ``seconds`` of the scenario's run with ``controller`` (the twin's own Python path):
    every control instant's readings as a firmware gets them (the IMU's in its own axes, turned
    back from the body's by ``imu_to_body``: 3 rows, None for the identity), the estimate, the
    torques, and the duties the export's driver law gives for them at the estimated shaft speeds."""
    # only: the drive's law, for the duties the firmware computes
    from twin.actuators.dc_motor import MotorDriver

    driver = None if motor is None else MotorDriver(motor)
    spec = sc.run_spec(controller)
    loop = build_loop(spec)
    n = int(round(seconds * loop.control_rate)) + 1
    rows = {k: [] for k in ("gyro", "accel", "encoder", "valid", "estimate", "torque", "duty")}
    with loop:
        res = loop.reset(spec.seed)
        for k in range(n):
            m, x = res.measurement, res.estimate
            c = loop.command()
            rows["gyro"].append(m.gyro if m.gyro is not None else (0.0, 0.0, 0.0))
            rows["accel"].append(m.accel if m.accel is not None else (0.0, 0.0, 0.0))
            enc = m.encoders if m.encoders is not None else (0.0, 0.0)
            counts = [int(round(v / rad_per_count)) if math.isfinite(v) else 0 for v in enc]
            if any(ci * rad_per_count != v for ci, v in zip(counts, enc) if math.isfinite(v)):
                raise TwinError("an encoder reading is not a whole number of counts; cannot record the host test")
            rows["encoder"].append(counts)
            rows["valid"].append((m.gyro is not None, m.accel is not None, m.encoders is not None))
            rows["estimate"].append(x)
            rows["torque"].append(c[:2])
            spin = b_over_r * x[5]
            omega = (x[3] - spin - x[1], x[3] + spin - x[1])
            rows["duty"].append((0.0, 0.0) if driver is None else tuple(driver.duty(c[i], omega[i])[0] for i in (0, 1)))
            if k == n - 1 or res.status != "running":
                break
            res = loop.step(c)
    out = {k: np.asarray(v, dtype=float) for k, v in rows.items()}
    if imu_to_body is not None and tuple(map(tuple, imu_to_body)) != gen.IDENTITY3:
        m = np.asarray(imu_to_body, dtype=float)  # v_imu = mᵀ v_body: as rows, v_body @ m
        out["gyro"], out["accel"] = out["gyro"] @ m, out["accel"] @ m
    t = spec.targets
    out.update(position=t.position, heading=t.heading,
               source=f"{len(out['estimate'])} control periods of scenario {sc.name} with {controller}, seed {spec.seed}")
    return out


__all__ = ["CONTROLLERS", "ESTIMATORS", "export", "exportable", "imu_mount", "record_run"]
