"""Time bases: the control period must be a whole number of physics steps."""
from __future__ import annotations

import math

from twin.errors import TwinError


def steps_per_control(physics_dt: float, control_dt: float) -> int:
    """Physics steps per control period; a clear error unless it is a whole number."""
    if not (physics_dt > 0 and control_dt > 0 and math.isfinite(physics_dt) and math.isfinite(control_dt)):
        raise TwinError(f"time steps must be positive, got physics {physics_dt} s and control {control_dt} s")
    ratio = control_dt / physics_dt
    k = round(ratio)
    if k < 1 or abs(ratio - k) > 1e-9 * max(1.0, ratio):
        raise TwinError(
            f"the control period ({control_dt:g} s) must be a whole number of physics steps ({physics_dt:g} s); "
            f"got {ratio:g}: choose a control rate that divides the physics rate"
        )
    return k
