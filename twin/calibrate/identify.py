"""Which fitted parameters the log determines: the intervals, and the warnings when it does not.

Each parameter's standard error is the largest of three (:mod:`twin.calibrate.fit`): the
Jacobian's s² H⁻¹, the window-clustered sandwich, and the spread of the bootstrap over windows.
The three agree when the information is spread over many windows; the bootstrap is the largest
when a few windows (a catch from a large tilt) carry most of it. The 95 % interval is
t₀.₉₇₅(dof) of that error either side: of the value for a sensor constant, of ln(value) for a
physical parameter (fitted as the logarithm of its factor), so [v e^(−t s), v e^(t s)] with s the
relative error.

A parameter is called identifiable when

* its interval's half-width is at most :data:`RELATIVE_HALF_WIDTH` of its value (a physical
  parameter, positive by construction) or at most its entry in :data:`SENSOR_HALF_WIDTH` (a sensor constant, in its unit:
  about half of a typical MEMS part's value, so that an interval wider than that says nothing);
* it is not a sensor constant that also takes up a model error (:data:`ABSORBS_MODEL_ERROR`);
* the yaw inertia comes from a log that turns (|α̇| reaching
  :data:`twin.calibrate.run.TURN_RATE`).

Pairs whose correlation reaches :data:`CONFOUNDED` get a warning naming both: the log moves them
together (l and n_yb in a short log; the stall torque and the mass always).
"""
from __future__ import annotations

import math

import numpy as np

from twin.calibrate.fit import correlation, t_quantile
from twin.calibrate.parameters import PARAMETERS

RELATIVE_HALF_WIDTH = 0.5
SENSOR_HALF_WIDTH = {"gyro_bias_x": 0.005, "gyro_bias_y": 0.005, "gyro_bias_z": 0.005,  # rad/s
                     "accel_bias_x": 0.05,  # m/s²
                     "gyro_scale_x": 0.01, "gyro_scale_y": 0.01, "gyro_scale_z": 0.01, "accel_scale_x": 0.01, "accel_scale_z": 0.01,
                     # A: about 3σ of an INA240-class channel's offset (twin.sensors.motor_current)
                     "current_offset_l": 0.01, "current_offset_r": 0.01}
# sensor constants that also take up a model error, so that their interval does not bound the
# sensor's own value: the forward accelerometer's scale absorbs the forward-acceleration model's
# error (the contact's effective rolling radius); on the twenty test robots its interval missed
# the truth in 3 of the 4 logs where it was narrower than ±0.01 (issue 30)
ABSORBS_MODEL_ERROR = {"accel_scale_x": "it also takes up the model's error in the forward acceleration (the "
                                        "wheels' effective rolling radius), so its interval does not bound the "
                                        "sensor's scale alone"}
CONFOUNDED = 0.95  # |correlation| from which two parameters are reported as confounded
BOOTSTRAP_RATIO = 2.0  # bootstrap spread over the Jacobian's error from which a warning says so


def assess(cal, turn_rate: float) -> tuple[dict, list, dict]:
    """(parameters, warnings, correlation) for :class:`twin.calibrate.run.Calibration` ``cal``:
    ``parameters`` maps each fitted name to ``value``, ``ci95``, ``unit``, ``identifiable``,
    ``standard_error`` and its three sources, ``nominal`` (the log's model) and, when not
    identifiable, ``why``; all in absolute SI values."""
    f = cal.fit
    plant = f.plant
    k = len(plant.names)
    # clusters, not residuals, are the independent units of the sandwich and the bootstrap
    tq = t_quantile(min(cal.info.dof, cal.clusters - 1))
    boot_sd = cal.boot.std(axis=0, ddof=1) if len(cal.boot) > 1 else np.zeros(k)
    params, warnings, spread = {}, [], {}
    for j, n in enumerate(plant.names):
        v = f.values[n]
        bn = n.split("@", 1)[0]  # a sensor constant of the k-th log is named NAME@k
        # a physical parameter is fitted as ln(factor): its errors are relative, sd(value) = value × sd(ln)
        unit_scale = v if plant.scaled(n) else 1.0
        sources = {"jacobian": math.sqrt(max(cal.C_jacobian[j, j], 0.0)) * unit_scale,
                   "sandwich": math.sqrt(max(cal.C_sandwich[j, j], 0.0)) * unit_scale,
                   "bootstrap": float(boot_sd[j]) * unit_scale}
        se = max(sources.values())
        why = None
        if plant.scaled(n):
            # the interval of ln(value), mapped back: [v e^(−t·s), v e^(t·s)], s the relative error
            rel = min(tq * se / v, 700.0)  # beyond e^700 a float overflows; the parameter is then nowhere
            ci = [v * math.exp(-rel), v * math.exp(rel)]
            if (ci[1] - ci[0]) / 2.0 > RELATIVE_HALF_WIDTH * v:
                why = (f"its 95 % interval is {ci[0] / v:.2g}× to {ci[1] / v:.2g}× the value (allowed: a half-width "
                       f"of {RELATIVE_HALF_WIDTH:.0%})")
            if bn == "n_zb" and cal.max_turn_rate < turn_rate:
                why = (f"the log never turns (|α̇| at most {cal.max_turn_rate:.3g} rad/s, below {turn_rate:g}): "
                       f"nothing excites the yaw inertia")
        else:
            hw = tq * se
            ci = [v - hw, v + hw]
            if hw > SENSOR_HALF_WIDTH[bn]:
                unit = "" if PARAMETERS[bn].unit == "1" else f" {PARAMETERS[bn].unit}"
                why = f"its 95 % interval is ±{hw:.3g}{unit} (allowed: ±{SENSOR_HALF_WIDTH[bn]:g}{unit})"
            elif bn in ABSORBS_MODEL_ERROR:
                why = ABSORBS_MODEL_ERROR[bn]
        if sources["jacobian"] > 0 and sources["bootstrap"] > BOOTSTRAP_RATIO * sources["jacobian"]:
            spread[n] = sources["bootstrap"] / sources["jacobian"]
        params[n] = {"value": v, "ci95": ci, "unit": PARAMETERS[bn].unit, "identifiable": why is None,
                     "standard_error": se, "standard_error_sources": sources, "nominal": plant.base(n),
                     "doc": PARAMETERS[bn].doc + (f" (log {n.split('@')[1]})" if bn != n else "")}
        if why:
            params[n]["why"] = why
            warnings.append(f"{n} is not identified by this log: {why}")
    if spread:
        warnings.insert(0, f"the bootstrap over the log's stretches spreads {min(spread.values()):.1f}× to "
                           f"{max(spread.values()):.1f}× the Jacobian's error for {', '.join(spread)}: a few stretches "
                           f"(a catch, a push) carry most of the information; those intervals are the bootstrap's")
    if "imu_latency" in cal.names:
        per_log = getattr(cal, "latency_profiles", None) or [cal.latency_costs]
        lats = getattr(cal, "latencies", None) or [cal.imu_latency]
        rates = [float(s.control_rate) for s in cal.streams] if len(cal.streams) == len(lats) else \
            [cal.fit.plant.control_rate] * len(lats)
        for i, (costs, d, rate) in enumerate(zip(per_log, lats, rates)):
            name = "imu_latency" if i == 0 else f"imu_latency@{i + 1}"
            params[name] = latency_entry(cal, costs, d, rate)
            if not params[name]["identifiable"]:
                warnings.append(f"{name} is not identified by this log: {params[name]['why']}")
    C = correlation(cal.C_jacobian)
    names = list(plant.names)
    for a in range(k):
        for b in range(a + 1, k):
            if abs(C[a, b]) >= CONFOUNDED:
                warnings.append(f"{names[a]} and {names[b]} are confounded in this log (correlation {C[a, b]:+.3f}): "
                                f"it moves them together; fix one (measure it) or record manoeuvres that tell them "
                                f"apart")
    return params, warnings, {"names": names, "matrix": [[float(x) for x in row] for row in C]}


def latency_entry(cal, costs=None, best=None, control_rate=None) -> dict:
    """The IMU latency: the whole number of periods with the lowest cost, and as its interval the
    latencies whose cost is within the χ²(1) 95 % point (3.84 × s², in Σ r²) of it (one log's:
    ``costs`` by latency in periods, ``best``, ``control_rate`` Hz; default the first log's)."""
    T = 1.0 / (cal.fit.plant.control_rate if control_rate is None else control_rate)
    costs = cal.latency_costs if costs is None else costs
    best = cal.imu_latency if best is None else best
    if not costs:
        return {"value": best * T, "ci95": [best * T, best * T], "unit": "s", "identifiable": False,
                "why": "not profiled", "standard_error": None}
    s2 = max(cal.info.s2, 1e-12)
    near = [d for d, c in costs.items() if 2.0 * (c - costs[best]) <= 3.841458820694124 * s2]
    entry = {"value": best * T, "ci95": [min(near) * T, max(near) * T], "unit": "s", "identifiable": len(near) == 1,
             "profile": {f"{d * T:g}": c for d, c in sorted(costs.items())}, "nominal": None,
             "doc": PARAMETERS["imu_latency"].doc, "standard_error": None}
    if len(near) > 1:
        entry["why"] = f"latencies {', '.join(f'{d * T:g} s' for d in sorted(near))} fit equally well"
    return entry


__all__ = ["BOOTSTRAP_RATIO", "CONFOUNDED", "RELATIVE_HALF_WIDTH", "SENSOR_HALF_WIDTH", "assess", "latency_entry"]
