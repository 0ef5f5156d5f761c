"""MISMA study report: protocol and stamp lines, the summary, tables, figures and the saved models.

:func:`write_results` writes what :func:`icgo.studies.misma.study.run` returned into one (staged) directory:
``misma_*.csv`` / ``.md`` / ``.png``, ``misma_summary.md`` / ``.json``, and the fitted calibrations.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np


def variant_plots(name, plot, out: Path) -> None:
    """Convergence, field modulus and static-point azimuth error of one variant -> ``misma_<name>.png``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 3, figsize=(15, 4))
    # the rows minimise different objectives: each curve is shown relative to its own median at iteration 1
    for i, (lab, cu) in enumerate(plot.curves.items()):
        it = np.arange(1, cu.shape[1] + 1)
        start = float(np.median(cu[:, 0]))
        ax[0].plot(it, np.median(cu, 0) / start, f"C{i}", label=f"{lab} (median of {cu.shape[0]})")
        ax[0].fill_between(it, np.quantile(cu, 0.25, 0) / start, np.quantile(cu, 0.75, 0) / start, color=f"C{i}",
                           alpha=0.2)
    ax[0].set(yscale="log", xlabel="iteration", ylabel="best fitness / its median at iteration 1",
              title=f"convergence ({name}); each on its own objective")
    ax[0].text(0.02, 0.02, f"threshold_factor x F(true), magnetometer objective: {plot.threshold:.3g}",
               transform=ax[0].transAxes, fontsize=6)
    ax[0].legend(fontsize=6)
    for k, v in plot.moduli.items():
        ax[1].plot(plot.t, v, lw=0.6, label=k)
    ax[1].axhline(plot.ref_nT, color="k", ls=":", label="|M_omega|")
    ax[1].set(xlabel="time (s)", ylabel="|B| (nT)", title="field modulus before/after")
    ax[1].legend()
    for lab, e in plot.az_errors.items():
        ax[2].plot(np.arange(len(e)), e, ".", ms=3, label=f"{lab} (mean {e.mean():.2f} deg)")
    ax[2].set(yscale="log", xlabel="static sample index", ylabel="|azimuth error| (deg)", title="static survey points")
    ax[2].legend()
    fig.tight_layout()
    fig.savefig(out / f"misma_{name}.png", dpi=110)
    plt.close(fig)


def sweep_plot(sweep, out: Path) -> None:
    """Static-point |azimuth error| of MISMA with the gyro term against the gyro grade -> ``misma_gyro_sweep.png``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    for i, (variant, g) in enumerate(sweep.groupby("variant", sort=False)):
        x = g["bias_deg_h_max"].clip(lower=0.01)
        ax.plot(x, g["MISMA_gyro_az_err_mean_deg"], "o-", color=f"C{i}", label=f"{variant}: MISMA with J_gyro")
        ax.axhline(g["MISMA_no_gyro_az_err_mean_deg"].iloc[0], color=f"C{i}", ls="--", label=f"{variant}: without")
    ax.set(xscale="log", yscale="log", xlabel="gyro bias, largest axis (deg/h; 0 plotted at 0.01)",
           ylabel="mean |azimuth error| at the stops (deg)", title="gyro grade (errors and noise scaled together)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "misma_gyro_sweep.png", dpi=110)
    plt.close(fig)


def protocol(config) -> str:
    """The summary's protocol line (:func:`icgo.reporting.protocol.protocol_line`)."""
    from icgo.reporting.protocol import protocol_line
    from icgo.studies.misma.config import DEVELOPMENT_SEEDS

    sim, real = config.simulated, config.real
    dev = ", ".join(map(str, DEVELOPMENT_SEEDS))
    held = ("" if config.seed not in DEVELOPMENT_SEEDS else
            f" WARNING: seed {config.seed} is a development seed (the trajectory and the box-normalised coordinates "
            "were chosen on it): these numbers are not a result")
    return protocol_line(
        "`make misma` (`python -m experiments.misma`, config `conf/misma.yaml`)",
        f"{sim.repeats} search repeats per row (the same {sim.repeats} keys for every row: paired), one simulated "
        f"run per variant; real devices: {real.misma_repeats} MISMA runs per fit",
        "simulated: none held out (every search fits the run's samples, the static survey points included, and is "
        "scored at the static points against the true azimuth); real devices: in-sample and each rolled group held "
        "out in turn",
        f"data noise seed {config.seed}, searches PRNGKey({config.seed + 1}) split into {sim.repeats}, real-device "
        f"MISMA PRNGKey({config.seed + 7}); the trajectory and the coordinates were chosen on seed {dev} "
        f"(docs/misma.md), which is not reported here{held}",
        "paired Wilcoxon signed-rank (two-sided) on the per-repeat mean |azimuth error|, Holm over each variant's "
        f"contrasts (one family per variant), over the headline MISMA-vs-SMA test of the {len(sim.variants)} "
        f"variants (one family) and over the gyro sweep's {len(sim.variants) * len(sim.gyro.sweep)} cells "
        "(every variant x grade: one family)")


def settings(config) -> str:
    """The stamp line of every MISMA table (:func:`icgo.reporting.protocol.settings_line`): the searches' budget
    against the paper's Table 3 (population 30, 2051 iterations, box 128 / -68 uT)."""
    from icgo.reporting.protocol import settings_line
    from icgo.reporting.published import MISMA

    sim, real, paper = config.simulated, config.real, MISMA["table3"]
    same = (sim.pop_size, sim.n_iter) == (paper["pop_size"], paper["n_iter"])
    box = ("the paper's box" if sim.misma.bounds == "paper" else
           f"the box around U (`simulated.misma.bounds={sim.misma.bounds}`), not the paper's "
           f"{paper['upper_uT']:g} / {paper['lower_uT']:g} uT, which has its own row")
    return settings_line(
        f"population {sim.pop_size} x {sim.n_iter} iterations per simulated search; real devices: {real.misma_iter} "
        "iterations per MISMA run", f"{sim.repeats} search repeats per row, {real.misma_repeats} MISMA runs per "
        "real-device fit", "float64 searches",
        ("The paper's population and iterations (its Table 3)" if same else
         f"NOT the paper's population and iterations ({paper['pop_size']} x {paper['n_iter']}, its Table 3)")
        + f"; {box}; simulated runs, not the paper's field data.")


def paper_table(summary: list[dict]) -> list[str]:
    """The MISMA paper's field values (:data:`icgo.reporting.published.MISMA`) beside ours, per variant."""
    import pandas as pd

    from icgo.reporting.published import MISMA

    f10, a, b = MISMA["fig10"], MISMA["fig11_first2"], MISMA["fig11_rest"]
    paper = {"raw": f"- / {a['raw']} / {b['raw']}", "SMA": f"{f10['sma']} / {a['sma']} / {b['sma']}",
             "MISMA": f"{f10['misma']} / {a['misma']} / {b['misma']}",
             "MISMA reduction vs raw (%)": f"- / {100 * (1 - a['misma'] / a['raw']):.1f} / "
                                           f"{100 * (1 - b['misma'] / b['raw']):.1f}"}
    rows = {"raw": "az_err_raw_deg", "SMA": "az_err_SMA_deg_mean", "MISMA": "az_err_MISMA_deg_mean",
            "MISMA reduction vs raw (%)": "az_reduction_MISMA_pct"}
    table = pd.DataFrame([{"mean abs. azimuth error at the stops (deg)": k,
                           "paper: Fig. 10 / Fig. 11 first 2 stops / Fig. 11 the rest": paper[k],
                           **{f"ours: {s['variant']}": round(float(s[v]), 3 if "pct" not in v else 1)
                              for s in summary}} for k, v in rows.items()])
    conv = [c for s in summary for k, c in s["convergence"].items() if k.startswith("MISMA vs standard SMA")]
    return ["### The MISMA paper's values beside ours", "",
            "The paper's numbers are its coal-mine field runs (Figs. 10-11: mean |azimuth error| at the static survey "
            "points against the reference azimuth; Fig. 10 gives no raw value); ours are the simulated "
            "`rotating_drill` runs above. The `straight` variant is our reading of the paper's field run (a near-straight hole); "
            "`curving` is the identifiable build-and-turn section this study's default uses. Different data: compare "
            "orders of magnitude, not digits.", "", table.to_markdown(index=False), "",
            f"Convergence: the paper's MISMA reaches SMA's fitness {MISMA['fig7_faster_pct']} % faster (Fig. 7, "
            "simulated drilling); ours, MISMA vs the standard SMA on one objective: "
            + "; ".join(f"{s['variant']} {c['faster_pct']:.1f} %" for s, c in zip(summary, conv)) + ".", ""]


def summary_lines(result, config=None) -> list[str]:
    """The Markdown summary ``misma_summary.md``."""
    from icgo.physics.qc import qc_sentence

    lines = ["# MISMA study", "", "Command: `python -m experiments.misma` (config `conf/misma.yaml`).", ""]
    if config is not None:
        lines += [protocol(config), "", settings(config), ""]
    if "simulated" in result.summary:
        lines += ["## rotating_drill: MISMA vs SMA (same run)", "",
                  result.records["simulated"].to_markdown(floatfmt=".4g"), "",
                  "`p_MISMA_vs_SMA`: paired Wilcoxon signed-rank (two-sided) of MISMA against the standard SMA on the "
                  "per-repeat mean |azimuth error| at the stops; `p_MISMA_vs_SMA_holm`: Holm over the variants (one "
                  "family); `MISMA_vs_SMA`: MISMA's error lower or higher than SMA's at Holm p < 0.05 (median paired "
                  "difference), else no significant difference.", "",
                  *paper_table(result.summary["simulated"])]
        for s in result.summary["simulated"]:
            name = s["variant"]
            fair = result.records[f"fair_{name}"]
            lines += [f"### One contribution at a time ({name}; {len(fair)} searches on the same repeat keys)", "",
                      f"MISMA reported above = `{s['MISMA_row']}` ({s['MISMA_box']}); SMA = the standard SMA "
                      f"({s['SMA_box']}).", "", fair.to_markdown(index=False, floatfmt=".4g"), "",
                      "Paired Wilcoxon tests (per-repeat mean |azimuth error|, Holm-adjusted within the variant; "
                      "`b_vs_a`: b's error lower or higher than a's at Holm p < 0.05, by the median paired "
                      "difference):", "",
                      result.records[f"tests_{name}"].to_markdown(index=False, floatfmt=".3g"), "",
                      "Convergence (iterations to the worse of the two median final fitness values, a level both "
                      "reach): " + "; ".join(f"{k}: {c['median_iters_a']:g} vs {c['median_iters_b']:g} "
                                             f"iterations ({c['faster_pct']:.1f} % faster; reached {c['reached_a']} "
                                             f"and {c['reached_b']} repeats)" for k, c in s["convergence"].items()), "",
                      f"Baselines, mean |azimuth error| at the stops, variant {name}: "
                      + ", ".join(f"{k} {v:.3f} deg" for k, v in s["baselines_az_err_deg"].items()),
                      f"Relative singular values of the fitness Jacobian at the truth ({name}): "
                      + "; ".join(f"{k}: " + (", ".join(f"{v:.2g}" for v in sv) if isinstance(sv, list)
                                              else ", ".join(f"{p} {v:g}" for p, v in sv.items()))
                                  for k, sv in s["jacobian_singular_values"].items()),
                      f"At the static survey points ({s['variant']}; SMA and MISMA: the median-fitness repeat): "
                      + qc_sentence(s["qc_static"]), ""]
    if "gyro_sweep" in result.records:
        lines += ["## Gyro grade (MISMA with J_gyro vs without; errors and noise of the simulated gyro x factor)", "",
                  "Command: `python -m experiments.misma` (`simulated.gyro.sweep`). `reference_error_deg_rms`: angle "
                  "between the truly corrected field and M_omega at the window samples. `p`: paired Wilcoxon of MISMA "
                  "with J_gyro against MISMA without it (the same repeat keys); `p_holm`: Holm over every row of this "
                  "table (one family); `J_gyro`: the error with the term lower or higher at Holm p < 0.05 (median "
                  "paired difference `MISMA_gyro_az_err_median_diff_deg`), else no significant difference.", "",
                  result.records["gyro_sweep"].to_markdown(index=False, floatfmt=".4g"), ""]
    if "real" in result.summary:
        from icgo.models.cal_sanity import limits_sentence
        from icgo.studies.calibration import wide

        lines += ["## 9 real devices: peer metric (deg), ours vs circuitpython-mag-cal", "",
                  limits_sentence() + " Values and reasons per fit: `misma_real_devices.csv`. The recordings carry no "
                  "reference field (location and date unknown): survey QC against a reference does not apply.", "",
                  wide(result.records["real_devices"].rename(columns={"device": "recording"})).to_markdown(
                      index=False), "",
                  result.records["real_summary"].to_markdown(floatfmt=".3f"), ""]
    return lines


def write_results(result, composed: dict, out: Path, models_dir: Path | None, config=None) -> list[str]:
    """Tables, figures, summary (``out/misma_*``) and the fitted models (``models_dir``); returns the lines of the
    summary."""
    out.mkdir(parents=True, exist_ok=True)
    for name, plot in result.plots.items():
        params = result.records[f"params_{name}"]
        params.to_csv(out / f"misma_params_{name}.csv", index=False)
        head = f"# MISMA: recovered vs true parameters ({name})\n\n" + (
            protocol(config) + "\n\n" + settings(config) + "\n\n" if config else "")
        (out / f"misma_params_{name}.md").write_text(head + params.to_markdown(index=False, floatfmt=".5g") + "\n")
        result.records[f"modulus_{name}"].to_csv(out / f"misma_modulus_{name}.csv")
        result.records[f"fair_{name}"].to_csv(out / f"misma_fair_{name}.csv", index=False)
        result.records[f"tests_{name}"].to_csv(out / f"misma_tests_{name}.csv", index=False)
        variant_plots(name, plot, out)
    if "gyro_sweep" in result.records:
        result.records["gyro_sweep"].to_csv(out / "misma_gyro_sweep.csv", index=False)
        sweep_plot(result.records["gyro_sweep"], out)
    if "real_devices" in result.records:
        result.records["real_devices"].to_csv(out / "misma_real_devices.csv", index=False)
        result.records["real_summary"].to_csv(out / "misma_real_summary.csv")
    lines = summary_lines(result, config)
    (out / "misma_summary.md").write_text("\n".join(lines))
    (out / "misma_summary.json").write_text(json.dumps({"config": composed, **result.summary}, indent=1, default=float))
    if models_dir is not None:
        for name, model in result.models.items():
            model.save(models_dir / name)
    return lines


def write(result, data, config, stage: Path, invocation) -> str:
    """The study's outputs (:class:`icgo.studies.common.study.Study` ``.write``): :func:`write_results` with the composed
    settings; returns the summary and where the models went."""
    lines = write_results(result, invocation.settings, stage, invocation.models_dir, config)
    if invocation.models_dir is not None:
        lines = [*lines, f"[misma] {len(result.models)} fitted calibrations in {invocation.models_dir}"]
    return "\n".join(lines)
