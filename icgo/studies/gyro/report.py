"""Gyro inclinometer study report: protocol and stamp lines, tables, figures and the saved models.

:func:`write_results` writes what :func:`icgo.studies.gyro.study.run` returned into one (staged) directory: the tables
(``gyro_methods``, ``gyro_points``, ``gyro_seam`` .csv + .md), the figures (``gyro_points.png``, ``gyro_seam.png``,
``gyro_toolface.png``) and the fitted models; :func:`write_run_summary` writes ``gyro_run.json``.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from icgo.reporting.plots import plt_agg

#: Methods drawn in the seam figure (with ``raw``).
SEAM_FIGURE_METHODS = ("net_azimuth", "net_error", "net_azimuth_sgd_patent", "net_error_sgd_patent")

METHOD_COLUMNS = ["method", "test", "n_seeds", "rmse", "rmse_mean", "rmse_std", "mae_mean", "max_abs_mean"]
POINT_COLUMNS = ["method", "test", "azimuth_step_deg", "toolface_step_deg", "n_points", "rmse", "rmse_mean", "rmse_std"]



# ----------------------------------------------------------------- tables
def write_table(df: pd.DataFrame, path: Path, title: str, note: str = "") -> None:
    """CSV + Markdown (with a title and a note)."""
    df.to_csv(path.with_suffix(".csv"), index=False)
    md = f"# {title}\n\n{note}\n\n" + df.to_markdown(index=False, floatfmt=".4f") + "\n"
    path.with_suffix(".md").write_text(md)


# ----------------------------------------------------------------- figures
def fig_seam(preds: dict, f: pd.DataFrame, band, path: Path) -> None:
    """|error| vs true azimuth (10-deg bins, RMS over points and seeds) per method."""
    from icgo.physics.metrics import rmse

    plt = plt_agg()
    a = np.mod(f["azimuth_deg"].to_numpy(), 360.0)
    edges = np.arange(0, 361, 10.0)
    centers = 0.5 * (edges[1:] + edges[:-1])
    fig, ax = plt.subplots(figsize=(8, 4.2))
    for name, p in preds.items():
        p = np.atleast_2d(np.asarray(p))
        b = np.digitize(a, edges) - 1
        y = [float(rmse(np.broadcast_to(a[b == j], p[:, b == j].shape).ravel(), p[:, b == j].ravel()))
             if np.any(b == j) else np.nan for j in range(len(centers))]
        ax.plot(centers, y, marker="o", ms=3, label=name)
    ax.axvspan(0, band, color="0.9")
    ax.axvspan(360 - band, 360, color="0.9")
    ax.set_yscale("log")
    ax.set_xlabel("true azimuth (deg)")
    ax.set_ylabel("azimuth RMSE in 10-deg bin (deg)")
    ax.set_xticks(np.arange(0, 361, 45))
    ax.set_title("target=azimuth fails at the 0/360 seam; target=error does not (random test set)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def fig_points(df: pd.DataFrame, path: Path) -> None:
    """Test RMSE vs number of turntable points, table vs network, one panel per test set."""
    plt = plt_agg()
    tests = list(dict.fromkeys(df["test"]))
    fig, axes = plt.subplots(1, len(tests), figsize=(5 * len(tests), 4), squeeze=False)
    for ax, k in zip(axes[0], tests):
        d = df[df["test"] == k]
        for m, mk in (("table", "s"), ("network", "o"), ("raw", "")):
            dm = d[d["method"] == m].sort_values("n_points")
            if dm.empty:
                continue
            if m == "raw":
                ax.axhline(dm["rmse_mean"].iloc[0], color="0.5", ls="--", label="raw")
                continue
            for a_step, g in dm.groupby("azimuth_step_deg"):
                ax.errorbar(g["n_points"], g["rmse_mean"], yerr=g["rmse_std"], marker=mk, capsize=3,
                            label=f"{m}, azimuth step {a_step:g}")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ticks = sorted(set(d["n_points"].dropna().astype(int)))
        ax.set_xticks(ticks, [str(t) for t in ticks], rotation=60, fontsize=7)
        ax.minorticks_off()
        yt = [0.1, 0.2, 0.3, 0.5, 1.0, 2.0, 3.0, 5.0, 10.0]
        ax.set_yticks(yt, [f"{y:g}" for y in yt])
        ax.set_xlabel("turntable points")
        ax.set_ylabel("azimuth RMSE (deg)")
        ax.set_title(f"test set: {k}")
        ax.legend(fontsize=7, loc="center right")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def fig_toolface(train: pd.DataFrame, path: Path, inclination=25.0) -> None:
    """Raw azimuth error vs toolface at one inclination, one curve per azimuth (why the table fails)."""
    from icgo.physics.frames import angle_diff

    plt = plt_agg()
    d = train[np.isclose(train["inclination_deg"], inclination)]
    fig, ax = plt.subplots(figsize=(7, 4))
    for a, g in d.groupby("azimuth_deg"):
        g = g.sort_values("toolface_deg")
        error = np.asarray(angle_diff(g["azimuth_raw_deg"].to_numpy(), g["azimuth_deg"].to_numpy()))
        ax.plot(g["toolface_deg"], error, marker=".", lw=0.8, label=f"A={a:g}")
    ax.set_xlabel("toolface (deg)")
    ax.set_ylabel("raw azimuth error (deg)")
    ax.set_title(f"raw error vs toolface at I={inclination:g} deg: the table's toolface blind spot")
    ax.legend(fontsize=6, ncol=3)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


# ------------------------------------------------------------------ outputs
def rate_qc_sentence(qc: dict) -> str:
    """The earth-rate QC counts of the raw gyro (:func:`icgo.studies.gyro.study.rate_qc`) as one sentence."""
    from icgo.physics.qc import EARTH_RATE_TOL_DEG_H

    return (f"Survey QC of the raw gyro (|total rate - earth rate| <= {EARTH_RATE_TOL_DEG_H:g} deg/h; docs/qc.md): "
            + ("; ".join(f"{k}: {c['any']} of {c['n']} stations flagged" for k, c in qc.items())
               or "no gyro rates (wx, wy, wz) in the data")
            + ". The |G|, |B| and dip checks cannot fail on this instrument (no magnetometer, gz implied by |g|), "
            "and the methods correct the azimuth, not the rates: no count after.")


def protocol(config, data, test_sets: str) -> str:
    """A gyro table's protocol line (:func:`icgo.reporting.protocol.protocol_line`)."""
    from icgo.reporting.protocol import protocol_line

    return protocol_line(
        "`make gyro` (`python -m experiments.gyro`, config `conf/gyro.yaml`)",
        f"{config.n_seeds} seeds per trained method (network initialisation, early-stopping split, batches), all "
        "seeds in one run; raw and the lookup table are deterministic (one value)",
        f"trained on the patent's turntable plan ({len(data.train)} points; {100 * config.net.val_fraction:.0f} % "
        f"of them held out per seed for early stopping), scored on {test_sets}",
        f"data: turntable seed {config.seed}, random test set seed {config.seed + 1}, between-grid test set seed "
        f"{config.seed + 2}; networks: PRNGKey({config.seed}) split into {config.n_seeds}. No setting was chosen on "
        "these test sets",
        "none: the table reports mean +/- sample std (ddof 1) over seeds and calls no method better by a test; "
        "the patent gives no accuracy figure to put beside ours")


def settings(config) -> str:
    """The stamp line of every gyro table (:func:`icgo.reporting.protocol.settings_line`)."""
    from icgo.reporting.protocol import settings_line

    n, r = config.net, config.relm
    relm = (f"; RELM search: population {r.pop_size} x {r.iterations} iterations ({r.optimizer}, {r.strategy})"
            if r.enabled else "")
    return settings_line(f"networks {'-'.join(map(str, n.hidden))}: {n.optimizer}, up to {n.epochs} epochs (early "
                         f"stopping, patience {n.patience}), batch {n.batch_size} (variants as listed){relm}",
                         f"{config.n_seeds} seeds per trained method", "float64",
                         "No published protocol: the patent describes the network and the turntable plan but gives "
                         "no training budget and no accuracy.")


def write_results(result, data, config, out: Path, models_dir: Path | None) -> None:
    """Tables and figures into ``out`` (``gyro_*``), the fitted models into ``models_dir``."""
    out.mkdir(parents=True, exist_ok=True)
    both = (f"turntable_random ({len(data.tests['random'])} attitudes, I in [3, 75] deg) and turntable_between "
            f"({len(data.tests['between'])} attitudes between the grid's nodes)")
    methods = result.records["methods"].copy()
    methods["train_s"] = methods["method"].map(result.summary["train_seconds"])
    write_table(methods[METHOD_COLUMNS + ["train_s"]], out / "gyro_methods",
                "Gyro inclinometer: azimuth RMSE (deg) on attitudes off the training grid",
                protocol(config, data, both) + "\n\n" + settings(config) + "\n\n"
                f"Trained on the patent's turntable plan ({len(data.train)} points); {config.n_seeds} seeds "
                "per trained method (mean +/- std over seeds, one run). `train_s`: wall time of one "
                "vmapped call for all seeds, including compilation (one run on a shared machine: a rough figure). "
                "Command: `python -m experiments.gyro`.\n\n" + rate_qc_sentence(result.summary["qc"]))
    band = float(config.seam.band_deg)
    write_table(result.records["seam"], out / "gyro_seam", "The 0/360 seam: RMSE near north vs elsewhere",
                protocol(config, data, f"turntable_random ({len(data.tests['random'])} attitudes)") + "\n\n"
                + settings(config) + "\n\n"
                f"Random test set; 'north' = |true azimuth| < {band:g} deg. ratio = north / elsewhere.")
    seam_preds = {m: p["random"] for m, p in result.predictions.items() if m in SEAM_FIGURE_METHODS}
    seam_preds["raw"] = result.predictions["raw"]["random"]
    fig_seam(seam_preds, data.tests["random"], band, out / "gyro_seam.png")
    fig_toolface(data.train, out / "gyro_toolface.png")
    if "points" in result.records:
        write_table(result.records["points"][POINT_COLUMNS], out / "gyro_points",
                    "Azimuth RMSE (deg) vs number of turntable points",
                    protocol(config, data, both + " (the 30-deg plan's test sets for every point count)") + "\n\n"
                    + settings(config) + "\n\n"
                    f"network = variant `{config.sweep.variant}`, {config.n_seeds} seeds (mean +/- std); "
                    "inclinations as the patent; test sets fixed (30-deg plan's between-grid set).")
        fig_points(result.records["points"], out / "gyro_points.png")
    if models_dir is not None:
        for name, model in result.models.items():
            model.save(models_dir / f"gyro_{name}")


def write_run_summary(result, seconds: float, composed: dict, stage: Path) -> dict:
    """``gyro_run.json`` into ``stage``: the study's summary, ``total_seconds`` (the whole run) and the composed
    config; returns it."""
    summary = {**result.summary, "total_seconds": seconds, "config": composed}
    (stage / "gyro_run.json").write_text(json.dumps(summary, indent=1, default=float))
    return summary


def write(result, data, config, stage: Path, invocation) -> str:
    """The study's outputs (:class:`icgo.studies.common.study.Study` ``.write``): :func:`write_results` and
    :func:`write_run_summary` (the wall time since the door started); returns the rate QC and the done line."""
    import time

    models = invocation.models_dir
    write_results(result, data, config, stage, models)
    summary = write_run_summary(result, time.perf_counter() - invocation.started, invocation.settings, stage)
    return (rate_qc_sentence(result.summary["qc"]) + "\n"
            + f"[gyro] done in {summary['total_seconds']:.0f} s; results in {invocation.out}"
            + (f"; {len(result.models)} models in {models}" if models is not None else ""))
