"""What one Monte Carlo sample is: its number, level, seed, sampled values and scenario.

A sweep of a scenario with ``L`` uncertainty levels (``sweep.levels``) and ``N`` draws
has ``N·L`` samples, numbered ``k = j·L + i`` for draw ``j`` and level ``i``. Draw ``j``
is shared by every level (common random numbers): the same sensor-noise seed and the
same unit draws ``u`` for the parameter factors, initial tilt and pushes, with only
``λ`` changing the factors. So a curve against the level shows the level's effect and
not that of different noise; and adding draws (a larger ``--samples``) keeps every
existing sample as it was.

Seeds. The sweep's root seed (the scenario's ``seed``, or ``--seed``) is one
``SeedSequence``; draw ``j`` is its child ``j`` (``SeedSequence(root).spawn`` order), and
the sample's seed is a 63-bit integer generated from that child. That seed is the
scenario's ``seed`` for the run (sensor noise and faults), and the sampled values come
from ``SeedSequence(seed, spawn_key=(VALUES_STREAM,))``, a stream no sensor ever uses.
So :func:`sample_scenario` rebuilds any sample from the scenario, the root seed and
``k`` alone: that is what ``twin run SCENARIO --sample k`` does.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from twin.errors import TwinError
from twin.params import NOMINAL, PARAMETER_DOCS, clip_inertia_factors
from twin.plant.disturbances import random_pushes
from twin.scenarios.scenario import Scenario

# What sample k of a sweep is (its seed, sampled values and scenario) in this code: part of the
# configuration hash every stored sample carries (twin.sweep.store), so a sweep is never resumed
# with samples whose k meant something else. Raise it whenever sample_scenario changes what it
# gives for a k (tests/test_sweep_store.py pins one sample to catch that).
SAMPLES_VERSION = 1
VALUES_STREAM = 1_000_003  # spawn key of the sampled values' stream (sensors spawn 0, 1, 2, …)
# every Table III parameter that can be perturbed, in the fixed order of the draws
PERTURBABLE = tuple(n for n in PARAMETER_DOCS if n not in ("g", "n_xb"))
FACTOR_LIMITS = (0.2, 5.0)  # a sampled factor stays physical


@dataclass(frozen=True)
class Sample:
    """Sample ``index`` of a sweep: draw ``draw`` at level ``levels[level_index] = level``,
    run with ``seed``; ``values`` maps column names (unit in the name) to sampled values."""

    index: int
    draw: int
    level_index: int
    level: float
    seed: int
    values: dict
    scenario: Scenario


def sample_seed(root_seed: int, draw: int) -> int:
    """The 63-bit seed of draw ``draw``: child ``draw`` of ``SeedSequence(root_seed)``."""
    child = np.random.SeedSequence(root_seed, spawn_key=(draw,))
    return int(child.generate_state(1, np.uint64)[0] >> np.uint64(1))


def value_columns(scenario: Scenario) -> list[str]:
    """The sampled-value columns of ``scenario``'s sweep, in order (units in the names)."""
    sw = scenario.data["sweep"]
    cols = [f"factor_{n}" for n in PERTURBABLE]
    cols.append("initial_theta_rad")
    for i in range(1, sw["push_count"] + 1):
        cols += [f"push{i}_force_n", f"push{i}_start_s"]
    return cols


def sample_scenario(scenario: Scenario, root_seed: int, index: int) -> Sample:
    """Sample ``index`` of the sweep of ``scenario`` with root seed ``root_seed``."""
    sw = scenario.data["sweep"]
    levels = sw["levels"]
    if not (isinstance(index, int) and index >= 0):
        raise TwinError(f"sample number must be a non-negative integer, got {index!r}")
    draw, level_index = divmod(index, len(levels))
    level = levels[level_index]
    seed = sample_seed(root_seed, draw)
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(VALUES_STREAM,)))
    # every unit draw is taken whatever the settings, so that settings never shift other draws
    if sw["distribution"] == "uniform":
        units = rng.uniform(-1.0, 1.0, size=len(PERTURBABLE))
        steps = level * units
    else:
        units = rng.standard_normal(size=len(PERTURBABLE))
        steps = 0.5 * level * units
    theta_u = rng.random()
    push_rng = rng.spawn(1)[0]

    data = copy.deepcopy(scenario.data)
    base = data["plant"]["scale"]
    scale = dict(base)
    for name, step in zip(PERTURBABLE, steps):
        factor = float(np.clip(1.0 + step, *FACTOR_LIMITS)) if name in sw["parameters"] else 1.0
        total = base.get(name, 1.0) * factor
        if total != 1.0 or name in base:
            scale[name] = total
    scale = clip_inertia_factors(scale, NOMINAL)
    values = {f"factor_{name}": scale.get(name, 1.0) for name in PERTURBABLE}
    data["plant"]["scale"] = scale
    if sw["initial_theta"] is not None:
        lo, hi = sw["initial_theta"]
        data["initial"]["theta"] = float(lo + (hi - lo) * theta_u)
    values["initial_theta_rad"] = data["initial"]["theta"]
    pushes = random_pushes(push_rng, sw["push_count"], force=sw["push_force"], window=sw["push_window"],
                           duration=sw["push_duration"], height=sw["push_height"])
    for i, p in enumerate(pushes, 1):
        values[f"push{i}_force_n"] = p.force[0]
        values[f"push{i}_start_s"] = p.start
        if p.start < data["duration"]:
            data["pushes"].append({"force": p.force, "start": p.start, "duration": p.duration, "point": p.point,
                                   "frame": p.frame})
    data["pushes"].sort(key=lambda q: q["start"])
    data["seed"] = seed
    source = f"{scenario.source}, sweep sample {index} (root seed {root_seed})"
    return Sample(index, draw, level_index, level, seed, values, Scenario(data, source, scenario.overrides))


def success(metrics: dict, scenario: Scenario) -> bool:
    """A run succeeds when it did not fall, |θ| settled below 0.01 rad for good at least
    ``sweep.success_settled_for`` s before the end, and it ended within
    ``sweep.success_position_tol`` / ``success_heading_tol`` of its targets."""
    sw = scenario.data["sweep"]
    if metrics["fell"] or metrics["status"] != "ok" or metrics["settling_time_s"] is None:
        return False
    if metrics["settling_time_s"] > metrics["duration_s"] - sw["success_settled_for"] + 1e-9:
        return False
    pe, he = metrics["final_position_error_m"], metrics["final_heading_error_rad"]
    return (pe is None or abs(pe) <= sw["success_position_tol"]) and (
        he is None or abs(he) <= sw["success_heading_tol"])
