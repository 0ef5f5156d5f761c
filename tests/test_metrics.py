"""Metrics: eqs. (19)-(21) against numpy, angle wrapping, weights, error R^2."""

import numpy as np
import pandas as pd
import pytest

import icgo  # noqa: F401
from icgo.maths.stats import mean_std_table
from icgo.physics import metrics


def test_wrapping():
    assert float(metrics.mae(np.array([359.0, 1.0]), np.array([1.0, 359.0]))) == pytest.approx(2.0)
    assert float(metrics.rmse(np.array([0.0]), np.array([180.0]))) == pytest.approx(180.0)


def test_against_numpy_and_weights():
    rng = np.random.default_rng(0)
    a = rng.uniform(0, 360, 50)
    e = rng.normal(0, 0.5, 50)
    est = np.mod(a - e, 360.0)
    assert float(metrics.mae(a, est)) == pytest.approx(np.mean(np.abs(e)), rel=1e-10)
    assert float(metrics.rmse(a, est)) == pytest.approx(np.sqrt(np.mean(e**2)), rel=1e-10)
    assert float(metrics.r2(a, est)) == pytest.approx(1 - np.sum(e**2) / np.sum((a - a.mean()) ** 2), rel=1e-10)
    w = (rng.random(50) < 0.5).astype(float)
    for f in (metrics.mae, metrics.rmse, metrics.r2):
        assert float(f(a, est, w)) == pytest.approx(float(f(a[w > 0], est[w > 0])), rel=1e-12)


def test_r2_error_and_bundle():
    rng = np.random.default_rng(1)
    before = rng.normal(1.0, 2.0, 40)
    after = 0.1 * rng.normal(size=40)
    ref = 1 - np.sum(after**2) / np.sum((before - before.mean()) ** 2)
    assert float(metrics.r2_error(before, after)) == pytest.approx(ref, rel=1e-12)
    a = rng.uniform(0, 360, 40)
    m = metrics.azimuth_metrics(a, np.mod(a + after, 360), before)
    assert float(m.r2_error) == pytest.approx(ref, rel=1e-10)
    assert float(m.rmse) == pytest.approx(np.sqrt(np.mean(after**2)), rel=1e-10)


def test_mean_std_table_of_repeat_metrics():
    df = pd.DataFrame({"strategy": ["a"] * 3 + ["b"] * 3, "split": "test", "mae": [1.0, 2.0, 3.0, 4, 4, 4],
                       "rmse": 1.0, "r2": 0.5, "r2_error": 0.1})
    s = mean_std_table(df, ["strategy", "split"], ["mae", "rmse", "r2", "r2_error"])
    assert s.loc[("a", "test"), "mae_mean"] == 2.0 and s.loc[("a", "test"), "mae_std"] == 1.0
    assert s.loc[("b", "test"), "mae"] == "4.0000 +/- 0.0000"
