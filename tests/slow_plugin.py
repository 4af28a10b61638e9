"""A slow controller plugin for the tests of limits, kill signals and orphans: the state
feedback of examples/my_plugins.py that sleeps in some of its calls, written as a module
file where a test's command can import it (``--controller MODULE:Slow``)."""
from __future__ import annotations

from pathlib import Path

SOURCE = '''"""A test plugin written by tests/slow_plugin.py."""
import os
import time


class Slow:
    """The state feedback of examples/my_plugins.py; it sleeps {sleep_s} s (or $SLOW_PLUGIN_SLEEP_S)
    in calls {first} to {last} (counted from 1 after each reset; None: every later call), and on
    its first call leaves a file named by its process id in $SLOW_PLUGIN_MARKS, if that is set,
    holding its command line (a process may end before a poll of /proc sees it)."""

    first, last = {first}, {last}

    def __init__(self):
        self.calls = 0
        self.sleep = float(os.environ.get("SLOW_PLUGIN_SLEEP_S", "{sleep_s}"))

    def reset(self, targets):
        self.calls = 0

    def __call__(self, estimate, targets):
        self.calls += 1
        marks = os.environ.get("SLOW_PLUGIN_MARKS")
        if self.calls == 1 and marks:
            with open("/proc/self/cmdline", "rb") as f:
                cmdline = f.read().replace(b"\\0", b" ").decode(errors="replace").strip()
            mark = os.path.join(marks, str(os.getpid()))
            with open(mark + ".part", "w") as f:  # whole when it appears under its name
                f.write(cmdline)
            os.replace(mark + ".part", mark)
        if self.sleep and self.first <= self.calls and (self.last is None or self.calls <= self.last):
            time.sleep(self.sleep)
        theta, theta_dot, psi, psi_dot = estimate[:4]
        u = 1.2 * theta + 0.085 * theta_dot + 0.06 * psi + 0.032 * psi_dot
        return (0.5 * u, 0.5 * u)
'''


def write_slow_plugin(directory: Path, module: str, sleep_s: float, first: int = 1, last: int | None = None) -> str:
    """Write ``directory/module.py`` (a controller sleeping ``sleep_s`` s in calls ``first`` to
    ``last``); the controller's kind, ``"module:Slow"``."""
    (Path(directory) / f"{module}.py").write_text(SOURCE.format(sleep_s=float(sleep_s), first=int(first), last=last))
    return f"{module}:Slow"
