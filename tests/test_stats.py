"""Repeat statistics: closed-form values of the Wilcoxon and Friedman tests."""

import numpy as np
import pandas as pd
import pytest

from icgo.maths import stats


def test_mean_std():
    assert stats.mean_std([1.0, 2.0, 3.0, 4.0]) == (2.5, pytest.approx(np.sqrt(5 / 3)))


def test_wilcoxon_exact_all_positive():
    x = np.arange(1, 11) * 0.1 + 1.0
    y = np.ones(10)
    r = stats.wilcoxon_paired(x, y)
    # All 10 differences positive, no ties: W- = 0, exact two-sided p = 2 / 2^10.
    assert r.statistic == 0.0 and r.p_value == pytest.approx(2 / 1024)
    assert stats.wilcoxon_paired(x, x).p_value == 1.0
    with pytest.raises(ValueError, match="equal lengths"):
        stats.wilcoxon_paired(x, y[:5])


def test_friedman_closed_form():
    rng = np.random.default_rng(0)
    n, k = 8, 4
    table = rng.normal(size=(n, k)) + np.arange(k) * 0.3
    r = stats.friedman(table, names=list("abcd"))
    ranks = np.argsort(np.argsort(table, 1), 1) + 1.0
    Rj = ranks.sum(0)
    chi2 = 12.0 / (n * k * (k + 1)) * np.sum(Rj**2) - 3 * n * (k + 1)
    assert r.statistic == pytest.approx(chi2, rel=1e-12)
    assert list(r.mean_ranks.values()) == pytest.approx(list(Rj / n))
    perfect = stats.friedman({"x": np.arange(6.0), "y": np.arange(6.0) + 1, "z": np.arange(6.0) + 2})
    assert perfect.mean_ranks == {"x": 1.0, "y": 2.0, "z": 3.0}
    with pytest.raises(ValueError, match="k >= 3"):
        stats.friedman(table[:, :2])


def test_mean_std_table_and_compare():
    df = pd.DataFrame({"method": ["a"] * 6 + ["b"] * 6, "repeat": list(range(6)) * 2,
                       "mae": list(np.arange(6.0)) + list(np.arange(6.0) + 1)})
    t = stats.mean_std_table(df, ["method"], ["mae"])
    assert t.loc["b", "mae_mean"] == 3.5 and t.loc["a", "n"] == 6
    c = stats.compare_table(df, "method", "mae", reference="a")
    assert c.loc[0, "median_diff"] == 1.0 and c.loc[0, "p_value"] == pytest.approx(2 / 64)


def test_holm_hand_computed():
    """m = 4: sorted 0.005 x 4 = 0.02, 0.01 x 3 = 0.03, 0.03 x 2 = 0.06, 0.04 x 1 -> max(0.06, 0.04) = 0.06."""
    np.testing.assert_allclose(stats.holm([0.01, 0.04, 0.03, 0.005]), [0.03, 0.06, 0.06, 0.02])
    np.testing.assert_allclose(stats.holm([0.5, 0.9]), [1.0, 1.0])
    np.testing.assert_allclose(stats.holm([0.2]), [0.2])


def test_paired_z_hand_computed():
    before = np.array([3.0, 4.0, 5.0, 6.0])
    after = before - np.array([1.0, 2.0, 1.0, 2.0])  # improvement 1.5 +- 0.577 / 2
    assert stats.paired_z(before, after) == pytest.approx(1.5 / (np.std([1, 2, 1, 2], ddof=1) / 2))
    assert stats.paired_z(after, before) == pytest.approx(-stats.paired_z(before, after))
    # no spread: the standard error is floored at 1e-9, so the z is finite
    assert stats.paired_z(before, before - 1.0) == pytest.approx(1e9)
