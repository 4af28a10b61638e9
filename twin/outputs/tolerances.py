"""How far a run's signals may lie from a reference's: per-signal tolerances, absolute and relative.

A value agrees with its reference when ``|run − reference| ≤ atol + rtol · |reference|``
(``atol`` in the signal's SI unit: rad, rad/s, m, N·m, ...; ``rtol`` a fraction), or when
both are equal (infinities included) or both NaN. Used by ``twin check --golden`` and by
``twin compare``. Set in a scenario's ``[expect.golden]`` table::

    [expect.golden]
    atol = 1e-6                                   # every signal, in its SI unit
    rtol = 1e-9                                   # every signal, a fraction of |reference|
    signals = { theta = { atol = 1e-5 }, torque_l = { atol = 1e-3, rtol = 1e-6 } }

and on the command line: ``--atol 1e-6 --rtol 1e-9 --tolerance theta=1e-5 --tolerance
torque_l=1e-3,1e-6`` (repeatable ``--tolerance SIGNAL=ATOL[,RTOL]``).

Which tolerance a signal gets: for each of atol and rtol, its own entry (``signals.NAME``
or ``--tolerance NAME=...``) if that sets it, else the overall ``atol`` / ``rtol``, else
0. The command line's items replace the scenario's, one by one. With nothing set both
are 0: the comparison is bit for bit, as it has to be on one build (the twin is
deterministic). Between builds (the compiled kernels on one side, the pure-Python paths
on the other), which agree to about 1e-13 and not bit for bit, each is at least the
builds' floor :data:`BUILD_ATOL`, :data:`BUILD_RTOL` (see :mod:`twin.outputs.golden`).
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass

from twin.errors import TwinError
from twin.protocols import ACTUATION_NAMES, COMMAND_NAMES, ESTIMATE_NAMES, PUSH_NAMES, TRUTH_NAMES

BUILD_ATOL = 1e-9  # in each signal's SI unit: four orders above the builds' disagreement
BUILD_RTOL = 1e-9
RTOL_MAX = 1.0  # a relative tolerance above 100 % of the reference would accept any sign
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


@dataclass(frozen=True)
class Tolerances:
    """``atol`` (SI unit of each signal), ``rtol`` (fraction), and per-signal ``signals``
    ((name, atol, rtol), ...); None: not set here (see the module docstring)."""

    atol: float | None = None
    rtol: float | None = None
    signals: tuple = ()

    @property
    def is_set(self) -> bool:
        return self.atol is not None or self.rtol is not None or bool(self.signals)

    def over(self, base: "Tolerances | None") -> "Tolerances":
        """These settings on top of ``base``'s: each item set here replaces base's."""
        if base is None:
            return self
        own = {n: (a, r) for n, a, r in base.signals}
        for n, a, r in self.signals:
            old = own.get(n, (None, None))
            own[n] = (a if a is not None else old[0], r if r is not None else old[1])
        return Tolerances(self.atol if self.atol is not None else base.atol,
                          self.rtol if self.rtol is not None else base.rtol,
                          tuple((n, a, r) for n, (a, r) in sorted(own.items())))

    def of(self, signal: str, same_build: bool = True) -> tuple[float, float]:
        """(atol, rtol) of ``signal``; across builds never below the builds' floor."""
        a, r = self.atol, self.rtol
        for n, sa, sr in self.signals:
            if n == signal:
                a, r = sa if sa is not None else a, sr if sr is not None else r
        a, r = a or 0.0, r or 0.0
        return (a, r) if same_build else (max(a, BUILD_ATOL), max(r, BUILD_RTOL))

    def arrays(self, names, same_build: bool = True):
        """(atol, rtol): arrays (k,) for the signals ``names``."""
        import numpy as np

        pairs = [self.of(n, same_build) for n in names]
        return np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs])

    def check_signals(self, known, where: str) -> None:
        """A one-line error if a per-signal entry names a signal not in ``known``."""
        bad = [n for n, _, _ in self.signals if n not in known]
        if bad:
            raise TwinError(f"{where}: no signal {bad[0]!r} is logged; signals: {', '.join(known)}")

    def describe(self, same_build: bool = True) -> str:
        """What is compared how, in a few words: "bit for bit", or "atol 1e-06, rtol 0; theta: atol
        1e-05, rtol 0" (the signals whose tolerance differs from the overall one)."""
        overall = self.of("", same_build)  # no signal is named "": the overall atol and rtol

        def text(a, r):
            return "bit for bit" if a == 0 and r == 0 else f"atol {a:.3g}, rtol {r:.3g}"

        own = [f"{n}: {text(*self.of(n, same_build))}" for n, _, _ in self.signals
               if self.of(n, same_build) != overall]
        return "; ".join([text(*overall)] + own)


def known_signals(extra=()) -> tuple[str, ...]:
    """Every signal a twin run logs (truth, estimates, commands, actuation, pushes), then ``extra``
    (a controller's own, its ``signals`` attribute)."""
    names = TRUTH_NAMES + ESTIMATE_NAMES + COMMAND_NAMES + tuple(extra) + ACTUATION_NAMES + PUSH_NAMES
    return tuple(dict.fromkeys(names))


def _atol(v, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
        raise TwinError(f"{where}: must be a finite number ≥ 0 in the signal's SI unit (rad, m, N·m, ...), "
                        f"got {v!r}")
    return float(v)


def _rtol(v, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not (0.0 <= v <= RTOL_MAX):
        raise TwinError(f"{where}: must be a number in [0, {RTOL_MAX:g}] (a fraction of |reference|; 1e-6: "
                        f"a millionth), got {v!r}")
    return float(v)


def _signal(name, where: str) -> str:
    if not isinstance(name, str) or not _NAME.match(name):
        raise TwinError(f"{where}: {name!r} is not a signal's name; allowed: a logged signal such as theta, "
                        "psi_dot or torque_l")
    return name


def parse_table(table, where: str = "expect.golden") -> Tolerances:
    """A scenario's ``[expect.golden]`` table; a one-line error naming the key and what is allowed."""
    if not isinstance(table, dict):
        raise TwinError(f"{where}: must be a table with atol, rtol and/or signals, e.g. atol = 1e-6")
    allowed = ("atol", "rtol", "signals")
    for k in table:
        if k not in allowed:
            raise TwinError(f"{where}.{k}: unknown key; allowed here: {', '.join(allowed)}")
    atol = _atol(table["atol"], f"{where}.atol") if "atol" in table else None
    rtol = _rtol(table["rtol"], f"{where}.rtol") if "rtol" in table else None
    signals = table.get("signals", {})
    if not isinstance(signals, dict):
        raise TwinError(f"{where}.signals: must be a table of SIGNAL = {{ atol = ..., rtol = ... }}, e.g. "
                        f"signals = {{ theta = {{ atol = 1e-5 }} }}, got {signals!r}")
    out = []
    for name, entry in signals.items():
        w = f"{where}.signals.{name}"
        _signal(name, w)
        if not isinstance(entry, dict) or not entry or set(entry) - {"atol", "rtol"}:
            raise TwinError(f"{w}: must be a table with atol and/or rtol, e.g. {name} = {{ atol = 1e-5 }}, "
                            f"got {entry!r}")
        out.append((name, _atol(entry["atol"], f"{w}.atol") if "atol" in entry else None,
                    _rtol(entry["rtol"], f"{w}.rtol") if "rtol" in entry else None))
    return Tolerances(atol, rtol, tuple(sorted(out)))


def parse_options(atol: float | None = None, rtol: float | None = None, items=()) -> Tolerances:
    """``--atol``, ``--rtol`` and the ``--tolerance SIGNAL=ATOL[,RTOL]`` items."""
    a = _atol(atol, "--atol") if atol is not None else None
    r = _rtol(rtol, "--rtol") if rtol is not None else None
    own: dict[str, tuple] = {}
    for item in items:
        name, eq, values = item.partition("=")
        name = name.strip()
        parts = [p.strip() for p in values.split(",")]
        if not eq or not name or len(parts) > 2 or not parts[0]:
            raise TwinError(f"--tolerance must be SIGNAL=ATOL or SIGNAL=ATOL,RTOL (e.g. theta=1e-6 or "
                            f"theta=1e-6,1e-9), got {item!r}")
        _signal(name, f"--tolerance {item}")
        if name in own:
            raise TwinError(f"--tolerance names {name} twice; allowed: each signal once")
        nums = []
        for what, text in zip(("ATOL", "RTOL"), parts):
            try:
                nums.append(float(text))
            except ValueError:
                raise TwinError(f"--tolerance {item}: {what} must be a number, got {text!r}") from None
        own[name] = (_atol(nums[0], f"--tolerance {item}: ATOL"),
                     _rtol(nums[1], f"--tolerance {item}: RTOL") if len(nums) > 1 else None)
    return Tolerances(a, r, tuple((n, x, y) for n, (x, y) in sorted(own.items())))


__all__ = ["BUILD_ATOL", "BUILD_RTOL", "Tolerances", "known_signals", "parse_options", "parse_table"]
