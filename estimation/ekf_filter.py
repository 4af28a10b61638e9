"""The EKF's mathematics: the strapdown filter's state, its steps and its measurement models,
apart from what the sensor front end decides about the samples.

:class:`StrapdownFilter`  x (12,), P (12, 12) on a filter core (:mod:`estimation.ekf_core`), the
                          strapdown step (:meth:`~StrapdownFilter.propagate`: x⁺, F, Q), the
                          model's synthetic IMU sample, the encoders' measurement
                          (:meth:`~StrapdownFilter.encoder_fit`), the prior at rest, the
                          re-initialisation and re-basing arithmetic, the estimate
                          [θ, θ̇, ψ, ψ̇, α, α̇] and its covariance
:class:`Coasting`         the step where equation (1) stands in for the IMU, with ω, ω₋₁ and the
                          model's parameter errors in an augmented state
:func:`kernel_config`     the :class:`~estimation.ekf_config.KernelConfig` of a filter

The reasons behind the equations are in the module docstring of :mod:`estimation.ekf`; which
sample reaches which step is :mod:`estimation.ekf_fusion`'s and :mod:`estimation.ekf_frontend`'s.
Every sum runs in the compiled kernel's order (:mod:`estimation.detlinalg`, issue 25).
"""
from __future__ import annotations

import math

import numpy as np

from estimation.detlinalg import affine, mm, mm3, mv, positive_definite, quad_inv, solve
from estimation.ekf_config import (HEADING_VAR_MAX, MAX_RIM_SPEED, TILT_LIMIT, TILT_VAR_MAX, TRAPEZOID_VAR,
                                   KernelConfig)
from estimation.ekf_core import (AL, BY, BZ, C0, H0, PS, SAX, SAZ, SY, SZ, TH, V, N, cov_predict, make_core)
from estimation.model import TORQUE_TOLERANCE, EstimatorModel

_NOT_IN_MODEL = frozenset((PS, AL, C0, H0))  # states the synthetic IMU sample does not depend on


class StrapdownFilter:
    """The strapdown filter's state and arithmetic (see the module docstring).

    ``model`` the :class:`~estimation.model.EstimatorModel`, ``every`` control periods per IMU
    sample, ``alpha0`` the heading the encoders' odometry starts from (rad),
    ``model_uncertainty`` parameter name → relative half-range (checked, the zeros left out)."""

    def __init__(self, model: EstimatorModel, every: int, alpha0: float, model_uncertainty: dict):
        self.model = model
        self.every = int(every)
        self.dt = self.every * model.dt
        self.alpha0 = float(alpha0)
        self.model_uncertainty = model_uncertainty
        self.unc_names = tuple(model_uncertainty)
        # σ (1) of each relative parameter error, uniform in its box
        self.unc_var = np.array([(h / math.sqrt(3.0)) ** 2 for h in model_uncertainty.values()])
        imu = model.imu
        self.xi, self.zi = imu.position[0], imu.position[2]
        self.r = model.r
        self.b_r = model.b_r
        # per-sample noise of the IMU: white noise and the ADC step (the scale-factor part
        # depends on the reading and is added per sample)
        self.g_var = imu.gyro.white_sigma(self.dt) ** 2 + imu.gyro.lsb ** 2 / 12.0
        self.a_var = imu.accel.white_sigma(self.dt) ** 2 + imu.accel.lsb ** 2 / 12.0
        self.g_sf, self.a_sf = imu.gyro.scale_factor_error ** 2, imu.accel.scale_factor_error ** 2
        self.bias_q = imu.gyro.bias_random_walk ** 2 * self.dt
        # the accelerometer's constant forward bias b (turn_on_bias, σ_b m/s²) has no state: while
        # the robot moves on level ground it is one with a tilt (the strapdown's horizontal
        # acceleration is f_x cos θ + f_z sin θ, and b + g δθ = 0 for δθ = −b/g), so the filter
        # estimates θ − b/g and, through the encoders' ψ − θ + c, c − b/g, exactly: no update
        # sees b and no gain needs it. The reported covariance adds it as a Schmidt consider
        # parameter would, (σ_b/g)² on the θ, c block (:meth:`covariance12`); zero where the
        # specification has no turn-on bias (the twin's presets), so nothing changes there
        self.tilt_var = (imu.accel.turn_on_bias / model.g) ** 2
        self.delta = model.encoders.resolution
        # per wheel (left, right): e_i = ψ − θ + c ∓ ((b/r)(α − α_0) + h)
        self.H = np.zeros((2, N))
        for i, sgn in enumerate((-1.0, 1.0)):
            self.H[i, PS] = self.H[i, C0] = 1.0
            self.H[i, TH] = -1.0
            self.H[i, AL] = sgn * self.b_r
            self.H[i, H0] = sgn
        g, a = imu.gyro, imu.accel
        # the largest readings the ADC can give (a sample there may be clipped)
        self.limits = (g.lsb * ((1 << (g.bits - 1)) - 1),) * 2 + (a.lsb * ((1 << (a.bits - 1)) - 1),) * 2
        self.core = self.kf = self.coasting = self.held = None
        self.Cx = self.Cx_next = self.rep = None

    def new_run(self, compiled: bool | None, kernel, config: KernelConfig | None) -> None:
        """A fresh core (:func:`estimation.ekf_core.make_core`) and nothing of a previous run."""
        self.core = make_core(compiled, kernel, config)
        self.kf = self.core.kf  # its state (x, P, consider)
        self.held = None  # the mask of the states held now (None: none)
        # point samples, the reference path: Cov(δx, n) with the last sample's noise (see propagate;
        # None: nothing carried), the next step's, and the axes the model stands in for (imu_sample)
        self.Cx = self.Cx_next = self.rep = None
        self.coasting = Coasting(self)

    def hold(self, mask) -> None:
        """From now on the states of ``mask`` are consider states: no update corrects them."""
        self.held = mask
        self.core.hold(mask)

    def set_period(self, dt: float) -> None:
        """The next steps span ``dt`` s (a log whose rows are its instants: the model's period and
        RK4 steps, the gyro bias's random walk; see :meth:`estimation.ekf.EKFEstimator.set_sampling`)."""
        model = self.model
        model.dt = dt
        model.substeps = model._substeps()
        for other in model.__dict__.get("_perturbed", {}).values():  # the sensitivities' models too
            other.dt, other.substeps = dt, other._substeps()
        self.dt = dt
        self.bias_q = self.model.imu.gyro.bias_random_walk ** 2 * dt
        self.core.set_period(dt, dt, model.substeps, self.bias_q)

    # ---- the estimate ------------------------------------------------------------------------
    def rates(self, x=None, w=None, w_prev=None) -> tuple[float, float]:
        """(θ̇, α̇) in rad/s at the filter's time: the gyro's mean rates over the last two
        periods (``w``, ``w_prev``; default the filter's) extrapolated linearly to the end of
        the last one."""
        x = self.kf.x if x is None else x
        (wy, wz), (wy0, wz0) = (self.core.w if w is None else w), (self.core.w_prev if w_prev is None else w_prev)
        wy, wz = 1.5 * wy - 0.5 * wy0, 1.5 * wz - 0.5 * wz0
        return (wy - x[BY]) / (1.0 + x[SY]), (wz - x[BZ]) / ((1.0 + x[SZ]) * math.cos(x[TH]))

    def state6(self, x=None, w=None, w_prev=None) -> np.ndarray:
        """[θ, θ̇, ψ, ψ̇, α, α̇] at the filter's time (or of state ``x`` and gyro history ``w``,
        ``w_prev``)."""
        x = self.kf.x if x is None else x
        thd, ald = self.rates(x, w, w_prev)
        th = x[TH]
        dz = -self.xi * math.sin(th) + self.zi * math.cos(th)
        return np.array([th, thd, x[PS], (x[V] - thd * dz) / self.r, x[AL], ald])

    def covariance12(self, P) -> np.ndarray:
        """``P`` (12, 12) plus the accelerometer's turn-on bias as a consider parameter, (σ_b/g)²
        on the θ and encoder-zero block (see ``__init__``); ``P`` itself where there is none."""
        if self.tilt_var > 0.0:
            P = P.copy()
            for i in (TH, C0):
                P[i, TH] += self.tilt_var
                P[i, C0] += self.tilt_var
        return P

    def covariance6(self, x, P12) -> np.ndarray:
        """Covariance (6, 6) of :meth:`state6` of ``x`` whose covariance is ``P12``: mapped through
        the Jacobian of [θ, θ̇, ψ, ψ̇, α, α̇] by the state (central differences), plus the gyro's
        white noise in the extrapolated rates (1.5² + 0.5² samples' worth)."""
        J = np.empty((6, N))
        for j in range(N):
            h = 1e-6 * max(1.0, abs(x[j]))
            xp, xm = x.copy(), x.copy()
            xp[j] += h
            xm[j] -= h
            J[:, j] = (self.state6(xp) - self.state6(xm)) / (2.0 * h)
        C = mm3(J, P12, J.T)
        th = x[TH]
        dz = -self.xi * math.sin(th) + self.zi * math.cos(th)
        q_y, q_z = 1.0 / (1.0 + x[SY]), 1.0 / ((1.0 + x[SZ]) * math.cos(th))
        w = 2.5 * self.g_var
        # θ̇ enters ψ̇ through −θ̇ dz / r
        g = np.array([0.0, q_y, 0.0, -q_y * dz / self.r, 0.0, 0.0])
        C += w * np.outer(g, g)
        C[5, 5] += w * q_z * q_z
        return 0.5 * (C + C.T)

    # ---- priors ------------------------------------------------------------------------------
    def prior(self, accel, moving: bool = False):
        """(x, P): the state of a robot at rest from the accelerometer reading ``accel``
        (f_x, f_y, f_z) m/s² (see :meth:`estimation.ekf.EKFEstimator.start`). ``moving``: the
        robot may be moving (a re-initialisation, :meth:`reinitialise`): the speed is then known
        only to lie within ±:data:`~estimation.ekf_config.MAX_RIM_SPEED` (its uniform variance),
        and θ's variance takes in the specific force's departure from g, the least acceleration
        the reading shows; without a reading, θ is known only to lie in (−π/2, π/2)."""
        spec_g = self.model.imu.gyro
        x = np.zeros(N)
        if accel is None:
            theta0, var_theta, sc = 0.0, TILT_VAR_MAX, 0.0
        else:
            fx, _, fz = accel
            theta0 = math.atan2(-fx, fz)
            g = math.hypot(fx, fz)
            # tan θ reads tan θ (1 + s_x)/(1 + s_z): the scale errors tilt it by sc (s_x − s_z)
            sc = math.sin(theta0) * math.cos(theta0)
            # (the accelerometer's turn-on bias is not θ's error: the filter's θ is the tilt less b/g,
            # and the bias enters the reported covariance alone, see __init__)
            var_theta = self.a_var / max(g, 1.0) ** 2 + 2.0 * sc * sc * self.a_sf
            if moving:
                dev = (g - self.model.g) / self.model.g
                var_theta = min(var_theta + dev * dev, TILT_VAR_MAX)
        x[TH] = x[C0] = theta0
        x[AL] = self.alpha0
        bias_var = spec_g.turn_on_bias ** 2 + 1e-12
        # where the encoders' first edges lie is unknown: a constant offset of variance
        # Δ²/12 per wheel, Δ²/24 in the mean and in the half-difference
        edge_var = self.delta ** 2 / 24.0
        g_sf, a_sf = self.g_sf + 1e-12, self.a_sf + 1e-12
        v_var = MAX_RIM_SPEED ** 2 / 3.0 if moving else 1e-12
        P = np.diag([var_theta, 1e-12, v_var, 1e-12, bias_var, bias_var, var_theta + edge_var,
                     g_sf, edge_var, g_sf, a_sf, a_sf])
        P[TH, C0] = P[C0, TH] = var_theta
        for i in (TH, C0):
            P[i, SAX] = P[SAX, i] = -sc * self.a_sf
            P[i, SAZ] = P[SAZ, i] = sc * self.a_sf
        return x, P

    def reinitialise(self, accel, last_enc) -> None:
        """Start again from the accelerometer reading ``accel`` (None: none) for a robot that may
        be moving (:meth:`prior` with ``moving``); ψ and α keep their estimates (α's variance
        capped at :data:`~estimation.ekf_config.HEADING_VAR_MAX`, a uniform angle's), the encoder
        zeros are placed so that the last counts used (``last_enc``, None: none) are predicted,
        and the sensors' constants start again from their priors. On the core's Python-side
        state (the caller pulls and pushes)."""
        self.Cx = None
        kf = self.kf
        x_old, P_old = kf.x, kf.P
        x, P = self.prior(accel, moving=True)
        for i in (PS, AL):
            if math.isfinite(x_old[i]):
                x[i] = x_old[i]
        pa = P_old[AL, AL]
        P[AL, AL] = min(pa, HEADING_VAR_MAX) if pa > 0.0 else HEADING_VAR_MAX
        enc = last_enc
        if enc is not None:  # the counts ψ − θ + c ± (b/r (α − α0) + h) (self.H)
            x[C0] = 0.5 * (enc[0] + enc[1]) - x[PS] + x[TH]
            x[H0] = 0.5 * (enc[1] - enc[0]) - self.b_r * (x[AL] - self.alpha0)
            P[H0, H0] += self.b_r * self.b_r * P[AL, AL]
            P[H0, AL] = P[AL, H0] = -self.b_r * P[AL, AL]
        kf.x, kf.P = x, P
        self.coasting.reset()

    def rebase_encoders(self, enc):
        """Re-base the encoders' zeros c, h onto reading ``enc`` (a counter reset), with the
        filter's uncertainty of the reading as theirs; returns the innovation (2,) rad."""
        self.Cx = None
        self.core.pull()
        x, P = self.kf.x.copy(), self.kf.P.copy()
        off = np.array([self.b_r * self.alpha0, -self.b_r * self.alpha0])
        y = np.asarray(enc, dtype=float) - (mv(self.H, x) + off)
        S = mm3(self.H, P, self.H.T) + np.eye(2) * self.delta ** 2 / 12.0
        x[C0] += 0.5 * (y[0] + y[1])
        x[H0] += 0.5 * (y[1] - y[0])
        for i in (C0, H0):
            P[i, :] = P[:, i] = 0.0
        P[C0, C0] = 0.25 * (S[0, 0] + S[1, 1] + 2.0 * S[0, 1])
        P[H0, H0] = 0.25 * (S[0, 0] + S[1, 1] - 2.0 * S[0, 1])
        self.kf.x, self.kf.P = x, P
        aug = self.coasting.aug
        if aug is not None:
            aug[:N, :N] = P
            for i in (C0, H0):
                aug[i, N:] = aug[N:, i] = 0.0
        self.core.push()
        return y

    def restore(self) -> None:
        """The last good state, its covariance inflated (the core's ``restore``)."""
        self.Cx = None
        self.core.restore()
        self.coasting.reset()

    def symmetrised_health(self) -> int:
        """After a step on the Python side: P symmetrised; 1 if the state is finite, P's diagonal
        positive and the state within its physical range (:meth:`in_range`), −1 if finite but out
        of range, 0 if not finite."""
        kf = self.kf
        kf.P = 0.5 * (kf.P + kf.P.T)
        if np.isfinite(kf.x).all() and np.isfinite(kf.P).all() and (np.diag(kf.P) > 0).all():
            return 1 if self.in_range(kf.x, kf.P) else -1
        return 0

    @staticmethod
    def in_range(x, P) -> bool:
        """The state within its physical range (as the compiled kernel's ``in_range``): |θ| below
        :data:`~estimation.ekf_config.TILT_LIMIT`, θ's variance below
        :data:`~estimation.ekf_config.TILT_VAR_MAX`, P positive definite."""
        return abs(x[TH]) < TILT_LIMIT and P[TH, TH] < TILT_VAR_MAX and positive_definite(P)

    # ---- the strapdown step ------------------------------------------------------------------
    def synthetic(self, x, command, w=None, w_prev=None):
        """The IMU sample equation (1) predicts at the end of the next period, and the
        extra variance (gyro, accelerometer) that the model's torque uncertainty adds."""
        return self.scaled(x, self.model.synthetic_imu(self.state6(x, w, w_prev), command, self.every))

    @staticmethod
    def scaled(x, raw):
        """:meth:`synthetic` from the model's sample ``raw`` (true rates and specific force,
        and their variances): as the sensor would read it with the state's scale factors and biases."""
        (wy, wz, fx, fz), (gv, av) = raw
        return (((1.0 + x[SY]) * wy + x[BY], (1.0 + x[SZ]) * wz + x[BZ], (1.0 + x[SAX]) * fx, (1.0 + x[SAZ]) * fz),
                (gv, gv, av, av))

    def accel_innovation(self, x, sample, syn):
        """((e_x, e_z), S_x, S_z): the accelerometer half (f_x, f_z) of ``sample`` less the specific
        force equation (1) predicts from the state and the command (``syn`` from
        :meth:`synthetic`), and its variance per axis = the accelerometer's per-sample noise +
        the model's torque uncertainty (``synthetic``'s) + the state's share (θ through
        gravity, g² P_θθ, in f_x; the scale factors, f² P_s). Measured on fault-free runs
        (θ0 = 0.2 rad): e/√S has mean square 1.1–1.6 over both axes, max 17.5 in 3000 samples;
        a ±1 m/s² spike gives 300–470."""
        P = self.kf.P
        fx, fz = syn[0][2], syn[0][3]
        sx = self.a_var + syn[1][2] + self.model.g * self.model.g * P[TH, TH] + fx * fx * P[SAX, SAX]
        sz = self.a_var + syn[1][3] + fz * fz * P[SAZ, SAZ]
        return (sample[2] - fx, sample[3] - fz), sx, sz

    def propagate(self, x, sample, with_L: bool = False, half=None):
        """(x⁺, F, Q, (ω_y, ω_z)): one strapdown step with IMU ``sample`` (and the noise
        map L (12, 4), the derivative of x⁺ by the sample, with ``with_L``).

        ``sample`` is ((ω_y, ω_z, f_x, f_z), extra), the means over the period, with
        ``extra`` None for a real sample or the variances (4,) that synthetic values add. F and
        the noise map are the exact derivatives of the step, built by the chain rule over the
        state (vectors ``d*`` are gradients by x) and over the sample (``i*``, by (ω_y, ω_z, f_x,
        f_z)). ``half`` (point samples): see below; sets :attr:`Cx_next`.
        """
        (wy, wz, fx, fz), extra = sample
        dt, r, xi, zi = self.dt, self.r, self.xi, self.zi
        th, v, by, bz = x[TH], x[V], x[BY], x[BZ]
        q, qz, qax, qaz = 1.0 / (1.0 + x[SY]), 1.0 / (1.0 + x[SZ]), 1.0 / (1.0 + x[SAX]), 1.0 / (1.0 + x[SAZ])
        E = np.eye(N)
        thm = (wy - by) * q
        th1 = th + dt * thm
        thb = 0.5 * (th + th1)
        s0, c0, s1, c1 = math.sin(th), math.cos(th), math.sin(th1), math.cos(th1)
        cb, tb = math.cos(thb), math.tan(thb)
        ad = (wz - bz) * qz / cb
        dx0, dz0 = xi * c0 + zi * s0, -xi * s0 + zi * c0
        dx1, dz1 = xi * c1 + zi * s1, -xi * s1 + zi * c1
        fxt, fzt = fx * qax, fz * qaz
        Fx = c1 * fxt + s1 * fzt
        Fz = -s1 * fxt + c1 * fzt
        v1 = v + dt * (Fx + ad * ad * dx1)
        x1 = x.copy()
        x1[TH] = th1
        x1[AL] = x[AL] + dt * ad
        x1[V] = v1
        # r ψ = (the IMU point's forward position) − dx(θ)
        x1[PS] = x[PS] + (0.5 * dt * (v + v1) - dx1 + dx0) / r

        dth1 = E[TH] + dt * (-q * E[BY] - thm * q * E[SY])
        ith1 = np.array([dt * q, 0.0, 0.0, 0.0])
        dad = ad * tb * 0.5 * (E[TH] + dth1) - (qz / cb) * E[BZ] - ad * qz * E[SZ]
        iad = ad * tb * 0.5 * ith1 + np.array([0.0, qz / cb, 0.0, 0.0])
        dFx = Fz * dth1 - c1 * fxt * qax * E[SAX] - s1 * fzt * qaz * E[SAZ]
        iFx = Fz * ith1 + np.array([0.0, 0.0, c1 * qax, s1 * qaz])
        dv1 = E[V] + dt * (dFx + 2.0 * ad * dx1 * dad + ad * ad * dz1 * dth1)
        iv1 = dt * (iFx + 2.0 * ad * dx1 * iad + ad * ad * dz1 * ith1)
        F = E.copy()
        F[TH] = dth1
        F[AL] = E[AL] + dt * dad
        F[V] = dv1
        F[PS] = E[PS] + (0.5 * dt * (E[V] + dv1) - dz1 * dth1 + dz0 * E[TH]) / r
        L = np.zeros((N, 4))
        L[TH] = ith1
        L[AL] = dt * iad
        L[V] = iv1
        L[PS] = (0.5 * dt * iv1 - dz1 * ith1) / r
        # white noise and ADC steps; the scale factors are states
        base = np.array([self.g_var, self.g_var, self.a_var, self.a_var])
        var = base.copy()
        if half is not None:
            # point samples (half: 1.0 where an axis's mean is the trapezoid (n_{k−1} + n_k)/2 of two
            # samples' noise, then 1.0 where the axis is the reading's): the mean's own noise σ²/2, and
            # its n_{k−1} half correlated with the state through Cx = Cov(δx, n_{k−1}) of the step before
            # (the filter's white-noise step would take σ², twice the one step's, or σ²/2 and lose the
            # correlation: half the drift of an integral over many steps)
            for j in range(4):
                if half[j]:
                    var[j] *= 0.5
        if extra is not None:
            var += extra
        Q = mm(L * var, L.T)
        self.Cx_next = None
        if half is not None:
            Cx = self.Cx
            if Cx is not None:
                for j in range(4):
                    if half[j]:
                        G = mv(F, Cx[:, j])
                        cross = 0.5 * np.outer(G, L[:, j])
                        Q = Q + cross + cross.T
            self.Cx_next = L * np.array([(0.5 if half[j] else 1.0) * base[j] if half[4 + j] else 0.0
                                         for j in range(4)])
        Q[BY, BY] += self.bias_q
        Q[BZ, BZ] += self.bias_q
        # ψ integrates v by the trapezoid, exact only if the acceleration is constant over the
        # period; the IMU gives its mean alone. With v monotonic in between, ∫v lies anywhere in
        # Δt [v, v⁺] (taken uniform: σ = Δt |v⁺ − v| / √12). At release the motors' torque
        # steps from nothing and falls with the back-EMF within the first period: the
        # trapezoid was off by 0.2-0.6 mrad of ψ at σ 0.12, and the encoder zero absorbed it
        hv = dt * (v1 - v) / r
        Q[PS, PS] += hv * hv * TRAPEZOID_VAR
        if with_L:
            return x1, F, Q, (wy, wz), L
        return x1, F, Q, (wy, wz)

    def predict(self, pred) -> None:
        """The core's predict with ``pred`` = (x⁺, F, Q, ω) from :meth:`propagate`."""
        x_next, F, Q, w = pred
        self.core.predict(x_next, F, Q, w)

    def update(self, em) -> None:
        """The core's update with the encoder measurement ``em`` = (z, off, H, R), and the
        covariance of the state's error with the last point sample's noise carried through it."""
        z, off, H, R = em
        Cx = self.Cx
        if Cx is not None:  # Cov(δx, n) after the update: (I − K H) Cov(δx, n), K with the prior P
            P = self.core.kf.P
            PHt = mm(P, H.T)
            K = solve(mm(H, PHt) + R, PHt.T).T
            if self.held is not None:
                K[self.held] = 0.0  # Schmidt, as the update
            self.Cx = Cx - mm(K, mm(H, Cx))
        self.core.update(z, off, H, R)

    # ---- the encoders' measurement -----------------------------------------------------------
    def encoder_fit(self, enc, last, T: float, pred, P, test: bool = False):
        """(measurement, NIS, (y, S)) of encoder sample ``enc`` against the prior of ``pred`` =
        (x⁺, F, Q, ω) from ``P`` (None: the filter's current prior), ``last`` the counts of the
        last sample used, ``T`` s since it.

        The measurement is the position of the last edge each wheel crossed since the last
        encoder sample used, for the wheels whose count changed: the wheel was exactly
        there at an unknown instant of the interval T, so it now lies beyond the edge by
        u·|q̇|T, u ~ U(0, 1), at most one count (mean half, variance (q̇T)²/12, plus the
        uncertainty of q̇). Unchanged counts carry no new information (None, None, None)
        - the same quantisation error again, which a white-noise model would count anew.

        ``test``: for the IMU outlier test, a wheel whose count did not change is still
        somewhere inside its count: a row with the reading, variance Δ²/12. (That is
        what catches an IMU spike between two edges.)
        """
        changed = [i for i in (0, 1) if enc[i] != last[i]]
        rows = (0, 1) if test else changed
        if not rows:
            return None, None, None
        if pred is None:
            x, Pp, (wy, wz) = self.kf.x, self.kf.P, self.core.w
        else:
            x, F, Q, (wy, wz) = pred
            Pp = cov_predict(F, P, Q)
        dlt, b_r = self.delta, self.b_r
        th = x[TH]
        thd = (wy - x[BY]) / (1.0 + x[SY])
        dz = -self.xi * math.sin(th) + self.zi * math.cos(th)
        wheel = (x[V] - thd * dz) / self.r - thd
        spin = b_r * (wz - x[BZ]) / ((1.0 + x[SZ]) * math.cos(th))
        var_q = Pp[V, V] / self.r ** 2 + self.g_var * ((1.0 + dz / self.r) ** 2 + b_r * b_r)
        z, off, R = [], [], []
        for i in rows:
            sgn = 2 * i - 1
            if i not in changed:
                z.append(enc[i])
                off.append(-sgn * b_r * self.alpha0)
                R.append(dlt * dlt / 12.0)
                continue
            up = enc[i] > last[i]
            d = min(abs(wheel + sgn * spin) * T, dlt)
            d = d if up else -d
            z.append(enc[i] - 0.5 * dlt if up else enc[i] + 0.5 * dlt)
            off.append(-sgn * b_r * self.alpha0 - 0.5 * d)
            R.append(min(d * d / 12.0 + var_q * T * T / 3.0, dlt * dlt / 12.0))
        H = self.H[list(rows)]
        z, off, R = np.array(z), np.array(off), np.diag(R)
        y = z - affine(off, H, x)
        S = mm(H, mm(Pp, H.T)) + R
        return (z, off, H, R), quad_inv(y, S), (y, S)


def kernel_config(f: StrapdownFilter, gate, imu_gate, max_rejects_in_row: int, inside_half: float,
                  stuck_sigmas: float) -> KernelConfig:
    """The compiled kernel's configuration for filter ``f``: its constants and model, the χ²
    gates ``gate`` and ``imu_gate`` ({1: …, 2: …}) and the forced re-synchronisation after
    ``max_rejects_in_row`` (see :class:`~estimation.ekf_policies.EncoderGate`), the keep-inside
    interval's half width ``inside_half`` (rad) and ``stuck_sigmas`` (see
    :class:`~estimation.ekf_policies.KeepInside`)."""
    m = f.model
    motor, plant = m.motor, m.plant
    return KernelConfig(
        dt=f.dt, r=f.r, xi=f.xi, zi=f.zi, b_r=f.b_r, alpha0=f.alpha0, delta=f.delta, g_var=f.g_var, a_var=f.a_var,
        bias_q=f.bias_q, gate=(gate[1], gate[2]), imu_gate=(imu_gate[1], imu_gate[2]), lim=tuple(f.limits),
        mdt=m.dt, m11=m.m11, m12=m.m12, m22=m.m22, n_bla=plant.n_bla, d_b=plant.d_b, d_w=plant.d_w, g_b=plant.g_b,
        yaw_damping=plant.yaw_damping, m33=plant.m33, g=m.g, has_motor=motor is not None,
        compensates=bool(m.compensates), tau_max=m.tau_max, i_tau=m.i_tau, sigma_tau=m.sigma_tau, c_e=m.c_e,
        tol=TORQUE_TOLERANCE, every=f.every, max_rejects_in_row=int(max_rejects_in_row), inside_half=inside_half,
        stuck_sigmas=stuck_sigmas, msub=m.substeps)


class Coasting:
    """One step where equation (1) stands in for the IMU: without a (trustworthy) sample, or
    (``rail``: the reading and which of its axes are censored) for the axes of a sample at the
    end of their range, the others kept as readings.

    The predicted sample depends on the state, and on θ̇, which is no state of the
    filter but the gyro's last two samples ω, ω₋₁: while coasting these join the state
    (at the first coasting step ω, ω₋₁ are the readings with the gyro's white noise,
    uncorrelated). The Jacobian of the step then holds the pendulum's own instability, so
    the covariance grows as the model's error does and the encoders, which see the
    wheels, correct θ and θ̇ through the model. The model's parameters (``model_uncertainty``)
    join the state too, as random constants (relative errors δp with mean 0 and the box's
    variance at the first coasting step; state augmentation, Simon, *Optimal State
    Estimation*, 2006, §7.4): a wrong mass or height biases every synthetic sample the same
    way, so the errors of consecutive samples add up coherently, as white noise they would
    not (with the clipped samples of a catch from 0.48 rad the filter claimed about 8× too
    little, mean NEES 76). A synthetic gyro value is (1 + s_y) ω_model + b_y, so the step's
    Jacobian through it cancels its dependence on the scale factor and the bias: clipped
    samples teach the filter neither. The first real sample ends it (ω becomes a reading
    again, :meth:`reset`). Always the Python path: coasting is rare, and one implementation
    serves both cores."""

    def __init__(self, f: StrapdownFilter):
        self.f = f
        self.reset()
        self.model_rate = (False, False)  # the filter's ω (y, z) is the model's, not a reading (per axis)

    def reset(self) -> None:
        """The augmented state is dropped: the next coasting step starts it again."""
        self.aug = None  # the coasting covariance of (x, ω, ω₋₁, δp)
        self.dp = None  # the model parameters' relative errors while coasting (model_uncertainty's order)

    def predict(self, command, rail=None):
        """The coasting step's prediction with the wheel torque ``command`` (N·m) held, on the
        core's Python-side state (the caller has it ``take_over``, and pushes after the update);
        returns ``update(measurement)``, the augmented update of an encoder measurement."""
        f = self.f
        f.Cx = None  # (the compiled core's is cleared by the push at the end)
        kf, core = f.kf, f.core
        names = f.unc_names
        K = len(names)
        na = N + 4 + K
        Pa = self.aug
        if Pa is None:
            Pa = np.zeros((na, na))
            Pa[:N, :N] = kf.P
            Pa[N:N + 4, N:N + 4] = np.eye(4) * f.g_var
            Pa[N + 4:, N + 4:] = np.diag(f.unc_var)
            self.dp = np.zeros(K)
        x, w, wp = kf.x, core.w, core.w_prev
        rep = (True,) * 4 if rail is None else rail[1]
        # θ̇ and α̇ are the last two readings' linear extrapolation, 1.5 ω − 0.5 ω₋₁, exact only
        # for a rate linear over the two periods; where the model first stands in for a gyro axis
        # (its readings were used up to now) that extrapolation starts the model. Its error is
        # unknown but of the order of its own reach ½ (ω − ω₋₁): uniform within that, variance
        # (ω − ω₋₁)²/12, carried by ω₋₁ (weight ½ in the rate). At the start of a catch from
        # 0.35–0.45 rad (the torque stepping in, the gyro clipping in the next period) the
        # extrapolation was 0.93 rad/s short at σ 0.003, the model's θ 0.13 rad off at σ 0.023,
        # and the encoder zero kept ±10 mrad of it for good (mean NEES 29 over 10 logs; 18 with it)
        for i in (0, 1):
            if rep[i] and (self.aug is None or not self.model_rate[i]):
                dw = core.w[i] - core.w_prev[i]
                Pa[N + 2 + i, N + 2 + i] += dw * dw / 3.0
        self.model_rate = rep[:2]
        s6 = f.state6(x, w, wp)
        raw = f.model.synthetic_imu(s6, command, f.every)
        syn = f.scaled(x, raw)
        # the model's sample by its parameters (only the axes it stands in for)
        Dp = f.model.sensitivity(names, s6, command, f.every, raw[0]) if K else np.zeros((4, 0))
        for i in range(4):
            if rep[i]:
                Dp[i] *= (1.0 + x[SY]) if i == 0 else (1.0 + x[SZ]) if i == 1 else (1.0 + x[SAX]) if i == 2 else \
                    (1.0 + x[SAZ])
            else:
                Dp[i] = 0.0
        dp = self.dp
        value = tuple((syn[0][i] + float(mv(Dp[i:i + 1], dp)[0])) if rep[i] else rail[0][i] for i in range(4))
        extra = tuple(syn[1][i] if rep[i] else 0.0 for i in range(4))
        x1, F, Q, w1, L = f.propagate(x, (value, extra), with_L=True)
        z = np.concatenate([x, w, wp])

        def sample(zz):
            v = f.synthetic(zz[:N], command, (zz[N], zz[N + 1]), (zz[N + 2], zz[N + 3]))[0]
            return np.array([v[i] if rep[i] else 0.0 for i in range(4)])

        # the sample by (x, ω, ω₋₁, δp): forward differences (the model's RK4 step dominates a
        # coasting step's cost: half as many as central ones, 1e-6 relative error), the model's
        # sensitivity to its parameters
        D = np.zeros((4, na))
        at = np.array([syn[0][i] if rep[i] else 0.0 for i in range(4)])
        for j in range(N + 4):
            if j in _NOT_IN_MODEL:  # equation (1) does not depend on ψ, α nor the encoders' zeros
                continue
            h = 1e-6 * max(1.0, abs(z[j]))
            zp = z.copy()
            zp[j] += h
            D[:, j] = (sample(zp) - at) / h
        D[:, N + 4:] = Dp
        J = np.zeros((na, na))
        J[:N, :N] = F
        J[:N] += mm(L, D)
        J[N:N + 2] = D[:2]
        J[N + 2, N] = J[N + 3, N + 1] = 1.0
        for j in range(N + 4, na):
            J[j, j] = 1.0
        Pa = mm3(J, Pa, J.T)
        Pa[:N, :N] += Q
        # a new ω: the model's (its torque uncertainty added) or the reading (its white noise)
        Pa[N, N] += syn[1][0] if rep[0] else f.g_var
        Pa[N + 1, N + 1] += syn[1][1] if rep[1] else f.g_var
        kf.x, kf.P = x1, Pa[:N, :N].copy()
        core.w_prev, core.w = core.w, w1
        self.aug = Pa
        return self.update

    def update(self, em) -> None:
        """The augmented state's update with encoder measurement ``em`` = (z, off, H, R) (Joseph
        form, the consider states' gain rows zeroed, as the core's update)."""
        f = self.f
        kf, core = f.kf, f.core
        zm_, off, H, R = em
        na = len(self.aug)
        Ha = np.zeros((len(zm_), na))
        Ha[:, :N] = H
        za = np.concatenate([kf.x, core.w, core.w_prev, self.dp])
        Pa = self.aug
        PHt = mm(Pa, Ha.T)
        S = mm(Ha, PHt) + R
        Kg = solve(S, PHt.T).T
        if f.held is not None:
            Kg[:N][f.held] = 0.0  # Schmidt, as TwinEKF.update
        za = za + mv(Kg, zm_ - (mv(H, kf.x) + off))
        IKH = np.eye(na) - mm(Kg, Ha)
        Pa = mm3(IKH, Pa, IKH.T) + mm3(Kg, R, Kg.T)
        self.aug = 0.5 * (Pa + Pa.T)
        kf.x, kf.P = za[:N], self.aug[:N, :N].copy()
        core.w, core.w_prev = (za[N], za[N + 1]), (za[N + 2], za[N + 3])
        self.dp = za[N + 4:]


__all__ = ["Coasting", "StrapdownFilter", "kernel_config"]
