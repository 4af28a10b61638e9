"""The design store: the one place a balance design is looked up, solved and kept.

:func:`balance_design` answers with, in order: the design this process already holds for
the same inputs; the on-disk cache's (:mod:`twin.controllers.design_cache`, when it is
enabled); a fresh solve (:func:`twin.controllers.lmi.design_balance_gains`), which it
then keeps in both. A design is a pure function of its inputs (the robot parameters and
the design options, see :func:`twin.controllers.design_cache.inputs_of`), so the key is
those inputs and a design is solved at most once per process and, with the disk cache, per
machine. :func:`adopt` hands the store a design solved elsewhere (a sweep's workers take
the design the sweep solved once).

Layering: this module sits above :mod:`twin.controllers.lmi` (which solves and knows
nothing of caches) and :mod:`twin.controllers.design_cache` (which stores and reads
files); the scenarios, the registry's build context and the command line ask here.
"""
from __future__ import annotations

from twin.controllers import design_cache, lmi
from twin.controllers.lmi import (DEFAULT_ALL_VERTICES, DEFAULT_DAMPING, DEFAULT_DECAY_RATE, DEFAULT_EPSILON,
                                  DEFAULT_RHO, DEFAULT_UNCERTAIN)
from twin.params import NOMINAL, RobotParams

_HELD: dict[str, object] = {}  # key (design_cache.key_of) → BalanceDesign, this process's


def _inputs(params: RobotParams, options: dict) -> dict:
    solver = options["solver"]
    return design_cache.inputs_of(params, options["epsilon"], options["rho"], options["decay_rate"],
                                  options["max_gain"], solver.upper() if solver else None,
                                  damping=options["damping"], uncertain=options["uncertain"],
                                  all_vertices=options["all_vertices"])


def key_of(params: RobotParams = NOMINAL, **options) -> str:
    """The store's key of the design for ``params`` and ``options`` (those of
    :func:`balance_design`), checked as a design's options are."""
    return design_cache.key_of(_inputs(params, lmi.design_options(**options)))


def balance_design(params: RobotParams = NOMINAL, epsilon: float = DEFAULT_EPSILON, rho: float = DEFAULT_RHO,
                   decay_rate: float = DEFAULT_DECAY_RATE, max_gain: float | None = None, solver: str | None = None, *,
                   damping: float = DEFAULT_DAMPING, uncertain=DEFAULT_UNCERTAIN,
                   all_vertices: bool = DEFAULT_ALL_VERTICES, cache: bool | None = None, hold: bool = True):
    """The LMI balance design for ``params`` and the options of
    :func:`twin.controllers.lmi.design_balance_gains` (the same defaults and meanings), from this process's designs, then the disk cache, else solved and kept.

    ``cache``: use the disk cache (None: as the command line set it,
    :func:`twin.controllers.design_cache.enabled`). The designs held in this process are
    used either way: they are the same numbers, bit for bit. ``hold=False``: neither look
    in nor add to this process's designs (the disk cache alone, as a library call with
    ``design_balance_gains(cache=True)`` asks).
    """
    options = lmi.design_options(epsilon, rho, decay_rate, max_gain, solver, damping, uncertain, all_vertices)
    inputs = _inputs(params, options)
    key = design_cache.key_of(inputs)
    held = _HELD.get(key) if hold else None
    if held is not None:
        return held
    disk = design_cache.enabled() if cache is None else bool(cache)
    design = design_cache.load(key, inputs, params) if disk else None
    if design is None:
        design = lmi.design_balance_gains(params, **options)
        if disk:
            design_cache.store(key, inputs, design)
    if hold:
        _HELD[key] = design
    return design


def adopt(design, params: RobotParams = NOMINAL, **options) -> None:
    """Hold ``design``, solved elsewhere for ``params`` and ``options``, as this process's
    answer for them (it is not written to the disk cache)."""
    _HELD[key_of(params, **options)] = design


def forget() -> None:
    """Drop the designs held in this process (the disk cache is left as it is)."""
    _HELD.clear()


__all__ = ["adopt", "balance_design", "forget", "key_of"]
