"""The optimizer sweeps beside Table 3: three-stage schedules against the single strategies, and the mutation
readings."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from icgo.maths.stats import friedman, wilcoxon_paired
from icgo.optim.cgo import CGOConfig
from icgo.reporting import records as R
from icgo.reporting import stamp
from icgo.reporting.families import holm_once
from icgo.studies.icgo_relm.results.outputs import LABEL, PAPER, commands
from icgo.reporting.plots import plt_agg
from icgo.reporting.protocol import ALPHA
from icgo.studies.icgo_relm.results.repeat_tests import against_reference
from icgo.reporting.run_collection import Runs
from icgo.reporting.table_writer import mean_and_std, n_repeats, plus_minus, skip, write_table
from icgo.studies.icgo_relm.config import StudyConfig
from icgo.studies.icgo_relm.results.notes import STRATEGIES4, floor_note


def _schedule_name(info: dict) -> str:
    """A readable name of a run's three-stage schedule from its run record."""
    sc = info.get("schedule") or {}
    b = "/".join(f"{100 * x:.0f}" for x in sc.get("bounds", []))
    clock = " (wavelet on its stage clock)" if sc.get("clock") == "stage" else ""
    return f"three-stage {'>'.join(sc.get('order', []))} at {b} %{clock}"


def sweep_schedules(pooled: Runs, sched: Runs, out: Path) -> bool:
    """Three-stage under each schedule beside the single strategies (``experiment=sweep_schedules``).

    Every column holds the same 10 repeats (splits and keys of Table 3), so the
    comparison is paired: Friedman over all columns, Wilcoxon of each schedule
    against the best single strategy (Holm), and per-repeat winners.
    """
    m = pooled.metrics()
    singles = [s for s in STRATEGIES4 if s != "three_stage" and f"cgo-{s}" in set(m.method)]
    if not sched.runs or not singles:
        return False
    cols = {LABEL[s]: m[m.method == f"cgo-{s}"].set_index("repeat")["mae"] for s in singles}
    for info in sched.runs:
        t = R.read_table(info["dir"], "metrics")
        t = t[(t.split == "test") & (t.method == "cgo-three_stage")]
        cols[_schedule_name(info)] = t.set_index("repeat")["mae"]
    wide = pd.DataFrame(cols).dropna()
    if len(wide) < 2:
        return skip(f"{len(wide)} paired repeat(s): the Friedman and Wilcoxon tests need at least 2")
    names = list(wide.columns)
    fr = friedman({c: wide[c].to_numpy() for c in names})
    best_single = min((LABEL[s] for s in singles), key=lambda c: wide[c].mean())
    sched_cols = [c for c in names if c.startswith("three-stage")]
    p_holm = against_reference(wide, sched_cols, best_single)
    winners = wide.idxmin(axis=1).value_counts()
    rows = [{"column": c, "MAE (deg)": plus_minus(*mean_and_std(wide[c])), "mean rank": round(fr.mean_ranks[c], 2),
             "repeats best": int(winners.get(c, 0)),
             f"median difference vs {best_single} (deg)": round(float((wide[c] - wide[best_single]).median()), 4)
             if c in p_holm else np.nan,
             f"p vs {best_single} (Holm)": round(float(p_holm[c]), 4) if c in p_holm else np.nan}
            for c in sorted(names, key=lambda c: wide[c].mean())]
    df = pd.DataFrame(rows)
    first = df.iloc[0]["column"]
    worse = [c for c in sched_cols if p_holm[c] < ALPHA and (wide[c] - wide[best_single]).median() > 0]
    notes = [f"{len(wide)} paired repeats (same splits and keys in every column; the single strategies are Table 3's).",
             f"Friedman over all {len(names)} columns: chi2 = {fr.statistic:.2f}, p = {fr.p_value:.3g} (a family of "
             f"one test). First by mean MAE: {first} (best in {int(winners.get(first, 0))} of {len(wide)} repeats). "
             f"Wilcoxon of each schedule against the best single strategy ({best_single}), Holm over the "
             f"{len(sched_cols)} schedules, in the table: {len(worse)} of {len(sched_cols)} schedules significantly "
             f"worse than {best_single} (Holm p < {ALPHA:g}).",
             floor_note()]
    write_table(df, out, "sweep_schedules", "Sweep: three-stage schedules vs the single strategies (test MAE)", notes,
           stamp.protocol(commands("sweep_schedules"), f"Friedman over all {len(names)} columns (one test); paired "
                           f"Wilcoxon signed-rank (two-sided) of each schedule against {best_single}, Holm over the "
                           f"{len(sched_cols)} schedules"))
    plt = plt_agg()
    fig, ax = plt.subplots(figsize=(10, 4))
    order = [r["column"] for r in rows]
    ax.boxplot([wide[c] for c in order], orientation="horizontal", tick_labels=order)
    ax.set(xlabel="test MAE (deg), 10 paired repeats")
    ax.tick_params(axis="y", labelsize=7)
    stamp.save(fig, out / "sweep_schedules.png", "Three-stage schedules and single strategies (lab_casing)")
    return True


def _reading(params: dict) -> str:
    """The mutation reading a sweep run used, from its optimizer params (the rest at CGOConfig's defaults)."""
    d = CGOConfig()
    if "sigma" in params:
        low, high = StudyConfig().model.theta_bounds
        return f"Gaussian sigma {params['sigma']:g} ({params['sigma'] / (high - low):g} of the box width)"
    zeta = params.get("wavelet_zeta", d.wavelet_zeta)
    return f"wavelet zeta {zeta:g}, amplitude {params.get('wavelet_amplitude', d.wavelet_amplitude)}"


def sweep_mutations(pooled: Runs, sweep: Runs, out: Path) -> bool:
    """Mutation readings (``experiment=sweep_wavelet``, ``sweep_sigma``, ``sweep_paper_literal``): each reading's single strategy and three-stage, and the ranking.

    Each run holds one reading's single strategy (wavelet or Gaussian) and
    three-stage on Table 3's splits and keys; the other strategies keep their
    default readings (Table 3). Per reading: both MAEs, the paired Wilcoxon
    of three-stage vs the single strategy (Holm over the readings), and the
    order of the four strategies by mean MAE against the paper's.
    """
    m = pooled.metrics()
    base = {s: m[m.method == f"cgo-{s}"].set_index("repeat")["mae"] for s in STRATEGIES4 if f"cgo-{s}" in set(m.method)}
    if not sweep.runs or len(base) < len(STRATEGIES4):
        return False
    if n_repeats(m) < 2:
        return skip("one repeat: the paired Wilcoxon tests of the mutation readings need at least 2 repeats")
    paper = sorted(STRATEGIES4, key=lambda s: PAPER["table3"][s][0][0])
    rows = []
    for info in sweep.runs:
        t = R.read_table(info["dir"], "metrics")
        t = t[t.split == "test"]
        strategies = info.get("strategies", [])
        whole = set(STRATEGIES4) <= set(strategies)  # the sweep_paper_literal preset: every strategy from this run
        single = "wavelet" if whole else next(s for s in strategies if s != "three_stage")
        own = STRATEGIES4 if whole else (single, "three_stage")
        mae = {**base, **{s: t[t.method == f"cgo-{s}"].set_index("repeat")["mae"] for s in own}}
        order = sorted(STRATEGIES4, key=lambda s: mae[s].mean())
        w = pd.DataFrame({"three": mae["three_stage"], "single": mae[single]}).dropna()
        params = info.get("optimizer_params") or {}
        reading = _reading(params)
        if whole:
            no_sigma = {k: v for k, v in params.items() if k != "sigma"}
            reading = (f"the paper's literal readings (experiment=sweep_paper_literal): {_reading(no_sigma)}, "
                       f"{_reading({'sigma': params.get('sigma', CGOConfig().sigma)})}")
        rows.append({"reading": reading,
                     "single strategy alone (deg)": plus_minus(*mean_and_std(mae[single])), "three-stage (deg)": plus_minus(*mean_and_std(mae["three_stage"])),
                     "median difference three-stage - single (deg)":
                         round(float((w["three"] - w["single"]).median()), 4),
                     "p three-stage vs single": wilcoxon_paired(w["three"], w["single"]).p_value,
                     "order by mean MAE (untested)": " < ".join(LABEL[s] for s in order),
                     "paper's order by mean": order == paper,
                     "_pair": tuple(w[["three", "single"]].to_numpy().ravel())})
    df = pd.DataFrame(rows)
    # readings whose two columns are the same numbers (the three `amplitude none` rows and the paper's literal
    # reading: without the amplitude the dilation has no effect) are one test: Holm counts it once
    distinct = list(dict.fromkeys(df["_pair"]))
    df["p Holm"] = holm_once(df["p three-stage vs single"], df["_pair"])
    same = [g["reading"].tolist() for _, g in df.groupby("_pair", sort=False) if len(g) > 1]
    df = df.drop(columns="_pair").sort_values("reading").reset_index(drop=True)
    hits = df[df["paper's order by mean"]]["reading"].tolist()
    notes = ["`sweep_wavelet` (6 jobs) and `sweep_sigma` (3 jobs) use Table 3's runs for the strategies a reading "
             f"does not touch (their defaults: {_reading({})}, Gaussian sigma {CGOConfig().sigma:g}). "
             "`sweep_paper_literal` (1 job) runs all four strategies under the paper's literal readings (eq. 18's "
             "wavelet without Ling's amplitude factor, N(0, 1), thirds on the global clock); its row takes every "
             "column from that run (and the three `amplitude none` rows equal it: without the amplitude the "
             "dilation has no effect).",
             f"The paper's order: {' < '.join(LABEL[s] for s in paper)}. Readings that reproduce it by mean: "
             f"{', '.join(hits) if hits else 'none'}. The orders are of the means; adjacent places are not tested "
             "(only three-stage against the reading's single strategy is), so an order says nothing where two means "
             "are within their spread.",
             f"Holm over the {len(distinct)} distinct tests: the rows with identical columns are one test, counted "
             "once (" + "; ".join(", ".join(g) for g in same) + ")." if same else
             f"Holm over the {len(distinct)} readings.",
             "These are test-row numbers: they report what each reading does and choose nothing. The defaults were "
             "fixed before this sweep from the published readings (the wavelet of Ling et al., whom eq. 18 follows; "
             "sigma 1 as eq. 16 prints N(0, sigma^2) without a value: docs/optimizers.md).", floor_note()]
    write_table(df, out, "sweep_mutations", "Sweep: mutation readings (test MAE)", notes,
           stamp.protocol(commands("sweep_mutations"), f"paired Wilcoxon signed-rank (two-sided) of three-stage "
                           f"against the reading's single strategy, Holm over the {len(distinct)} distinct tests (rows "
                           "with identical columns counted once); the orders by mean are not tested"))
    return True
