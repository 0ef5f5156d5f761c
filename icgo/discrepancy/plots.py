"""show: the workflow's two figures (matplotlib, Agg backend)."""

from __future__ import annotations

import numpy as np

from icgo.discrepancy.search import Result, gap_table


def plot_residual_vs_toolface(res: Result, path):
    """Figure: B residual components (measured - predicted, nT) vs toolface, before
    (reference model) and after (final model)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(12, 6), sharex=True)
    for row, (cmp, title) in enumerate(((res.compare_before, "before"), (res.compare_after, "after"))):
        r, v = cmp.resid, cmp.valid
        T = np.mod(cmp.toolface, 360)
        for j, c in enumerate("xyz"):
            ax = axes[row, j]
            ax.plot(T[v], r[v, 3 + j], ".", ms=3)
            ax.axhline(0, color="k", lw=0.5)
            ax.set_title(f"b{c} residual, {title}")
            ax.set_ylabel("nT")
            if row == 1:
                ax.set_xlabel("toolface (deg)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_gap_per_step(res: Result, path):
    """Figure: held-out gap (RMS magnetometer residual nT, RMS azimuth error deg) after each step."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tab = gap_table(res)
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.8))
    x = np.arange(len(tab))
    ax[0].bar(x, tab["mag_rms_nT"])
    ax[0].set_ylabel("held-out RMS magnetometer residual (nT)")
    ax[1].bar(x, tab["azimuth_rms_deg"], color="C1")
    ax[1].set_ylabel("held-out RMS azimuth error (deg)")
    for a in ax:
        a.set_xticks(x, tab["model"], rotation=20, ha="right", fontsize=8)
        a.set_yscale("log")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
