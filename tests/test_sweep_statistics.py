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
    assert (e["controller"], e["reference"]) == ("it2", "t1")
    assert e["success"] == {"both": 2, "only_controller": 3, "only_reference": 1, "neither": 0,
                            "mcnemar_p": pytest.approx(0.625)}  # 2·(4 + 1)/16
    assert e["success"]["mcnemar_p"] == pytest.approx(stats.binomtest(3, 4, 0.5).pvalue)
    m = e["metrics"]["iae_theta"]  # pair 2 left out: its type-1 run fell
    d = np.array([-0.5, 0.0, -1.0, 0.5, -3.0])
    assert (m["n_pairs"], m["lower"], m["higher"], m["equal"]) == (5, 3, 1, 1)
    assert m["median_diff"] == -0.5 and m["median_diff_ci"] == (None, None)
    assert m["wilcoxon_p"] == pytest.approx(stats.wilcoxon(d[d != 0]).pvalue)
    assert m["sign_p"] == pytest.approx(0.625) and not m["no_difference"]

    e = entry(p, 0.1)  # all fell: nothing to compare, no exception
    assert e["success"]["neither"] == 3 and e["success"]["mcnemar_p"] == 1.0
    assert e["metrics"]["iae_theta"]["n_pairs"] == 0 and e["metrics"]["iae_theta"]["wilcoxon_p"] == 1.0

    e = entry(p, 0.2)  # the error row's pair is out; IT2 ∞ settling against 4 s is +∞
    s = e["metrics"]["settling_time_s"]
    assert s["n_pairs"] == 3 and (s["lower"], s["higher"]) == (2, 1)
    assert s["wilcoxon_p"] == pytest.approx(stats.wilcoxon([-1.0, 100.0, -1.0]).pvalue)
    assert e["metrics"]["final_heading_error_rad"]["no_difference"]

    e = entry(p, None)
    assert e["n_pairs"] == 13 and (e["success"]["only_controller"], e["success"]["only_reference"]) == (3, 2)


def test_wilcoxon_exact_known_value():
    # five positive distinct differences: T− = 0, exact two-sided p = 2/2⁵
    m = paired_metric([1.0, 2.0, 3.0, 4.0, 5.0])
    assert m["wilcoxon_p"] == pytest.approx(2 / 32) and m["sign_p"] == pytest.approx(2 / 32)
    assert m["higher"] == 5 and m["lower"] == 0 and m["median_diff"] == 3.0


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


# ----------------------------------------------------------------------------- any controllers

from twin.sweep.statistics import controller_labels, default_label, resolve_controllers  # noqa: E402

THREE = ("it2", "t1", "lqr")
PLUGIN = "pkg.mod:Mine"


def ranked_rows(controllers, offset, levels=(0.0, 0.3), per_level=8, fails=None):
    """Rows where controller c's IAE is the sample's base value plus ``offset[c]`` (so the
    paired differences are exactly the offsets' differences) and c's settling time 1 + the
    offset; ``fails[c]``: the samples (per level, 0-based) where c falls."""
    fails = fails or {}
    out = []
    for li, lv in enumerate(levels):
        for j in range(per_level):
            k = li * per_level + j
            base = 1.0 + 0.125 * j
            for c in controllers:
                fell = j in fails.get(c, ())
                out.append(row(k, lv, c, status="fell" if fell else "ok", iae_theta=base + offset[c],
                               settling_time_s=None if fell else 1.0 + offset[c],
                               oscillation_peak_to_peak_rad=1e-3))
    return out


def sections(paired):
    return list(dict.fromkeys((p["controller"], p["reference"]) for p in paired))


def test_default_labels_plugins_and_collisions():
    assert [default_label(c) for c in THREE] == ["IT2", "type-1", "LQR"]
    assert default_label(PLUGIN) == "Mine" and default_label("mine") == "mine"
    assert controller_labels([*THREE, PLUGIN]) == {"it2": "IT2", "t1": "type-1", "lqr": "LQR", PLUGIN: "Mine"}
    # two plugins named alike: both by their full names, the others unchanged
    assert controller_labels(["it2", PLUGIN, "other.mod:Mine"]) == {
        "it2": "IT2", PLUGIN: PLUGIN, "other.mod:Mine": "other.mod:Mine"}
    # given labels win; a given label that collides with a default one falls back too
    assert controller_labels(THREE, {"lqr": "LQR baseline"})["lqr"] == "LQR baseline"
    assert controller_labels(["it2", "t1"], {"t1": "IT2"}) == {"it2": "it2", "t1": "t1"}


def test_controllers_first_seen_and_reference_last():
    rows = ranked_rows(("t1", "lqr", "it2"), {"t1": 0.0, "lqr": 0.0, "it2": 0.0})
    assert resolve_controllers(rows) == (["t1", "lqr", "it2"], "it2")  # no preference for "it2"
    assert resolve_controllers(rows, THREE) == (list(THREE), "lqr")
    assert resolve_controllers(rows, THREE, "it2") == (list(THREE), "it2")
    assert resolve_controllers(rows, ["it2", "t1"]) == (["it2", "t1"], "t1")
    with pytest.raises(ValueError, match="reference"):
        resolve_controllers(rows, ["it2", "t1"], reference="lqr")
    with pytest.raises(ValueError, match="more than once"):
        resolve_controllers(rows, ["it2", "t1", "it2"])
    assert resolve_controllers([]) == ([], None)


def test_three_controllers_summaries_in_the_given_order():
    rows = ranked_rows(THREE, {"it2": 0.0, "t1": 0.5, "lqr": 2.0}, fails={"lqr": (0, 1, 2)})
    s = summarize(rows, controllers=["lqr", "it2", "t1"])
    assert [(e["level"], e["controller"]) for e in s] == [
        (lv, c) for lv in (0.0, 0.3, None) for c in ("lqr", "it2", "t1")]
    s = summarize(rows)  # first seen
    assert [e["controller"] for e in s[:3]] == list(THREE)
    for c, off in (("it2", 0.0), ("t1", 0.5)):
        e = entry(s, 0.0, c)
        assert (e["n"], e["successes"], e["falls"]) == (8, 8, 0)
        assert e["metrics"]["iae_theta"]["median"] == pytest.approx(1.4375 + off)
    e = entry(s, 0.3, "lqr")
    assert (e["n"], e["successes"], e["falls"], e["stayed_up"]) == (8, 5, 3, 5)
    assert e["metrics"]["iae_theta"]["median"] == pytest.approx(1.625 + 2.0)  # of j = 3…7
    assert entry(s, None, "lqr")["falls"] == 6
    # a controller left out of the list is left out of the summary
    assert {e["controller"] for e in summarize(rows, controllers=["it2", "lqr"])} == {"it2", "lqr"}
    # and so are its metrics: one only type-1 has is not summarised without type-1
    rows = [dict(r, final_position_error_m=-0.1) if r["controller"] == "t1" else r for r in rows]
    assert entry(summarize(rows), 0.0, "it2")["metrics"]["final_position_error_m"]["n"] == 0
    assert "final_position_error_m" not in entry(summarize(rows, controllers=["it2", "lqr"]), 0.0, "it2")["metrics"]
    assert "final_position_error_m" not in paired_tests(rows, controllers=["it2", "lqr"])[0]["metrics"]


def test_three_controllers_paired_against_the_last_by_default():
    rows = ranked_rows(THREE, {"it2": 0.0, "t1": 0.5, "lqr": 2.0}, fails={"lqr": (0, 1, 2)})
    p = paired_tests(rows, controllers=THREE)
    assert p == paired_tests(rows)  # default: first seen, reference the last
    assert sections(p) == [("it2", "lqr"), ("t1", "lqr")]
    assert [(e["controller"], e["level"]) for e in p] == [
        (c, lv) for c in ("it2", "t1") for lv in (0.0, 0.3, None)]
    for c, diff in (("it2", -2.0), ("t1", -1.5)):
        e = next(x for x in p if x["controller"] == c and x["level"] == 0.0)
        assert e["reference"] == "lqr" and e["n_pairs"] == 8
        assert e["success"] == {"both": 5, "only_controller": 3, "only_reference": 0, "neither": 0,
                                "mcnemar_p": pytest.approx(0.25)}
        m = e["metrics"]["iae_theta"]  # the 3 pairs where LQR fell are out
        assert (m["n_pairs"], m["lower"], m["higher"], m["equal"]) == (5, 5, 0, 0)
        assert m["median_diff"] == pytest.approx(diff) and m["sign_p"] == pytest.approx(2 / 32)
        assert e["metrics"]["settling_time_s"]["median_diff"] == pytest.approx(diff)
        assert next(x for x in p if x["controller"] == c and x["level"] is None)["n_pairs"] == 16


def test_the_reference_is_honoured():
    rows = ranked_rows(THREE, {"it2": 0.0, "t1": 0.5, "lqr": 2.0}, fails={"lqr": (0,)})
    p = paired_tests(rows, controllers=THREE, reference="it2")
    assert sections(p) == [("t1", "it2"), ("lqr", "it2")]
    for c, diff in (("t1", 0.5), ("lqr", 2.0)):
        e = next(x for x in p if x["controller"] == c and x["level"] is None)
        assert e["reference"] == "it2"
        m = e["metrics"]["iae_theta"]
        assert m["higher"] == m["n_pairs"] and m["lower"] == 0 and m["median_diff"] == pytest.approx(diff)
    e = next(x for x in p if x["controller"] == "lqr" and x["level"] == 0.0)
    assert (e["success"]["only_controller"], e["success"]["only_reference"]) == (0, 1)
    # the middle one as reference: one controller better, one worse
    p = paired_tests(rows, controllers=THREE, reference="t1")
    assert sections(p) == [("it2", "t1"), ("lqr", "t1")]
    d = {x["controller"]: x["metrics"]["iae_theta"]["median_diff"] for x in p if x["level"] is None}
    assert d == {"it2": pytest.approx(-0.5), "lqr": pytest.approx(1.5)}


def test_one_controller_has_no_pairs():
    rows = ranked_rows(("it2",), {"it2": 0.0})
    s, p = summarize(rows), paired_tests(rows)
    assert p == [] and len(s) == 3
    md = summary_markdown(s, p, "Sweep")
    assert "nothing to pair" in md and "against" not in md
    assert summary_json(s, p)["reference"] is None


def test_markdown_and_json_with_a_plugin_and_three_controllers():
    ctl = ["it2", PLUGIN, "t1"]
    rows = ranked_rows(ctl, {"it2": 0.0, PLUGIN: 1.0, "t1": 0.5}, fails={PLUGIN: (0,)})
    s, p = summarize(rows, controllers=ctl), paired_tests(rows, controllers=ctl)
    md = summary_markdown(s, p, "Sweep")
    assert "| 0 | Mine | 8 |" in md and "| 0 | IT2 | 8 |" in md and PLUGIN not in md
    assert md.index("## IT2 against type-1, paired") < md.index("## Mine against type-1, paired")
    assert md.count("paired on the same samples") == 2
    assert "| λ | pairs | both succeed | only Mine | only type-1 | neither | McNemar p |" in md
    assert "median Mine − type-1" in md and "Mine lower / higher / equal" in md
    assert "| all | IAE of θ (rad·s) | 14 | 0.5 [0.5, 0.5] | 0 / 14 / 0 |" in md
    assert "| all | IAE of θ (rad·s) | 16 | -0.5 [-0.5, -0.5] | 16 / 0 / 0 |" in md
    md = summary_markdown(s, p, "Sweep", labels={PLUGIN: "my controller"})
    assert "## my controller against type-1" in md
    j = json.loads(json.dumps(summary_json(s, p), allow_nan=False))
    assert j["controllers"] == ctl and j["reference"] == "t1"
    assert j["labels"] == {"it2": "IT2", PLUGIN: "Mine", "t1": "type-1"}
    assert j["comparisons"] == [{"controller": "it2", "reference": "t1"}, {"controller": PLUGIN, "reference": "t1"}]
    assert all({"controller", "reference", "level"} <= set(e) for e in j["paired"])
    # colliding labels: the full names in the report
    ctl = ["it2", PLUGIN, "other:Mine"]
    rows = ranked_rows(ctl, dict.fromkeys(ctl, 0.0))
    md = summary_markdown(summarize(rows), paired_tests(rows), "Sweep")
    assert f"## {PLUGIN} against other:Mine, paired" in md and "| Mine |" not in md


# ----------------------------------------------------------------------------- sweep.csv rows

def _record(sample, runs, error=""):
    return {"sample": sample, "draw": sample, "level": 0.1, "seed": 7 + sample, "values": {"factor_m_b": 1.05},
            "runs": {c: {"status": "ok", "success": True, "iae_theta": 0.5 + i} for i, c in enumerate(runs)},
            "error": error}


def test_table_rows_follow_the_given_controller_order():
    from twin.sweep.table import columns, record_controllers, rows_of

    recs = [_record(2, ["lqr", "it2", "t1"]), _record(0, ["it2", "t1", "lqr"]), _record(1, [], "worker died")]
    assert record_controllers(recs) == ["it2", "t1", "lqr"]  # first seen, samples in order
    rows = rows_of(recs, ["factor_m_b"], controllers=["lqr", "t1", "it2"])
    assert [(r["sample"], r["controller"]) for r in rows] == [
        (k, c) for k in range(3) for c in ("lqr", "t1", "it2")]
    assert all(r["status"] == "error" and r["error"] == "worker died" for r in rows if r["sample"] == 1)
    assert rows[0]["iae_theta"] == 2.5 and rows[6]["iae_theta"] == 0.5  # sample 0's lqr, sample 2's lqr
    rows = rows_of(recs, ["factor_m_b"])
    assert [r["controller"] for r in rows[:3]] == ["it2", "t1", "lqr"] and len(rows) == 9
    rows = rows_of(recs, ["factor_m_b"], controllers=["t1", "it2"])  # runs of others left out
    assert [(r["sample"], r["controller"]) for r in rows] == [(k, c) for k in range(3) for c in ("t1", "it2")]
    assert set(rows[0]) == set(columns(["factor_m_b"]))


# ----------------------------------------------------------------------------- figures, any controllers

def _capture(monkeypatch):
    """Keep the figures instead of freeing them after saving."""
    import twin.sweep.figures as figures

    kept, save = [], figures._save

    def keep(fig, path):
        kept.append((fig, [(t.get_text(), h) for lg in [*fig.legends, *(a.get_legend() for a in fig.axes)]
                           if lg is not None for t, h in zip(lg.get_texts(), lg.legend_handles)],
                     [(c.get_label(), c.lines[0].get_color()) for a in fig.axes for c in a.containers
                      if hasattr(c, "has_xerr")],
                     [(a.get_title(), a.get_xlabel(), a.get_ylabel()) for a in fig.axes]))
        return save(fig, path)

    monkeypatch.setattr(figures, "_save", keep)
    return kept


def test_figure_colours_labels_and_layout_for_any_controllers(tmp_path, monkeypatch):
    from matplotlib.colors import to_rgba

    from twin.sweep.figures import TAB10, controller_colours, plot_distributions, plot_paired, plot_success

    assert controller_colours(["it2", "t1"]) == {"it2": "tab:blue", "t1": "tab:orange"}
    assert controller_colours(["lqr", "it2"]) == {"lqr": "tab:blue", "it2": "tab:orange"}
    assert controller_colours([f"c{i}" for i in range(12)])["c10"] == TAB10[0]

    kept = _capture(monkeypatch)
    ctl = ["it2", "t1", "lqr", PLUGIN]
    rows = ranked_rows(ctl, {"it2": 0.0, "t1": 0.5, "lqr": 2.0, PLUGIN: 1.0}, fails={"lqr": (0, 1)})
    _check_png(plot_success(summarize(rows, controllers=ctl), tmp_path / "s.png", controllers=ctl))
    _check_png(plot_distributions(rows, tmp_path / "d.png", controllers=ctl, labels={"lqr": "LQR (baseline)"}))
    _check_png(plot_paired(rows, tmp_path / "p.png", controllers=ctl, reference="t1"))

    (_, success, bars, _), (_, dist, _, _), (fig, paired, _, panels) = kept
    assert [t for t, _ in success] == ["IT2", "type-1", "LQR", "Mine"]
    assert [(t, to_rgba(c)) for t, c in bars] == [(t, to_rgba(c)) for t, c in zip(
        ["IT2", "type-1", "LQR", "Mine"], TAB10)]
    assert [t for t, _ in dist] == ["IT2", "type-1", "LQR (baseline)", "Mine"]
    assert [to_rgba(h.get_facecolor())[:3] for _, h in dist] == [to_rgba(c)[:3] for c in TAB10[:4]]
    # one group of panels per controller other than the reference, in order
    metrics = ["IAE of θ", "θ peak-to-peak, last 5 s", "settling time"]
    assert [(t.split(" (")[0], x, y) for t, x, y in panels] == [
        (f"{a} against type-1: {m}", f"type-1 ({u})", f"{a} ({u})")
        for a in ("IT2", "LQR", "Mine") for m, u in zip(metrics, ("rad·s", "rad", "s"))]
    assert {t for t, _ in paired if "=" in t and "λ" not in t} == {"IT2 = type-1", "LQR = type-1", "Mine = type-1"}

    # the default pair keeps its colours and a single comparison keeps its plain titles
    kept.clear()
    two = [r for r in rows if r["controller"] in ("it2", "t1")]
    plot_paired(two, tmp_path / "p2.png")
    plot_success(summarize(two), tmp_path / "s2.png")
    assert [t for t, _, _ in kept[0][3]] == metrics
    assert [(t, to_rgba(c)) for t, c in kept[1][2]] == [("IT2", to_rgba("tab:blue")), ("type-1", to_rgba("tab:orange"))]

    # one controller: nothing to pair, no exception
    one = [r for r in rows if r["controller"] == "lqr"]
    _check_png(plot_paired(one, tmp_path / "p1.png"))
    _check_png(plot_distributions(one, tmp_path / "d1.png"))
