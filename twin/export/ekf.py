"""The twin's EKF (:class:`estimation.ekf.EKFEstimator`) as C: ``mtwip_estimator.h`` and
``mtwip_estimator.c``.

The algorithm is static C (``twin/export/c/estimator_ekf.h`` and ``.c``): the compiled kernel's
IMU-driven step (``estimation/_ekf.c``), the coasting step on equation (1), the sensor front end,
the fusion step's decisions, the policies and the forward prediction across the latency, each
sum in the order of the path the twin runs by default (the compiled kernel where it is built).
What is generated here is every number of the filter, as an exact C literal
(:func:`twin.export.literals.literal`) in one ``static const`` configuration, and the sizes the
state needs (the model's uncertain parameters, the latency's reach, the latency watch's window).
The same estimator gives the same bytes.

Supported: an estimator as the twin builds it (any robot, sensors, latencies, IMU rate, gate
probability, consider states, learning time and model uncertainty), with the default sampling of
the twin's own runs (IMU rows the means over their period, commands held, a constant period);
:meth:`~estimation.ekf.EKFEstimator.set_sampling`'s other variants and the reference path
(``compiled=False``) are refused with a one-line :class:`~twin.errors.TwinError`.
"""
from __future__ import annotations

import math

import numpy as np

from estimation import ekf_config as P
from estimation.ekf import EKFEstimator
from estimation.ekf_filter import kernel_config
from estimation.model import SENSITIVITY_STEP, TORQUE_TOLERANCE
from twin.errors import TwinError
from twin.export.literals import check_precision, integer, literal, static_text

_SIZES = "/* @MTWIP_EKF_SIZES@ */"
_CONFIG = "/* @MTWIP_EKF_CONFIG@ */"
_GAPS = 8  # the latency watch's arrival gaps kept per triad (LatencyWatch.observe)
_MAD_SCALE = 1.4826  # the median absolute deviation's σ factor of the latency watch's winsorising
_FD_STEP = 1e-6  # the coasting step's relative forward-difference step (Coasting.predict)
# float32: 1e-6 is 8 ulps of float32, and the coasting step's derivatives would be rounding noise (a 1.5 s IMU
# dropout on paper-exp3 left θ 2.8 rad off the float64 build); √ε of float32 instead, with the synthetic sample
# formed from the model's increments (the configuration's `increments`): 1.3e-4 rad there. In float64 a step
# of √ε_float32 would move the estimate by at most 1e-7 rad on sensor-faults; float64 keeps the twin's 1e-6
_FD_STEP_FLOAT32 = math.sqrt(float(np.finfo(np.float32).eps))
_PRIOR_TINY = 1e-12  # the prior's variance of the states known exactly at rest (StrapdownFilter.prior)
_MAX_PAIRWISE = 128  # the latency watch's sums are NumPy's pairwise ones of at most this many rows

_MODEL_FIELDS = ("dt", "m11", "m12", "m22", "n_bla", "d_b", "d_w", "g_b", "yaw_damping", "m33", "b_r", "g", "r", "xi",
                 "zi", "tau_max", "i_tau", "sigma_tau", "c_e", "tol")
_MODEL_INTS = ("msub", "has_motor", "compensates")



def _model_values(m, what: str) -> dict:
    """The numbers of :class:`estimation.model.EstimatorModel` ``m`` that the C model reads."""
    p = m.plant
    for name in ("m11", "m12", "m22"):
        if getattr(p, name) != getattr(m, name):
            raise TwinError(f"cannot export the EKF: {what}'s {name} differs between its parameters and its plant "
                            f"({getattr(m, name)!r} against {getattr(p, name)!r}); allowed: an EstimatorModel as "
                            f"estimation.model builds it")
    if p.b / p.r != m.b_r:
        raise TwinError(f"cannot export the EKF: {what}'s b/r differs between its parameters and its plant")
    motor = m.motor is not None
    v = {"dt": m.dt, "m11": m.m11, "m12": m.m12, "m22": m.m22, "n_bla": p.n_bla, "d_b": p.d_b, "d_w": p.d_w,
         "g_b": p.g_b, "yaw_damping": p.yaw_damping, "m33": p.m33, "b_r": m.b_r, "g": m.g, "r": m.r, "xi": m.xi,
         "zi": m.zi, "tau_max": m.tau_max if motor else 0.0, "i_tau": m.i_tau if motor else 0.0,
         "sigma_tau": m.sigma_tau if motor else 0.0, "c_e": m.c_e, "tol": TORQUE_TOLERANCE,
         "msub": int(m.substeps), "has_motor": int(motor), "compensates": int(motor and bool(m.compensates))}
    return v


def _model_init(v: dict, precision: str, indent: str) -> str:
    items = [f".{k} = {literal(v[k], precision)}" for k in _MODEL_FIELDS] + \
            [f".{k} = {integer(v[k])}" for k in _MODEL_INTS]
    return "{\n" + indent + (",\n" + indent).join(items) + "}"


# exact: the twin's arithmetic operation for operation (the float64 build is the Python EKF bit for bit);
# lean: a microcontroller's, for the costly steps only: the coasting step's sample Jacobian by the chain rule
# through the model's four inputs, J Pa Jᵀ and the Joseph update factored on the symmetric half, squares as
# products, the latency watch's correlations in one pass. The same equations: the lean build differs from
# the exact one by rounding and the forward differences' truncation (tests/test_export_ekf.py bounds it)
ARITHMETICS = ("exact", "lean")


def default_arithmetic(precision: str) -> str:
    """float64 is the twin's own arithmetic; float32 is for a microcontroller: lean."""
    return "lean" if precision == "float32" else "exact"


def check_arithmetic(arithmetic: str) -> None:
    if arithmetic not in ARITHMETICS:
        raise TwinError(f"unknown EKF arithmetic {arithmetic!r}; allowed: {', '.join(ARITHMETICS)}")


def check_supported(estimator) -> None:
    """A one-line :class:`~twin.errors.TwinError` if ``estimator`` was built or set up with an option
    the C does not implement."""
    if not isinstance(estimator, EKFEstimator):
        raise TwinError(f"twin.export.ekf exports an estimation.ekf.EKFEstimator, got "
                        f"{type(estimator).__module__}.{type(estimator).__qualname__}")
    sampling = (estimator.imu_sampling, estimator.command_semantics, estimator.periods)
    if sampling != ("mean", "held", "constant"):
        raise TwinError(f"cannot export the EKF with set_sampling(imu={sampling[0]!r}, commands={sampling[1]!r}, "
                        f"periods={sampling[2]!r}); allowed: the default imu=\"mean\", commands=\"held\", "
                        f"periods=\"constant\" (the twin's own runs)")
    if estimator._compiled is False:
        raise TwinError("cannot export the EKF built with compiled=False (the filterpy reference path); allowed: "
                        "compiled=None or True, whose compiled-kernel path the C reproduces")


def config_values(estimator, precision: str = "float64") -> tuple[dict, dict]:
    """(sizes, values): the C sizes and every number of the configuration, by the C field's name, for
    ``precision``."""
    check_supported(estimator)
    f, m, front = estimator.filter, estimator.model, estimator.front
    inside = front.inside
    kc = kernel_config(f, estimator.gates, estimator.imu_gates, estimator.max_rejects_in_row, inside.half,
                       inside.gate)
    names = tuple(f.unc_names)
    cache = m.__dict__.get("_perturbed", {})
    perturbed = [_model_values(cache[n] if n in cache else m.perturbed(n, SENSITIVITY_STEP), f"the model with "
                                                                                               f"{n} perturbed")
                 for n in names]
    main = _model_values(m, "the estimator's model")
    watches = bool(front.watches)
    if watches and P.WATCH_WINDOW > _MAX_PAIRWISE:
        raise TwinError(f"cannot export the EKF's latency watch with a window of {P.WATCH_WINDOW} rows; allowed: at "
                        f"most {_MAX_PAIRWISE}")
    reach = max(estimator.d_imu, estimator.d_enc, P.WATCH_MAX_LAG if watches else 0)
    sizes = {"MTWIP_EKF_NK": len(names), "MTWIP_EKF_RING": reach + 2 * estimator.every + 2,
             "MTWIP_EKF_WATCH_W": P.WATCH_WINDOW if watches else 1,
             "MTWIP_EKF_WATCH_N": P.WATCH_WINDOW + P.WATCH_MAX_LAG + 5 if watches else 1, "MTWIP_EKF_GAPS": _GAPS}
    hold_from = estimator._consider.hold_from
    spec_g = m.imu.gyro
    v = {
        "model": main,
        "perturbed": perturbed or [main],
        "unc_var": [float(u) for u in f.unc_var] or [0.0],
        "dt": kc.dt, "r": kc.r, "xi": kc.xi, "zi": kc.zi, "b_r": kc.b_r, "alpha0": kc.alpha0, "delta": kc.delta,
        "g_var": kc.g_var, "a_var": kc.a_var, "bias_q": kc.bias_q, "gate": list(kc.gate),
        "imu_gate": list(kc.imu_gate), "lim": list(kc.lim), "inside_half": kc.inside_half,
        "stuck_sigmas": kc.stuck_sigmas, "tilt_limit": kc.tilt_limit, "tilt_var_max": kc.tilt_var_max,
        "trapezoid_var": kc.trapezoid_var, "gyro_extrapolation_samples": kc.gyro_extrapolation_samples,
        "accel_variance_factor": kc.accel_variance_factor, "restore_inflation": kc.restore_inflation,
        "restore_jitter": kc.restore_jitter,
        "a_sf": f.a_sf, "prior_tiny": _PRIOR_TINY, "prior_bias_var": spec_g.turn_on_bias ** 2 + _PRIOR_TINY,
        "prior_edge_var": f.delta ** 2 / 24.0, "prior_g_sf": f.g_sf + _PRIOR_TINY, "prior_a_sf": f.a_sf + _PRIOR_TINY,
        "prior_v_var_moving": P.MAX_RIM_SPEED ** 2 / 3.0, "heading_var_max": P.HEADING_VAR_MAX,
        "rebase_var": f.delta ** 2 / 12.0,
        "rails": list(front.rails), "max_wheel_rate": front.max_wheel_rate, "enc_range": front.enc_range,
        "hold_from": hold_from if math.isfinite(hold_from) else 0.0, "control_rate": 1.0 / m.dt,
        "sens_step": SENSITIVITY_STEP, "fd_step": _FD_STEP_FLOAT32 if precision == "float32" else _FD_STEP, "sqrt_2": math.sqrt(2.0),
        "sqrt_2pi": math.sqrt(2.0 * math.pi),
        "square": 2.0,
        "watch_rho": P.WATCH_RHO, "watch_margin": P.WATCH_MARGIN, "watch_clip": P.WATCH_CLIP, "mad_scale": _MAD_SCALE,
        "torque_sign": front.torque_sign,
        # integers
        "every": estimator.every, "d_imu": estimator.d_imu, "d_enc": estimator.d_enc,
        "max_rejects_in_row": estimator.max_rejects_in_row, "accel_max_in_row": P.ACCEL_MAX_IN_ROW,
        "has_hold": int(math.isfinite(hold_from)), "watches": int(watches), "watch_window": P.WATCH_WINDOW,
        "watch_every": P.WATCH_EVERY, "watch_max_lag": P.WATCH_MAX_LAG, "watch_persist": P.WATCH_PERSIST,
        "stale_check": [int(bool(s)) for s in front.stale_check],
        "increments": int(precision == "float32"),
        "consider": [int(bool(b)) for b in estimator._consider.mask],
        "untaught": [int(bool(b)) for b in estimator._untaught],
    }
    return sizes, v


_INTS = {"increments", "every", "d_imu", "d_enc", "max_rejects_in_row", "accel_max_in_row", "has_hold", "watches", "watch_window",
         "watch_every", "watch_max_lag", "watch_persist", "stale_check", "consider", "untaught"}


def _config_text(v: dict, precision: str) -> str:
    lines = ["/* The EKF's configuration, every number of the filter (generated by twin export from the",
             "   estimator as the twin built it: exact literals, do not edit). */",
             "static const mtwip_ekf_config_t mtwip_ekf_config = {"]
    ind = "    "
    lines.append(f"{ind}.model = {_model_init(v['model'], precision, ind * 2)},")
    lines.append(f"{ind}.perturbed = {{" + ", ".join(_model_init(p, precision, ind * 2) for p in v["perturbed"]) + "},")
    for key, val in v.items():
        if key in ("model", "perturbed"):
            continue
        if isinstance(val, list):
            body = ", ".join(integer(x) if key in _INTS else literal(x, precision) for x in val)
            lines.append(f"{ind}.{key} = {{{body}}},")
        else:
            lines.append(f"{ind}.{key} = {integer(val) if key in _INTS else literal(val, precision)},")
    lines[-1] = lines[-1].rstrip(",")
    lines.append("};")
    return "\n".join(lines)


def emit(estimator, precision: str, arithmetic: str = "exact") -> dict[str, str]:
    """``{"mtwip_estimator.h": ..., "mtwip_estimator.c": ...}`` for the built EKF ``estimator`` in
    ``precision`` ("float64" or "float32") with ``arithmetic`` (:data:`ARITHMETICS`)."""
    check_precision(precision)
    check_arithmetic(arithmetic)
    sizes, values = config_values(estimator, precision)
    sizes["MTWIP_EKF_LEAN"] = int(arithmetic == "lean")
    header, source = static_text("estimator_ekf.h"), static_text("estimator_ekf.c")
    if _SIZES not in header or _CONFIG not in source:
        raise TwinError("twin/export/c/estimator_ekf.h or .c lacks its generated part's marker; reinstall the twin")
    size_text = "\n".join([f"/* generated from the estimator by twin export ({precision}) */"] +
                          [f"#define {k} {integer(n)}" for k, n in sizes.items()])
    return {"mtwip_estimator.h": header.replace(_SIZES, size_text),
            "mtwip_estimator.c": source.replace(_CONFIG, _config_text(values, precision))}


__all__ = ["ARITHMETICS", "check_arithmetic", "check_supported", "config_values", "default_arithmetic", "emit"]
