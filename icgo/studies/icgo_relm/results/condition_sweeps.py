"""Noise and interference sweeps (``experiment=sweep_noise``, ``sweep_casing``, ``sweep_casing_strength``): every method against the noise floor, per level.

Built by :func:`icgo.studies.icgo_relm.results.build.build` from the runs of three presets (labels below):

* ``sweep_noise``: the accelerometer and magnetometer white noise both x {0.25, 0.5, 1, 2, 4}
  (``lab_casing``'s ``noise_scale``; x1 = 5e-4 g and 30 nT per raw sample);
* ``sweep_casing``: the casing's axis {0.5, 0.75, 1, 1.5, 2} m from the turntable's vertical
  axis (``casing_distance_m``; the paper's lab: 1 m);
* ``sweep_casing_strength``: the casing's magnetization {2, 4, 8, 16, 32} kA/m at 1 m
  (``casing_magnetization_A_m``; default 8 kA/m).

Each level runs every method on Table 3's splits and keys (10 paired repeats): plain RELM,
PSO-RELM, GA-RELM and CGO-RELM's five 4th-seed strategies. Per level the table gives each
method's test MAE, the noise floor of that level's data (:func:`icgo.datasets.casing_stations.noise_floor`: the
same draw without casing, sensor effects and spikes), the casing's field at the sensor, the order
of the methods by mean MAE, the Friedman test over the methods (Holm over the levels), the best
method against the second (paired Wilcoxon, its median difference, Holm over the levels), and
Kendall's tau between the level's order and the default level's. Two families per sweep, each
Holm-adjusted over the sweep's levels: "do the methods differ at this level" (Friedman) and "is
the first place separable from the second at this level" (Wilcoxon). Outputs:
``results/sweep_noise.{md,csv,png}`` and ``results/sweep_casing.{md,csv,png}`` (distance and strength).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from scipy.stats import kendalltau

from icgo.datasets.casing_stations import lab_casing, noise_floor
from icgo.maths.stats import format_mean_std, friedman, holm, mean_std, wilcoxon_paired
from icgo.physics.qc import survey_qc
from icgo.reporting import records as R
from icgo.reporting import stamp
from icgo.studies.icgo_relm.names import METHOD_NAMES
from icgo.reporting.plots import plt_agg
from icgo.reporting.protocol import ALPHA

#: Run label of each sweep -> (dataset keyword swept, its readable name, its default value).
SWEEPS = {"sweep_noise": ("noise_scale", "noise x", 1.0),
          "sweep_casing": ("casing_distance_m", "casing distance (m)", 1.0),
          "sweep_casing_strength": ("casing_magnetization_A_m", "casing magnetization (A/m)", 8000.0)}
#: Output name -> the sweeps it reports.
OUTPUTS = {"sweep_noise": ("sweep_noise",), "sweep_casing": ("sweep_casing", "sweep_casing_strength")}
#: Method column -> its name in the tables (the compensators; raw and MSA-only are reported beside them).
METHODS = {m: METHOD_NAMES[m] for m in ("relm", "pso", "ga", "cgo-original", "cgo-chaos", "cgo-gaussian",
                                         "cgo-wavelet", "cgo-three_stage")}


def _level_data(kwargs: dict) -> dict:
    """One level's ``lab_casing`` draw (seed 0): its noise floor (deg), the casing field at the sensor (nT)
    and the physics of its raw readings against the site's reference (:func:`icgo.physics.qc.survey_qc`): RMS
    deviation of |G| (mg), |B| (nT) and dip (deg), which noise and casing disturb before any compensation."""
    floor = noise_floor("lab_casing", 0, **kwargs).iloc[0]
    ds = lab_casing(0, **kwargs)
    b = np.linalg.norm(ds.truth["casing_field_ned_nT"], axis=1)
    f, m = ds.frame, ds.meta
    qc = survey_qc(f[["gx", "gy", "gz"]].to_numpy(float), f[["bx", "by", "bz"]].to_numpy(float),
                   m["total_field_nT"], m["dip_deg"], m["gravity_g"]).table
    rms = lambda c: float(np.sqrt(np.mean(qc[c] ** 2)))  # noqa: E731
    return {"floor MAE (deg)": float(floor.mae),
            "casing field at sensor (nT)": f"{np.median(b):.0f} ({b.min():.0f}-{b.max():.0f})",
            "raw |G| dev RMS (mg)": round(1e3 * rms("dg_g"), 3), "raw |B| dev RMS (nT)": round(rms("db_nT"), 1),
            "raw dip dev RMS (deg)": round(rms("ddip_deg"), 3)}


def _levels(runs, label: str) -> dict:
    """{level value: wide (repeat x method) test-MAE frame} of one sweep's runs; raises on a clash."""
    key = SWEEPS[label][0]
    frames: dict = {}
    for info in runs.runs:
        if info.get("label") != label:
            continue
        kw = info.get("dataset_kwargs") or {}
        level = float(kw.get(key, SWEEPS[label][2]))
        t = R.read_table(info["dir"], "metrics")
        t = t[t.split == "test"].pivot_table(index="repeat", columns="method", values="mae")
        frames.setdefault(level, []).append((info["mtime"], t))
    out = {}
    for level, ts in frames.items():
        ts.sort(key=lambda x: x[0])
        wide = pd.concat([t for _, t in ts], axis=1)
        out[level] = wide.loc[:, ~wide.columns.duplicated(keep="last")]
    return dict(sorted(out.items()))


#: The optimizer override of each method's job (a sweep job runs one optimizer; CGO runs every strategy).
OPTIMIZER_OF = {"relm": "none", "pso": "pso", "ga": "ga"}


def missing_cells(label: str, levels: dict) -> list[str]:
    """One line per (level, method) of a sweep that has no result, naming the job that makes it."""
    key = SWEEPS[label][0]
    methods = [m for m in METHODS if any(m in w.columns for w in levels.values())]
    return [f"{label}: level {key}={level:g} has no {METHODS[m]} (`python -m experiments.run experiment={label} "
            f"+dataset.kwargs.{key}={level:g} optimizer={OPTIMIZER_OF.get(m, 'cgo')}`)"
            for level, w in levels.items() for m in methods if m not in w.columns]


def table(label: str, levels: dict) -> tuple[pd.DataFrame, list[str]]:
    """One sweep's rows (one per level) and the methods any level has; a method a level lacks is marked
    ``missing`` in its cell (never a dropped column), and that level's order and tests use the methods it has."""
    key, name, default = SWEEPS[label]
    methods = [m for m in METHODS if any(m in w.columns for w in levels.values())]
    base_order = None
    if default in levels:
        base_order = sorted([m for m in methods if m in levels[default]], key=lambda m: levels[default][m].mean())
    rows, p_best, p_fr = [], [], []
    for level, wide in levels.items():
        here = [m for m in methods if m in wide.columns]
        w = wide[here].dropna()
        order = sorted(here, key=lambda m: w[m].mean())
        row = {name: level, **_level_data({key: level}),
               "raw MAE (deg)": round(float(wide["raw"].mean()), 4) if "raw" in wide else np.nan,
               "MSA MAE (deg)": round(float(wide["msa"].mean()), 4) if "msa" in wide else np.nan}
        row |= {METHODS[m]: format_mean_std(*mean_std(w[m])) if m in here else "missing" for m in methods}
        best = w[order[0]]
        row["best / floor"] = round(float(best.mean()) / row["floor MAE (deg)"], 2)
        row["order by MAE"] = " < ".join(METHODS[m] for m in order)
        common = [m for m in here if base_order and m in base_order]
        row["Kendall tau vs default order"] = (
            round(float(kendalltau([base_order.index(m) for m in common], [order.index(m) for m in common])
                        .statistic), 2) if len(common) >= 2 else np.nan)
        row["first in repeats"] = f"{METHODS[order[0]]} {int((w.idxmin(axis=1) == order[0]).sum())}/{len(w)}"
        fr = friedman({m: w[m].to_numpy() for m in here}) if len(here) >= 3 and len(w) >= 2 else None
        p_fr.append(float(fr.p_value) if fr else np.nan)
        two = len(order) > 1 and len(w) > 1
        row["best - second, median (deg)"] = round(float((w[order[0]] - w[order[1]]).median()), 4) if two else np.nan
        p_best.append(wilcoxon_paired(w[order[0]], w[order[1]]).p_value if two else np.nan)
        rows.append(row)
    df = pd.DataFrame(rows)
    df["Friedman p (Holm)"] = holm(np.nan_to_num(np.asarray(p_fr, float), nan=1.0))
    df["p best vs second (Holm)"] = holm(np.nan_to_num(np.asarray(p_best, float), nan=1.0))
    return df, methods


def _plot(ax, label: str, df: pd.DataFrame, levels: dict, methods) -> None:
    name = SWEEPS[label][1]
    x = df[name].to_numpy(float)
    for m in methods:
        ax.plot(x, [levels[v][m].mean() if m in levels[v] else np.nan for v in x], "o-", ms=3, lw=1,
                label=METHODS[m])
    ax.plot(x, df["MSA MAE (deg)"], "s:", ms=3, color="grey", label="MSA only")
    ax.plot(x, df["floor MAE (deg)"], "k--", lw=1.5, label="noise floor")
    n = min(len(w) for w in levels.values())
    ax.set(xlabel=name, ylabel=f"test MAE (deg), mean of {n} repeat(s)", yscale="log")
    if label != "sweep_casing":
        ax.set_xscale("log", base=2)
    ax.grid(alpha=0.3, which="both")


def build(runs, out: Path, name: str, lacking: list | None = None) -> bool:
    """Write ``results/<name>.{md,csv,png}`` from the sweeps of :data:`OUTPUTS` ``[name]``; False if none ran.

    Args:
        runs: :class:`icgo.reporting.run_collection.Runs` holding the sweeps' runs (other labels are ignored).
        out: output folder. name: ``sweep_noise`` or ``sweep_casing``.
        lacking: gets a ``"partial: ..."`` line per missing job (:func:`missing_cells`).
    """
    parts = [(label, _levels(runs, label)) for label in OUTPUTS[name]]
    parts = [(label, lv) for label, lv in parts if lv]
    if not parts:
        return False
    text, csv, plt = [], [], plt_agg()
    fig, axes = plt.subplots(1, len(parts), figsize=(6.5 * len(parts), 4.2), squeeze=False)
    for ax, (label, levels) in zip(axes[0], parts):
        df, methods = table(label, levels)
        if lacking is not None:
            lacking.extend(f"partial: {x}" for x in missing_cells(label, levels))
        key, _, default = SWEEPS[label]
        test = (f"per level, Friedman over the methods and the paired Wilcoxon signed-rank (two-sided) of the first "
                f"against the second by mean MAE; each of the two families Holm-adjusted over the {len(df)} levels")
        text += [f"## {label}: `python -m experiments.run -m experiment={label}`", "",
                 stamp.protocol(f"`make figures` (the runs `python -m experiments.run -m experiment={label}`, then "
                                 "`python -m experiments.figures`)", test), "",
                 df.to_markdown(index=False, floatfmt=".4g"), "",
                 f"Levels of `dataset.kwargs.{key}` (default {default:g}); each row: {len(methods)} methods x "
                 f"{min(len(w) for w in levels.values())} paired repeats (Table 3's splits and keys). "
                 + _changes(df, SWEEPS[label][1], default) + " " + _separable(df, SWEEPS[label][1]), ""]
        csv.append(df.assign(sweep=label))
        _plot(ax, label, df, levels, methods)
    axes[0][0].legend(fontsize=7)
    title = {"sweep_noise": "Sweep: sensor noise", "sweep_casing": "Sweep: casing distance and strength"}[name]
    pd.concat(csv, ignore_index=True).to_csv(out / f"{name}.csv", index=False)
    notes = ["Noise floor: the level's own `lab_casing` draw (seed 0) with the casing, every systematic sensor "
             "effect and the spikes removed, through the standard azimuth formula: the error the simulated "
             "sensor noise alone leaves. `best / floor` = the best method's MAE over it. Casing field: median "
             "(range) of |B_casing| at the sensor over the kept rows. Raw |G|, |B|, dip: RMS deviation of the "
             "level's raw readings from the site's reference field and gravity (the data set's metadata; `icgo.physics.qc.survey_qc`), "
             "the physics the noise and the casing disturb. The methods output an azimuth correction only (no "
             "corrected G or B), so these columns describe each level's data, not a method's output."]
    stamp_lines = [stamp.note(), ""] if stamp.note() else []
    (out / f"{name}.md").write_text("\n".join([f"# {title} (test MAE, lab_casing)", "", *stamp_lines, *text, *notes]) + "\n")
    stamp.save(fig, out / f"{name}.png", f"{title}: every method against the noise floor (lab_casing)")
    return True


def _separable(df: pd.DataFrame, name: str) -> str:
    """One sentence: at which levels the first place is separable from the second (Holm p < ALPHA)."""
    sig = df["p best vs second (Holm)"] < ALPHA
    levels = lambda mask: ", ".join(f"{v:g}" for v in df.loc[mask, name]) or "none"  # noqa: E731
    return (f"The first place is separable from the second (Holm p < {ALPHA:g}) at {int(sig.sum())} of {len(df)} "
            f"levels ({levels(sig)}); at the others ({levels(~sig)}) the first two are not significantly different.")


def _changes(df: pd.DataFrame, name: str, default: float) -> str:
    """One sentence: which method is first at each level and how far the order moves from the default level's."""
    firsts = df["order by MAE"].str.split(" < ").str[0]
    text = "First by mean MAE: " + ", ".join(f"{v:g}: {f}" for v, f in zip(df[name], firsts)) + "."
    tau = df["Kendall tau vs default order"]
    if tau.isna().all():
        return text + f" The default level {default:g} did not run, so no order is compared."
    lo = df.loc[tau.idxmin()]
    return text + (f" The order of all {sum(c in df.columns for c in METHODS.values())} methods moves most from the default level's at {lo[name]:g} "
                   f"(Kendall tau {lo['Kendall tau vs default order']:.2f}; 1 = the same order).")
