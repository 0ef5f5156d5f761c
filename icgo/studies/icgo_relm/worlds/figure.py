"""The figure of a worlds run (``worlds.png``): each world's value of every method, and the pooled order."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from icgo.studies.icgo_relm.names import method_name
from icgo.reporting.plots import plt_agg, save_figure
from icgo.studies.icgo_relm.worlds.stats import VALUE_NAMES, order, wide


def plot_worlds(per: pd.DataFrame, methods: Sequence[str], path: Path, title: str = "", value: str = "mae") -> None:
    """Methods left to right in their pooled order (lowest pooled mean ``value`` first,
    :func:`icgo.studies.icgo_relm.worlds.stats.order`); each world's mean over its repeats as a dot, one grey line joining a
    world's methods (the pairing the tests over worlds use); the pooled mean +/- sample std over worlds in black.

    Args:
        per: :func:`icgo.studies.icgo_relm.worlds.stats.per_world`'s table. methods: the methods compared.
        path: PNG path. title: figure title. value: the metric plotted.
    """
    plt = plt_agg()
    ranked = order(per, methods, value)
    w = wide(per, ranked, value)
    x = np.arange(len(ranked))
    fig, ax = plt.subplots(figsize=(max(4.5, 1.4 * len(ranked) + 2), 4))
    for _, row in w.iterrows():
        ax.plot(x, row.to_numpy(), color="0.7", lw=0.7, marker="o", ms=3, zorder=1)
    mean, std = w.mean(), w.std(ddof=1) if len(w) > 1 else w.mean() * 0
    ax.errorbar(x, mean.to_numpy(), yerr=std.to_numpy(), color="k", marker="s", ms=6, capsize=4, lw=1.5,
                zorder=2, label=f"pooled mean +/- std over {len(w)} worlds")
    ax.set_xticks(x, [method_name(m) for m in ranked], rotation=20, ha="right", fontsize=8)
    ax.set_ylabel(f"{VALUE_NAMES.get(value, value)}, test, mean over a world's repeats")
    ax.set_xlabel("pooled order, lowest mean first (its tests: summary.md)")
    ax.legend(fontsize=7)
    save_figure(fig, path, title)
