"""Monte Carlo sweeps: IT2 against type-1 on the same sampled plants, noise and disturbances.

Data flow: :mod:`~twin.sweep.sampling` (what sample k is) → :mod:`~twin.sweep.worker`
(run one sample) on :mod:`~twin.sweep.backends` (local processes or Ray) →
:mod:`~twin.sweep.store` (finished samples, resumable) → :mod:`~twin.sweep.table`,
:mod:`~twin.sweep.statistics` and :mod:`~twin.sweep.figures` (the report), driven by
:func:`~twin.sweep.runner.run_sweep`.
"""
from twin.sweep.runner import SweepResult, replay_command, run_sweep
from twin.sweep.sampling import sample_scenario

__all__ = ["SweepResult", "replay_command", "run_sweep", "sample_scenario"]
