"""IT2 parallel-distributed-compensation balance controller (paper equations 7–14).

Rule i: if θ is M̃_i then u = G_i x. With the Nie–Tan weights of the TS model,
u = Σ m_i(θ) G_i x, x = [θ, θ̇, ψ, ψ̇] (rad, rad/s, rad, rad/s), u = ul + ur in N·m.
The type-1 counterpart replaces the IT2 antecedents by type-1 triangles: the lower
and upper membership functions collapse onto one (half-width ``t1_half_width``).
"""
from __future__ import annotations

import math

import numpy as np

from twin.errors import TwinError
from twin.plant.ts_model import LOWER_HALF_WIDTH, UPPER_HALF_WIDTH


class PDCBalanceController:
    """u = Σ m_i(θ) G_i x.

    Parameters
    ----------
    gains : array_like, shape (2, 4)
        G1 (upright rule) and G2 (tilted rule), from :func:`twin.controllers.lmi.design_balance_gains`.
    kind : {"it2", "t1"}
        "it2": the IT2 antecedents with Nie–Tan weights. "t1": one type-1 triangle on θ
        of half-width ``t1_half_width`` (default: the mean of the IT2 lower and upper
        half-widths, so both controllers share the same nominal weighting).
    """

    def __init__(self, gains, kind: str = "it2", t1_half_width: float | None = None):
        G = np.asarray(gains, dtype=float)
        if G.shape != (2, 4) or not np.all(np.isfinite(G)):
            raise TwinError(f"balance gains must be a finite 2x4 array (G1, G2 for [θ, θ̇, ψ, ψ̇]), got shape {G.shape}")
        if kind not in ("it2", "t1"):
            raise TwinError(f"controller kind must be 'it2' or 't1', got {kind!r}")
        self.G = G
        self.kind = kind
        self._g1 = tuple(float(v) for v in G[0])
        self._g2 = tuple(float(v) for v in G[1])
        if kind == "it2":
            self._lo, self._up = LOWER_HALF_WIDTH, UPPER_HALF_WIDTH
        else:
            hw = 0.5 * (LOWER_HALF_WIDTH + UPPER_HALF_WIDTH) if t1_half_width is None else float(t1_half_width)
            if not (hw > 0 and math.isfinite(hw)):
                raise TwinError(f"t1_half_width must be a positive angle in rad, got {t1_half_width!r}")
            self._lo = self._up = hw

    @property
    def half_widths(self) -> tuple[float, float]:
        """(lower, upper) half-widths in rad of the upright rule's membership of θ (equal for "t1")."""
        return self._lo, self._up

    def weight(self, theta: float) -> float:
        """m1(θ), the weight of the upright rule (m2 = 1 − m1)."""
        a = abs(theta)
        return 0.5 * (max(0.0, 1.0 - a / self._lo) + max(0.0, 1.0 - a / self._up))

    def __call__(self, theta: float, theta_dot: float, psi: float, psi_dot: float, theta_off: float = 0.0) -> float:
        """Total torque u = ul + ur in N·m for the state (rad, rad/s, rad, rad/s).

        ``theta_off`` (rad) is the position controller's inclination offset: the gains
        act on θ − θ_off while the rule weights use θ itself.
        """
        m1 = self.weight(theta)
        g1, g2 = self._g1, self._g2
        th = theta - theta_off
        u1 = g1[0] * th + g1[1] * theta_dot + g1[2] * psi + g1[3] * psi_dot
        u2 = g2[0] * th + g2[1] * theta_dot + g2[2] * psi + g2[3] * psi_dot
        u = m1 * u1 + (1.0 - m1) * u2
        if not math.isfinite(u):
            raise TwinError(f"balance controller got a non-finite state {(theta, theta_dot, psi, psi_dot)}")
        return u
