"""Repeat statistics and significance tests for study tables (host-side, numpy/scipy).

* :func:`mean_std` / :func:`mean_std_table`: mean +/- sample std (ddof = 1)
  over repeats, the paper's Table 3 format;
* :func:`wilcoxon_paired`: Wilcoxon signed-rank test between two methods on
  paired repeats (same split, same key), two-sided;
* :func:`friedman`: Friedman test over k >= 3 methods on the same repeats, with
  the mean rank of each method (rank 1 = smallest value = best for errors);
* :func:`holm`: Holm's step-down adjustment of a family of p-values;
* :func:`paired_z`: the paired z of a per-unit improvement (the discrepancy workflow's decision statistic).
"""

from __future__ import annotations

import math
from typing import NamedTuple, Sequence

import numpy as np
import pandas as pd


def mean_std(x, ddof: int = 1) -> tuple[float, float]:
    """(mean, std) of a 1-D sample; std with ``ddof`` (sample std by default)."""
    x = np.asarray(x, dtype=float).ravel()
    if x.size == 0:
        raise ValueError("mean_std: empty sample")
    return float(x.mean()), float(x.std(ddof=ddof)) if x.size > ddof else float("nan")


def format_mean_std(mean: float, std: float, digits: int = 4) -> str:
    """``"0.0391 +/- 0.0100"``; the mean alone when the std is undefined (one repeat), never ``"+/- nan"``."""
    if not np.isfinite(std):
        return f"{mean:.{digits}f}"
    return f"{mean:.{digits}f} +/- {std:.{digits}f}"


def mean_std_table(df: pd.DataFrame, by: Sequence[str], columns: Sequence[str], digits: int = 4) -> pd.DataFrame:
    """Mean and std of ``columns`` per group of ``by`` (all rows if ``by`` is empty).

    Returns:
        DataFrame with ``<col>_mean``, ``<col>_std`` and ``<col>`` ("m +/- s")
        per group, plus ``n`` (repeats).
    """
    missing = [c for c in list(by) + list(columns) if c not in df.columns]
    if missing:
        raise ValueError(f"mean_std_table: missing columns {missing}")
    groups = df.groupby(list(by), sort=False) if by else [((), df)]
    rows = []
    for key, g in groups:
        key = key if isinstance(key, tuple) else (key,)
        row = dict(zip(by, key))
        row["n"] = len(g)
        for c in columns:
            m, s = mean_std(g[c].to_numpy())
            row[f"{c}_mean"], row[f"{c}_std"], row[c] = m, s, format_mean_std(m, s, digits)
        rows.append(row)
    out = pd.DataFrame(rows)
    return out.set_index(list(by)) if by else out


class TestResult(NamedTuple):
    """statistic, p_value, and (Friedman) mean ranks per method name."""

    statistic: float
    p_value: float
    mean_ranks: dict | None = None


def wilcoxon_paired(x, y, alternative: str = "two-sided") -> TestResult:
    """Wilcoxon signed-rank test on paired repeats (x[k], y[k] from repeat k).

    Args:
        x, y: (R,) per-repeat values of two methods on the same repeats.
        alternative: ``"two-sided"``, ``"less"`` (x < y) or ``"greater"``.
    Returns:
        TestResult (exact p for R <= 50 without ties, scipy's default).
    """
    x = np.asarray(x, dtype=float).ravel()
    y = np.asarray(y, dtype=float).ravel()
    if x.shape != y.shape:
        raise ValueError(f"wilcoxon_paired: paired samples need equal lengths, got {x.size} and {y.size}")
    if x.size < 2:
        raise ValueError("wilcoxon_paired: need at least 2 paired repeats")
    if np.all(x == y):
        return TestResult(0.0, 1.0)
    from scipy import stats as _st  # here, not at import: scipy.stats costs 1.2 s, and a study's worker needs none

    r = _st.wilcoxon(x, y, alternative=alternative)
    return TestResult(float(r.statistic), float(r.pvalue))


def holm(p_values) -> np.ndarray:
    """Holm-adjusted p-values (family-wise error control over the whole family).

    The i-th smallest of m p-values is multiplied by (m - i + 1); the running
    maximum keeps the order; values are capped at 1. Reject at level alpha
    where the adjusted value is < alpha.

    Args:
        p_values: (m,) raw p-values.
    Returns:
        (m,) adjusted p-values, in the input order.
    """
    p = np.asarray(p_values, dtype=float).ravel()
    m = p.size
    order = np.argsort(p, kind="stable")
    adj = np.minimum(np.maximum.accumulate((m - np.arange(m)) * p[order]), 1.0)
    out = np.empty(m)
    out[order] = adj
    return out


def paired_z(before, after) -> float:
    """Paired z of the per-unit improvement ``before - after``.

    ``z = mean(d) / (std(d, ddof=1) / sqrt(n))`` with ``d = before - after`` (the standard error floored at
    1e-9); positive when ``after`` is smaller. The discrepancy workflow takes it for a candidate's improvement
    over the current model and for the evidence margin of the best candidate over another (held-out chi2 per
    station in both cases), as a decision statistic, not a reported test.

    Args:
        before, after: (n,) per-unit values (e.g. held-out chi2 per station), paired by unit.
    Returns:
        z, dimensionless.
    """
    d = np.asarray(before) - np.asarray(after)
    return float(d.mean() / max(d.std(ddof=1) / math.sqrt(d.size), 1e-9))


def friedman(table, names: Sequence[str] | None = None) -> TestResult:
    """Friedman test with mean ranks.

    Args:
        table: (R, k) values, rows = repeats (blocks), columns = methods; or a
            dict name -> (R,) values.
        names: method names for the columns of an array ``table``.
    Returns:
        TestResult with ``mean_ranks`` {name: mean rank} (1 = smallest).
    """
    if isinstance(table, dict):
        names = list(table)
        table = np.column_stack([np.asarray(table[n], dtype=float) for n in names])
    table = np.asarray(table, dtype=float)
    if table.ndim != 2 or table.shape[1] < 3 or table.shape[0] < 2:
        raise ValueError(f"friedman: need an (R >= 2, k >= 3) table, got shape {table.shape}")
    names = [str(i) for i in range(table.shape[1])] if names is None else list(names)
    if len(names) != table.shape[1]:
        raise ValueError(f"friedman: {len(names)} names for {table.shape[1]} columns")
    from scipy import stats as _st

    ranks = np.apply_along_axis(_st.rankdata, 1, table)
    r = _st.friedmanchisquare(*table.T)
    return TestResult(float(r.statistic), float(r.pvalue), dict(zip(names, ranks.mean(0).tolist())))


def compare_table(df: pd.DataFrame, method_col: str, value_col: str, reference: str,
                  repeat_col: str = "repeat") -> pd.DataFrame:
    """Wilcoxon signed-rank of each method against ``reference`` on paired repeats.

    Returns:
        DataFrame per method: median difference (method - reference), statistic,
        p-value.
    """
    wide = df.pivot_table(index=repeat_col, columns=method_col, values=value_col)
    if reference not in wide.columns:
        raise ValueError(f"compare_table: reference {reference!r} not in {list(wide.columns)}")
    rows = []
    for m in wide.columns:
        if m == reference:
            continue
        t = wilcoxon_paired(wide[m], wide[reference])
        rows.append({method_col: m, "vs": reference, "median_diff": float(np.median(wide[m] - wide[reference])),
                     "statistic": t.statistic, "p_value": t.p_value})
    return pd.DataFrame(rows)
