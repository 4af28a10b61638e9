"""What ``twin calibrate`` writes: report.json, calibration.toml and figure.png.

``report.json``: ``parameters`` (each fitted one as ``{"value", "ci95": [low, high], "unit",
"identifiable", ...}`` in absolute SI values), ``correlation`` (names and matrix),
``warnings`` (one line each), ``method`` (windows, residual σ, solver, wall time) and
``validation`` (per held-out log, the nominal and the calibrated twin's prediction errors).

``calibration.toml``: the twin's true plant and sensors as a scenario takes them —
``[plant] scale`` (factors of Table III, :data:`twin.params.NOMINAL`, for the identified
physical parameters; for a calibration of the robot, the twin's values that reproduce it,
:func:`twin.calibrate.robot.to_twin`, with the wheels' compensation) and ``[sensors]
imu_latency`` — for ``twin run SCENARIO --plant calibration.toml`` or ``--set``; the robot's
own physical values, the fitted sensor constants, the motor figures and the provenance are in
``[calibration]`` (read by nothing but people).
"""
from __future__ import annotations

import json
import math

import numpy as np

from twin.calibrate.parameters import PARAMETERS
from twin.calibrate.physical import substeps
from twin.calibrate.robot import twin_lags
from twin.errors import TwinError
from twin.params import NOMINAL

SCALE_RANGE = (0.2, 5.0)  # plant.scale's allowed factors (twin/scenarios/schema.py)


def _base(n: str) -> str:
    return n.split("@", 1)[0]


def report_doc(cal, params: dict, warnings: list, corr: dict, validation, seed: int, twin=None) -> dict:
    f = cal.fit
    st = f.windows.streams
    if getattr(cal, "model_kind", "twin") == "physical":
        return _physical_doc(cal, params, warnings, corr, validation, seed, twin)
    return {
        **_head(cal, params, corr, warnings),
        "method": {
            "model": "the PyBullet twin's stepping of equation (1) (twin.calibrate.model.step_windows): the log is "
                     "the twin's own, and that stepping is its robot's dynamics exactly",
            "physics_rate_hz": f.plant.physics_rate, "control_rate_hz": f.plant.control_rate,
            "window_s": f.windows.periods / f.plant.control_rate, "windows": f.windows.count,
            "windows_in_log": cal.windows_total, "windows_left_out_at_s": cal.dropped,
            "drive": "duty" if st.drive_is_duty else "torque",
            "residual_sigma": math.sqrt(cal.info.s2), "degrees_of_freedom": cal.info.dof,
            "solver": "scipy.optimize.least_squares (trf, lsmr, sparse Jacobian)",
            "bootstrap_replicates": int(len(cal.boot)), "seed": seed, "wall_s": cal.wall_s,
        },
        "validation": validation,
    }


def _head(cal, params, corr, warnings) -> dict:
    """report.json's first keys, whichever model was fitted."""
    return {"format": 1, "command": "twin calibrate", "logs": cal.logs, "parameters": params, "correlation": corr,
            "warnings": warnings}


def _physical_doc(cal, params, warnings, corr, validation, seed, twin) -> dict:
    f = cal.robot_fit
    groups = f.groups
    return {
        **_head(cal, params, corr, warnings),
        "twin": twin,
        "method": {
            "model": "the robot's continuous equations: equation (1) with the yaw coupling, by RK4 at "
                     "the integration rate, the motors (torque = duty × stall torque − c_e × the wheel's speed "
                     "relative to the body, or ideal torque sources), the commands held or sampled as the log "
                     "says (twin.calibrate.physical)",
            "physical": True,
            "per_log": [{"log": str(g.log.path), "control_rate_hz": g.rate,
                         "integration_rate_hz": substeps(g.rate) * g.rate, "window_s": g.periods / g.rate,
                         "window_periods": g.periods, "windows": g.count,
                         "commands": "sampled" if g.sampled else "held",
                         "drive": "duty" if g.motor is not None else "torque",
                         "imu_sampling": "point" if g.point else "mean",
                         "twin_log": bool(_lags(g.log))} for g in groups],
            "control_rate_hz": groups[0].rate, "physics_rate_hz": substeps(groups[0].rate) * groups[0].rate,
            "window_s": groups[0].periods / groups[0].rate, "windows": sum(g.count for g in groups),
            "windows_in_log": cal.windows_total, "windows_left_out_at_s": cal.dropped,
            "residual_sigma": math.sqrt(cal.info.s2), "degrees_of_freedom": cal.info.dof,
            "solver": "Levenberg–Marquardt, window states eliminated per window (Schur complement), "
                      "forward-difference Jacobian in one batch (twin.calibrate.robot)",
            "iterations": f.iterations,
            "bootstrap_replicates": int(len(cal.boot)), "seed": seed, "wall_s": cal.wall_s,
        },
        "validation": validation,
    }


def _lags(log):
    return twin_lags(log)


def calibration_toml(cal, params: dict, twin=None, geometry: tuple | None = None) -> str:
    """The text of calibration.toml (see the module docstring). ``twin``: for a calibration of the
    robot (the physical model), :func:`twin.calibrate.robot.to_twin`'s mapping, whose values
    become [plant] scale (the robot brought into the twin's stepping). ``geometry``: the logs'
    (wheel radius m, half track m); the twin's wheels and track are Table III's, so a robot with
    others cannot be run by it (the file then says why, and has no [plant])."""
    lines = ["# Written by 'twin calibrate'. 'twin run SCENARIO --plant calibration.toml' runs this robot:",
             "# [plant] and [sensors] replace the scenario's true plant and IMU latency; [calibration] is a record.", ""]
    lines += ["[calibration]", f"logs = {json.dumps(cal.logs)}",
              f"fitted = {json.dumps(list(params))}"]
    not_id = [n for n, e in params.items() if not e["identifiable"]]
    lines.append(f"not_identified = {json.dumps(not_id)}  # left at the nominal value in [plant]")
    sensor = {n.replace("@", "_log"): e["value"] for n, e in params.items()
              if PARAMETERS[_base(n)].group == "imu" and _base(n) != "imu_latency"}
    if sensor:
        lines.append("# the IMU's constants of the calibration log (the twin draws its own per run)")
        lines.append("imu = { " + ", ".join(f"{n} = {_num(v)}" for n, v in sensor.items()) + " }")
    motor = {n: e["value"] for n, e in params.items() if PARAMETERS[_base(n)].group == "motor" and e["identifiable"]}
    if motor:
        lines.append("motor = { " + ", ".join(f"{n} = {_num(v)}" for n, v in motor.items()) + " }")
    if twin is not None and twin.get("values") is None:  # no rigid-body twin reproduces it
        lines.append(f"# the twin cannot be given this robot ({twin.get('why')}): [plant] holds its physical values")
        twin = None
    if twin is not None:
        phys = {n: e["value"] for n, e in params.items() if PARAMETERS[_base(n)].group == "plant"}
        lines.append("# the robot's physical parameters (SI), as fitted; [plant] holds the twin's that reproduce them")
        lines.append("physical = { " + ", ".join(f"{n} = {_num(v)}" for n, v in phys.items()) + " }")
        lines.append(f"# the twin's stepping at {twin['control_rate_hz']:g} Hz control, {twin['physics_rate_hz']:g} Hz "
                     f"physics (twin.calibrate.robot.to_twin)")
        lines.append(f"twin_rates = [{_num(twin['control_rate_hz'])}, {_num(twin['physics_rate_hz'])}]")
    lines.append("")
    scale = {}
    entries = dict(params)  # a wheel inertia out of plant.scale's range: the twin cannot run the robot (below)
    if twin is not None:  # the twin's values for the identified parameters, and its wheels' compensation
        entries = {n: dict(e, value=twin["values"][n]) for n, e in params.items() if n in twin["values"]}
        for n in ("n_wa", "n_wd"):  # the wheels: the twin's compensation (not fitted)
            factor = twin["values"][n] / getattr(NOMINAL, n)
            if abs(factor - 1.0) <= 1e-9:
                continue
            entries[n] = {"value": twin["values"][n], "identifiable": True, "unit": "kg·m²"}
    outside = []
    if geometry is not None:
        r, b = geometry
        if not (math.isclose(r, NOMINAL.r, rel_tol=1e-6) and math.isclose(b, NOMINAL.b, rel_tol=1e-6)):
            outside.append(f"its wheel radius {r:.4g} m and track {2 * b:.4g} m are not the twin's "
                           f"({NOMINAL.r:.4g} m, {2 * NOMINAL.b:.4g} m)")
    for n, e in entries.items():
        if n in PARAMETERS and PARAMETERS[n].group == "plant" and e["identifiable"] or n in ("n_wa", "n_wd"):
            factor = e["value"] / getattr(NOMINAL, n)
            if not SCALE_RANGE[0] <= factor <= SCALE_RANGE[1]:
                outside.append(f"{n} = {e['value']:.4g} {e['unit']} is {factor:.3g} × Table III's")
                continue
            scale[n] = factor
    if outside:
        # the calibration stands (report.json, [calibration] above); only the twin, Table III scaled,
        # cannot run this robot: said here, and by 'twin run --plant' in one line
        why = (f"{'; '.join(outside)}: the twin is Table III's robot, its wheels and track as they are and "
               f"its masses and inertias scaled within plant.scale's [{SCALE_RANGE[0]:g}, {SCALE_RANGE[1]:g}]")
        lines.insert(lines.index("[calibration]") + 1, f"twin_runnable = false  # {why}")
        lines.insert(lines.index("[calibration]") + 2, f"twin_why = {json.dumps(why, ensure_ascii=False)}")
        return "\n".join(lines + [""])
    lines += ["[plant]", "# factors of Table III (twin.params.NOMINAL)",
              "scale = { " + ", ".join(f"{n} = {_num(v)}" for n, v in scale.items()) + " }", ""]
    if "imu_latency" in params and params["imu_latency"]["identifiable"]:
        lines += ["[sensors]", f"imu_latency = {_num(params['imu_latency']['value'])}  # s", ""]
    return "\n".join(lines)


def six_digits(v: float) -> float:
    """``v`` to six significant digits: what a fit knows, without its floating-point tail."""
    return float(f"{float(v):.6g}")


def _num(v: float) -> str:
    return repr(six_digits(v))


def plant_overrides(path) -> list[str]:
    """``--set`` items of a calibration.toml's [plant] and [sensors] (``twin run --plant``), or a
    one-line :class:`TwinError`."""
    import tomllib
    from pathlib import Path

    p = Path(path)
    try:
        doc = tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise TwinError(f"--plant {p}: no such file") from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise TwinError(f"--plant {p}: not a calibration.toml ({' '.join(str(exc).split())})") from None
    if (doc.get("calibration") or {}).get("twin_runnable") is False:
        raise TwinError(f"--plant {p}: the twin cannot run this calibrated robot: "
                        f"{doc['calibration'].get('twin_why', 'outside the twin’s plant.scale range')}")
    if "plant" not in doc or "calibration" not in doc:
        raise TwinError(f"--plant {p}: not a calibration.toml (it needs the [calibration] and [plant] tables "
                        f"'twin calibrate' writes)")
    allowed = {"plant": {"scale"}, "sensors": {"imu_latency"}}
    items = []
    for table, keys in allowed.items():
        for key, value in (doc.get(table) or {}).items():
            if key not in keys:
                raise TwinError(f"--plant {p}: [{table}] {key} is not taken from a calibration; allowed: "
                                f"{', '.join(sorted(keys))}")
            if isinstance(value, dict):
                text = "{" + ", ".join(f"{k} = {float(v)!r}" for k, v in value.items()) + "}"
            else:
                text = repr(value)
            items.append(f"{table}.{key}={text}")
    return items


def write_figure(cal, params: dict, validation, path) -> None:
    """figure.png: the fit over the log's first seconds, the residuals, the intervals and the
    validation's prediction error over the horizon."""
    # heavy: matplotlib, only when the figure is drawn
    from twin.outputs.report import load_matplotlib

    load_matplotlib(pyplot=True)  # signals held while its C++ modules load (an interrupt there broke them)
    import matplotlib
    import matplotlib.pyplot as plt

    f = cal.fit
    w = f.windows
    T = 1.0 / f.plant.control_rate
    model = "robot model" if getattr(cal, "model_kind", "twin") == "physical" else "twin"
    imu, _ = f.plant.predict(w, f.values, f.S, f.offsets)
    fig, ax = plt.subplots(2, 2, figsize=(12, 8), constrained_layout=True)
    # (a) gyro pitch rate: readings and the fitted windows, over the first 3 s of fitted windows
    a = ax[0, 0]
    show = w.t0 <= w.t0[0] + 1.5
    for i in np.flatnonzero(show):
        t = w.t0[i] + T * (np.arange(w.periods) + 1)
        a.plot(t, w.imu[i, :, 1], ".", color="0.55", ms=3, label="gyro y reading" if i == 0 else None)
        a.plot(t, imu[i, :, 1], "-", color="C0", lw=1.2, label=f"fitted {model} (each window)" if i == 0 else None)
    a.set_title("Fit: pitch rate, first 1.5 s of fitted windows", fontsize=10)
    a.set_xlabel("t [s]")
    a.set_ylabel("gyro y [rad/s]")
    a.legend(loc="upper right", fontsize=8)
    # (b) normalised residuals per channel
    b = ax[0, 1]
    r = f.residuals
    N = w.periods
    chans = ["gyro x", "gyro y", "gyro z", "accel x", "accel z"]
    E = N * 5 + (N + 1) * 2  # the encoders' residuals end here; the motor currents' (if any) follow
    parts = [r[:, :N * 5].reshape(len(r), N, 5)[..., c].ravel() for c in range(5)] + [r[:, N * 5:E].ravel()]
    labels = chans + ["encoders"]
    if r.shape[1] > E and getattr(w, "current", None) is not None:
        parts.append(r[:, E:].ravel())
        labels.append("current")
    b.boxplot(parts, tick_labels=labels, showfliers=False, whis=(2.5, 97.5))
    b.axhline(0.0, color="0.3", lw=0.8)
    for y in (-1.96, 1.96):
        b.axhline(y, color="C3", lw=0.8, ls="--")
    b.set_title(f"Residuals / σ (whiskers 2.5–97.5 %), s = {math.sqrt(cal.info.s2):.2f}", fontsize=10)
    b.set_ylabel("residual / σ")
    # (c) intervals of the physical parameters as factors of the log's model
    c = ax[1, 0]
    phys = [n for n in f.plant.names if PARAMETERS[_base(n)].group in ("plant", "motor")]
    # a logarithmic axis over factors 1/10 … 10: an interval reaching past it (a parameter the log
    # does not identify can span decades) is drawn to the edge with an arrow, so that it does not
    # squeeze every other interval into a dot
    edge = (0.1, 10.0)
    for k, n in enumerate(phys):
        e = params[n]
        base = e["nominal"]
        lo, hi = e["ci95"][0] / base, e["ci95"][1] / base
        col = "C0" if e["identifiable"] else "C3"
        c.plot([min(max(lo, edge[0]), edge[1]), min(max(hi, edge[0]), edge[1])], [k, k], "-", color=col, lw=3)
        c.plot([min(max(e["value"] / base, edge[0]), edge[1])], [k], "o", color=col)
        if lo < edge[0]:
            c.plot([edge[0]], [k], "<", color=col, ms=8)
        if hi > edge[1]:
            c.plot([edge[1]], [k], ">", color=col, ms=8)
    c.set_xscale("log")
    c.set_xlim(edge[0] / 1.15, edge[1] * 1.15)
    c.axvline(1.0, color="0.4", lw=0.8, ls=":")
    c.set_yticks(range(len(phys)), [n + ("" if params[n]["identifiable"] else " (not identified)") for n in phys])
    c.set_xlabel("fitted value / the log's model (95 % interval; arrows: beyond ×10 or ÷10)")
    c.set_title("Physical parameters (red: not identified)", fontsize=10)
    # (d) validation or the latency profile
    d = ax[1, 1]
    if validation:
        v = validation[0]
        h = np.arange(1, len(v["nominal"]["_horizon"]) + 1) * T
        d.plot(h, v["nominal"]["_horizon"], "-o", ms=3, color="C3", label=f"nominal ({v['nominal']['rms_sigma']:.2f} σ)")
        d.plot(h, v["calibrated"]["_horizon"], "-o", ms=3, color="C0",
               label=f"calibrated ({v['calibrated']['rms_sigma']:.2f} σ)")
        d.axhline(1.0, color="0.4", lw=0.8, ls=":")
        d.set_xlabel("prediction horizon [s]")
        d.set_ylabel("RMS prediction error / σ")
        d.set_title(f"Held-out log, {v['windows']} windows: model error nominal / calibrated = {v['ratio']:.2f}",
                    fontsize=10)
        d.legend(fontsize=8)
    else:
        prof = params.get("imu_latency", {}).get("profile") or {}
        if prof:
            d.bar([float(k) * 1e3 for k in prof], list(prof.values()), width=3.0, color="C0")
            d.set_xlabel("IMU latency [ms]")
            d.set_ylabel("cost ½Σr²")
            d.set_title("IMU latency profile (no --validate log)", fontsize=10)
        else:
            d.axis("off")
            d.text(0.5, 0.5, "no held-out log: give one with --validate LOG\nto see how well the calibrated model "
                             "predicts it", ha="center", va="center", fontsize=10, color="0.35",
                   transform=d.transAxes)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def strip_private(validation):
    """The validation entries without the figure's per-step series."""
    if not validation:
        return validation
    out = []
    for e in validation:
        e = dict(e)
        for k in ("nominal", "calibrated"):
            e[k] = {kk: vv for kk, vv in e[k].items() if not kk.startswith("_")}
        out.append(e)
    return out


__all__ = ["calibration_toml", "plant_overrides", "report_doc", "strip_private", "write_figure"]
