"""The run figures the documentation shows, drawn by the commands the pages name.

* ``docs/paper-exp3-twin.png``: ``twin run paper-exp3 --no-video`` (the tutorial's command: IT2
  and type-1, the twin with the EKF);
* ``docs/paper-exp3-twin-lqr.png``: the same with ``--controller it2,t1,lqr`` (the paper-claim
  page, LQR beside the fuzzy cascades);
* ``docs/paper-exp3-analytic.png``: ``twin run paper-exp3 --set plant.model=analytic --set
  plant.scale={} --set sensors.sensing=ideal --no-video`` (equation (1) itself, the method page).

Run from the repository root after a change to the figure or to the runs::

    python benchmarks/docs_figures.py

Each command runs in a subprocess (``python -m twin.cli``) in a temporary directory; its
``figure.png`` is copied over the page's image. Look at them before committing.
"""
from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FIGURES = {
    "paper-exp3-twin.png": ["run", "paper-exp3", "--no-video"],
    "paper-exp3-twin-lqr.png": ["run", "paper-exp3", "--controller", "it2,t1,lqr", "--no-video"],
    "paper-exp3-analytic.png": ["run", "paper-exp3", "--set", "plant.model=analytic", "--set", "plant.scale={}",
                                "--set", "sensors.sensing=ideal", "--no-video"],
}


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp:
        for name, args in FIGURES.items():
            out = Path(tmp) / name.removesuffix(".png")
            subprocess.run([sys.executable, "-m", "twin.cli", *args, "--out", str(out)], check=True, cwd=tmp,
                           stdout=subprocess.DEVNULL)
            shutil.copyfile(out / "figure.png", ROOT / "docs" / name)
            print(f"docs/{name}: twin {' '.join(args)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
