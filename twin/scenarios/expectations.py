"""Expectations: bounds on a run's metrics from a scenario's ``[expect]`` table, and their verdicts.

The TOML form reads like the bound it states, one key per bound::

    [expect]                                  # for every controller
    fell = false
    settling_time_s = "<= 9"                  # s
    "|final_position_error_m|" = "<= 0.02"    # m: |x| bounds the magnitude
    oscillation_peak_to_peak_rad = "<= 0.02"

    [expect.lqr]                              # for one controller kind (quote an import path); an
                                              # "export:DIR" is held to its controller's (expect.it2 ...)
    settling_time_s = "<= 14"

    [expect.seeds]                            # over the seeds of 'twin check --seeds N'
    pass_rate = ">= 0.95"                     # fraction of seeds on which every bound above holds
    "p95(iae_theta)" = "<= 0.8"               # a statistic over the seeds: mean, median, min, max, pNN

    [expect.golden]                           # tolerances of 'twin check --golden' (twin.outputs.tolerances)
    atol = 1e-6                               # in each signal's SI unit
    signals = { theta = { atol = 1e-5 } }

Why this form: the key is the quantity (a metric of :func:`twin.outputs.metrics.run_metrics`,
optionally ``|…|`` and a statistic over seeds) and the value is the comparison
(``<=``, ``<``, ``>=``, ``>``, ``==`` and a number, or true/false for ``fell``), so a
bound is read exactly as it is written in a report: ``|final_position_error_m| <= 0.02``.
Quoting is needed only where the key has ``|`` or ``(``.

Meaning. A per-run bound must hold on every seed, unless ``[expect.seeds]`` sets a
``pass_rate``: then it is the fraction of seeds on which all the per-run bounds of a
controller hold that must meet it. A metric that is undefined (``settling_time_s`` of
a run that never settles, a position error without a position target) fails a per-run
bound, and in a statistic counts on the failing side of its bound (+∞ under a cap such as
``<=``, −∞ over a floor such as ``>=``).
"""
from __future__ import annotations

import math
import operator
import re
from dataclasses import dataclass

from twin.errors import TwinError
from twin.outputs.tolerances import parse_table
from twin.registry import check_kind, exported_kind

# the metrics of twin.outputs.metrics.run_metrics that a bound may name, with their units
METRICS = {
    "fell": "true/false", "settling_time_s": "s", "theta_rms_rad": "rad", "oscillation_peak_to_peak_rad": "rad",
    "final_theta_rad": "rad", "final_distance_m": "m", "final_heading_rad": "rad", "final_position_error_m": "m",
    "final_heading_error_rad": "rad", "iae_theta": "rad·s", "control_effort": "N²·m²·s", "max_abs_torque_nm": "N·m",
    "estimator_theta_rmse_rad": "rad", "rejected_measurements": "1", "duration_s": "s",
    "estimator_events": "1", "estimator_nees_mean": "1", "estimator_nis_per_dof": "1",
}
WHOLE_NUMBERS = ("rejected_measurements", "rejected_total", "estimator_events")  # the metrics == may compare
# the metrics of a replay on a sensor log (twin.logs.replay) that a log's [expect] may name
REPLAY_METRICS = {
    "theta_rmse_rad": "rad", "theta_max_abs_rad": "rad", "psi_rmse_rad": "rad", "psi_max_abs_rad": "rad",
    "alpha_rmse_rad": "rad", "alpha_max_abs_rad": "rad", "nis_per_dof": "1", "rejected_total": "1",
    "nees_mean": "1", "whiteness_outside_fraction": "1",
}
OPS = {"<=": operator.le, "<": operator.lt, ">=": operator.ge, ">": operator.gt, "==": operator.eq}
ALL = "*"  # the scope of the bounds that apply to every controller
SEEDS = "seeds"  # the table of bounds over seeds
GOLDEN = "golden"  # the tolerances of golden comparisons (twin.outputs.tolerances), not bounds
_KEY = re.compile(r"^(?:(?P<stat>mean|median|min|max|p\d{1,2})\()?(?P<bar>\|)?(?P<metric>[a-z_]+)(?P<bar2>\|)?"
                  r"(?P<close>\))?$")
_VALUE = re.compile(r"^\s*(?P<op><=|>=|==|<|>)\s*(?P<num>[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?)\s*$")


class ExpectError(TwinError):
    """An invalid ``[expect]`` entry (the message names the key and what is allowed)."""


@dataclass(frozen=True)
class Bound:
    """One bound: ``stat(|metric|) op value`` (``stat`` None: on each run)."""

    key: str
    metric: str
    absolute: bool
    stat: str | None
    op: str
    value: float | bool

    def __str__(self) -> str:
        value = str(self.value).lower() if isinstance(self.value, bool) else f"{self.value:g}"
        return f"{self.key} {self.op} {value}"

    @property
    def unit(self) -> str:
        return "1" if self.metric == "pass_rate" else {**METRICS, **REPLAY_METRICS}[self.metric]

    def measure(self, metrics: dict):
        """This bound's quantity in one run's metrics (None where undefined)."""
        v = metrics.get(self.metric)
        if v is None or isinstance(v, bool):
            return v
        v = float(v)
        return abs(v) if self.absolute else v

    def holds(self, measured) -> bool:
        if measured is None or (isinstance(measured, float) and math.isnan(measured)):
            return False
        if isinstance(self.value, bool):
            return bool(measured) == self.value
        return bool(OPS[self.op](float(measured), self.value))


def parse_bound(key: str, value, where: str, over_seeds: bool, metrics: dict = METRICS) -> Bound:
    """One ``key = value`` of an ``[expect]`` table; ``where`` names it in errors; ``metrics``
    the quantities it may name (a run's, :data:`METRICS`, or a replay's, :data:`REPLAY_METRICS`)."""
    if over_seeds and key == "pass_rate":
        stat, metric, absolute = None, "pass_rate", False
    else:
        m = _KEY.match(key)
        if not m or bool(m["bar"]) != bool(m["bar2"]) or bool(m["stat"]) != bool(m["close"]):
            raise ExpectError(f"{where}: {key!r} is not a bound's quantity; allowed: a metric, |metric|"
                              + (", stat(metric) with stat mean, median, min, max or pNN, or pass_rate" if over_seeds
                                 else "") + f" (metrics: {', '.join(metrics)})")
        stat, metric, absolute = m["stat"], m["metric"], bool(m["bar"])
        if metric not in metrics:
            raise ExpectError(f"{where}: unknown metric {metric!r}; allowed: {', '.join(metrics)}")
        if over_seeds != (stat is not None):
            raise ExpectError(f"{where}: " + (f"{key!r} needs a statistic over seeds here (mean, median, min, max, "
                                              f"pNN), e.g. 'p95({key})', or pass_rate" if over_seeds else
                                              f"a statistic over seeds ({stat}) belongs in [expect.seeds]"))
        if stat and stat.startswith("p") and not 1 <= int(stat[1:]) <= 99:
            raise ExpectError(f"{where}: percentile {stat!r} out of range; allowed p1 to p99")
    if metric == "fell" and absolute:
        raise ExpectError(f"{where}: |fell| has no meaning; fell takes true or false")
    if metric == "fell" and stat is None:
        if not isinstance(value, bool):
            raise ExpectError(f"{where}: fell takes true or false, got {value!r}")
        return Bound(key, metric, absolute, stat, "==", value)
    m = _VALUE.match(value) if isinstance(value, str) else None
    if not m:
        raise ExpectError(f"{where}: {value!r} is not a bound; allowed: a string \"<op> number\" with op one of "
                          f"<=, <, >=, >, == (e.g. \"<= 0.02\", in {metrics.get(metric, '1')})")
    number = float(m["num"])
    if not math.isfinite(number):
        raise ExpectError(f"{where}: {value!r} is not a finite number")
    if m["op"] == "==" and metric not in WHOLE_NUMBERS and not (metric == "fell"):
        raise ExpectError(f"{where}: == on a real-valued metric holds only by accident of rounding; use <= and >= "
                          f"(== is for whole numbers: rejected_measurements, estimator_events)")
    if metric == "pass_rate" and not 0.0 <= number <= 1.0:
        raise ExpectError(f"{where}: a pass rate is a fraction in [0, 1], got {number:g}")
    return Bound(key, metric, absolute, stat, m["op"], number)


def parse_expect(table, path: str = "expect", metrics: dict = METRICS,  # noqa: C901
                 role: str = "controller") -> dict[str, tuple[Bound, ...]]:
    """The ``[expect]`` table as scope → bounds: :data:`ALL` for every controller, a kind for one,
    :data:`SEEDS` for the statistics over seeds (and ``pass_rate``). ``[expect.golden]`` holds
    tolerances, not bounds: validated here, read by :mod:`twin.verify.check`. A sensor log's
    ``[expect]`` names :data:`REPLAY_METRICS` and estimator kinds (``role`` "estimator")."""
    if not isinstance(table, dict):
        raise ExpectError(f"{path}: must be a table of bounds, e.g. fell = false, settling_time_s = \"<= 9\"")
    out: dict[str, list[Bound]] = {}
    for key, value in table.items():
        if key == GOLDEN:
            try:
                parse_table(value, f"{path}.{GOLDEN}")
            except TwinError as exc:
                raise ExpectError(str(exc)) from None
            continue
        if isinstance(value, dict):
            over = key == SEEDS
            if not over:
                try:
                    check_kind(role, key)
                except TwinError as exc:
                    raise ExpectError(f"{path}.{key}: a sub-table is [expect.seeds], [expect.golden] or "
                                      f"[expect.KIND] for one {role}; {exc}") from None
            for k, v in value.items():
                out.setdefault(key, []).append(parse_bound(k, v, f"{path}.{key}.{k}", over, metrics))
        else:
            out.setdefault(ALL, []).append(parse_bound(key, value, f"{path}.{key}", False, metrics))
    return {k: tuple(v) for k, v in out.items()}


@dataclass(frozen=True)
class Verdict:
    """A bound checked on one run (``seed``) or over seeds (``seed`` None)."""

    controller: str
    seed: int | None
    bound: Bound
    measured: object
    holds: bool
    detail: str = ""  # a pass_rate's: the seeds that broke a bound, and which

    def measured_text(self, full: bool = False) -> str:
        """The measured value for a report: 4 significant digits, or (``full``) 6, and every digit
        only where 6 would print the bound's own value."""
        v = self.measured
        if v is None:
            return "undefined"
        if isinstance(v, bool):
            return str(v).lower()
        if not full:
            return f"{v:.4g}"
        text = f"{float(v):.6g}"
        bound = self.bound.value
        if not isinstance(bound, bool) and float(text) == float(bound) and float(v) != float(bound):
            return repr(float(v))
        return text

    def measured_with_unit(self, full: bool = True) -> str:
        """:meth:`measured_text` with the metric's unit; none where it is "1", nor after
        "undefined" or a truth value."""
        text = self.measured_text(full=full)
        unit = self.bound.unit
        if self.measured is None or isinstance(self.measured, bool) or unit in ("", "1"):
            return text
        return f"{text} {unit}"


def _stat(name: str, values: list[float], undefined: float = math.inf) -> float:
    xs = sorted(undefined if v is None else float(v) for v in values)
    if name == "mean":
        return math.fsum(xs) / len(xs)
    if name == "min":
        return xs[0]
    if name == "max":
        return xs[-1]
    q = 0.5 if name == "median" else int(name[1:]) / 100.0
    # linear interpolation between order statistics (numpy's default 'linear'); an infinite
    # neighbour is not interpolated towards (0 · ∞ is NaN): the value is infinite once past it
    pos = q * (len(xs) - 1)
    lo = math.floor(pos)
    hi = min(lo + 1, len(xs) - 1)
    if pos == lo or xs[lo] == xs[hi]:
        return xs[lo]
    if math.isinf(xs[hi]) or math.isinf(xs[lo]):
        return xs[hi] if math.isinf(xs[hi]) else xs[lo]
    return xs[lo] + (pos - lo) * (xs[hi] - xs[lo])


def evaluate(bounds: dict[str, tuple[Bound, ...]], controller: str, runs: dict[int, dict]) -> list[Verdict]:
    """The verdicts of ``controller``'s runs (seed → :func:`twin.outputs.metrics.run_metrics` dict)."""
    # an export's C is held to the bounds of the controller it was made from, unless it has its own
    per_run = bounds.get(ALL, ()) + bounds.get(controller, bounds.get(exported_kind(controller), ()))
    over = bounds.get(SEEDS, ())
    out = []
    passed = 0
    broke = []  # (seed, the bounds it broke)
    for seed, metrics in sorted(runs.items()):
        measured = [(b, b.measure(metrics)) for b in per_run]
        verdicts = [Verdict(controller, seed, b, m, b.holds(m)) for b, m in measured]
        passed += all(v.holds for v in verdicts)
        if not all(v.holds for v in verdicts):
            broke.append(f"seed {seed} broke " + ", ".join(f"{v.bound} ({v.measured_with_unit()})"
                                                           for v in verdicts if not v.holds))
        out += verdicts
    for b in over:
        if b.metric == "pass_rate":
            value = passed / len(runs)
            out.append(Verdict(controller, None, b, value, b.holds(value),
                               f"{passed} of {len(runs)} seeds held every bound" + ("; " if broke else "")
                               + "; ".join(broke)))
            continue
        else:
            values = [b.measure(m) for m in runs.values()]
            # an undefined value is on the failing side of the bound: +∞ under a cap, −∞ over a floor
            worst = math.inf if b.op in ("<=", "<") else -math.inf if b.op in (">=", ">") else math.nan
            value = _stat(b.stat, [float(v) if isinstance(v, bool) else v for v in values], worst)
        out.append(Verdict(controller, None, b, value, b.holds(value)))
    return out


def failed(verdicts: list[Verdict], bounds: dict[str, tuple[Bound, ...]]) -> list[Verdict]:
    """The verdicts that fail the check: with a pass_rate, per-run failures are the rate's to judge."""
    has_rate = any(b.metric == "pass_rate" for b in bounds.get(SEEDS, ()))
    return [v for v in verdicts if not v.holds and (v.seed is None or not has_rate)]


__all__ = ["ALL", "Bound", "ExpectError", "GOLDEN", "METRICS", "REPLAY_METRICS", "SEEDS", "Verdict", "evaluate", "failed", "parse_bound",
           "parse_expect"]
