"""The module paths of the flat layout, kept importable after the modules moved into
:mod:`twin.sim`, :mod:`twin.outputs` and :mod:`twin.verify` (issue 27).

``import twin.loop`` (or ``from twin.rundir import ...``) gives the very module that
``twin.sim.loop`` is, not a copy: patching one patches the other. New code should use the
new paths; these aliases are kept for code written against 0.1.
"""
from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys

MOVED = {
    "loop": "sim", "recorder": "sim", "runs": "sim", "bullet_loop": "sim", "analytic_loop": "sim",
    "report": "outputs", "figure": "outputs", "figure_worker": "outputs", "rundir": "outputs",
    "compare": "outputs", "fingerprint": "outputs", "metrics": "outputs",
    "expectations": "verify", "check": "verify", "golden": "verify", "testing": "verify",
    "pytest_plugin": "verify", "tolerances": "verify",
}
OLD_TO_NEW = {f"twin.{m}": f"twin.{sub}.{m}" for m, sub in MOVED.items()}


class _Alias(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds an old path and loads it as the new module (put into ``sys.modules`` under both names)."""

    def find_spec(self, name, path=None, target=None):
        if name in OLD_TO_NEW:
            return importlib.util.spec_from_loader(name, self)
        return None

    def create_module(self, spec):
        return None  # a placeholder: exec_module swaps the real module in

    def exec_module(self, module):
        # the import system returns sys.modules[name] after this: the new module itself
        sys.modules[module.__name__] = importlib.import_module(OLD_TO_NEW[module.__name__])


def install() -> None:
    """Put the alias finder on ``sys.meta_path`` (once)."""
    if not any(isinstance(f, _Alias) for f in sys.meta_path):
        sys.meta_path.append(_Alias())
