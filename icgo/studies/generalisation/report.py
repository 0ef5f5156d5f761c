"""Generalisation study report: the Markdown table (MAE, significance marks, coverage, noise floors, QC), the
figure and the files of :func:`icgo.studies.generalisation.study.run` (:func:`write_results`).
"""

from __future__ import annotations

import io
from pathlib import Path

from icgo.studies.icgo_relm import METHOD_NAMES

#: The methods of the report in table order, named as in every output (icgo.studies.icgo_relm.names), plus the physics baseline.
NAMES = {**{m: METHOD_NAMES[m] for m in ("raw", "msa", "relm", "pso", "ga", "cgo-original", "cgo-chaos",
                                         "cgo-gaussian", "cgo-wavelet", "cgo-three_stage")},
         "physics": "physics (12-par + field)"}
PROTOCOL_NAMES = {"random": "random 7:3", "leave_azimuth_out": "leave-azimuth-out",
                  "leave_condition_out": "leave-condition-out", "transfer": "transfer"}


def cell_name(name, protocol) -> str:
    """A cell's label: data set / protocol."""
    return f"{name} / {PROTOCOL_NAMES[protocol]}"


def bands() -> str:
    """The QC bands as one phrase (:class:`icgo.physics.qc.QCBands`)."""
    from icgo.physics.qc import QCBands

    b = QCBands()
    return f"|G| {1000 * b.g_tol_g:g} mg, |B| {b.b_tol_nT:g} nT, dip {b.dip_tol_deg:g} deg"


def markdown(rec: dict, config, seconds: dict) -> str:
    """The Markdown report: MAE table (mean +/- std), significance marks, coverage table, noise floors."""
    from icgo.maths.stats import format_mean_std, mean_std
    from icgo.reporting.choices import LAMBDA
    from icgo.reporting.protocol import ALPHA, protocol_line
    from icgo.studies.icgo_relm import StudyConfig

    m, cov, tests, floor = rec["metrics"], rec["coverage"], rec["tests"], rec["noise_floor"]
    cells = list(dict.fromkeys(zip(m["dataset"], m["protocol"])))
    methods = [k for k in NAMES if k in set(m["method"])]
    tr = config.transfer
    line = protocol_line(
        "`make generalisation` (`python -m experiments.generalisation`)",
        f"{config.n_repeats} per cell, paired (every method of a cell shares the cell's splits and keys)",
        "per cell: random 7:3 (test = the other 30 %), leave-azimuth-out / leave-condition-out (each station or "
        "condition scored by the fold that held it out), transfer (fitted on the source instrument's random 70 %, "
        "scored on every row of the target instrument); docs/generalisation.md",
        f"data: noise seed {config.data_seed} (transfer target: seed {tr.seed}); study key PRNGKey({config.seed}), "
        "repeat k its fold_in(., k). The budget, L and the transfer draw were fixed before the first run; "
        + LAMBDA.sentence()
        + (", the noise seed the transfer target is drawn with (casing and misalignment changed): the transfer "
           "column is scored on the draw lambda was chosen on" if tr.seed == LAMBDA.seed else
           ", which no cell reports"),
        "paired Wilcoxon signed-rank (two-sided) of each cell's first method by mean against every other method of "
        f"the cell, Holm over the cell's tests (one family per cell); `*` at Holm p < {ALPHA:g}")
    from icgo.reporting.protocol import settings_line

    paper = (config.pop_size, config.iterations) == (30, 100)
    stamp = settings_line(
        f"population {config.pop_size} x {config.iterations} iterations, L = {config.hidden} hidden units",
        f"{config.n_repeats} repeats per cell", f"search dtype {StudyConfig().precision}",
        ("The paper's population and iterations (30 x 100)" if paper else
         "NOT the paper's population and iterations (30 x 100)")
        + "; only the random 7:3 cells are the paper's split, the others are this project's protocols.")
    lines = ["# Generalisation: every method under every protocol", "", line, "", stamp, "",
             f"Azimuth MAE (deg) on the test rows, mean +/- std over {config.n_repeats} repeats (fold protocols: "
             "each repeat a full pass, every row predicted by the fold that held it out). The first of each column "
             f"by mean is in bold when it differs from every other method at Holm-adjusted p < {ALPHA:g} (the best), "
             "else marked \"first by mean\" (not separable from the methods marked `=`); `*` = different from the "
             f"first at Holm-adjusted p < {ALPHA:g}; `=` = not significantly different. Budget: population "
             f"{config.pop_size}, {config.iterations} iterations, L = {config.hidden} "
             f"hidden units, search dtype `{StudyConfig().precision}` (the ICGO-RELM study's default; every reported "
             "number is the float64 refit).", ""]
    from icgo.reporting.published import ICGO_LAB_MAE

    head = "| method | " + " | ".join(cell_name(*c) for c in cells) + " | paper (its lab data, random 7:3) |"
    lines += [head, "|" + "---|" * (len(cells) + 2)]
    for meth in methods:
        row = [NAMES[meth]]
        for c in cells:
            g = m[(m["dataset"] == c[0]) & (m["protocol"] == c[1])]
            means = g.groupby("method")["mae"].mean()
            x = g[g["method"] == meth]["mae"]
            cell = format_mean_std(*mean_std(x))
            if means.idxmin() == meth:
                others = tests[(tests["dataset"] == c[0]) & (tests["protocol"] == c[1])]
                cell = f"**{cell}**" if (others["p_holm"] < ALPHA).all() else f"{cell} (first by mean)"
            else:
                t = tests[(tests["dataset"] == c[0]) & (tests["protocol"] == c[1]) & (tests["method"] == meth)]
                cell += " *" if float(t["p_holm"].iloc[0]) < ALPHA else " ="
            row.append(cell)
        paper = ICGO_LAB_MAE.get(meth)
        row.append(f"{paper[0]:.4f} ({paper[1]})" if paper else "-")
        lines.append("| " + " | ".join(row) + " |")
    fl = ["noise floor"]
    for c in cells:
        f = floor[(floor["dataset"] == c[0]) & (floor["protocol"] == c[1])]
        fl.append(f"{float(f['mae'].iloc[0]):.4f}")
    lines.append("| " + " | ".join(fl) + " | - |")
    lines += ["", "The noise floor is the MAE of the standard formula on a draw with the same plan and noise but "
              "no casing and no sensor errors (`icgo.datasets.casing_stations.noise_floor`): what no compensation "
              "can beat on average. The paper's column is its own measured lab data under its random split "
              "(ICGO paper, `icgo.reporting.published`); it reports no other protocol and no well-condition MAE "
              "per method.", "",
              "## Coverage of the 90 % conformal interval", "",
              "Fraction of test rows whose azimuth error lies within the member's interval, mean over repeats "
              "(mean half-width in deg in brackets). Each fitted model's half-width is calibrated on rows of its "
              "own training data predicted by the other members that held them out (`icgo.maths.conformal`); its test "
              "rows never calibrate it. For transfer, only the source instrument's rows calibrate.", ""]
    cov_methods = [k for k in methods if k in set(cov["method"])]
    lines += ["| method | " + " | ".join(cell_name(*c) for c in cells) + " |", "|" + "---|" * (len(cells) + 1)]
    for meth in cov_methods:
        row = [NAMES[meth]]
        for c in cells:
            g = cov[(cov["dataset"] == c[0]) & (cov["protocol"] == c[1]) & (cov["method"] == meth)]
            row.append(f"{g['coverage'].mean():.3f} ({g['halfwidth_deg'].mean():.3f})")
        lines.append("| " + " | ".join(row) + " |")
    lines += ["", "## Per-cell tests against the first by mean", "",
              "| cell | first by mean | method | mean diff (deg) | p | p (Holm) |",
              "|---|---|---|---|---|---|"]
    for _, t in tests.iterrows():
        lines.append(f"| {cell_name(t['dataset'], t['protocol'])} | {NAMES[t['best']]} | {NAMES[t['method']]} | "
                     f"{t['mean_diff']:+.4f} | {t['p_value']:.3g} | {t['p_holm']:.3g} |")
    qc = rec["qc"]
    lines += ["", "## Survey QC", "",
              f"Stations outside the QC bands ({bands()}; docs/qc.md), before and after the corrections that "
              "correct the field itself: raw and MSA on all the cell's stations (the target instrument's under "
              "transfer). RELM and the searched methods correct the azimuth only; their field is MSA's. "
              "Physics: each station corrected by the repeat-0 member that tested it (random split: repeat 0's "
              "test rows only).", "",
              "| cell | stage | stations | flagged | \\|G\\| | \\|B\\| | dip |", "|---|---|---|---|---|---|---|"]
    for _, q in qc.iterrows():
        lines.append(f"| {cell_name(q['dataset'], q['protocol'])} | {q['stage']} | {q['n']} | {q['any']} | {q['g']} | "
                     f"{q['b']} | {q['dip']} |")
    lines += ["", "## Settings", "",
              f"- Transfer target: noise seed {tr.seed}, casing position x {tr.casing_distance_scale}, "
              f"magnetization x {tr.casing_strength_scale}, magnetometer misalignment + {list(tr.misalignment_deg)} "
              "deg (chosen before any run; docs/generalisation.md)"
              + (f"; its noise seed is the one lambda was chosen on ({LAMBDA.sentence()})." if tr.seed == LAMBDA.seed
                 else "."),
              "- Seconds per cell: " + ", ".join(f"{k} {v:.0f} s" for k, v in seconds.items()) + "."]
    return "\n".join(lines) + "\n"


def figure(rec: dict) -> bytes:
    """Mean MAE per method (log scale), one group of bars per cell, the noise floor dashed. Returns PNG bytes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    m, floor = rec["metrics"], rec["noise_floor"]
    cells = list(dict.fromkeys(zip(m["dataset"], m["protocol"])))
    methods = [k for k in NAMES if k in set(m["method"])]
    fig, ax = plt.subplots(figsize=(12, 4.5))
    width = 0.8 / len(methods)
    for j, meth in enumerate(methods):
        vals = [m[(m["dataset"] == c[0]) & (m["protocol"] == c[1]) & (m["method"] == meth)]["mae"].mean()
                for c in cells]
        ax.bar(np.arange(len(cells)) + (j - len(methods) / 2 + 0.5) * width, vals, width, label=NAMES[meth])
    for i, c in enumerate(cells):
        f = float(floor[(floor["dataset"] == c[0]) & (floor["protocol"] == c[1])]["mae"].iloc[0])
        ax.hlines(f, i - 0.45, i + 0.45, colors="k", linestyles="--", lw=1, label="noise floor" if i == 0 else None)
    ax.set_yscale("log")
    ax.set_xticks(np.arange(len(cells)), [cell_name(*c).replace(" / ", "\n") for c in cells])
    ax.set_ylabel("test azimuth MAE (deg)")
    ax.legend(ncol=4, fontsize=7)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=120)
    plt.close(fig)
    return buf.getvalue()


def write_results(res, config, stage: Path) -> None:
    """generalisation.md, generalisation.csv (per cell, method and repeat), generalisation_coverage.csv,
    generalisation_tests.csv, generalisation_qc.csv and generalisation.png into ``stage``."""
    rec = res.records
    png = figure(rec)
    (stage / "generalisation.png").write_bytes(png)
    (stage / "generalisation.md").write_text(markdown(rec, config, res.seconds))
    for name in ("metrics", "coverage", "tests", "qc"):
        suffix = "" if name == "metrics" else f"_{name}"
        (stage / f"generalisation{suffix}.csv").write_text(rec[name].to_csv(index=False))


def write(result, data, config, stage: Path, invocation) -> str:
    """The study's outputs (:class:`icgo.studies.common.study.Study` ``.write``): :func:`write_results`; returns
    generalisation.md."""
    write_results(result, config, stage)
    return (stage / "generalisation.md").read_text()
