"""Families of paired tests as the tables report them: each test's p, the family's Holm adjustment, the effect and
the one word a table may say about it (docs/reporting.md, rules 3-4).

* :func:`paired_family`: paired Wilcoxon signed-rank (two-sided) of each pair of per-repeat series, Holm over all
  of them (one family), the median paired difference and :func:`effect_word`.
* :func:`holm_once`: Holm over the distinct tests of a table whose rows repeat a test (rows with the same numbers
  are one test, counted once).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from icgo.maths.stats import holm, wilcoxon_paired
from icgo.reporting.protocol import ALPHA


def effect_word(median_diff: float, p_holm: float, alpha: float = ALPHA) -> str:
    """``"lower"`` or ``"higher"`` (a against b, by the sign of the median paired difference a - b) when the
    Holm-adjusted p is below ``alpha``; else ``"no significant difference"``."""
    if not (np.isfinite(p_holm) and p_holm < alpha):
        return "no significant difference"
    return "lower" if median_diff < 0 else "higher"


def paired_family(pairs, alpha: float = ALPHA) -> pd.DataFrame:
    """Paired tests of a family, Holm-adjusted together.

    Args:
        pairs: ``(label, a, b)`` per test, ``a`` and ``b`` per-repeat values (pandas Series indexed by repeat); each
            test uses the repeats both hold.
        alpha: the family-wise level of :func:`effect_word`.
    Returns:
        One row per test: ``label``, ``n`` (paired repeats), ``median_diff`` (median of a - b), ``p`` (paired
        Wilcoxon signed-rank, two-sided), ``p_holm`` (Holm over every row) and ``result`` (:func:`effect_word`).
    """
    rows = []
    for label, a, b in pairs:
        d = pd.concat([pd.Series(a, name="a"), pd.Series(b, name="b")], axis=1).dropna()
        if len(d) < 2:
            raise ValueError(f"{label}: {len(d)} paired repeat(s), a paired test needs at least 2")
        rows.append({"label": label, "n": len(d), "median_diff": float((d["a"] - d["b"]).median()),
                     "p": wilcoxon_paired(d["a"], d["b"]).p_value})
    df = pd.DataFrame(rows, columns=["label", "n", "median_diff", "p"])
    df["p_holm"] = holm(df["p"].to_numpy()) if len(df) else []
    df["result"] = [effect_word(m, p, alpha) for m, p in zip(df["median_diff"], df["p_holm"])]
    return df


def holm_once(p_values, keys) -> np.ndarray:
    """Holm-adjusted p of each row, where rows with the same ``key`` are the same test: the family counts each
    distinct test once, and every row of a test gets its adjusted p.

    Args:
        p_values: (N,) raw p of each row (rows of one key must have the same p).
        keys: (N,) hashable identity of each row's test (e.g. the tuple of the numbers it compares).
    """
    p_values, keys = list(p_values), list(keys)
    first = {}
    for k, p in zip(keys, p_values):
        if k in first and first[k] != p:
            raise ValueError(f"rows of one test have different p ({first[k]} and {p})")
        first.setdefault(k, p)
    adjusted = dict(zip(first, holm(np.asarray(list(first.values()), float))))
    return np.array([adjusted[k] for k in keys])
