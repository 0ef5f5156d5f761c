"""Figs. 10-13 of the ICGO paper: the five strategies' error and convergence, the error modelling and the
compensation."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from icgo.reporting import stamp
from icgo.studies.icgo_relm.results.outputs import LABEL, METRICS, MNAME, PAPER
from icgo.reporting.plots import plt_agg
from icgo.reporting.run_collection import Runs
from icgo.reporting.table_writer import have, mean_and_std
from icgo.studies.icgo_relm.results.notes import STRATEGIES4, STRATEGIES5


def fig10(runs: Runs, out: Path) -> bool:
    """Fig. 10: MAE and RMSE of the five strategies (mean +/- std over repeats), paper's Table 2 values."""
    m = runs.metrics()
    methods = [f"cgo-{s}" for s in STRATEGIES5]
    if not have(m, methods):
        return False
    rows = []
    for s in STRATEGIES5:
        g = m[m.method == f"cgo-{s}"]
        row = {"strategy": s, "n_repeats": len(g)}
        for k in ("mae", "rmse"):
            row[f"{k}_mean"], row[f"{k}_std"] = mean_and_std(g[k])
            row[f"{k}_repeat0"] = float(g[g.repeat == 0][k].iloc[0]) if (g.repeat == 0).any() else np.nan
            row[f"{k}_paper"] = PAPER["table2"][s][METRICS.index(k)]
        rows.append(row)
    df = pd.DataFrame(rows)
    df.to_csv(out / "fig10.csv", index=False)
    plt = plt_agg()
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    x = np.arange(len(STRATEGIES5))
    for ax, k in zip(axes, ("mae", "rmse")):
        ax.bar(x - 0.2, df[f"{k}_mean"], 0.4, yerr=df[f"{k}_std"], capsize=3, label="ours, mean +/- std")
        ax.bar(x + 0.2, df[f"{k}_paper"], 0.4, color="0.6", label="paper (Table 2)")
        ax.plot(x - 0.2, df[f"{k}_repeat0"], "k.", label="ours, repeat 0")
        ax.set_xticks(x, [LABEL[s] for s in STRATEGIES5], rotation=15)
        ax.set_title(MNAME[k])
    axes[0].legend(fontsize=8)
    stamp.save(fig, out / "fig10.png", "Fig. 10: error of the five 4th-seed strategies (test split, lab_casing)")
    return True


def fig11(runs: Runs, out: Path) -> bool:
    """Fig. 11: convergence (best training RMSE vs iteration) of the five strategies."""
    c = runs.convergence()
    methods = [f"cgo-{s}" for s in STRATEGIES5]
    if not have(c, methods):
        return False
    c = c[c.method.isin(methods)]
    agg = c.groupby(["method", "iteration"]).agg(evals=("evals", "mean"), mean=("best_fitness", "mean"),
                                                 std=("best_fitness", "std")).reset_index()
    r0 = c[c.repeat == 0][["method", "iteration", "best_fitness"]].rename(columns={"best_fitness": "repeat0"})
    agg = agg.merge(r0, on=["method", "iteration"], how="left")
    agg.to_csv(out / "fig11.csv", index=False)
    plt = plt_agg()
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for s in STRATEGIES5:
        g = agg[agg.method == f"cgo-{s}"]
        axes[0].plot(g["iteration"], g["repeat0"], label=LABEL[s])
        axes[1].plot(g["iteration"], g["mean"], label=LABEL[s])
    axes[0].set_title("repeat 0 (one split)")
    axes[1].set_title(f"mean over {c['repeat'].nunique()} repeats")
    for ax in axes:
        ax.set_xlabel("iteration")
        ax.set_ylabel("best training RMSE (deg)")
        ax.set_yscale("log")
    axes[1].legend(fontsize=8)
    stamp.save(fig, out / "fig11.png", "Fig. 11: convergence of the five 4th-seed strategies (lab_casing)")
    return True


def fig12(runs: Runs, out: Path) -> bool:
    """Fig. 12: error modelling: the MSA residual (target) and each strategy's prediction on test rows, repeat 0."""
    p = runs.predictions()
    methods = [f"cgo-{s}" for s in STRATEGIES4]
    if not have(p, methods):
        return False
    p = p[(p.repeat == 0) & (p.split == "test") & p.method.isin(methods)]
    wide = p.pivot_table(index=["row", "station", "azimuth_true", "error_msa"], columns="method",
                         values="predicted_error").reset_index().sort_values("station")
    wide.to_csv(out / "fig12.csv", index=False)
    plt = plt_agg()
    fig, axes = plt.subplots(2, 1, figsize=(11, 6), sharex=True)
    x = np.arange(len(wide))
    axes[0].plot(x, wide["error_msa"], "k-", lw=2, label="MSA residual (target)")
    for s in STRATEGIES4:
        axes[0].plot(x, wide[f"cgo-{s}"], lw=0.9, label=LABEL[s])
        axes[1].plot(x, wide["error_msa"] - wide[f"cgo-{s}"], lw=0.9, label=LABEL[s])
    axes[0].set_ylabel("azimuth error (deg)")
    axes[1].set_ylabel("model residual (deg)")
    axes[1].set_xlabel("test sample (sorted by station: azimuth, then toolface)")
    axes[0].legend(fontsize=8, ncol=5)
    stamp.save(fig, out / "fig12.png", "Fig. 12: error modelling of the MSA residual (repeat 0, test rows, lab_casing)")
    return True


def fig13(runs: Runs, out: Path) -> bool:
    """Fig. 13: (a) azimuth error before/after compensation (repeat 0, test); (b) MAE per repeat by strategy."""
    p, m = runs.predictions(), runs.metrics()
    methods = [f"cgo-{s}" for s in STRATEGIES4]
    if not (have(p, methods) and have(m, methods)):
        return False
    p0 = p[(p.repeat == 0) & (p.split == "test") & (p.method == "cgo-three_stage")].sort_values("station")
    raw = ((p0["azimuth_raw"] - p0["azimuth_true"] + 180) % 360) - 180
    per = m[m.method.isin(methods)].pivot_table(index="repeat", columns="method", values="mae")
    per.to_csv(out / "fig13.csv")
    plt = plt_agg()
    fig, axes = plt.subplots(1, 2, figsize=(12, 3.8))
    x = np.arange(len(p0))
    axes[0].plot(x, raw, lw=0.8, label="raw (eq. 1)")
    axes[0].plot(x, p0["error_msa"], lw=0.8, label="after MSA")
    axes[0].plot(x, p0["error_compensated"], lw=1.2, label="after ICGO-RELM")
    axes[0].set_xlabel("test sample (sorted by station)")
    axes[0].set_ylabel("azimuth error (deg)")
    axes[0].set_title("(a) repeat 0")
    axes[0].legend(fontsize=8)
    for s in STRATEGIES4:
        axes[1].plot(per.index, per[f"cgo-{s}"], "o-", label=LABEL[s])
    axes[1].set_xlabel("repeat")
    axes[1].set_ylabel("test MAE (deg)")
    axes[1].set_title("(b) MAE per repeat")
    axes[1].legend(fontsize=8)
    stamp.save(fig, out / "fig13.png", "Fig. 13: azimuth error compensation (lab_casing)")
    return True
