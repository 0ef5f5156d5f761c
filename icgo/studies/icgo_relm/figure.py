"""The figure of one ICGO-RELM run directory (``experiments.run``'s ``figures=true``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from icgo.physics.frames import angle_diff
from icgo.studies.icgo_relm.names import method_name
from icgo.reporting.plots import plt_agg, save_figure


def plot_study(result, path: Path, title: str = "") -> None:
    """The run directory's figure: convergence, test error before/after, per-repeat MAE.

    Args:
        result: :class:`icgo.studies.icgo_relm.result.StudyResult`.
        path: PNG path.
        title: figure title.
    """
    plt = plt_agg()
    methods = result.config.method_names()
    fig, axes = plt.subplots(1, 3, figsize=(15, 3.8))
    h = result.histories
    for mth in methods:
        g = h[h.method == mth].groupby("iteration")["best_fitness"].mean()
        axes[0].plot(g.index, g.values, label=method_name(mth))
    axes[0].set_xlabel("iteration")
    axes[0].set_ylabel("best training RMSE (deg), mean over repeats")
    axes[0].set_yscale("log")
    axes[0].legend(fontsize=7)
    p = result.predictions
    r0 = p["repeat"].min()
    d = p[(p.repeat == r0) & (p.split == "test") & (p.method == methods[-1])].sort_values("station")
    x = np.arange(len(d))
    raw = np.asarray(angle_diff(d["azimuth_raw"].to_numpy(), d["azimuth_true"].to_numpy()))
    axes[1].plot(x, raw, lw=0.8, label="raw")
    axes[1].plot(x, d["error_msa"], lw=0.8, label="after MSA")
    axes[1].plot(x, d["error_compensated"], lw=1.0, label=f"after {method_name(methods[-1])}")
    axes[1].set_xlabel(f"test sample, repeat {r0}")
    axes[1].set_ylabel("azimuth error (deg)")
    axes[1].legend(fontsize=7)
    m = result.metrics
    m = m[m.split == "test"]
    for mth in ["raw", "msa"] + methods:
        g = m[m.method == mth]
        axes[2].plot(g["repeat"], g["mae"], "o-", ms=3, label=method_name(mth))
    axes[2].set_yscale("log")
    axes[2].set_xlabel("repeat")
    axes[2].set_ylabel("test MAE (deg)")
    axes[2].legend(fontsize=7)
    save_figure(fig, path, title, dpi=110)  # a run's own figure: its run directory says what it ran
