"""Validation on held-out logs: how well a twin predicts readings it was not fitted to.

For each window of a held-out log (:data:`FIT_PERIODS` + :data:`HORIZON_PERIODS` control
periods), the twin's start state is fitted to the readings of its first :data:`FIT_PERIODS`
periods (0.05 s at 200 Hz), and the IMU's constants (biases and scale factors) once per log
from those same fit parts (they change at every power-up, or with every run of the twin, and a
plant is not judged by them); from there the twin predicts the next :data:`HORIZON_PERIODS`
(0.1 s) open loop, with the log's drive applied, and the prediction is compared with the
readings, which the fit never saw. The nominal twin (the log's model, sensor constants at zero) and the
calibrated one go through the same procedure on the same windows, which overlap (one starts every
:data:`STRIDE_PERIODS`). Windows that neither twin can start (the fit part's cost beyond
:func:`twin.calibrate.fit.outlier_limit` for both: a push) are left out; a window only one twin
cannot start stays, for that is that twin's error.

Errors are root-mean-square over the predicted samples, per channel in SI units, and all
channels together in σ units (each reading divided by its white-noise σ: 1 is the readings' own
noise, what a perfect model leaves). The ratio compares what each twin adds to that noise,
√(rms² − 1) in σ units (Pythagoras: the model's error and the readings' noise are independent):
most of a balancing log is the robot standing, where every plant predicts the noise alone, and
the plain RMS would hide a model twice as wrong under it.
"""
from __future__ import annotations

import math

import numpy as np

from twin.calibrate import fit as F
from twin.calibrate.windows import IMU_CHANNELS, Windows, cut, streams
from twin.errors import TwinError

FIT_PERIODS = 10  # periods whose readings set the start state (0.05 s at 200 Hz)
HORIZON_PERIODS = 20  # periods predicted (0.1 s at 200 Hz)
STRIDE_PERIODS = 10  # a window starts every 0.05 s: overlapping, so that no stretch of the log goes unpredicted
# the manifest's figures two logs of one robot share
# (not the logging rate: one robot may be logged at 30 Hz one day and at 1 kHz the next)
SAME_ROBOT = ("wheel_radius", "track", "encoder_counts", "imu_position", "robot", "motor")


def same_robot(reference, log) -> None:
    """A one-line :class:`TwinError` if ``log`` is not of the robot of ``reference`` (its
    manifest differs in one of :data:`SAME_ROBOT`)."""
    a, b = reference.manifest, log.manifest
    for key in SAME_ROBOT:
        if a.get(key) != b.get(key):
            raise TwinError(f"--validate {log.path}: another robot than the calibration log {reference.path} "
                            f"(log.toml's {key} is {_short(b.get(key))}, the calibration log's {_short(a.get(key))}); "
                            f"validate on logs of the robot calibrated")


def _short(v) -> str:
    text = repr(v)
    return text if len(text) <= 60 else text[:57] + "..."


def prediction_errors(plant: F.Plant, values: dict, log, imu_latency: int, st=None) -> dict:
    """The errors of one twin (``plant`` with parameter ``values``) on ``log``."""
    st = streams(log) if st is None else st
    K, H = FIT_PERIODS, HORIZON_PERIODS
    w = cut(st, imu_latency, K + H, STRIDE_PERIODS)
    if w.count == 0:
        raise TwinError(f"--validate {log.path}: no {(K + H) / log.control_rate:g} s stretch with every reading")
    head = Windows(w.starts, w.S0, w.drive[:, :K], w.imu[:, :K], w.angles[:, :K + 1], w.imu_latency, st)
    twin = F.Plant(log, F.SENSOR_NAMES, plant.physics_rate, fixed=values)
    f = F.fit(twin, head, p0=np.zeros(len(F.SENSOR_NAMES)))
    limit = F.outlier_limit(f.window_costs, F.residual_count(head))
    v = twin.values(f.p)
    imu, ang = twin.predict(w, v, f.S, f.offsets)
    return {"imu": imu[:, K:] - w.imu[:, K:], "enc": ang[:, K + 1:] - w.angles[:, K + 1:],
            "ok": f.window_costs <= limit, "sigma": st.imu_sigma, "enc_sigma": st.encoder_sigma}


def validate(cal, logs) -> list[dict]:
    """Per held-out log: nominal and calibrated prediction errors and their ratio."""
    plant = cal.fit.plant
    nominal = {n: plant.base(n) for n in cal.fit.values}  # the log's model, sensor constants at zero
    out = []
    for log in logs:
        st = streams(log)
        a = prediction_errors(plant, nominal, log, cal.imu_latency, st)
        b = prediction_errors(plant, cal.fit.values, log, cal.imu_latency, st)
        out.append(aggregate(log, a, b, FIT_PERIODS / log.control_rate, HORIZON_PERIODS / log.control_rate))
    return out


def aggregate(log, a: dict, b: dict, fit_s: float, horizon_s: float) -> dict:
    """One held-out log's entry from the nominal (``a``) and the calibrated (``b``) twin's prediction
    errors (``imu`` (W, H, 5), ``enc`` (W, H, 2), ``ok`` (W,), ``sigma``, ``enc_sigma``)."""
    ok = a["ok"] | b["ok"]  # out only where neither twin can start (a push), not where one fails
    entry = {"log": str(log.path), "windows": int(ok.sum()), "left_out": int((~ok).sum()),
             "fit_s": fit_s, "horizon_s": horizon_s}
    for name, e in (("nominal", a), ("calibrated", b)):
        imu, enc = e["imu"][ok], e["enc"][ok]
        norm = np.concatenate([(imu / e["sigma"]).ravel(), (enc / e["enc_sigma"]).ravel()])
        entry[name] = {"rms_sigma": float(math.sqrt(np.mean(norm ** 2))),
                       "rms": {ch: float(math.sqrt(np.mean(imu[..., i] ** 2))) for i, ch in enumerate(IMU_CHANNELS)}
                       | {"encoders": float(math.sqrt(np.mean(enc ** 2)))},
                       "units": {ch: ("rad/s" if ch.startswith("gyro") else "m/s²") for ch in IMU_CHANNELS}
                       | {"encoders": "rad"}}
        entry[name]["_horizon"] = _by_step(imu, enc, e)
    for name in ("nominal", "calibrated"):
        entry[name]["model_error_sigma"] = math.sqrt(max(entry[name]["rms_sigma"] ** 2 - 1.0, 0.0))
    # the calibrated twin at the noise floor: the ratio is bounded by the floor's 1 % (not infinite)
    entry["ratio"] = entry["nominal"]["model_error_sigma"] / max(entry["calibrated"]["model_error_sigma"], 0.01)
    return entry


def _by_step(imu, enc, e) -> list:
    """σ-unit RMS at each predicted period (for the figure)."""
    ni = (imu / e["sigma"]) ** 2
    ne = (enc / e["enc_sigma"]) ** 2
    return [float(math.sqrt((np.sum(ni[:, j]) + np.sum(ne[:, j])) / (ni[:, j].size + ne[:, j].size)))
            for j in range(imu.shape[1])]


__all__ = ["FIT_PERIODS", "HORIZON_PERIODS", "SAME_ROBOT", "aggregate", "prediction_errors", "same_robot", "validate"]
