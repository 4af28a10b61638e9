"""The paper's control architecture (Fig. 4): balance PDC + position FLS + direction FLS.

Data flow for one control step, state s = [θ, θ̇, ψ, ψ̇, α, α̇] (rad, rad/s):

1. position FLS (if a distance target p_d is set): θ_off = F_p(p_e, θ̇), p_e = r ψ − p_d;
2. balance PDC: u = Σ m_i(θ) G_i [θ − θ_off, θ̇, ψ_e, ψ̇] (total torque, N·m), u_p = u / 2
   per wheel. The weights m_i use the measured θ (they describe the plant's
   nonlinearity); the offset θ_off makes the PDC "see" the robot out of balance so it
   drives towards the target;
3. direction FLS (if a heading target α_d is set): u_α = F_d(α − α_d, α̇);
4. wheel torques ul = u_p − u_α, ur = u_p + u_α (N·m).

The ψ channel of the PDC (a design choice the paper leaves open). The LMI gains include
feedback on ψ, which on its own regulates the robot back to where it started and would
fight the position loop: with θ_off → 0 at the target, the robot would return to ψ = 0.
So ψ is measured from the target, ψ_e = ψ − p_d / r, and clipped to ±``psi_error_limit``
(rad) so that a distant target does not turn into a huge torque. Far from the target the
FLS and the clipped ψ channel both drive the robot; near it the ψ channel holds it
exactly where it should be. Without a position target the PDC regulates ψ to zero, as
in the paper's first experiment.

How much each part contributes (nominal analytic model, paper experiment 2, time to
reach 0.7 m within 1 cm): 5.7 s with the FLS, 6.7 s with θ_off ≡ 0, 8.3 s with the FLS's
sign flipped; the FLS alone (ψ channel off) moves the robot only to 0.40 m in 15 s,
because Table I normalises p_e by 3 m (0.7 m is 0.23 of the range, so θ_off stays near
0.01 rad). The tests check each of these directions.
"""
from __future__ import annotations

import math
from typing import NamedTuple

from twin.controllers.balance import PDCBalanceController
from twin.controllers.mamdani import DEFAULT_FOU, ScaledFLS, direction_controller, position_controller
from twin.controllers.robot_settings import UNIVERSES
from twin.errors import TwinError
from twin.params import NOMINAL, RobotParams
from twin.protocols import Targets

DEFAULT_PSI_ERROR_LIMIT = 1.0  # rad of wheel rotation (4 cm of travel on the nominal wheel)


class Command(NamedTuple):
    """One control step's output (ul, ur) and intermediate signals (for logging): a tuple
    ``(ul, ur, *signals)`` as :class:`twin.protocols.Controller` asks."""

    ul: float  # N·m
    ur: float  # N·m
    u: float  # N·m, balance PDC output (ul + ur without the direction term)
    theta_off: float  # rad
    u_alpha: float  # N·m per wheel


class FuzzyCascade:
    """Balance, position and direction controllers combined as in the paper's Fig. 4.

    Meets :class:`twin.protocols.Controller`: ``cascade(estimate, targets)`` returns a
    :class:`Command` (ul, ur, u, θ_off, u_α), whose last three entries are the logged
    ``signals``.

    Parameters
    ----------
    balance : PDCBalanceController
    position, direction : ScaledFLS or None
        None disables that loop (experiment 1 uses neither, experiment 2 only position).
    wheel_radius : float
        r in m, to turn ψ into travelled distance p = r ψ.
    psi_error_limit : float
        Clip of the PDC's ψ-error channel in rad (see the module docstring).
    """

    signals = ("u", "theta_off", "u_alpha")
    signal_units = {"u": "N·m", "theta_off": "rad", "u_alpha": "N·m"}

    def __init__(self, balance: PDCBalanceController, position: ScaledFLS | None = None,
                 direction: ScaledFLS | None = None, wheel_radius: float = 0.04,
                 psi_error_limit: float = DEFAULT_PSI_ERROR_LIMIT):
        if not (wheel_radius > 0 and math.isfinite(wheel_radius)):
            raise TwinError(f"wheel radius must be a positive length in m, got {wheel_radius!r}")
        if not (psi_error_limit > 0 and math.isfinite(psi_error_limit)):
            raise TwinError(f"psi_error_limit must be a positive angle in rad, got {psi_error_limit!r}")
        self.balance = balance
        self.position = position
        self.direction = direction
        self.r = float(wheel_radius)
        self.psi_error_limit = float(psi_error_limit)

    def reset(self, targets: Targets = Targets()) -> None:
        """Nothing to clear: the cascade is memoryless (a static map of the estimate)."""

    def __call__(self, state, targets: Targets = Targets()) -> Command:
        """Wheel torques for ``state`` = [θ, θ̇, ψ, ψ̇, α, α̇] and ``targets`` p_d (m), α_d (rad)."""
        p_d, alpha_d = targets
        theta, theta_dot, psi, psi_dot, alpha, alpha_dot = map(float, state[:6])
        theta_off = 0.0
        psi_e = psi
        if self.position is not None and p_d is not None:
            p_e = self.r * psi - p_d
            theta_off = self.position(p_e, theta_dot)
            lim = self.psi_error_limit
            psi_e = min(lim, max(-lim, psi - p_d / self.r))
        u = self.balance(theta, theta_dot, psi_e, psi_dot, theta_off)
        u_alpha = 0.0
        if self.direction is not None and alpha_d is not None:
            u_alpha = self.direction(alpha - alpha_d, alpha_dot)
        u_p = 0.5 * u
        return Command(u_p - u_alpha, u_p + u_alpha, u, theta_off, u_alpha)


def build_cascade(kind: str, design, targets: Targets = Targets(), params: RobotParams = NOMINAL,
                  fou: float = DEFAULT_FOU, type_reduction: str = "bmm",
                  psi_error_limit: float = DEFAULT_PSI_ERROR_LIMIT, universes=None, rho=None) -> FuzzyCascade:
    """The IT2 (``kind="it2"``) or type-1 (``"t1"``) cascade with the balance gains of
    ``design`` (a :class:`~twin.controllers.lmi.BalanceDesign`), on the model ``params``.

    The position and direction controllers are built for the loops ``targets`` closes
    (a target of None leaves that loop off, as the paper's experiments 1 and 2 do), with the
    ranges ``universes`` gives (names of :data:`twin.controllers.robot_settings.UNIVERSES`;
    each absent one Table I's). ``rho`` (the design's torque bound) is the design's already.
    """
    u = {**{k: v for k, (v, _) in UNIVERSES.items()}, **(universes or {})}
    balance = PDCBalanceController(design.gains, kind)
    position = position_controller(kind, fou, type_reduction, (u["position_error"], u["pitch_rate"], u["lean"])) \
        if targets.position is not None else None
    direction = direction_controller(kind, fou, type_reduction, u["turn_torque"],
                                     (u["heading_error"], u["turn_rate"])) if targets.heading is not None else None
    return FuzzyCascade(balance, position, direction, params.r, psi_error_limit)
