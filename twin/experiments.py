"""What a run is asked to do: the initial tilt, the targets and the duration; the paper's three experiments."""
from __future__ import annotations

from dataclasses import dataclass

from twin.protocols import Targets


@dataclass(frozen=True)
class Experiment:
    """Initial state and targets of a run. ``theta0`` in rad, ``p_d`` in m, ``alpha_d`` in rad
    (None: that loop is off), ``duration`` in s."""

    name: str
    description: str
    theta0: float = 0.48  # rad
    p_d: float | None = None
    alpha_d: float | None = None
    duration: float = 15.0  # s

    @property
    def targets(self) -> Targets:
        """The targets handed to a controller."""
        return Targets(self.p_d, self.alpha_d)


PAPER_EXPERIMENTS = {
    1: Experiment("paper-exp1", "balance only from θ0 = 0.48 rad"),
    2: Experiment("paper-exp2", "balance + position, p_d = 0.7 m", p_d=0.7),
    3: Experiment("paper-exp3", "balance + position + direction, p_d = 1 m, α_d = 1.5 rad", p_d=1.0, alpha_d=1.5),
}

__all__ = ["Experiment", "PAPER_EXPERIMENTS"]
