"""Statistics of a Monte Carlo robustness sweep: success rates, metric quantiles, paired tests.

A sweep gives rows, one per (sample, controller), at each uncertainty level λ. Any list of
controllers may run (built-in names such as "it2", "t1", "lqr", or plugins named by import
path, "pkg.mod:Class"); the rows of one sample ran on identical conditions, so each
controller's row is paired with the row of a chosen *reference* controller (by default the
last of the list: for ``["it2", "t1"]``, IT2 against type-1). Nothing here knows a
controller by name: display names come from the registry (:func:`default_label`).
Everything here is distribution-free or exact where it can be:

* success rates: Wilson score intervals;
* quantiles (median, 95th percentile) of a metric: order-statistic (binomial) intervals;
* a controller against the reference on success: exact McNemar test (binomial test on
  discordant pairs);
* a controller against the reference on a metric: median of the paired differences
  ``controller − reference`` with its order-statistic interval, Wilcoxon signed-rank test
  and sign test.

Metrics are summarised over the runs that stayed up (status neither "fell", "diverged"
nor "error"). A run that stayed up but never settled has settling time +∞ (a censored
value): ranks, and so order-statistic intervals and rank tests, stay valid with it, and
dropping such runs would flatter the controller that fails to settle more often.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence

import numpy as np
from scipy import stats
from twin.registry import label

FELL_STATUSES = ("fell", "diverged")


# ---------------------------------------------------------------------------- controllers

def default_label(name: str) -> str:
    """The display name of controller ``name``, as :func:`twin.registry.label` gives it (the
    registry alone knows the built-in kinds): "IT2", "type-1", "LQR" for the built-in "it2",
    "t1", "lqr"; for a plugin named by import path ("pkg.mod:MyController") the attribute
    after the ":" ("MyController"); otherwise ``name`` itself."""
    return label(name) or name


def controller_labels(controllers: Sequence[str], labels: Mapping[str, str] | None = None) -> dict[str, str]:
    """Display names of ``controllers``: ``labels[c]`` where given, else :func:`default_label`.

    Controllers whose labels would coincide are shown by their full names instead, so that
    no two controllers of a report look alike.
    """
    labels = labels or {}
    out = {c: str(labels[c]) if c in labels else default_label(c) for c in controllers}
    counts: dict[str, int] = {}
    for lb in out.values():
        counts[lb] = counts.get(lb, 0) + 1
    return {c: c if counts[lb] > 1 else lb for c, lb in out.items()}


def resolve_controllers(rows: Sequence[dict], controllers: Sequence[str] | None = None,
                        reference: str | None = None) -> tuple[list[str], str | None]:
    """The controllers of a report, in order, and the reference controller.

    Parameters
    ----------
    rows : sequence of dict
        The sweep's rows.
    controllers : sequence of str, optional
        The controllers in the order to report them (e.g. the manifest's ``controllers``);
        rows of other controllers are ignored. None: the controllers of ``rows`` in
        first-seen order.
    reference : str, optional
        The controller every other one is paired with. None: the last of ``controllers``.

    Returns
    -------
    tuple
        ``(controllers, reference)``; ``reference`` is None only without any controller.

    Raises
    ------
    ValueError
        A controller listed twice, or a ``reference`` that is not one of the controllers.
    """
    if controllers is None:
        controllers = list(dict.fromkeys(r["controller"] for r in rows))
    else:
        controllers = [str(c) for c in ([controllers] if isinstance(controllers, str) else controllers)]
        if len(set(controllers)) != len(controllers):
            raise ValueError(f"controllers listed more than once: {controllers}")
    if reference is None:
        reference = controllers[-1] if controllers else None
    elif reference not in controllers:
        raise ValueError(f"reference {reference!r} is not one of the controllers {controllers}")
    return controllers, reference


def _abs(v):
    return None if v is None else abs(float(v))


def _same(v):
    return None if v is None else float(v)


def _never_settled_is_inf(v):
    # only applied to runs that stayed up, where None means "never settled in the run"
    return math.inf if v is None else float(v)


#: Metrics summarised, as (row key, label, unit, transform of the row value).
METRICS: tuple[tuple[str, str, str, Callable], ...] = (
    ("iae_theta", "IAE of θ", "rad·s", _same),
    ("oscillation_peak_to_peak_rad", "θ peak-to-peak, last 5 s", "rad", _same),
    ("final_position_error_m", "|final position error|", "m", _abs),
    ("final_heading_error_rad", "|final heading error|", "rad", _abs),
    ("settling_time_s", "settling time", "s", _never_settled_is_inf),
)


# ---------------------------------------------------------------------------- intervals

def wilson_interval(successes: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion.

    Parameters
    ----------
    successes : int
        Number of successes, ``0 ≤ successes ≤ n``.
    n : int
        Number of trials.
    confidence : float
        Two-sided confidence level (dimensionless, in (0, 1)).

    Returns
    -------
    tuple of float
        ``(lower, upper)`` bounds of the success probability (dimensionless, in [0, 1]);
        ``(0.0, 1.0)`` when ``n == 0``.
    """
    if n == 0:
        return 0.0, 1.0
    z = stats.norm.ppf(0.5 + confidence / 2)
    p, z2 = successes / n, z * z
    denom = 1 + z2 / n
    centre = (p + z2 / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z2 / (4 * n * n)) / denom
    # the exact ends at 0 and n are 0 and 1; clip the rounding error
    lo = 0.0 if successes == 0 else max(0.0, centre - half)
    hi = 1.0 if successes == n else min(1.0, centre + half)
    return float(lo), float(hi)


def _quantile_sorted(x: np.ndarray, q: float) -> float:
    """numpy's default (linear) sample quantile of sorted ``x``, defined with ±∞ values."""
    h = (len(x) - 1) * q
    i = int(math.floor(h))
    f = h - i
    if f == 0 or x[i] == x[i + 1]:
        return float(x[i])
    lo, hi = float(x[i]), float(x[i + 1])
    if math.isinf(lo) or math.isinf(hi):
        # a mix with an infinite neighbour is that infinity; −∞ with +∞ is undefined
        return math.nan if (math.isinf(lo) and math.isinf(hi)) else (lo if math.isinf(lo) else hi)
    return lo + f * (hi - lo)


def order_statistic_ranks(n: int, q: float, confidence: float = 0.95) -> tuple[int, int]:
    """Ranks ``(l, u)`` (1-based) of the order-statistic interval ``[X₍l₎, X₍u₎]`` of the
    ``q`` quantile from ``n`` samples.

    With ``B ~ Bin(n, q)`` the number of samples below the quantile, the interval covers
    it with probability ``P(l ≤ B < u) ≥ confidence`` (exactly so for a continuous
    distribution, conservatively otherwise). The ranks are equal-tailed: ``l`` the largest
    with ``P(B < l) ≤ α/2``, ``u`` the smallest with ``P(B ≥ u) ≤ α/2``
    (``α = 1 − confidence``). ``l = 0`` means no lower bound and ``u = n + 1`` no upper
    bound; when exactly one end is unbounded, its tail has probability 0, so the other end
    takes all of ``α`` (a one-sided bound at ``confidence``).
    """
    alpha = 1 - confidence
    k = np.arange(n)
    cdf, sf = stats.binom.cdf(k, n, q), stats.binom.sf(k, n, q)   # P(B ≤ k), P(B > k)

    def lower(a):  # P(B < l) = cdf[l − 1] is non-decreasing in l
        return int(np.count_nonzero(cdf <= a))

    def upper(a):  # P(B ≥ u) = sf[u − 1] is non-increasing in u
        return 1 + int(np.count_nonzero(sf > a))

    l, u = lower(alpha / 2), upper(alpha / 2)
    if l >= 1 and u == n + 1:
        l = lower(alpha)
    elif l == 0 and u <= n:
        u = upper(alpha)
    return l, u


def quantile_interval(values: Iterable[float], q: float, confidence: float = 0.95
                      ) -> tuple[float | None, float | None, float | None]:
    """Sample quantile and its distribution-free confidence interval.

    Parameters
    ----------
    values : iterable of float
        The sample (any unit; ``None`` entries are ignored; ``+∞`` is allowed, e.g. a
        settling time that never came).
    q : float
        Quantile level, in (0, 1) (0.5 is the median).
    confidence : float
        Two-sided confidence level of the interval.

    Returns
    -------
    tuple
        ``(estimate, lower, upper)`` in the unit of ``values``: the sample quantile
        (numpy's default linear interpolation) and the order-statistic interval of
        :func:`order_statistic_ranks`. An end that ``n`` samples cannot bound is ``None``
        (e.g. the upper end for the 95th percentile with ``n = 20``); all three are
        ``None`` for an empty sample.
    """
    x = np.sort(np.asarray([v for v in values if v is not None], dtype=float))
    n = len(x)
    if n == 0:
        return None, None, None
    est = _quantile_sorted(x, q)
    l, u = order_statistic_ranks(n, q, confidence)
    return (None if math.isnan(est) else est,
            float(x[l - 1]) if l >= 1 else None,
            float(x[u - 1]) if u <= n else None)


# ---------------------------------------------------------------------------- rows

def stayed_up(row: dict) -> bool:
    """Whether a run neither fell, diverged nor errored (its metrics are then summarised)."""
    return row.get("status") not in (*FELL_STATUSES, "error") and not row.get("fell", False)


def metric_value(row: dict, key: str) -> float | None:
    """The summarised value of metric ``key`` for ``row`` (transformed; None if undefined)."""
    transform = next(m[3] for m in METRICS if m[0] == key)
    return transform(row.get(key))


def present_metrics(rows: Sequence[dict]) -> list[tuple[str, str, str, Callable]]:
    """The entries of :data:`METRICS` with a value in at least one run that stayed up."""
    up = [r for r in rows if stayed_up(r)]
    return [m for m in METRICS if any(m[3](r.get(m[0])) is not None for r in up)]


def _levels(rows):
    return sorted({float(r["level"]) for r in rows})


def select_controllers(rows, controllers):
    """The rows (or summary entries) of ``controllers``."""
    keep = set(controllers)
    return [r for r in rows if r["controller"] in keep]


# ---------------------------------------------------------------------------- summary

def summarize(rows: Sequence[dict], confidence: float = 0.95, *,
              controllers: Sequence[str] | None = None) -> list[dict]:
    """Per (level, controller) success rate and metric quantiles.

    Parameters
    ----------
    rows : sequence of dict
        The sweep's rows (see the module docstring).
    confidence : float
        Confidence level of every interval.
    controllers : sequence of str, optional
        The controllers to summarise, in this order (rows of others are ignored; one
        without rows has entries with ``n == 0``). None: those of ``rows``, first-seen order.

    Returns
    -------
    list of dict
        One entry per (level, controller), sorted by level then controller (in the order
        of ``controllers``), then one per controller over all levels (``level`` None). Keys: ``level`` (λ,
        dimensionless), ``controller``, ``confidence``, ``n`` (runs), ``successes``,
        ``success_rate`` (None if ``n == 0``), ``success_ci`` (Wilson), ``falls`` (status "fell" or
        "diverged"), ``errors`` (status "error"), ``stayed_up``, and ``metrics``: for
        each metric of :func:`present_metrics`, a dict with ``n`` (runs that stayed up and
        have the metric), ``n_infinite`` (of them, +∞: never settled), ``median``,
        ``median_ci``, ``p95``, ``p95_ci`` (:func:`quantile_interval`; metric unit).
    """
    controllers, _ = resolve_controllers(rows, controllers)
    rows = select_controllers(rows, controllers)
    metrics = present_metrics(rows)

    def entry(level, controller, group):
        n = len(group)
        succ = sum(bool(r.get("success")) for r in group)
        up = [r for r in group if stayed_up(r)]
        out = {"level": level, "controller": controller, "confidence": confidence,
               "n": n, "successes": succ,
               "success_rate": succ / n if n else None,
               "success_ci": wilson_interval(succ, n, confidence),
               "falls": sum(r.get("status") in FELL_STATUSES for r in group),
               "errors": sum(r.get("status") == "error" for r in group),
               "stayed_up": len(up), "metrics": {}}
        for key, _, _, tf in metrics:
            v = [x for x in (tf(r.get(key)) for r in up) if x is not None]
            med, p95 = quantile_interval(v, 0.5, confidence), quantile_interval(v, 0.95, confidence)
            out["metrics"][key] = {"n": len(v), "n_infinite": sum(math.isinf(x) for x in v),
                                   "median": med[0], "median_ci": med[1:],
                                   "p95": p95[0], "p95_ci": p95[1:]}
        return out

    out = [entry(lv, c, [r for r in rows if float(r["level"]) == lv and r["controller"] == c])
           for lv in _levels(rows) for c in controllers]
    out += [entry(None, c, [r for r in rows if r["controller"] == c]) for c in controllers]
    return out


# ---------------------------------------------------------------------------- paired tests

def paired_rows(rows: Sequence[dict], controller: str, reference: str) -> list[tuple[dict, dict]]:
    """``[(controller_row, reference_row)]`` matched by (level, sample), sorted by them;
    a sample without both rows is left out."""
    if controller == reference:
        raise ValueError(f"a controller is not paired with itself ({controller!r})")
    by_key: dict = {}
    for r in rows:
        if r["controller"] in (controller, reference):
            by_key.setdefault((float(r["level"]), r["sample"]), {})[r["controller"]] = r
    return [(d[controller], d[reference]) for _, d in sorted(by_key.items()) if len(d) == 2]


def _difference(a: float, b: float) -> float:
    # both infinite (e.g. neither settled) is a tie, not NaN
    return 0.0 if (a == b) else a - b


def paired_metric(d: Sequence[float], confidence: float = 0.95) -> dict:
    """Tests on paired differences ``d = controller − reference`` of one metric.

    Returns a dict with ``n_pairs``; ``median_diff`` and ``median_diff_ci`` (the
    order-statistic interval of the median difference, :func:`quantile_interval`);
    ``lower``, ``higher``, ``equal`` (counts of ``d < 0``, ``d > 0``, ``d == 0``: the
    controller's value below, above or equal to the reference's);
    ``wilcoxon_p``: two-sided Wilcoxon signed-rank p-value with the "wilcox" zero
    convention: zero differences are dropped first, then ``scipy.stats.wilcoxon`` (method
    "auto": exact null distribution for ≤ 50 distinct non-zero differences, otherwise
    exact permutations up to 13 or the tie-corrected normal approximation); ``sign_p``:
    two-sided exact sign test (binomial test of ``lower`` among the non-zero
    differences). With no non-zero difference (e.g. bit-identical runs, or no pair) both
    p-values are 1.0 and ``no_difference`` is True, so that nothing is tested.
    """
    d = np.asarray(d, dtype=float)
    nz = d[d != 0]
    lower, higher = int(np.count_nonzero(nz < 0)), int(np.count_nonzero(nz > 0))
    med = quantile_interval(d, 0.5, confidence)
    out = {"n_pairs": len(d), "median_diff": med[0], "median_diff_ci": med[1:],
           "lower": lower, "higher": higher, "equal": len(d) - len(nz),
           "wilcoxon_p": 1.0, "sign_p": 1.0, "no_difference": len(nz) == 0}
    if len(nz):
        # ±∞ (one run never settled) → a finite value beyond every other |d|: same ranks,
        # so the same rank statistic
        fin = nz[np.isfinite(nz)]
        big = 2 * float(np.max(np.abs(fin))) + 1 if len(fin) else 1.0
        ranked = np.where(np.isfinite(nz), nz, np.sign(nz) * big)
        out["wilcoxon_p"] = float(stats.wilcoxon(ranked, zero_method="wilcox").pvalue)
        out["sign_p"] = float(stats.binomtest(lower, len(nz), 0.5).pvalue)
    return out


def paired_tests(rows: Sequence[dict], confidence: float = 0.95, *,
                 controllers: Sequence[str] | None = None, reference: str | None = None) -> list[dict]:
    """Each controller against the reference on the same samples, per level and over all levels.

    Parameters
    ----------
    rows : sequence of dict
        The sweep's rows; a controller's and the reference's rows with the same (level,
        sample) are a pair.
    confidence : float
        Confidence level of the intervals.
    controllers : sequence of str, optional
        The controllers, in the order of the report (see :func:`resolve_controllers`).
        None: those of ``rows``, first-seen order.
    reference : str, optional
        The controller the others are paired with. None: the last of ``controllers``.

    Returns
    -------
    list of dict
        For each controller other than the reference (in the order of ``controllers``), one
        entry per level (sorted), then one over all levels (``level`` None); no entry with
        fewer than two controllers. Keys: ``controller``, ``reference``, ``level``;
        ``n_pairs``; ``success``: ``both``, ``only_controller``, ``only_reference``,
        ``neither`` (pair counts) and ``mcnemar_p``, the exact two-sided McNemar p-value
        (``scipy.stats.binomtest`` of ``only_controller`` among the discordant pairs with
        p = ½; 1.0 without discordant pairs); ``metrics``: for each metric of
        :func:`present_metrics`, :func:`paired_metric` of the differences
        ``controller − reference`` over the pairs in which both runs stayed up and have the
        metric (metric unit).
    """
    controllers, reference = resolve_controllers(rows, controllers, reference)
    rows = select_controllers(rows, controllers)
    metrics = present_metrics(rows)

    def entry(controller, level, group):
        s = [(bool(a.get("success")), bool(b.get("success"))) for a, b in group]
        b_, c_ = s.count((True, False)), s.count((False, True))
        out = {"controller": controller, "reference": reference, "level": level, "n_pairs": len(group),
               "success": {"both": s.count((True, True)), "only_controller": b_, "only_reference": c_,
                           "neither": s.count((False, False)),
                           "mcnemar_p": float(stats.binomtest(b_, b_ + c_, 0.5).pvalue)
                           if b_ + c_ else 1.0},
               "metrics": {}}
        up = [(a, b) for a, b in group if stayed_up(a) and stayed_up(b)]
        for key, _, _, tf in metrics:
            vals = [(tf(a.get(key)), tf(b.get(key))) for a, b in up]
            d = [_difference(x, y) for x, y in vals if x is not None and y is not None]
            out["metrics"][key] = paired_metric(d, confidence)
        return out

    out = []
    for c in controllers:
        if c == reference:
            continue
        pairs = paired_rows(rows, c, reference)
        out += [entry(c, lv, [p for p in pairs if float(p[0]["level"]) == lv]) for lv in _levels(rows)]
        out.append(entry(c, None, pairs))
    return out


def comparisons(paired: Sequence[dict]) -> list[tuple[str, str]]:
    """The (controller, reference) sections of :func:`paired_tests` output, in order."""
    return list(dict.fromkeys((p["controller"], p["reference"]) for p in paired))


# ---------------------------------------------------------------------------- reports

def _num(x) -> str:
    """A value with 3 significant digits; "—" if undefined, "∞" if infinite."""
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "—"
    if math.isinf(x):
        return "∞" if x > 0 else "−∞"
    return f"{x:.3g}"


def _with_ci(est, ci) -> str:
    return f"{_num(est)} [{_num(ci[0])}, {_num(ci[1])}]"


def _level(level) -> str:
    return "all" if level is None else f"{level:g}"


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    line = lambda cells: "| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |"  # noqa: E731
    return [line(header), "|" + "---|" * len(header), *map(line, rows)]


def _rate(s: dict) -> str:
    lo, hi = s["success_ci"]
    rate = "—" if s["success_rate"] is None else f"{s['success_rate']:.3f}"
    return f"{rate} [{lo:.3f}, {hi:.3f}]"


def _report_controllers(summary, paired) -> list[str]:
    """The controllers of a report in its order: the summary's, then any only in ``paired``."""
    return list(dict.fromkeys([*(s["controller"] for s in summary),
                               *(c for pair in comparisons(paired) for c in pair)]))


def summary_markdown(summary: list[dict], paired: list[dict], title: str,
                     notes: Sequence[str] = (), *, labels: Mapping[str, str] | None = None) -> str:
    """The sweep's report in Markdown: success rates, metric quantiles, paired tests.

    Parameters
    ----------
    summary : list of dict
        :func:`summarize` output.
    paired : list of dict
        :func:`paired_tests` output: one section per (controller, reference).
    title : str
        Level-1 heading.
    notes : sequence of str
        Lines written under the title (e.g. the scenario, the number of samples).
    labels : mapping of str to str, optional
        Display names of the controllers (:func:`controller_labels`; default
        :func:`default_label`).

    Returns
    -------
    str
        Markdown text; "—" marks an undefined value or an end no sample can bound.
    """
    pct = f"{100 * (summary[0]['confidence'] if summary else 0.95):g} %"
    names = controller_labels(_report_controllers(summary, paired), labels)
    ctl = names.__getitem__
    keys = list(summary[0]["metrics"]) if summary else []
    info = {m[0]: m for m in METRICS}
    out = [f"# {title}", ""]
    if notes:
        out += [*notes, ""]
    out += ["## Success", ""]
    out += _table(["λ", "controller", "n", f"success rate [{pct} CI]", "falls", "errors"],
                  [[_level(s["level"]), ctl(s["controller"]), str(s["n"]),
                    _rate(s), str(s["falls"]), str(s["errors"])]
                   for s in summary])
    out += ["", f"CI: Wilson score interval, {pct}. Falls: the pendulum fell or the "
            "simulation diverged.", ""]

    out += ["## Metrics over the runs that stayed up", ""]
    if not keys:
        out += ["No run stayed up: no metric to summarise.", ""]
    for key in keys:
        _, label, unit, _ = info[key]
        out += [f"### {label} ({unit})", ""]
        out += _table(["λ", "controller", "n", f"median ({unit}) [{pct} CI]", f"p95 ({unit}) [{pct} CI]"],
                      [[_level(s["level"]), ctl(s["controller"]), str(s["metrics"][key]["n"]),
                        _with_ci(s["metrics"][key]["median"], s["metrics"][key]["median_ci"]),
                        _with_ci(s["metrics"][key]["p95"], s["metrics"][key]["p95_ci"])]
                       for s in summary])
        line = f"CI: distribution-free order-statistic interval, {pct}; \"—\": not bounded by n runs."
        if key == "settling_time_s":
            line += " ∞: never settled within the run."
        out += ["", line, ""]

    sections = comparisons(paired)
    if not sections:
        out += ["## Paired comparison", "", "Fewer than two controllers: nothing to pair.", ""]
    for c, ref in sections:
        a, b = ctl(c), ctl(ref)
        section = [p for p in paired if (p["controller"], p["reference"]) == (c, ref)]
        out += [f"## {a} against {b}, paired on the same samples", "", "### Success", ""]
        out += _table(["λ", "pairs", "both succeed", f"only {a}", f"only {b}", "neither", "McNemar p"],
                      [[_level(p["level"]), str(p["n_pairs"]), *(str(p["success"][k]) for k in
                        ("both", "only_controller", "only_reference", "neither")), _num(p["success"]["mcnemar_p"])]
                       for p in section])
        out += ["", "p: exact two-sided McNemar test (binomial test on the discordant pairs).", ""]
        if keys:
            out += ["### Metrics", ""]
            body = []
            for p in section:
                for key in keys:
                    m, (_, label, unit, _) = p["metrics"][key], info[key]
                    body.append([_level(p["level"]), f"{label} ({unit})", str(m["n_pairs"]),
                                 _with_ci(m["median_diff"], m["median_diff_ci"]),
                                 f"{m['lower']} / {m['higher']} / {m['equal']}",
                                 _num(m["wilcoxon_p"]) + ("" if not m["no_difference"] else
                                                          " (no pairs)" if not m["n_pairs"] else " (all equal)"),
                                 _num(m["sign_p"])])
            out += _table(["λ", "metric", "pairs", f"median {a} − {b} [{pct} CI]",
                           f"{a} lower / higher / equal", "Wilcoxon p", "sign p"], body)
            out += ["", f"Over the pairs in which both runs stayed up. CI: order-statistic interval of "
                    f"the median difference, {pct}. p: two-sided Wilcoxon signed-rank test (zero "
                    "differences dropped) and exact sign test; no test is made without a non-zero "
                    "difference (p = 1).", ""]
    return "\n".join(out)


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        x = float(x)
        if math.isnan(x):
            return None
        return x if math.isfinite(x) else ("inf" if x > 0 else "-inf")
    return x


def summary_json(summary: list[dict], paired: list[dict], *, labels: Mapping[str, str] | None = None) -> dict:
    """:func:`summarize` and :func:`paired_tests` as a JSON-serialisable dict.

    Intervals become two-element lists; undefined values are None; an infinite value
    (e.g. a settling time that never came) is the string "inf" (JSON has no infinity).
    ``metrics`` lists the key, label and unit (SI) of each summarised metric;
    ``controllers`` the controllers in the report's order, ``labels`` their display names
    (:func:`controller_labels` of ``labels``); ``reference`` the controller the others are
    paired with (None without pairs); ``comparisons`` the paired sections, as
    ``{"controller", "reference"}`` (``paired`` holds their entries, each naming both).
    """
    keys = list(summary[0]["metrics"]) if summary else []
    controllers = _report_controllers(summary, paired)
    return _jsonable({"metrics": [{"key": k, "label": lb, "unit": u} for k, lb, u, _ in METRICS if k in keys],
                      "controllers": controllers, "labels": controller_labels(controllers, labels),
                      "reference": paired[0]["reference"] if paired else None,
                      "comparisons": [{"controller": c, "reference": r} for c, r in comparisons(paired)],
                      "summary": summary, "paired": paired})
