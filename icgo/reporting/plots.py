"""Figures, one function per figure. Each takes plain arrays / DataFrames and returns a matplotlib Figure.

The library never chooses where to save: callers (``experiments/``) write the
files. matplotlib is imported with the non-interactive Agg backend.
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402


def plt_agg():
    """``matplotlib.pyplot`` on the non-interactive Agg backend (for callers that draw their own figures)."""
    return plt


def save_figure(fig, path, title: str | None, dpi: int = 120) -> None:
    """Title (None: none), lay out, write and close a figure."""
    if title is not None:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


def azimuth_per_station(stats: pd.DataFrame, title: str = "Azimuth per station (ICGO Fig. 6)"):
    """Computed azimuth (mean +- std over toolface) against the true azimuth, per method.

    Args:
        stats: rows per (true azimuth, method) with columns ``azimuth_deg`` (true,
            deg), ``method`` (str), ``mean_deg``, ``std_deg`` (computed azimuth).
    Returns:
        matplotlib Figure.
    """
    fig, ax = plt.subplots(figsize=(7, 4.5))
    methods = list(dict.fromkeys(stats["method"]))
    width = 4.0
    for k, m in enumerate(methods):
        s = stats[stats["method"] == m]
        x = s["azimuth_deg"].to_numpy() + (k - (len(methods) - 1) / 2) * width
        ax.errorbar(x, s["mean_deg"], yerr=s["std_deg"], fmt="o", capsize=3, label=m)
    t = np.unique(stats["azimuth_deg"])
    ax.plot(t, t, "k_", markersize=18, label="true azimuth")
    ax.set_xlabel("true azimuth (deg)")
    ax.set_ylabel("computed azimuth (deg)")
    ax.set_title(title)
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return fig


def error_vs_toolface(frame: pd.DataFrame, columns=("raw", "MSA"), title: str = "Azimuth error vs toolface (ICGO Fig. 7)"):
    """Azimuth error (deg) against toolface, one panel per error column, one line per true azimuth.

    Args:
        frame: columns ``azimuth_deg`` (true), ``toolface_deg`` and one error column (deg) per name in ``columns``.
    Returns:
        matplotlib Figure.
    """
    fig, axes = plt.subplots(1, len(columns), figsize=(5.5 * len(columns), 4), sharey=True, squeeze=False)
    for ax, col in zip(axes[0], columns):
        for a, g in frame.groupby("azimuth_deg"):
            g = g.sort_values("toolface_deg")
            ax.plot(g["toolface_deg"], g[col], ".-", ms=2, lw=0.8, label=f"A = {a:g}")
        ax.set_xlabel("toolface (deg)")
        ax.set_title(f"{col} error")
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("azimuth error (deg)")
    axes[0][-1].legend(fontsize=7, ncol=2)
    fig.suptitle(title)
    fig.tight_layout()
    return fig


def error_by_condition(table: pd.DataFrame, title: str = "Raw azimuth error per condition (ICGO Table 4)"):
    """Bar chart of raw azimuth error mean +- std per condition, simulation next to the paper.

    Args:
        table: columns ``label`` (str), ``sim_mean_deg``, ``sim_std_deg``,
            ``paper_mean_deg``, ``paper_std_deg``.
    Returns:
        matplotlib Figure.
    """
    fig, ax = plt.subplots(figsize=(7, 4))
    x = np.arange(len(table))
    ax.bar(x - 0.2, table["sim_mean_deg"], 0.4, yerr=table["sim_std_deg"], capsize=3, label="simulation (well_conditions)")
    ax.bar(x + 0.2, table["paper_mean_deg"], 0.4, yerr=table["paper_std_deg"], capsize=3, label="paper, Table 4 original")
    ax.set_xticks(x, table["label"], rotation=20)
    ax.set_ylabel("raw azimuth error (deg)")
    ax.set_title(title)
    ax.legend()
    ax.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    return fig


def residual_vs_toolface(panels):
    """Magnetometer residual components (measured - predicted, nT) against toolface, one row of panels per set
    (not yet laid out: :func:`save_figure` does it).

    Args:
        panels: ``(name, toolface deg (n,), residual (n, 3) nT of bx, by, bz)`` per row (e.g. before and after a
            model; stations to draw only).
    Returns:
        matplotlib Figure.
    """
    fig, axes = plt.subplots(len(panels), 3, figsize=(12, 3 * len(panels)), sharex=True, squeeze=False)
    for row, (name, toolface, resid) in enumerate(panels):
        T = np.mod(toolface, 360)
        for j, c in enumerate("xyz"):
            ax = axes[row, j]
            ax.plot(T, resid[:, j], ".", ms=3)
            ax.axhline(0, color="k", lw=0.5)
            ax.set_title(f"b{c} residual, {name}")
            ax.set_ylabel("nT")
            if row == len(panels) - 1:
                ax.set_xlabel("toolface (deg)")
    return fig


def gap_per_step(table: pd.DataFrame):
    """Held-out gap after each step of a model search: RMS magnetometer residual (nT) and RMS azimuth error (deg)
    (not yet laid out: :func:`save_figure` does it).

    Args:
        table: one row per model, columns ``model`` (its name), ``mag_rms_nT`` and ``azimuth_rms_deg``.
    Returns:
        matplotlib Figure.
    """
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.8))
    x = np.arange(len(table))
    ax[0].bar(x, table["mag_rms_nT"])
    ax[0].set_ylabel("held-out RMS magnetometer residual (nT)")
    ax[1].bar(x, table["azimuth_rms_deg"], color="C1")
    ax[1].set_ylabel("held-out RMS azimuth error (deg)")
    for a in ax:
        a.set_xticks(x, table["model"], rotation=20, ha="right", fontsize=8)
        a.set_yscale("log")
    return fig
