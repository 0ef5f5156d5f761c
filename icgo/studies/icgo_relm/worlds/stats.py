"""Results over independent simulated worlds: each world's numbers, the pooled ones, the ranking and the tests.

A *world* is one independent simulated data set (its own data seed: noise draw, MSA, splits and search keys;
:mod:`icgo.studies.icgo_relm.worlds.study`). A world's value of a method is its mean over that world's repeats (the repeats of
one world share its data, so they are not independent of each other); the worlds are the independent units:

* :func:`per_world`: one row per (world, method): repeats and the mean over them of each metric;
* :func:`pooled`: one row per method: worlds, mean +/- sample std over worlds of each metric, and in how many
  worlds the method was first (lowest mean MAE: :func:`first_counts`);
* :func:`paired_tests`: Wilcoxon signed-rank over worlds (paired by world) of each pair of a family, Holm over
  the family, each with its sentence (:func:`icgo.reporting.protocol.comparison`: "better" only at p < 0.05);
* :func:`friedman_over_worlds`: Friedman over worlds of several methods.

Pure pandas/numpy on the study's metrics table (``world`` column: the data seed), so the run directory of a
worlds run and the results builder (``icgo.studies.icgo_relm.results.worlds_tables``) compute the same numbers.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import pandas as pd

from icgo.maths.stats import format_mean_std, friedman, holm, wilcoxon_paired
from icgo.studies.icgo_relm.names import method_name
from icgo.reporting.protocol import comparison

#: The column naming a row's world (its data seed) in every table of a worlds run.
WORLD = "world"
#: The metrics a world's row carries (test split), in this order.
VALUES = ("mae", "rmse", "r2_error")
#: Their names in tables.
VALUE_NAMES = {"mae": "MAE (deg)", "rmse": "RMSE (deg)", "r2_error": "R^2 of error"}


def per_world(metrics: pd.DataFrame, split: str = "test", values: Sequence[str] = VALUES) -> pd.DataFrame:
    """One row per (world, method): ``n`` repeats and the mean over them of each of ``values``.

    Args:
        metrics: a study's metrics (method, repeat, split, values...) with a :data:`WORLD` column.
        split: the rows scored (``test``).
    """
    if WORLD not in metrics.columns:
        raise ValueError(f"per_world: the metrics have no {WORLD!r} column (not a worlds run)")
    m = metrics[metrics["split"] == split]
    g = m.groupby([WORLD, "method"], sort=True)
    out = g[list(values)].mean()
    out.insert(0, "n", g.size())
    return out.reset_index()


def wide(per: pd.DataFrame, methods: Sequence[str], value: str = "mae") -> pd.DataFrame:
    """(worlds x methods) of one value; only the worlds that hold every method (paired)."""
    w = per.pivot_table(index=WORLD, columns="method", values=value)
    missing = [m for m in methods if m not in w.columns]
    if missing:
        raise ValueError(f"worlds: no rows of method(s) {missing}; the runs hold {sorted(w.columns)}")
    return w[list(methods)].dropna()


def first_counts(per: pd.DataFrame, methods: Sequence[str], value: str = "mae") -> pd.Series:
    """In how many worlds each method has the lowest mean ``value`` among ``methods`` (a tie counts for each)."""
    w = wide(per, methods, value)
    return (w.eq(w.min(axis=1), axis=0)).sum().astype(int).reindex(list(methods))


def pooled(per: pd.DataFrame, methods: Sequence[str], values: Sequence[str] = VALUES, digits: int = 4) -> pd.DataFrame:
    """One row per method: worlds, mean +/- sample std over worlds of each value (its per-world means), and
    ``first`` ("k of N": the worlds in which it has the lowest mean MAE among ``methods``)."""
    firsts = first_counts(per, methods)
    n_all = len(wide(per, methods))
    rows = []
    for m in methods:
        g = per[per["method"] == m]
        row = {"method": m, "name": method_name(m), "worlds": int(g[WORLD].nunique()),
               "repeats per world": _span(g["n"])}
        for v in values:
            x = g[v].to_numpy(float)
            row[VALUE_NAMES[v]] = format_mean_std(float(x.mean()), float(x.std(ddof=1)) if x.size > 1 else 0.0,
                                                  digits)
        row["first (worlds)"] = f"{int(firsts[m])} of {n_all}"
        rows.append(row)
    return pd.DataFrame(rows)


def _span(n: pd.Series) -> str:
    lo, hi = int(n.min()), int(n.max())
    return f"{lo}" if lo == hi else f"{lo}-{hi}"


def order(per: pd.DataFrame, methods: Sequence[str], value: str = "mae") -> list[str]:
    """``methods`` sorted by their pooled mean ``value`` over the worlds that hold them all (lowest first)."""
    return list(wide(per, methods, value).mean().sort_values(kind="stable").index)


def paired_tests(per: pd.DataFrame, pairs: Sequence[tuple[str, str]], value: str = "mae") -> pd.DataFrame:
    """Wilcoxon signed-rank (two-sided) over worlds of a - b for each pair, Holm over all the pairs (one family).

    Columns: comparison, a, b, worlds, the median and mean of the per-world differences a - b (deg), p,
    p (Holm), verdict (one sentence). Empty when fewer than 2 worlds hold a pair.
    """
    rows = []
    for a, b in pairs:
        w = wide(per, [a, b], value)
        if len(w) < 2:
            continue
        d = w[a] - w[b]
        t = wilcoxon_paired(w[a], w[b])
        rows.append({"comparison": f"{method_name(a)} vs {method_name(b)}", "a": a, "b": b, "worlds": len(w),
                     "median difference a - b": float(d.median()), "mean difference a - b": float(d.mean()),
                     "p": t.p_value})
    df = pd.DataFrame(rows)
    if df.empty:
        return df
    df["p (Holm)"] = holm(df["p"].to_numpy())
    df["verdict"] = [comparison(method_name(r.a), method_name(r.b), r["p (Holm)"], r["median difference a - b"],
                                family=len(df)) for _, r in df.iterrows()]
    return df


def first_against_rest(per: pd.DataFrame, methods: Sequence[str], value: str = "mae") -> pd.DataFrame:
    """The method first by pooled mean against each other one: :func:`paired_tests` of that family."""
    ranked = order(per, methods, value)
    return paired_tests(per, [(ranked[0], m) for m in ranked[1:]], value)


def friedman_over_worlds(per: pd.DataFrame, methods: Sequence[str], value: str = "mae"):
    """Friedman test over worlds (blocks) of ``methods`` (>= 3): :class:`icgo.maths.stats.TestResult` with the mean
    ranks, or None with fewer than 2 worlds."""
    w = wide(per, methods, value)
    if len(w) < 2 or len(methods) < 3:
        return None
    return friedman({m: w[m].to_numpy() for m in methods})


def seeds_text(seeds: Sequence[int]) -> str:
    """Data seeds as ranges: ``100-129`` or ``100-104, 110``."""
    s = sorted(int(x) for x in seeds)
    if not s:
        return "none"
    parts, start, prev = [], s[0], s[0]
    for x in s[1:] + [None]:
        if x is not None and x == prev + 1:
            prev = x
            continue
        parts.append(f"{start}" if start == prev else f"{start}-{prev}")
        if x is not None:
            start = prev = x
    return ", ".join(parts)


def markdown_tests(tests: pd.DataFrame) -> list[str]:
    """The tests as Markdown lines: the table (without the id columns) and one sentence per test."""
    if tests.empty:
        return ["No test over worlds: fewer than 2 worlds hold the compared methods."]
    table = tests.drop(columns=["a", "b", "verdict"]).to_markdown(index=False, floatfmt=".4g")  # a metric column stays
    return [table, "", *(f"- {v}" for v in tests["verdict"])]


def rank_sentence(per: pd.DataFrame, methods: Sequence[str]) -> str:
    """"Order by pooled mean MAE: A < B < C; first in k of N worlds: A k1, B k2, ..."."""
    ranked = order(per, methods)
    firsts = first_counts(per, methods)
    n = len(wide(per, methods))
    counts = ", ".join(f"{method_name(m)} {int(firsts[m])}" for m in ranked)
    return (f"Order by pooled mean MAE: {' < '.join(method_name(m) for m in ranked)}; first (lowest mean MAE) in "
            f"k of {n} worlds: {counts}.")


def spread(per: pd.DataFrame, method: str, value: str = "mae") -> tuple[float, float]:
    """(min, max) over worlds of a method's per-world mean ``value``."""
    x = per.loc[per["method"] == method, value].to_numpy(float)
    return float(np.min(x)), float(np.max(x))


def smallest_p(n_worlds: int, tests: int = 1) -> float:
    """The smallest Holm-adjusted p any of ``tests`` exact two-sided Wilcoxon signed-rank tests over ``n_worlds``
    paired worlds can give: every difference of one sign gives p = 2 / 2**n (the exact null distribution puts
    2**-n on each extreme), and Holm multiplies the smallest p by the family's size (capped at 1)."""
    if n_worlds < 1:
        return 1.0
    return min(1.0, tests * 2.0 / 2.0 ** int(n_worlds))


def worlds_needed(tests: int = 1, alpha: float = 0.05) -> int:
    """The fewest worlds with which :func:`smallest_p` of a family of ``tests`` tests is below ``alpha``."""
    n = 1
    while smallest_p(n, tests) >= alpha:
        n += 1
    return n


def power_note(n_worlds: int, n_methods: int, alpha: float = 0.05) -> str | None:
    """One sentence when ``n_worlds`` are too few for the run's test over worlds (the first method against each of
    the other ``n_methods - 1``, exact two-sided Wilcoxon, Holm) to reach p < ``alpha`` whatever the data
    (:func:`smallest_p`); None when it can, or when there is no test."""
    tests = n_methods - 1
    if tests < 1 or n_worlds < 2:
        return None
    p = smallest_p(n_worlds, tests)
    if p < alpha:
        return None
    return (f"{n_worlds} worlds are too few for the test over worlds: the smallest p an exact two-sided Wilcoxon over "
            f"{n_worlds} worlds gives, Holm over {tests} test(s), is {p:.3g} (not < {alpha:g}), so no order of the "
            f"methods can be established; {worlds_needed(tests, alpha)} worlds are the fewest that can")
