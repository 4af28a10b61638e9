"""The IT2 Takagi–Sugeno model of the balance subsystem (paper equations 4–6).

Two local linear models of x' = A x + B u, x = [θ, θ̇, ψ, ψ̇] (rad, rad/s, rad, rad/s),
u = ul + ur (N·m): rule 1 linearised at θ = 0, rule 2 at θ = ±π/6. For rule 2 the paper
replaces cos θ by β = cos(π/6) and sin θ by β θ (a sector-like choice, not the tangent at
π/6); we follow it. Antecedents are IT2 triangles on θ, type-reduced by Nie–Tan into
crisp weights m1(θ) + m2(θ) = 1.
"""
from __future__ import annotations

import math

import numpy as np

from twin.params import RobotParams

THETA_DOMAIN = math.pi / 6  # rad: the fuzzy model's domain [-π/6, π/6]
# β = cos(π/6) = √3/2 of rule 2, by a square root (correctly rounded everywhere) rather than the C
# library's cos(), whose last bit may depend on the CPU: the design's inputs are the same everywhere.
COS_DOMAIN = math.sqrt(3.0) / 2.0
LOWER_HALF_WIDTH = math.pi / 7  # rad: lower MF of rule 1 reaches 0 here
UPPER_HALF_WIDTH = math.pi / 6  # rad: upper MF of rule 1 reaches 0 here


def local_model(params: RobotParams, beta: float) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of the model linearised with cos θ -> β and sin θ -> β θ.

    ``beta = 1`` gives rule 1 (the exact Jacobian at the upright equilibrium),
    ``beta = cos(π/6)`` rule 2. Shapes (4, 4) and (4, 1).
    """
    m11, m12, m22, g_b, d_b, d_w = params.m11, params.m12, params.m22, params.g_b, params.d_b, params.d_w
    mb = m12 * beta
    delta = m11 * m22 - mb * mb
    mb1 = m11 + m12 * beta
    mb2 = m12 * beta + m22
    A = np.array(
        [
            [0.0, 1.0, 0.0, 0.0],
            [m11 * g_b * beta / delta, -2 * d_b * mb1 / delta, 0.0, 2 * (m12 * d_w * beta + d_b * mb1) / delta],
            [0.0, 0.0, 0.0, 1.0],
            [-m12 * g_b * (beta * beta) / delta, 2 * d_b * mb2 / delta, 0.0, -2 * (m22 * d_w + d_b * mb2) / delta],
        ]
    )
    B = np.array([[0.0], [-mb1 / delta], [0.0], [mb2 / delta]])
    return A, B


def ts_matrices(params: RobotParams) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """([A1, A2], [B1, B2]) of the two rules."""
    A1, B1 = local_model(params, 1.0)
    A2, B2 = local_model(params, COS_DOMAIN)
    return [A1, A2], [B1, B2]


def antecedent_bounds(theta) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Lower and upper memberships (μ̲1, μ̄1, μ̲2, μ̄2) of θ (rad), elementwise."""
    a = np.abs(np.asarray(theta, dtype=float))
    lo1 = np.maximum(0.0, 1.0 - a / LOWER_HALF_WIDTH)
    up1 = np.maximum(0.0, 1.0 - a / UPPER_HALF_WIDTH)
    return lo1, up1, 1.0 - up1, 1.0 - lo1


def nie_tan_weights(theta) -> np.ndarray:
    """Crisp weights [m1, m2] = (μ̲i + μ̄i)/2, summing to 1; shape (..., 2)."""
    lo1, up1, _, _ = antecedent_bounds(theta)
    m1 = 0.5 * (lo1 + up1)
    return np.stack([m1, 1.0 - m1], axis=-1)


def rule1_weight(theta: float) -> float:
    """m1(θ) for a scalar θ in rad (fast path of :func:`nie_tan_weights`)."""
    a = abs(theta)
    return 0.5 * (max(0.0, 1.0 - a / LOWER_HALF_WIDTH) + max(0.0, 1.0 - a / UPPER_HALF_WIDTH))


def ts_dynamics(t: float, x, u: float, params: RobotParams) -> np.ndarray:
    """x' = Σ m_i(θ) (A_i x + B_i u), the fuzzy model; shape (4,)."""
    (A1, A2), (B1, B2) = ts_matrices(params)
    m1 = rule1_weight(float(x[0]))
    x = np.asarray(x, dtype=float)
    return m1 * (A1 @ x + B1[:, 0] * u) + (1 - m1) * (A2 @ x + B2[:, 0] * u)
