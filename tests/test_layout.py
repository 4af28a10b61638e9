"""The layout of issue 27: the engine in twin/sim, the outputs in twin/outputs, verification in
twin/verify; the flat paths of 0.1 still import the very modules that moved (not copies)."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from twin._moved import OLD_TO_NEW

ROOT = Path(__file__).resolve().parent.parent


def test_every_moved_module_is_in_its_package_and_not_left_at_the_top():
    for old, new in OLD_TO_NEW.items():
        assert (ROOT / (new.replace(".", "/") + ".py")).is_file(), new
        assert not (ROOT / (old.replace(".", "/") + ".py")).exists(), f"{old} is still a file of its own"


@pytest.mark.parametrize("old", sorted(OLD_TO_NEW))
def test_an_old_path_imports_the_module_that_moved(old):
    new = OLD_TO_NEW[old]
    code = (f"import importlib, sys\n"
            f"a = importlib.import_module({old!r})\n"
            f"b = importlib.import_module({new!r})\n"
            f"assert a is b, (a, b)\n"
            f"assert b.__name__ == {new!r} and b.__spec__.name == {new!r}\n"
            f"assert sys.modules[{old!r}] is b\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert out.returncode == 0, out.stderr


def test_from_imports_of_old_paths_and_patching_one_name_patches_both():
    code = ("from twin.rundir import MANIFEST\n"
            "from twin.bullet_loop import simulate_twin\n"
            "import twin.loop, twin.sim.loop\n"
            "twin.loop.MARK = 1\n"
            "assert twin.sim.loop.MARK == 1 and MANIFEST == 'manifest.json'\n"
            "import twin.nonexistent_module\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert out.returncode == 1 and "No module named 'twin.nonexistent_module'" in out.stderr, out.stderr
