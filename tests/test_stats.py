"""``benchmarks.stats``: Welch's interval and Mann–Whitney's U against values computed by hand and, once, by
``scipy.stats`` (``ttest_ind(equal_var=False).confidence_interval()``, ``mannwhitneyu``), written here as
literals; the verdict rule."""

from __future__ import annotations

import math

import pytest

from benchmarks import stats

UNEQUAL = ([2414.0, 1900, 3100, 560, 2900, 2200, 1800, 3239], [1925.0, 1200, 2600, 1500, 2800, 900, 2100])
TIES = ([1.0, 2, 2, 3, 5], [2.0, 3, 3, 4])


def test_welch_by_hand_with_equal_sizes_and_variances():
    """a = 1…5, b = 3…7: difference −2, each variance 2.5 over 5 seeds, so se = 1 and df = 8; t(0.975, 8) =
    2.306 from the t table: the interval −2 ± 2.306."""
    w = stats.welch([1, 2, 3, 4, 5], [3, 4, 5, 6, 7])
    assert w["diff"] == -2.0 and w["se"] == pytest.approx(1.0) and w["df"] == pytest.approx(8.0)
    assert w["lo"] == pytest.approx(-2 - 2.306004, abs=1e-6) and w["hi"] == pytest.approx(-2 + 2.306004, abs=1e-6)
    assert w["p"] == pytest.approx(0.08051623795726262, rel=1e-9)  # scipy


def test_welch_matches_scipy_with_unequal_sizes_and_variances():
    w = stats.welch(*UNEQUAL)
    assert w["diff"] == pytest.approx(403.4107142857142, rel=1e-12)
    assert (w["lo"], w["hi"]) == pytest.approx((-477.6522669583612, 1284.4736955297897), rel=1e-9)
    assert w["df"] == pytest.approx(12.93782493662364, rel=1e-9) and w["p"] == pytest.approx(0.3404946596571234)


def test_welch_needs_two_values_a_side_and_takes_constant_sides():
    with pytest.raises(ValueError, match="at least 2 values"):
        stats.welch([1.0], [1.0, 2.0])
    same = stats.welch([1000.0] * 3, [1000.0] * 3)
    assert (same["diff"], same["lo"], same["hi"], same["p"]) == (0.0, 0.0, 0.0, 1.0)
    apart = stats.welch([5.0, 5.0], [3.0, 3.0])
    assert (apart["lo"], apart["hi"], apart["p"]) == (2.0, 2.0, 0.0)


def test_u_distribution_by_hand():
    """Sizes 2 and 2: the 6 orders aabb … bbaa give U = 0, 1, 2, 2, 3, 4."""
    assert stats.u_counts(2, 2).tolist() == [1, 1, 2, 1, 1]
    assert stats.u_counts(3, 3).sum() == math.comb(6, 3) and stats.u_counts(8, 7).sum() == math.comb(15, 7)


def test_mann_whitney_exact_by_hand_and_against_scipy():
    """a = 1, 2, 3 below b = 4, 5, 6: U = 0, the most extreme of C(6, 3) = 20 orders, two-sided p = 2/20."""
    low = stats.mann_whitney([1, 2, 3], [4, 5, 6])
    assert (low["u"], low["p"], low["method"]) == (0.0, pytest.approx(0.1), "exact")
    assert stats.mann_whitney([4, 5, 6], [1, 2, 3])["u"] == 9.0
    mw = stats.mann_whitney(*UNEQUAL)
    assert (mw["u"], mw["method"]) == (37.0, "exact") and mw["p"] == pytest.approx(0.33566433566433573, rel=1e-12)


def test_mann_whitney_with_ties_against_scipy():
    mw = stats.mann_whitney(*TIES)
    assert (mw["u"], mw["method"]) == (7.0, "asymptotic") and mw["p"] == pytest.approx(0.5261684777561433, rel=1e-9)


def test_verdicts_and_words():
    ahead = stats.compare([10.0, 11, 12], [1.0, 2, 3])
    assert ahead["verdict"] == "ahead" and (ahead["n_ours"], ahead["n_theirs"]) == (3, 3)
    assert stats.compare([1.0, 2, 3], [10.0, 11, 12])["verdict"] == "behind"
    level = stats.compare(*UNEQUAL)
    assert level["verdict"] == "level"
    assert stats.words(level) == "level: +403 (95 % CI −478 … +1284; Welch), Mann–Whitney p 0.34, 8 vs 7 seeds"
    assert stats.compare([1000.0] * 3, [1000.0] * 3)["verdict"] == "level"
    one = stats.compare([5.0], [1.0, 2.0, float("nan")])
    assert one["verdict"] == "not tested" and one["n_theirs"] == 2
    assert stats.words(one) == "not tested (1 vs 2 seeds; 2 a side needed)"
    # every seed of one side above every seed of the other, one wild seed: Welch level, the ranks apart
    wild = stats.compare([-14.2, -14.5, -14.9, -14.3], [-21.2, -20.5, -148.6, -22.0])
    assert wild["verdict"] == "level" and wild["mann_whitney"]["p"] == pytest.approx(2 / math.comb(8, 4))
