"""The EKF's filter core: the state (x, P, the gyro's last two rates) and the filter's steps,
behind one interface with two implementations.

:class:`FilterCore` (the interface) in textbook terms: ``x`` (12,) and ``P`` (12, 12);
``predict(x_next, F, Q, w)``, the state predicted beforehand (the strapdown step is
nonlinear: :meth:`estimation.ekf_filter.StrapdownFilter.propagate` computes x⁺, F and Q) with
P = F P Fᵀ + Q; ``update(z, off, H, R)``, the Joseph-form update of the affine measurement
z = off + H x + v, v ~ N(0, R), with the consider states' gain rows zeroed (Schmidt), returning
the innovation y and its covariance S; ``hold(mask)`` makes the masked states consider states;
``forward(commands, state6, step6)`` predicts the controllers' state across the latency.

The implementations:

* :class:`PythonCore`, the reference: filterpy's ExtendedKalmanFilter
  (:class:`~estimation.twin_ekf.TwinEKF`, imported on first use: filterpy imports scipy.stats).
* :class:`CompiledCore`: the state lives in the compiled kernel ``estimation._ekf``, built from
  a :class:`~estimation.ekf_config.KernelConfig` (read by field name), with a Python-side
  mirror (:class:`KernelState`). ``pull()`` brings the mirror up to date,
  ``push()`` writes it back; between the two, Python code (coasting, re-basing the encoders,
  and ``predict``/``update`` here, which run the same arithmetic on the mirror) works on the
  mirror. The kernel also *fuses* the whole IMU-driven step, the EKF's policies included
  (accelerometer outlier test, IMU outlier test, encoder gate, truncation into an unchanged
  count), in ``CompiledCore.advance``: ``fuses_imu_step`` says so, and the fusion step
  (:class:`estimation.ekf_fusion.Fusion`) then books the kernel's decisions instead of taking
  them one by one in Python.

Both implementations run the same sums in the same order (:mod:`estimation.detlinalg`), so
a predict/update sequence gives the same bits on either (tests/test_ekf_core.py).

Nothing here imports the twin beyond numpy and this package.
"""
from __future__ import annotations

import math
import os
import struct
from functools import partial
from typing import Protocol

import numpy as np

from estimation.detlinalg import affine
from estimation.ekf_config import CONFIG_FIELDS, RESTORE_INFLATION, RESTORE_JITTER, KernelConfig
# the state vector and the two steps both implementations run (TwinEKF too): estimation.ekf_steps;
# named here as well, where estimation.ekf and the tests import them
from estimation.ekf_steps import (AL, BY, BZ, C0, H0, PS, SAX, SAZ, STATE_NAMES, STATE_UNITS, SY, SZ,  # noqa: F401
                                  TH, V, N, cov_predict, joseph_update)

_STATE = struct.Struct(f"{N + N * N}d")  # x then P, as state_into() writes them
_PACK_STATE_INTO, _STATE_BYTES = _STATE.pack_into, _STATE.size

try:  # the optional compiled path (setup.py); TWIN_PURE_PYTHON=1 turns it off
    from estimation import _ekf as _kernel
except ImportError:  # pragma: no cover - no C compiler where it was installed
    _kernel = None
if os.environ.get("TWIN_PURE_PYTHON", "") not in ("", "0"):
    _kernel = None


def compiled_kernel_loaded() -> bool:
    """True if the compiled EKF kernel (``estimation._ekf``) is built and not turned off
    (``TWIN_PURE_PYTHON=1``) in this process."""
    return _kernel is not None


class FilterCore(Protocol):
    """The filter core's interface (see the module docstring)."""

    compiled: bool
    fuses_imu_step: bool  # True: advance() runs the whole IMU step, policies included
    kf: object  # the Python-side state: x, P, consider
    w: tuple  # the gyro's mean rates (ω_y, ω_z) over the last period and the one before
    w_prev: tuple

    @property
    def x(self) -> np.ndarray: ...

    @property
    def P(self) -> np.ndarray: ...

    def pull(self) -> None:
        """Bring the Python-side state up to date with the implementation's."""

    def push(self) -> None:
        """Write the Python-side state to the implementation."""

    def state_into(self, out, row: int = 0) -> None:
        """x then P into row ``row`` of ``out`` (C-contiguous rows of 156 float64), from the
        implementation's own state."""

    def set_state(self, x, P, w, w_prev) -> None: ...

    def hold(self, mask) -> None: ...

    def set_period(self, dt: float, mdt: float, msub: int, bias_q: float) -> None:
        """The period of the next steps: the filter's step ``dt`` and the model's ``mdt`` (s), the
        model's RK4 steps ``msub`` over it, the gyro bias's random-walk variance ``bias_q``
        (rad/s)² over it (a log whose rows are its instants)."""

    def keep_good(self) -> None:
        """Remember the state as the last good one (:meth:`restore`)."""

    def take_over(self) -> None:
        """Python code is about to step the filter: the state as it is now is the last good one."""

    def restore(self) -> None:
        """The last good state, its covariance inflated (4 P + 1e-10 I)."""

    def predict(self, x_next, F, Q, w) -> None: ...

    def update(self, z, off, H, R) -> tuple[np.ndarray, np.ndarray]: ...

    def forward(self, commands, state6, step6) -> tuple: ...

    def forwarder(self, state6, step6):
        """``forward`` with ``state6`` and ``step6`` bound: ``f(commands) -> (state, finite)``."""


class KernelState:
    """The Python side of the compiled path's filter state: x (12,), P (12, 12) and the
    consider mask, as on :class:`~estimation.twin_ekf.TwinEKF` (which starts them the same
    way), brought up to date from the kernel by :meth:`CompiledCore.pull`. The kernel does the
    filter step, so filterpy (and its import) is not needed there."""

    __slots__ = ("x", "P", "consider")

    def __init__(self):
        self.x = np.zeros(N)
        self.P = np.eye(N)
        self.consider = np.zeros(N, dtype=bool)


class _Core:
    """What both implementations share: the Python-side state and the last good one."""

    kf: object
    w = w_prev = (0.0, 0.0)
    good = None

    @property
    def x(self) -> np.ndarray:
        return self.kf.x

    @x.setter
    def x(self, value) -> None:
        self.kf.x = value

    @property
    def P(self) -> np.ndarray:
        return self.kf.P

    @P.setter
    def P(self, value) -> None:
        self.kf.P = value

    def set_state(self, x, P, w, w_prev) -> None:
        self.kf.x, self.kf.P = x, P
        self.w, self.w_prev = w, w_prev
        self.push()

    def state_into(self, out, row: int = 0) -> None:
        """Write x (12,) then P (12, 12) row by row into row ``row`` of ``out``, a C-contiguous
        float64 array of rows of 156: the state at the filter's own time, for a reader that
        wants it at every step without arrays of its own
        (:class:`estimation.consistency.RunningConsistency`, fed by
        :func:`twin.sim.simulate.simulate` in every run with the EKF)."""
        kf = self.kf
        if not isinstance(out, np.ndarray):  # any writable buffer of float64
            out = np.frombuffer(out, dtype=np.float64)
        if out.ndim == 1:  # a flat buffer: its rows of 156
            out = out.reshape(-1, N + N * N)
        out[row, :N] = kf.x
        out[row, N:] = np.ravel(kf.P)

    def keep_good(self) -> None:
        kf = self.kf
        self.good = (kf.x.copy(), kf.P.copy(), self.w, self.w_prev)

    def restore(self) -> None:
        x, P, self.w, self.w_prev = self.good
        self.kf.x, self.kf.P = x.copy(), RESTORE_INFLATION * P + np.diag(np.full(N, RESTORE_JITTER))
        self.push()


class PythonCore(_Core):
    """The reference implementation on filterpy's ExtendedKalmanFilter
    (:class:`~estimation.twin_ekf.TwinEKF`): the state lives there, ``pull``/``push`` have
    nothing to do."""

    compiled = False
    fuses_imu_step = False

    def __init__(self):
        # filterpy (imported with TwinEKF) imports scipy.stats, 0.8 s: only this path loads it
        from estimation.twin_ekf import TwinEKF

        self.kf = TwinEKF()

    def pull(self) -> None:
        pass

    def push(self) -> None:
        pass

    def take_over(self) -> None:
        pass

    def hold(self, mask) -> None:
        self.kf.consider = np.array(mask, dtype=bool)

    def set_period(self, dt: float, mdt: float, msub: int, bias_q: float) -> None:
        pass  # the composed step reads the period from the estimator and its model

    def predict(self, x_next, F, Q, w) -> None:
        self.kf.predict(x_next=x_next, F=F, Q=Q)
        self.w_prev, self.w = self.w, w

    def update(self, z, off, H, R):
        kf = self.kf
        kf.update(z, lambda x: H, lambda x: affine(off, H, x), R=R)
        return kf.y, kf.S

    def forward(self, commands, state6, step6):
        """(state, finite): [θ, θ̇, ψ, ψ̇, α, α̇] of the filter (``state6()``) predicted over
        ``commands`` with ``step6(s, command)``; the filter's own if that is not finite."""
        s6 = s = state6()
        try:
            for c in commands:
                s = step6(s, c)
        except (ValueError, OverflowError, FloatingPointError):
            return s6, False
        if not np.isfinite(s).all():
            return s6, False
        return s, True

    def forwarder(self, state6, step6):
        """:meth:`forward` with ``state6`` and ``step6`` bound: a callable of the commands alone."""
        return partial(self.forward, state6=state6, step6=step6)


class CompiledCore(_Core):
    """The compiled kernel ``estimation._ekf`` (``kernel``, built from ``config``, a
    :class:`~estimation.ekf_config.KernelConfig` it reads by field name), with the Python-side
    mirror :class:`KernelState`."""

    compiled = True
    fuses_imu_step = True

    def __init__(self, kernel, config: KernelConfig):
        if not isinstance(config, KernelConfig):
            raise TypeError(f"the compiled core is built from a KernelConfig, got {type(config).__name__}")
        check_kernel_layout(kernel)
        self.kf = KernelState()
        self._kernel = kernel
        self._core = kernel.new(config)
        # the whole IMU-driven step, called every control period: the kernel's own function
        # bound to this core once (no Python frame in between); see advance() in estimation/_ekf.c:
        # advance(sample, enc, last, T, command, in_row, acc_test) ->
        # (imu_code, saturated, enc_code, nis, dof, ok, acc_out, e_x, e_z, inside)
        self.advance = partial(kernel.advance, self._core)
        into = getattr(kernel, "state_into", None)
        if into is not None:  # the kernel's own copy, bound to this core (no Python frame): see state_into()
            self.state_into = partial(into, self._core)

    def pull(self) -> None:
        x, P, self.w, self.w_prev = self._kernel.state(self._core)
        self.kf.x, self.kf.P = np.array(x), np.array(P).reshape(N, N)

    def push(self) -> None:
        self._kernel.set_state(self._core, self.kf.x, self.kf.P.ravel(), self.w, self.w_prev)

    def state_into(self, out, row: int = 0) -> None:
        """As :meth:`_Core.state_into`, from the kernel's own state (the mirror is not updated):
        from its tuples of Python floats (``state``), about 3 µs. A kernel with a
        ``state_into(core, out, row)`` of its own (a copy in C, about 0.2 µs) replaces this
        method on the instance (see ``__init__``)."""
        x, P, _, _ = self._kernel.state(self._core)
        _PACK_STATE_INTO(out, row * _STATE_BYTES, *x, *P)

    def take_over(self) -> None:
        self.pull()  # the kernel restores a broken state itself: what it holds is good
        self.keep_good()

    def hold(self, mask) -> None:
        self.kf.consider = np.array(mask, dtype=bool)
        self._kernel.set_consider(self._core, [float(v) for v in mask])

    def set_period(self, dt: float, mdt: float, msub: int, bias_q: float) -> None:
        self._kernel.set_period(self._core, (float(dt), float(mdt), float(msub), float(bias_q)))

    def predict(self, x_next, F, Q, w) -> None:
        """On the mirror (``pull()`` before, ``push()`` after), as the kernel's step predicts."""
        kf = self.kf
        kf.x, kf.P = x_next, cov_predict(F, kf.P, Q)
        self.w_prev, self.w = self.w, w

    def update(self, z, off, H, R):
        """On the mirror (``pull()`` before, ``push()`` after), as the kernel's ``kalman_update``."""
        kf = self.kf
        kf.x, kf.P, y, S, _, _ = joseph_update(kf.x, kf.P, z, lambda x: z - affine(off, H, x), H, R, kf.consider)
        return y, S

    def forward(self, commands, state6=None, step6=None):
        """As :meth:`PythonCore.forward`, in the kernel (from the kernel's own state)."""
        return self._kernel.forward(self._core, commands)

    def forwarder(self, state6=None, step6=None):
        """:meth:`forward` as a callable of the commands alone: the kernel's own function, bound
        to this core (called every control period: no Python frame in between)."""
        return partial(self._kernel.forward, self._core)


def check_kernel_layout(kernel) -> None:
    """Raise if ``kernel`` reads another configuration than :class:`~estimation.ekf_config.KernelConfig`
    (a build older than the Python side, or a header not regenerated): its fields by name and in
    order, or no list of them at all (a kernel that took the constants as a positional tuple)."""
    fields = getattr(kernel, "config_fields", None)
    got = None if fields is None else tuple(fields())
    if got != CONFIG_FIELDS:
        raise RuntimeError("the compiled EKF kernel (estimation._ekf) was built for another configuration than "
                           "estimation.ekf_config.KernelConfig: regenerate its header (python -m "
                           "estimation.ekf_config) and rebuild it (python setup.py build_ext --inplace)")


def make_core(compiled: bool | None, kernel, config: KernelConfig | None) -> FilterCore:
    """The core for ``compiled`` (None: the kernel where it is built), the compiled one built
    from ``config``."""
    if kernel is not None and compiled is not False:
        return CompiledCore(kernel, config)
    return PythonCore()


__all__ = ["CompiledCore", "FilterCore", "KernelState", "N", "PythonCore", "STATE_NAMES", "STATE_UNITS",
           "check_kernel_layout", "compiled_kernel_loaded", "cov_predict", "joseph_update", "make_core"]
