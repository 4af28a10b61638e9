"""Scenarios: TOML files that say what to run (initial state, targets, the true plant,
disturbances, sensors, faults, video), validated on load, and the runner that turns one
into a directory of trajectories, metrics, figures and a video."""
from twin.scenarios.scenario import Scenario, builtin_names, builtin_scenarios, load_scenario
from twin.scenarios.schema import ScenarioError

__all__ = ["Scenario", "ScenarioError", "builtin_names", "builtin_scenarios", "load_scenario"]
