"""The IMU's noise measured from a log's own readings, and the noise figures a replay uses.

A log's noise figures (``[imu.gyro]``/``[imu.accel]`` ``noise_density`` or ``sigma``, or a
version-1 log's scenario) may be missing, or wrong for the readings as logged: a robot that
logs one row every 30 ms of a 1 kHz loop, with its motors shaking the IMU, has noise 25–100×
the datasheet's density at that rate, and an estimator told the datasheet's figure then
rejects most readings. This module measures the noise from the readings themselves, while the
robot moves.

**Method: variance estimation by differences** (the difference-based noise estimators of
nonparametric regression): for readings y_i = f(t_i) + e_i with a smooth motion f and white
noise e of variance σ², a linear combination r_i = Σ_j w_j y_{i+j} of k + 1 consecutive rows
whose weights annihilate every polynomial of degree below k removes the motion to order
f^(k) Δt^k, and has variance σ² Σ_j w_j²; normalised to Σ w² = 1, each r_i estimates σ.
The weights are the k-th divided difference's, w_j ∝ 1 / ∏_{l≠j} (t_{i+j} − t_{i+l}), so
irregular row times (a logger's jitter) are handled exactly: on a regular grid they are the
binomial coefficients (−1)^j C(k, j) over √C(2k, k) (Rice's k = 1, Gasser, Sroka and
Jennen-Steinmetz's k = 2 pseudo-residuals, which they give for unequal spacing, and the
higher orders of Hall, Kay and Titterington):

* J. Rice, "Bandwidth choice for nonparametric regression", *Annals of Statistics* 12(4),
  1215–1230, 1984.
* T. Gasser, L. Sroka, C. Jennen-Steinmetz, "Residual variance and residual pattern in
  nonlinear regression", *Biometrika* 73(3), 625–633, 1986.
* P. Hall, J. W. Kay, D. M. Titterington, "Asymptotically optimal difference-based
  estimation of variance in nonparametric regression", *Biometrika* 77(3), 521–528, 1990.

Order :data:`ORDER` = 3: at 30 Hz a balancing robot's motion (poles of 5–20 rad/s, ωΔt up to
0.6) still leaks into a first or second difference, while each order costs only a little
variance (the σ estimate's relative standard error grows from 0.87/√n at k = 1 to 1.08/√n
at k = 3). The scale of the residuals is robust, so a stand-up, a push or a catch (a few
per cent of the rows, far outside the noise) does not inflate it: the median absolute
deviation (×1.4826) first, then twice the root mean square of the residuals within
:data:`CLIP` such σ, corrected for the cut (a Gaussian's variance inside ±c σ is
1 − 2 c φ(c) / (2 Φ(c) − 1) of it), which keeps nearly the efficiency of the plain variance
(the MAD alone has 37 %). A window is left out where it contains a railed reading (within
1.5 ADC steps of the range: a clipped sample is not noise), a triad repeated three or more
times in a row (a stuck sensor), a duplicated time or a gap (its span over :data:`GAP` times
the median window's).
The measured σ includes the ADC step's q²/12 (the estimators add q²/12 themselves, so the
white part √(σ² − q²/12) is what a noise density says); the density equivalent is
σ / √(row rate) (a mean over one row interval of white noise of that density has σ).

What differences cannot remove is motion that is not smooth at the rows' scale: a torque held
over each control period steps the wheels' acceleration every period (a step in the forward
specific force, a kink in the pitch rate), and where the controller answers each reading's
noise those steps are as frequent as the rows. On the independent simulator's 200 Hz logs
(torques held over 5 ms) the measured σ is 1.6–1.8 × the true one on the pitch gyro and
1.3–1.5 × on the forward accelerometer, inside :data:`FACTOR`. Regressing the commands' share
out does not work: the commands answer the very noise being measured (it removed up to 85 %
of a twin log's yaw-gyro noise), so the estimate is left biased high there (an estimator told
it is cautious, not overconfident).

**Allan variance** (IEEE Std 952-1997, Annex C; overlapping estimator) where the log has at
least :data:`ALLAN_MIN_ROWS` usable rows of an axis: the Allan deviation σ_A(τ) at τ = m τ_0
(m = 1, 2, 4, … up to a ninth of the rows; τ_0 the median row interval, rows taken as
equally spaced), with the white-noise figure σ_A(τ_0) (= the per-sample σ for white noise),
the bias instability min σ_A / 0.664 (the flicker floor) and, where the curve rises at its
end (slope ≥ :data:`ALLAN_RISE`), the rate random walk σ_A(τ) √(3/τ). It is of the readings
themselves: on a moving robot the motion is in it, and where σ_A(τ_0) exceeds the
differencing σ by :data:`ALLAN_MOTION` it is reported as an upper bound ("motion": true).
The estimators never take the Allan figures: only the white noise reaches them.

**The verdict** on the figures a log gives: the measured per-sample σ against the one the
figures imply at the estimators' IMU rate, √(density² · rate + q²/12): "contradict" where the
ratio is beyond :data:`FACTOR` either way and the given σ lies outside the measurement's
99 % interval, else "agree"; "unmeasured" with fewer than :data:`MIN_RESIDUALS` usable
windows.

**Which figures a replay uses** (:func:`choose`; ``twin replay --noise``): ``log`` (the
default): the log's figures (a version-2 log's ``noise_density``/``sigma``, a version-1 log's
named scenario), except where it gives none or the data contradict them: then the measured
ones (a log too short to measure keeps the log's or the datasheet's, with a note);
``given``: the log's figures whatever the data say (those the reader assumed where it gives
none: the replay of a twin's run as the run went, even where its estimator was told wrong
figures); ``measured``: the measured ones (a log too short is one line); ``datasheet``: the IMU
part's (the preset's, default MPU-6050). One figure per triad reaches the estimators, as they take
one: the largest of the three axes' (told less noise than an axis has, an estimator is
overconfident on it; told more, only cautious). The EKF takes it through the IMU's
``noise_density`` (per-sample σ = density · √rate); the two-state Kalman filter ``kalman2``
is tuned from measured figures (R_measure the accelerometer angle's variance σ_a²/g²,
Q_angle the gyro's σ_g² Δt, in its degrees); with the log's or the datasheet's figures it
keeps its published tuning, as in the twin's own loop; the complementary filter takes no
noise figure.
"""
from __future__ import annotations

import math
from dataclasses import replace
from statistics import NormalDist

import numpy as np

from twin.errors import TwinError
from twin.logs.format import imu_preset_of, rows_times
from twin.sensors.specs import preset_name
from twin.sensors.specs import IMU_PRESETS

ORDER = 3  # the differences' order k: motion to order f^(k) Δt^k is removed (see the module docstring)
MAD_SCALE = 1.482602218505602  # 1/Φ⁻¹(3/4): the MAD of N(0, σ²) is σ / 1.4826
CLIP = 4.0  # residuals beyond this many robust σ are motion (a stand-up, a push), not noise
GAP = 1.5  # a window spanning more than this × the median window's straddles a gap: left out
MIN_RESIDUALS = 50  # usable windows an axis needs for a measurement (σ's relative error about 15 %)
FACTOR = 2.0  # a given σ within this factor of the measured one is not contradicted (variance: 4×)
CONFIDENCE = 0.99  # and not where it lies inside the measurement's interval of this confidence
ALLAN_MIN_ROWS = 1000  # usable rows an axis needs for its Allan deviation
ALLAN_MIN_CLUSTERS = 9  # the longest τ keeps at least this many clusters (τ ≤ T/9)
ALLAN_FLICKER = 0.664  # the flicker floor of σ_A over the bias instability (IEEE Std 952-1997)
ALLAN_RISE = 0.3  # a log-log slope at the longest τs at least this: a random walk shows there
ALLAN_MOTION = 1.5  # σ_A(τ_0) above this × the differencing σ: the readings hold motion
MODES = ("log", "given", "measured", "datasheet")
AXES = ("x", "y", "z")
TRIADS = {"gyro": "rad/s", "accel": "m/s²"}
G = 9.81  # m/s²: kalman2's accelerometer angle, tilt ≈ f / g


def _clip_factor(c: float) -> float:
    """E[x² | |x| < c] for x ~ N(0, 1): the variance left inside a cut at ±c σ."""
    nd = NormalDist()
    inside = 2.0 * nd.cdf(c) - 1.0
    return 1.0 - 2.0 * c * nd.pdf(c) / inside


def _relative_se(order: int, n: int) -> float:
    """The relative standard error of the σ estimate from n overlapping k-th-difference residuals:
    a variance estimate's is √(2 (1 + 2 Σ_j ρ_j²) / n) (ρ_j the residuals' autocorrelation,
    (−1)^j C(2k, k+j) / C(2k, k)), half that for σ."""
    c = math.comb(2 * order, order)
    s = sum((math.comb(2 * order, order + j) / c) ** 2 for j in range(1, order + 1))
    return 0.5 * math.sqrt(2.0 * (1.0 + 2.0 * s) / max(n, 1))


def difference_weights(t: np.ndarray, order: int = ORDER) -> tuple[np.ndarray, np.ndarray]:
    """(w (m, k+1), span (m,)) for the m = n − k windows of k + 1 consecutive times ``t`` (s):
    the k-th divided difference's weights, normalised to Σ w² = 1 (NaN where two times of a
    window coincide), and each window's span (s)."""
    n = len(t)
    m = n - order
    if m <= 0:
        return np.empty((0, order + 1)), np.empty(0)
    win = np.lib.stride_tricks.sliding_window_view(t, order + 1)
    span = win[:, -1] - win[:, 0]
    # relative times in units of the window's span: the normalised weights do not depend on the
    # scale, and moderate numbers keep the products far from under- or overflow
    with np.errstate(divide="ignore", invalid="ignore"):
        x = (win - win[:, :1]) / span[:, None]
        w = np.ones_like(x)
        for j in range(order + 1):
            for l in range(order + 1):
                if l != j:
                    w[:, j] = w[:, j] / (x[:, j] - x[:, l])
        w = w / np.sqrt((w * w).sum(axis=1))[:, None]
    bad = ~np.isfinite(w).all(axis=1)
    w[bad] = np.nan
    return w, span


def robust_sigma(r: np.ndarray) -> float:
    """σ of residuals ``r`` that are N(0, σ²) but for a minority far outside: the MAD's σ, then
    twice the RMS within :data:`CLIP` σ of the latest, corrected for the cut."""
    if r.size == 0:
        return math.nan
    s = MAD_SCALE * float(np.median(np.abs(r - np.median(r))))
    if not s > 0.0:  # more than half the residuals equal: no spread to measure
        return s
    k = _clip_factor(CLIP)
    for _ in range(2):
        inside = r[np.abs(r) <= CLIP * s]
        s = math.sqrt(float(np.mean(inside * inside)) / k)
    return s


CHUNK = 262_144  # windows whose weights are made at a time: a long log's measurement holds no (n, k+1) arrays


def difference_sigma(t, y, order: int = ORDER, exclude=None) -> dict:
    """The white-noise σ per sample of readings ``y`` (n,) at times ``t`` (n,) s, by differences
    of ``order`` (see the module docstring). ``exclude`` (n,) bool: rows no window may hold (a
    railed or stale reading). Returns ``sigma`` (NaN with fewer than :data:`MIN_RESIDUALS`
    windows), ``residuals`` (the windows used), ``rows`` (the rows they hold), ``se_rel`` the
    estimate's relative standard error, ``order``, ``left_out`` {"excluded", "gaps",
    "duplicated"}: windows left out and why. Memory: the residuals (8 bytes a row) and
    :data:`CHUNK` windows' weights at a time."""
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    ok = np.isfinite(t) & np.isfinite(y)
    t, y = t[ok], y[ok]
    ex = np.zeros(len(t), bool) if exclude is None else np.asarray(exclude, bool)[ok]
    out = {"order": order, "sigma": math.nan, "residuals": 0, "rows": 0, "se_rel": math.nan,
           "left_out": {"excluded": 0, "gaps": 0, "duplicated": 0}}
    m = len(t) - order
    if m <= 0:
        return out
    span = t[order:] - t[:-order]
    dt = np.diff(t)
    # a window with two equal times (a duplicated row) has no divided difference
    dup = np.lib.stride_tricks.sliding_window_view(dt, order).min(axis=1) <= 0.0
    typical = float(np.median(span[~dup])) if (~dup).any() else math.nan
    gap = ~dup & (span > GAP * typical)
    exw = np.lib.stride_tricks.sliding_window_view(ex, order + 1).any(axis=1)
    keep = ~dup & ~gap & ~exw
    r = np.empty(int(keep.sum()))
    done = 0
    for a in range(0, m, CHUNK):
        b = min(m, a + CHUNK)
        idx = np.flatnonzero(keep[a:b]) + a
        if not idx.size:
            continue
        w, _ = difference_weights(t[a:b + order], order)
        yw = np.lib.stride_tricks.sliding_window_view(y[a:b + order], order + 1)
        r[done:done + idx.size] = (w[idx - a] * yw[idx - a]).sum(axis=1)
        done += idx.size
    bad = ~np.isfinite(r)  # (weights of nearly equal times that overflowed: as a duplicated row)
    r = r[~bad]
    out["left_out"] = {"excluded": int((exw & ~dup & ~gap).sum()), "gaps": int(gap.sum()),
                       "duplicated": int(dup.sum() + bad.sum())}
    out["residuals"] = int(r.size)
    rows = np.zeros(len(t), bool)
    kept = np.flatnonzero(keep)
    for j in range(order + 1):
        rows[kept + j] = True
    out["rows"] = int(rows.sum())
    if r.size >= MIN_RESIDUALS:
        out["sigma"] = robust_sigma(r)
        out["se_rel"] = _relative_se(order, r.size)
    return out


def allan_deviation(y, tau0: float, min_clusters: int = ALLAN_MIN_CLUSTERS) -> tuple[np.ndarray, np.ndarray]:
    """(τ (j,) s, σ_A (j,)) the overlapping Allan deviation of rows ``y`` taken τ_0 s apart
    (IEEE Std 952-1997, Annex C), at τ = m τ_0 for m = 1, 2, 4, … while m ≤ n / ``min_clusters``."""
    y = np.asarray(y, dtype=float)
    n = len(y)
    theta = np.concatenate([[0.0], np.cumsum(y)]) * tau0  # the integral at each row boundary
    taus, devs = [], []
    m = 1
    while m <= n // min_clusters and n - 2 * m >= 1:
        d = theta[2 * m:] - 2.0 * theta[m:-m] + theta[:-2 * m]
        tau = m * tau0
        taus.append(tau)
        devs.append(math.sqrt(float(np.mean(d * d)) / (2.0 * tau * tau)))
        m *= 2
    return np.array(taus), np.array(devs)


def allan_figures(y, tau0: float, diff_sigma: float) -> dict | None:
    """The Allan deviation's figures of rows ``y`` (see the module docstring), or None with fewer
    than :data:`ALLAN_MIN_ROWS` rows."""
    y = np.asarray(y, dtype=float)
    if len(y) < ALLAN_MIN_ROWS:
        return None
    taus, devs = allan_deviation(y, tau0)
    if len(taus) < 3:
        return None
    i = int(np.argmin(devs))
    slope = float(math.log(devs[-1] / devs[-2]) / math.log(taus[-1] / taus[-2])) if devs[-2] > 0 else math.nan
    motion = bool(devs[0] > ALLAN_MOTION * diff_sigma) if math.isfinite(diff_sigma) else False
    return {"tau_s": taus.tolist(), "adev": devs.tolist(), "white_sigma": float(devs[0]),
            "white_density": float(devs[0] * math.sqrt(tau0)), "bias_instability": float(devs[i] / ALLAN_FLICKER),
            "bias_instability_tau_s": float(taus[i]),
            "random_walk": float(devs[-1] * math.sqrt(3.0 / taus[-1])) if slope >= ALLAN_RISE else None,
            "end_slope": slope, "motion": motion}


# ---- a log's noise -----------------------------------------------------------------------------------
def _imu_axes(log) -> tuple[np.ndarray, np.ndarray]:
    """(gyro, accel) (n, 3) in the IMU's own axes: a clipped reading is clipped there."""
    g, a = log.gyro, log.accel
    if log.imu_rotation is not None:  # v_body = C v_imu, rows: V_imu = V_body C
        c = np.array(log.imu_rotation, dtype=float)
        g, a = rows_times(g, c), rows_times(a, c)  # elementwise: the same bits on every CPU
    return g, a


def _railed(v: np.ndarray, triad) -> np.ndarray:
    """(n, 3) readings within 1.5 ADC steps of the range's ends (the twin's codes run from
    −2^(b−1) to 2^(b−1) − 1 steps): a clipped sample, no measure of the noise."""
    lsb = triad.lsb
    top, bottom = lsb * ((1 << (triad.bits - 1)) - 1), -lsb * (1 << (triad.bits - 1))
    return (v >= top - 1.5 * lsb) | (v <= bottom + 1.5 * lsb)


def given_sigma(triad, rate: float) -> float:
    """The per-sample σ a triad's figures say at IMU ``rate`` (Hz), the ADC step's share included."""
    return math.sqrt(triad.white_sigma(1.0 / rate) ** 2 + triad.lsb ** 2 / 12.0)


def measure(log, order: int = ORDER) -> dict:
    """Each IMU axis's noise measured from ``log``'s readings (see the module docstring): {"gyro":
    {"x": {...}, "y", "z"}, "accel": ..., "row_rate_hz", "jitter", "rows"}; per axis ``sigma`` (per
    row, the ADC step included; NaN: too few windows), ``white_sigma`` (without it), ``density``
    (σ / √row rate), ``residuals``, ``rows``, ``railed_rows``, ``stale_rows``, ``se_rel``,
    ``allan`` (or None); ``jitter`` the rows' largest departure from their median interval (as a
    fraction of it, gaps aside) and ``gaps`` the intervals over :data:`GAP` times it."""
    t = np.asarray(log.imu_t, dtype=float)
    g, a = _imu_axes(log)
    dt = np.diff(t)
    pos = dt[dt > 0]
    median = float(np.median(pos)) if pos.size else math.nan
    rate = 1.0 / median if median > 0 else math.nan
    # the rows' jitter (the largest departure from the median interval, gaps aside) and their gaps
    regular = pos[pos <= GAP * median] if pos.size else pos
    jitter = float(np.max(np.abs(regular - median)) / median) if regular.size else math.nan
    out = {"row_rate_hz": rate, "jitter": jitter, "gaps": int((pos > GAP * median).sum()) if pos.size else 0,
           "rows": int(len(t))}
    for name, v, triad in (("gyro", g, log.sensors.imu.gyro), ("accel", a, log.sensors.imu.accel)):
        have = np.isfinite(v).all(axis=1)
        railed = _railed(v, triad) & have[:, None]
        # a triad repeating the row before exactly, in a run of three or more, is stuck (a stale sample,
        # not a new one); a single repeat is left in: with noise of about an ADC step it happens by chance
        # (a few per cent of rows), and leaving those out would leave out the smallest differences
        same = np.zeros(len(t), bool)
        same[1:] = have[1:] & have[:-1] & (v[1:] == v[:-1]).all(axis=1)
        stale = same & (np.roll(same, 1) | np.roll(same, -1))
        stale[0] = False
        q2 = triad.lsb ** 2 / 12.0
        axes = {}
        for j, ax in enumerate(AXES):
            rows = have
            d = difference_sigma(t[rows], v[rows, j], order, exclude=(railed[rows, j] | stale[rows]))
            s = d["sigma"]
            ok = math.isfinite(s)
            white = math.sqrt(max(s * s - q2, 0.0)) if ok else math.nan
            e = {"sigma": s if ok else None, "white_sigma": white if ok else None,
                 "density": white / math.sqrt(rate) if ok and rate > 0 else None,
                 "residuals": d["residuals"], "rows": d["rows"], "railed_rows": int(railed[:, j].sum()),
                 "stale_rows": int(stale.sum()), "se_rel": d["se_rel"] if ok else None,
                 "left_out": d["left_out"], "allan": None}
            if ok:
                use = have & ~railed[:, j] & ~stale
                e["allan"] = allan_figures(v[use, j], median, s)
            axes[ax] = e
        out[name] = axes
    return out


def _triad_sigma(axes: dict) -> tuple[float | None, str | None]:
    """(the largest measured σ of a triad's axes, its axis), or (None, None) unless all three measured."""
    got = [(e["sigma"], ax) for ax, e in axes.items() if e["sigma"] is not None]
    if len(got) < len(axes):
        return None, None
    s, ax = max(got)
    return s, ax


def verdict(measured: float | None, se_rel: float | None, given: float) -> str:
    """"agree", "contradict" or "unmeasured": the measured σ against a given one (see the module
    docstring)."""
    if measured is None or se_rel is None:
        return "unmeasured"
    if not (measured > 0.0 and given > 0.0):  # (the ADC step alone gives every figure a σ above 0)
        return "agree" if measured == given else "contradict"
    ratio = measured / given
    z = NormalDist().inv_cdf(0.5 + 0.5 * CONFIDENCE)
    outside = abs(math.log(ratio)) > z * se_rel  # (the log of σ̂ has about σ̂'s relative error)
    return "contradict" if outside and (ratio > FACTOR or ratio < 1.0 / FACTOR) else "agree"


def datasheet_triads(log):
    """(gyro, accel) TriadSpec of the IMU part's datasheet (the preset a version-2 log names, or a
    version-1 log's scenario names; default MPU-6050), and the preset's name."""
    # the part whose figures the log's are, whichever way it gave them; else the preset it names
    name = preset_name(log.sensors.imu.gyro, log.sensors.imu.accel)
    if name is not None:
        pass
    elif log.version >= 2:
        name = imu_preset_of(log.manifest)
    else:
        name = "mpu6050"
        sc = getattr(log, "scenario", None)
        if sc is not None:
            s = sc.data["sensors"]
            name = s["believed"]["imu"] or s["imu"]
    return IMU_PRESETS[name], name


def gives_figures(log, triad: str) -> bool:
    """Whether ``log`` gives the noise of ``triad`` ("gyro", "accel"): a version-2 log's
    ``[imu.TRIAD]`` noise_density or sigma; a version-1 log's scenario when it names one (its
    figures are then the log's, by reference)."""
    if log.version >= 2:
        imu = log.manifest.get("imu") or {}
        t = imu.get(triad) or {}
        return isinstance(t, dict) and ("noise_density" in t or "sigma" in t)
    return "scenario" in log.manifest


def choose(log, mode: str = "log", order: int = ORDER) -> tuple[dict, object, dict]:
    """(replay.json's ``noise`` entry, the SensorConfig the estimators are built with, kalman2's
    parameters or {}) for ``log`` and ``mode`` (one of :data:`MODES`; see the module docstring).
    With the log's figures in use for both triads the log's own SensorConfig is returned
    unchanged (a twin log replays bit for bit). A measurement asked for and impossible, or
    figures the IMU's range cannot hold, is a one-line :class:`TwinError`."""
    if mode not in MODES:
        raise TwinError(f"--noise: {mode!r}; allowed: {', '.join(MODES)}")
    imu = log.sensors.imu
    rate = float(imu.rate)
    m = measure(log, order)
    sheet, preset = datasheet_triads(log)
    entry = {"mode": mode, "method": (f"differences of order {order} (Rice 1984; Gasser, Sroka and Jennen-Steinmetz "
                                      f"1986; Hall, Kay and Titterington 1990), robust scale; Allan deviation (IEEE "
                                      f"Std 952-1997) from {ALLAN_MIN_ROWS} rows"),
             "imu_rate_hz": rate, "row_rate_hz": m["row_rate_hz"], "row_jitter": m["jitter"], "row_gaps": m["gaps"],
             "preset": preset,
             "factor": FACTOR, "confidence": CONFIDENCE}
    triads, used_any_measured, lines = {}, False, []
    for (name, unit), spec, ds in zip(TRIADS.items(), (imu.gyro, imu.accel), sheet):
        axes = m[name]
        s_meas, axis = _triad_sigma(axes)
        se = axes[axis]["se_rel"] if axis else None
        given = gives_figures(log, name)
        s_given = given_sigma(spec, rate)
        s_sheet = given_sigma(replace(spec, noise_density=ds.noise_density), rate)
        v = verdict(s_meas, se, s_given)
        if mode == "measured":
            if s_meas is None:
                short = min(e["residuals"] for e in axes.values())
                raise TwinError(f"{log.path}: --noise measured: too few usable IMU rows to measure the {name}'s noise "
                                f"({short} windows of {order + 1} rows; at least {MIN_RESIDUALS}); allowed: a longer "
                                f"log, or --noise log, given or datasheet")
            used, why = "measured", "--noise measured"
        elif mode == "datasheet":
            used, why = "datasheet", f"the {preset} datasheet's density, --noise datasheet"
        elif mode == "given":
            used, why = "log", ("the log's figure, --noise given" if given else
                                "--noise given, and the log gives none: the figure the reader assumed for it")
        elif not given:
            if s_meas is not None:
                used, why = "measured", "the log gives no noise figure"
            else:
                used, why = "datasheet", (f"the log gives no noise figure and is too short to measure it: the "
                                          f"{preset} datasheet's")
        elif v == "contradict":
            used, why = "measured", (f"the data contradict the log's figure: measured σ {s_meas:.3g} {unit}, "
                                     f"{s_meas / s_given:.3g}× the log's {s_given:.3g} {unit} per sample")
        elif v == "unmeasured":
            used, why = "log", "the log's figure (too few rows to check it against the data)"
        else:
            used, why = "log", (f"the log's figure, which the data do not contradict (measured σ {s_meas:.3g} {unit}, "
                                f"{s_meas / s_given:.3g}× it)")
        if used == "measured":
            used_any_measured = True
            white = math.sqrt(max(s_meas ** 2 - spec.lsb ** 2 / 12.0, 0.0))
            density = white / math.sqrt(rate)  # per-sample σ = density · √rate at the estimators' IMU rate
        elif used == "datasheet":
            density = ds.noise_density
        else:
            density = spec.noise_density
        triads[name] = {
            "unit": unit, "used": used, "why": why, "verdict": v,
            "given": {"sigma": s_given, "noise_density": spec.noise_density} if given else None,
            "datasheet": {"sigma": s_sheet, "noise_density": ds.noise_density},
            "measured": {"sigma": s_meas, "axis": axis, "noise_density": (
                math.sqrt(max(s_meas ** 2 - spec.lsb ** 2 / 12.0, 0.0)) / math.sqrt(rate) if s_meas is not None
                else None), "se_rel": se},
            "noise_density": density, "sigma": given_sigma(replace(spec, noise_density=density), rate),
            "lsb": spec.lsb, "axes": axes}
        lines.append(f"{name} {triads[name]['sigma']:.3g} {unit} per sample ({used}: {why})")
    entry["triads"] = triads
    entry["used_by"] = ["ekf"] + (["kalman2"] if used_any_measured else [])
    entry["text"] = "noise: " + "; ".join(lines)
    sensors = log.sensors
    if any(triads[n]["used"] != "log" for n in TRIADS):
        try:
            new_imu = replace(imu, gyro=replace(imu.gyro, noise_density=triads["gyro"]["noise_density"]),
                              accel=replace(imu.accel, noise_density=triads["accel"]["noise_density"]))
        except TwinError as exc:
            raise TwinError(f"{log.path}: the noise figures in use ({entry['text']}) do not fit the IMU: {exc}") \
                from None
        sensors = replace(sensors, imu=new_imu)
    k2 = {}
    if used_any_measured:
        dt = 1.0 / float(log.control_rate)
        deg = 180.0 / math.pi
        sg, sa = triads["gyro"]["sigma"], triads["accel"]["sigma"]
        # TKJ's filter: P00 grows by Q_angle·Δt a step (so Q_angle = σ_g² Δt, the gyro's angle noise
        # per second) and R_measure is the accelerometer angle's variance, (σ_a / g)², in degrees
        k2 = {"q_angle": (sg * deg) ** 2 * dt, "r_measure": (sa / G * deg) ** 2}
        entry["kalman2"] = dict(k2)
    return entry, sensors, k2


__all__ = ["ALLAN_MIN_ROWS", "CLIP", "CONFIDENCE", "FACTOR", "MIN_RESIDUALS", "MODES", "ORDER", "allan_deviation",
           "allan_figures", "choose", "datasheet_triads", "difference_sigma", "difference_weights", "given_sigma",
           "gives_figures", "measure", "robust_sigma", "verdict"]
