"""The test families of the ICGO-RELM tables over paired repeats (the same splits and keys for every method):
paired Wilcoxon of method pairs with Holm over the table (:func:`paired_by_repeat`), Table 3's Friedman and
Wilcoxon families (:func:`table3_tests`), Fig. 9's under two budgets (:func:`budget_tests`) and columns against one
reference (:func:`against_reference`, the schedules sweep). docs/reporting.md, rules 3-4.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from icgo.maths.stats import friedman, holm, wilcoxon_paired
from icgo.studies.icgo_relm.results.outputs import LABEL, MNAME
from icgo.studies.icgo_relm.names import method_name
from icgo.reporting.protocol import comparison


def paired_by_repeat(m: pd.DataFrame, pairs, value: str = "mae") -> pd.DataFrame:
    """Paired Wilcoxon (two-sided) of ``a`` against ``b`` on the repeats both hold, for each ``(a, b)``, Holm over
    them all: one family. Columns: comparison, median difference (a - b), p, p (Holm), verdict (a sentence of
    :func:`icgo.reporting.protocol.comparison`)."""
    w = m.pivot_table(index="repeat", columns="method", values=value)
    eff = f"median {value.upper()} difference a - b (deg)"
    rows = []
    for a, b in pairs:
        d = w[[a, b]].dropna()
        if len(d) < 2:
            continue
        t = wilcoxon_paired(d[a], d[b])
        rows.append({"comparison": f"{method_name(a)} vs {method_name(b)}", "a": a, "b": b, "n": len(d),
                     eff: float((d[a] - d[b]).median()), "p": t.p_value})
    df = pd.DataFrame(rows)
    if df.empty:
        return df
    df["p (Holm)"] = holm(df["p"].to_numpy())
    df["verdict"] = [comparison(method_name(r.a), method_name(r.b), r["p (Holm)"], r[eff], family=len(df))
                     for _, r in df.iterrows()]
    return df.drop(columns=["a", "b"])


def table3_tests(wide: dict, strategies) -> pd.DataFrame:
    """Table 3's tests on the paired repeats, per metric (MAE, RMSE): Friedman over the four mutated strategies and
    Wilcoxon of three-stage against each single one; two families (Friedman, Wilcoxon), each Holm-adjusted.

    Args:
        wide: {metric: (repeats x ``cgo-<strategy>``) frame} of ``mae`` and ``rmse``, paired repeats only.
        strategies: the mutated strategies (``three_stage`` among them), in the order of the rows.
    Returns:
        One row per test; ``effect``: the Friedman mean ranks, or the median paired difference three-stage - single
        (deg).
    """
    rows = []
    for k in ("mae", "rmse"):
        w = wide[k]
        fr = friedman({s: w[f"cgo-{s}"].to_numpy() for s in strategies})
        rows.append({"metric": MNAME[k], "family": "Friedman", "test": "Friedman (4 strategies)", "comparison": "all",
                     "statistic": round(fr.statistic, 4),
                     "effect": ", ".join(f"{LABEL[s]} {fr.mean_ranks[s]:.2f}" for s in strategies),
                     "p": fr.p_value})
        for s in (x for x in strategies if x != "three_stage"):
            t = wilcoxon_paired(w["cgo-three_stage"], w[f"cgo-{s}"])
            rows.append({"metric": MNAME[k], "family": "Wilcoxon", "test": "Wilcoxon signed-rank (paired repeats)",
                         "comparison": f"three-stage vs {LABEL[s]}", "statistic": round(t.statistic, 4),
                         "effect": round(float(np.median(w["cgo-three_stage"] - w[f"cgo-{s}"])), 4), "p": t.p_value})
    df = pd.DataFrame(rows)
    df["p (Holm)"] = np.nan
    for fam, g in df.groupby("family"):
        df.loc[g.index, "p (Holm)"] = holm(g["p"].to_numpy())
    return df


def budget_tests(by_budget: dict, a: str, others, names: dict) -> pd.DataFrame:
    """Paired Wilcoxon (two-sided) on test MAE of method ``a`` against each of ``others`` under each budget, Holm over
    all of them (one family).

    Args:
        by_budget: {budget name: metrics (method, repeat, mae) of that budget's runs}, the repeats paired.
        a: the method tested. others: the methods it is tested against. names: method id -> its name in the table.
    Returns:
        One row per (budget, other): ``budget``, ``comparison``, ``median MAE difference (deg)`` (a - other), ``p``,
        ``p_holm``.
    """
    tests = []
    for budget, m in by_budget.items():
        w = m.pivot_table(index="repeat", columns="method", values="mae")
        for x in others:
            t = wilcoxon_paired(w[a], w[x])
            tests.append({"budget": budget, "comparison": f"{names[a]} vs {names[x]}",
                          "median MAE difference (deg)": float((w[a] - w[x]).median()), "p": t.p_value})
    tdf = pd.DataFrame(tests)
    tdf["p_holm"] = holm(tdf["p"].to_numpy())
    return tdf


def against_reference(wide: pd.DataFrame, columns, reference: str) -> dict:
    """{column: Holm-adjusted p} of the paired Wilcoxon (two-sided) of each of ``columns`` against ``reference``, Holm
    over ``columns`` (one family); the rows of ``wide`` are paired repeats."""
    return dict(zip(columns, holm([wilcoxon_paired(wide[c], wide[reference]).p_value for c in columns])))
