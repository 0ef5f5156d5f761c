"""icgo.survey.apply_stream: a streamed survey's sums, exact medians from disk and chunked positions against the
whole-array computations (numpy, welleng on the whole survey)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from icgo.core.errors import DataError
from icgo.survey import apply_stream
from icgo.survey.apply_stream import DiskColumn, Moments, StreamedPositions
from icgo.survey.trajectory import position_change


@pytest.mark.parametrize("n", [1, 2, 7, 5000, 5001])
@pytest.mark.parametrize("kind", ["normal", "ties", "tiny_range"])
def test_disk_median_is_numpys_median_bitwise(tmp_path, monkeypatch, n, kind):
    monkeypatch.setattr(apply_stream, "BLOCK", 64)  # many passes, the narrowing exercised
    rng = np.random.default_rng(n)
    x = {"normal": rng.standard_normal(n) * 1e3,
         "ties": rng.integers(0, 3, n).astype(float),
         "tiny_range": 1.0 + rng.integers(0, 5, n) * np.finfo(float).eps}[kind]
    col = DiskColumn(tmp_path / "c.f64")
    for part in np.array_split(x, 7):
        col.add(part)
    assert col.n == n
    got = col.median()
    assert got == np.median(x), (got, np.median(x))
    for k in {0, n // 2, n - 1}:
        assert col.kth(k) == np.sort(x)[k]


def test_disk_median_of_nothing_or_nan_is_nan(tmp_path):
    assert np.isnan(DiskColumn(tmp_path / "a.f64").median())
    col = DiskColumn(tmp_path / "b.f64")
    col.add([1.0, np.nan, 2.0])
    assert np.isnan(col.median()) and np.isnan(np.median([1.0, np.nan, 2.0]))


def test_moments_merge_to_the_whole_arrays_mean_and_std():
    x = np.random.default_rng(0).normal(5e4, 30.0, 10_001)
    m = Moments()
    for part in np.array_split(x, 13):
        m.add(part)
    m.add(np.array([]))
    assert m.n == x.size
    assert m.mean == pytest.approx(np.mean(x), rel=1e-15)
    assert m.std() == pytest.approx(np.std(x), rel=1e-12)


def _well(n, seed=0):
    rng = np.random.default_rng(seed)
    md = 30.0 * np.arange(n) + 100.0
    inc = np.clip(np.cumsum(rng.normal(0.5, 0.3, n)), 0, 95)
    azi = np.mod(40.0 + np.cumsum(rng.normal(0.2, 0.5, n)), 360.0)
    return md, inc, azi


def test_chunked_positions_are_the_whole_surveys(tmp_path):
    md, inc, azi = _well(1000)
    inc_c, azi_c = inc + 0.1, np.mod(azi - 0.3, 360.0)
    table, summary = position_change(md, inc, azi, inc_c, azi_c, inc + 0.05, azi)
    sp = StreamedPositions(tmp_path / "pos.csv")
    for idx in np.array_split(np.arange(1000), [1, 2, 300, 301, 777]):  # chunks of one row among them
        sp.add({"md": md[idx], "inc_raw": inc[idx], "azi_raw": azi[idx], "inc_cor": inc_c[idx], "azi_cor": azi_c[idx],
                "inc_ref": inc[idx] + 0.05, "azi_ref": azi[idx]})
    got = sp.summary()
    assert got.keys() == summary.keys()
    for k, v in summary.items():
        assert got[k] == (pytest.approx(v, rel=1e-12, abs=1e-9) if isinstance(v, dict) else v), k
    pd.testing.assert_frame_equal(pd.read_csv(tmp_path / "pos.csv"), table, rtol=1e-12, atol=1e-9)


def test_a_depth_that_does_not_increase_in_a_later_chunk_names_the_surveys_row(tmp_path):
    md, inc, azi = _well(50)
    md[30] = md[29]                            # the whole survey's line names it
    with pytest.raises(DataError) as whole:
        position_change(md, inc, azi, inc, azi)
    sp = StreamedPositions(tmp_path / "pos.csv")
    for idx in np.array_split(np.arange(50), [10, 30]):   # the bad step across a chunk boundary
        sp.add({"md": md[idx], "inc_raw": inc[idx], "azi_raw": azi[idx], "inc_cor": inc[idx], "azi_cor": azi[idx]})
    with pytest.raises(DataError) as streamed:
        sp.summary()
    assert str(streamed.value) == str(whole.value)
    assert not (tmp_path / "pos.csv").exists()
