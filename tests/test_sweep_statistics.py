"""Statistics and figures of the robustness sweep, checked against hand computations,
scipy and coverage simulations (seeded Generators only)."""
import itertools
import json
import math
import warnings

import numpy as np
import pytest
from scipy import stats

from twin.sweep.statistics import (METRICS, order_statistic_ranks, paired_metric, paired_tests,
                                   quantile_interval, summarize, summary_json, summary_markdown,
                                   wilson_interval)

METRIC_KEYS = ("settling_time_s", "theta_rms_rad", "oscillation_peak_to_peak_rad",
               "final_position_error_m", "final_heading_error_rad", "iae_theta",
               "control_effort", "max_abs_torque_nm", "estimator_theta_rmse_rad")


def row(sample, level, controller, status="ok", success=None, **metrics):
    """A sweep row; metrics not given are None (no position target etc.)."""
    r = {"sample": sample, "draw": sample, "level": level, "seed": 1000 + sample,
         "controller": controller, "status": status,
         "success": (status == "ok") if success is None else success,
         "error": "boom" if status == "error" else "", "fell": status == "fell",
         "factor_m_b": 1.1, "initial_theta_rad": 0.05}
    r.update({k: None for k in METRIC_KEYS})
    if status != "error":
        r.update(metrics)
    return r


@pytest.fixture
def rows():
    """Level 0: six pairs, hand-computed below. Level 0.1: every run fell. Level 0.2: an
    error row, a run that never settled. No position target (its metric is all None)."""
    out = []
    it2_iae, t1_iae = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0], [1.5, 2.0, 99.0, 5.0, 4.5, 9.0]
    success = [(True, True), (True, True), (True, False), (True, False), (True, False), (False, True)]
    for k in range(6):
        s_it2, s_t1 = success[k]
        out.append(row(k, 0.0, "it2", success=s_it2, iae_theta=it2_iae[k],
                       final_heading_error_rad=-0.01 * (k + 1), settling_time_s=1.0 + k,
                       oscillation_peak_to_peak_rad=1e-3))
        out.append(row(k, 0.0, "t1", status="fell" if k == 2 else "ok", success=s_t1,
                       iae_theta=t1_iae[k], final_heading_error_rad=0.02 * (k + 1),
                       settling_time_s=None if k == 2 else 2.0 + k,
                       oscillation_peak_to_peak_rad=2e-3))
    for k in range(6, 9):
        for c, st in (("it2", "fell"), ("t1", "diverged")):
            out.append(row(k, 0.1, c, status=st, iae_theta=50.0))
    for k in range(9, 13):
        out.append(row(k, 0.2, "it2", status="error" if k == 9 else "ok", iae_theta=1.0 + k,
                       settling_time_s=None if k == 10 else 3.0, final_heading_error_rad=0.0,
                       oscillation_peak_to_peak_rad=1e-3))
        out.append(row(k, 0.2, "t1", iae_theta=2.0 + k, settling_time_s=4.0,
                       final_heading_error_rad=0.0, oscillation_peak_to_peak_rad=1e-3))
    return out


def entry(entries, level, controller=None):
    return next(e for e in entries if e["level"] == level
                and (controller is None or e["controller"] == controller))


# ----------------------------------------------------------------------------- Wilson

def test_wilson_hand_computed_and_edges():
    lo, hi = wilson_interval(8, 10)
    assert lo == pytest.approx(0.4902, abs=1e-4) and hi == pytest.approx(0.9433, abs=1e-4)
    assert wilson_interval(0, 0) == (0.0, 1.0)
    z2 = stats.norm.ppf(0.975) ** 2
    lo, hi = wilson_interval(10, 10)
    assert hi == 1.0 and lo == pytest.approx(10 / (10 + z2))  # closed form at p̂ = 1
    lo, hi = wilson_interval(0, 10)
    assert lo == 0.0 and hi == pytest.approx(z2 / (10 + z2))
    lo90, hi90 = wilson_interval(8, 10, 0.90)
    assert 0.4902 < lo90 < hi90 < 0.9433


# ----------------------------------------------------------------------------- quantiles

def test_order_statistic_ranks_textbook_and_exact_coverage():
    # textbook (Conover) 95 % median ranks
    assert order_statistic_ranks(50, 0.5) == (18, 33)
    assert order_statistic_ranks(20, 0.5) == (6, 15)
    for n, q in itertools.product((1, 5, 10, 20, 37, 100), (0.5, 0.9, 0.95)):
        lo, up = order_statistic_ranks(n, q)
        cover = stats.binom.cdf(up - 1, n, q) - (stats.binom.cdf(lo - 1, n, q) if lo >= 1 else 0.0)
        assert 0 <= lo < up <= n + 1
        assert cover >= 0.95 - 1e-12


def test_quantile_estimate_matches_numpy():
    x = np.random.default_rng(3).lognormal(size=37)
    for q in (0.5, 0.95, 0.1):
        assert quantile_interval(x, q)[0] == pytest.approx(np.quantile(x, q), rel=1e-12)
    assert quantile_interval([], 0.5) == (None, None, None)
    assert quantile_interval([None, 2.0], 0.5) == (2.0, None, None)


def test_quantile_interval_unbounded_ends():
    x = np.arange(1.0, 21.0)[::-1]  # n = 20, unsorted on purpose
    est, lo, hi = quantile_interval(x, 0.95)
    assert est == pytest.approx(19.05)
    # B ~ Bin(20, 0.95): P(B ≤ 16) = 0.016 ≤ 0.05 < P(B ≤ 17) = 0.075; no upper bound
    assert hi is None and lo == 17.0
    # median from 5: P(B = 0) = 1/32 > 0.025 on each side: unbounded both ways
    assert quantile_interval([1.0, 2.0, 3.0, 4.0, 5.0], 0.5) == (3.0, None, None)
    # median from 6: P(B = 0) = 1/64 ≤ 0.025: the extremes
    assert quantile_interval([4.0, 1.0, 6.0, 2.0, 5.0, 3.0], 0.5) == (3.5, 1.0, 6.0)


@pytest.mark.parametrize("q,n", [(0.5, 50), (0.95, 100)])
def test_quantile_interval_coverage(q, n):
    rng = np.random.default_rng(20240611)
    truth = -math.log(1 - q)  # exponential(1) quantile
    hits = 0
    for _ in range(2000):
        _, lo, hi = quantile_interval(rng.exponential(size=n), q)
        hits += (lo is None or lo <= truth) and (hi is None or truth <= hi)
    lo_r, up_r = order_statistic_ranks(n, q)
    nominal = stats.binom.cdf(up_r - 1, n, q) - stats.binom.cdf(lo_r - 1, n, q)
    assert hits / 2000 >= 0.94
    # and it is the advertised coverage, not a trivially wide interval (3.5 binomial SE)
    assert abs(hits / 2000 - nominal) < 3.5 * math.sqrt(nominal * (1 - nominal) / 2000)


def test_quantile_with_infinite_values():
    est, lo, hi = quantile_interval([1.0, 2.0, 3.0, 4.0, 5.0, math.inf, math.inf], 0.95)
    assert est == math.inf and hi is None
    assert quantile_interval([1.0, 2.0, 3.0, math.inf, math.inf, math.inf], 0.5)[0] == math.inf


# ----------------------------------------------------------------------------- summary

def test_summarize_hand_computed(rows):
    s = summarize(rows)
    assert [(e["level"], e["controller"]) for e in s] == [
        (0.0, "it2"), (0.0, "t1"), (0.1, "it2"), (0.1, "t1"), (0.2, "it2"), (0.2, "t1"),
        (None, "it2"), (None, "t1")]
    # no position target: left out; heading absolute
    assert set(entry(s, 0.0)["metrics"]) == {"iae_theta", "oscillation_peak_to_peak_rad",
                                              "final_heading_error_rad", "settling_time_s"}

    e = entry(s, 0.0, "it2")
    assert (e["n"], e["successes"], e["falls"], e["errors"]) == (6, 5, 0, 0)
    assert e["success_rate"] == pytest.approx(5 / 6)
    assert e["success_ci"] == pytest.approx(wilson_interval(5, 6))
    iae = e["metrics"]["iae_theta"]
    assert iae["n"] == 6 and iae["median"] == 3.5 and iae["median_ci"] == (1.0, 6.0)
    # p95 of 1..6: 5 + 0.75; no upper bound; one-sided lower rank 5 (P(B ≤ 4) = 0.033 ≤ 0.05)
    assert iae["p95"] == pytest.approx(5.75) and iae["p95_ci"] == (5.0, None)
    assert e["metrics"]["final_heading_error_rad"]["median"] == pytest.approx(0.035)

    e = entry(s, 0.0, "t1")  # the fallen run (IAE 99) is left out
    assert (e["n"], e["successes"], e["falls"], e["stayed_up"]) == (6, 3, 1, 5)
    assert e["metrics"]["iae_theta"]["median"] == 4.5 and e["metrics"]["iae_theta"]["n"] == 5

    for c in ("it2", "t1"):  # every run fell
        e = entry(s, 0.1, c)
        assert (e["n"], e["successes"], e["falls"], e["success_rate"]) == (3, 0, 3, 0.0)
        assert e["metrics"]["iae_theta"] == {"n": 0, "n_infinite": 0, "median": None,
                                             "median_ci": (None, None), "p95": None,
                                             "p95_ci": (None, None)}

    e = entry(s, 0.2, "it2")
    assert (e["n"], e["errors"], e["falls"], e["successes"]) == (4, 1, 0, 3)
    st_ = e["metrics"]["settling_time_s"]  # never settled counts as +∞, not dropped
    assert st_["n"] == 3 and st_["n_infinite"] == 1 and st_["median"] == 3.0

    e = entry(s, None, "it2")
    assert (e["n"], e["successes"], e["falls"], e["errors"]) == (13, 8, 3, 1)
    assert e["metrics"]["iae_theta"]["n"] == 9


def test_paired_tests_hand_computed(rows):
    p = paired_tests(rows)
    assert [e["level"] for e in p] == [0.0, 0.1, 0.2, None]
    e = entry(p, 0.0)
    assert e["success"] == {"both": 2, "it2_only": 3, "t1_only": 1, "neither": 0,
                            "mcnemar_p": pytest.approx(0.625)}  # 2·(4 + 1)/16
    assert e["success"]["mcnemar_p"] == pytest.approx(stats.binomtest(3, 4, 0.5).pvalue)
    m = e["metrics"]["iae_theta"]  # pair 2 left out: its type-1 run fell
    d = np.array([-0.5, 0.0, -1.0, 0.5, -3.0])
    assert (m["n_pairs"], m["it2_lower"], m["it2_higher"], m["equal"]) == (5, 3, 1, 1)
    assert m["median_diff"] == -0.5 and m["median_diff_ci"] == (None, None)
    assert m["wilcoxon_p"] == pytest.approx(stats.wilcoxon(d[d != 0]).pvalue)
    assert m["sign_p"] == pytest.approx(0.625) and not m["no_difference"]

    e = entry(p, 0.1)  # all fell: nothing to compare, no exception
    assert e["success"]["neither"] == 3 and e["success"]["mcnemar_p"] == 1.0
    assert e["metrics"]["iae_theta"]["n_pairs"] == 0 and e["metrics"]["iae_theta"]["wilcoxon_p"] == 1.0

    e = entry(p, 0.2)  # the error row's pair is out; IT2 ∞ settling against 4 s is +∞
    s = e["metrics"]["settling_time_s"]
    assert s["n_pairs"] == 3 and (s["it2_lower"], s["it2_higher"]) == (2, 1)
    assert s["wilcoxon_p"] == pytest.approx(stats.wilcoxon([-1.0, 100.0, -1.0]).pvalue)
    assert e["metrics"]["final_heading_error_rad"]["no_difference"]

    e = entry(p, None)
    assert e["n_pairs"] == 13 and (e["success"]["it2_only"], e["success"]["t1_only"]) == (3, 2)


def test_wilcoxon_exact_known_value():
    # five positive distinct differences: T− = 0, exact two-sided p = 2/2⁵
    m = paired_metric([1.0, 2.0, 3.0, 4.0, 5.0])
    assert m["wilcoxon_p"] == pytest.approx(2 / 32) and m["sign_p"] == pytest.approx(2 / 32)
    assert m["it2_higher"] == 5 and m["median_diff"] == 3.0


def test_identical_runs_give_no_difference():
    rows = [row(k, lv, c, iae_theta=0.1 * (k + 1), settling_time_s=None if k % 4 else 2.0,
                oscillation_peak_to_peak_rad=1e-3)
            for k, lv in enumerate([0.0] * 30) for c in ("it2", "t1")]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        p = paired_tests(rows)
        s = summarize(rows)
    for e in p:
        assert e["success"]["mcnemar_p"] == 1.0
        for m in e["metrics"].values():
            assert m["no_difference"] and m["wilcoxon_p"] == 1.0 and m["sign_p"] == 1.0
            assert m["median_diff"] == 0.0 and m["median_diff_ci"] == (0.0, 0.0)
            assert m["equal"] == m["n_pairs"] == 30
    json.dumps(summary_json(s, p), allow_nan=False)


# ----------------------------------------------------------------------------- reports

def test_markdown_and_json(rows):
    s, p = summarize(rows), paired_tests(rows)
    md = summary_markdown(s, p, "Sweep", notes=["scenario: test", "N = 6"])
    assert md.startswith("# Sweep") and "scenario: test" in md
    lo, hi = wilson_interval(5, 6)
    assert f"0.833 [{lo:.3f}, {hi:.3f}]" in md and "0.833 [0.436, 0.970]" in md
    assert "3.5 [1, 6]" in md and "5.75 [5, —]" in md        # IT2 IAE at λ = 0
    assert "| 0 | 6 | 2 | 3 | 1 | 0 | 0.625 |" in md           # McNemar row
    assert "-0.5 [—, —]" in md and "3 / 1 / 1" in md           # paired IAE at λ = 0
    assert "position" not in md and "Wilson" in md and "order-statistic" in md
    assert "∞" in md and "1 (no pairs)" in md and "1 (all equal)" in md
    assert "\\|final heading error\\|" in md  # a "|" in a cell would break the table
    j = summary_json(s, p)
    text = json.dumps(j, allow_nan=False)
    back = json.loads(text)
    assert back == j
    assert [m["key"] for m in back["metrics"]] == [k for k, *_ in METRICS if k != "final_position_error_m"]
    e = next(x for x in back["summary"] if x["level"] == 0.0 and x["controller"] == "it2")
    assert e["metrics"]["iae_theta"]["p95_ci"] == [5.0, None]
    e = next(x for x in back["summary"] if x["level"] == 0.2 and x["controller"] == "it2")
    assert e["metrics"]["settling_time_s"]["p95"] == "inf"


# ----------------------------------------------------------------------------- figures

def _check_png(path):
    import matplotlib.image as mpimg

    assert path.exists() and path.stat().st_size > 0
    img = mpimg.imread(path)
    assert img.ndim == 3 and img.shape[0] > 100 and img.shape[1] > 100


def test_figures(rows, tmp_path):
    from twin.sweep.figures import plot_distributions, plot_paired, plot_success

    single = [r for r in rows if r["level"] == 0.0]
    all_fell = [r for r in rows if r["level"] == 0.1]
    spread = [row(k, 0.0, c, iae_theta=10.0 ** (k - 3), settling_time_s=1.0)  # log scale
              for k in range(8) for c in ("it2", "t1")]
    for name, data in (("full", rows), ("single", single), ("fell", all_fell), ("log", spread)):
        _check_png(plot_success(summarize(data), tmp_path / f"{name}_success.png"))
        _check_png(plot_distributions(data, tmp_path / f"{name}_dist.png"))
        _check_png(plot_paired(data, tmp_path / name / "paired.png"))
