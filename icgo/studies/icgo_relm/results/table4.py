"""Table 4 and Fig. 15 of the ICGO paper: raw and compensated azimuth error under six well conditions."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from icgo.datasets.casing_stations import noise_floor
from icgo.reporting import stamp
from icgo.studies.icgo_relm.results.outputs import LABEL, PAPER, commands
from icgo.reporting.plots import plt_agg
from icgo.reporting.run_collection import Runs
from icgo.reporting.table_writer import have, write_table
from icgo.studies.icgo_relm.results.notes import STRATEGIES5


def _condition_of(p: pd.DataFrame) -> pd.Series:
    """Table 4 row (0-5) of each prediction row, from its (inclination, azimuth) pair or 'condition' column."""
    if "inclination_true" in p.columns:
        inc = p["inclination_true"].to_numpy()
    else:
        inc = np.full(len(p), np.nan)
    az = p["azimuth_true"].to_numpy()
    cond = np.full(len(p), -1)
    for k, row in enumerate(PAPER["table4"]):
        hit = np.isclose(az, row[1], atol=1e-6) & (np.isnan(inc) | np.isclose(inc, row[0], atol=1e-6))
        cond[hit] = k
    return pd.Series(cond, index=p.index)


def _table4_high_inclination(t: pd.DataFrame) -> str:
    """Why the compensated error at I >= 60 deg stays above this table's noise floor (measured in docs/experiments.md,
    "Table 4": the same study on the four I >= 60 deg conditions alone)."""
    hi, lo = t[t["inclination (deg)"] >= 60], t[t["inclination (deg)"] < 60]
    if hi.empty or lo.empty:
        return ""
    r = hi["compensated mean ours"] / hi["noise floor MAE"]
    c_hi, c_lo = hi["compensated mean ours"], lo["compensated mean ours"]
    return (f"At I >= 60 deg the compensated mean stays {r.min():.1f}-{r.max():.1f} times its noise floor (the paper's "
            "is lower still). One model is fitted to all six conditions, and the near-vertical ones, whose compensated "
            f"means are {c_lo.min() / c_hi.max():.1f}-{c_lo.max() / c_hi.min():.1f} times those at I >= 60 deg, weigh "
            "most in the training RMSE the search minimises and in the ridge fit. Fitted on the four I >= 60 deg "
            "conditions alone, those rows come to their noise floor (a development measurement with its script, "
            "docs/experiments.md, \"Table 4\"; untested). The table keeps the joint fit, chosen before any result "
            "(MSA needs more than one attitude: \"Choices\" in docs/experiments.md); splitting the conditions after "
            "seeing these rows would be choosing on test data.")


def table4(runs: Runs, out: Path) -> bool:
    """Table 4 and Fig. 15: six well conditions, raw vs ICGO-RELM error (|error| mean and std, test rows)."""
    p = runs.predictions(dataset="well_conditions")
    if not have(p, ["cgo-three_stage"]):
        return False
    p = p[(p.repeat == 0) & (p.split == "test")].copy()
    if (p["condition"] >= 0).any():
        p["cond"] = p["condition"]
    else:
        p["cond"] = _condition_of(p)
    p = p[p.cond >= 0]
    raw_err = lambda d: np.abs(((d["azimuth_raw"] - d["azimuth_true"] + 180) % 360) - 180)  # noqa: E731

    floor = noise_floor("well_conditions", 0).set_index("condition")
    rows = []
    for k, (inc, az, rm, rs, cm, cs) in enumerate(PAPER["table4"]):
        d = p[(p.cond == k) & (p.method == "cgo-three_stage")]
        if d.empty:
            continue
        e_raw, e_comp = raw_err(d), np.abs(d["error_compensated"])
        rows.append({"inclination (deg)": inc, "azimuth (deg)": az, "n test rows": len(d),
                     "raw mean ours": round(e_raw.mean(), 4), "raw std ours": round(e_raw.std(ddof=1), 4),
                     "raw mean paper": rm, "raw std paper": rs,
                     "compensated mean ours": round(e_comp.mean(), 4),
                     "compensated std ours": round(e_comp.std(ddof=1), 4),
                     "compensated mean paper": cm, "compensated std paper": cs,
                     "noise floor MAE": round(float(floor.loc[k, "mae"]), 4)})
    if not rows:
        return False
    notes = ["Ours: simulated `well_conditions`, one study over all six conditions (7:3 split of all rows, repeat 0, "
             "three-stage ICGO-RELM); statistics of |azimuth error| on the test rows of each condition. The paper "
             "does not say whether its means are of signed or absolute errors; its compensated means are all "
             "positive, so we read them as absolute.",
             "**The raw columns are calibration targets, not a result.** The simulator's casing geometry and lab "
             "field were set so that the raw error of each condition lands near the paper's raw column "
             "(`icgo.datasets.casing_stations.TABLE4_ORIGINAL` holds the paper's values; `tests/test_datasets.py` "
             "requires |simulated - paper| < 6 deg per condition; docs/datasets.md). Agreement there is by construction; only "
             "the compensated columns measure the method.",
             "Noise floor MAE: the same draw (seed 0) with the casing, every systematic effect and the spikes removed "
             "(all rows of the condition): the simulated sensor noise alone. Near vertical (I = 0.594, 1.8 deg) the "
             "azimuth is ill-conditioned (error ~ sigma_G / sin I) and the floor is far above the paper's "
             "compensated means, so those rows measure the assumed accelerometer noise more than the method.",
             _table4_high_inclination(pd.DataFrame(rows))]
    write_table(pd.DataFrame(rows), out, "table4", "Table 4: raw and compensated azimuth error per well condition (deg)",
           notes, stamp.protocol(commands("table4"), "none: one split; per-condition mean and std of |error| "
                                  "(no method is compared with another here; Fig. 15 shows the five strategies)",
                                  repeats="1 (one split)"))
    # Fig. 15: five methods per condition
    methods = [f"cgo-{s}" for s in STRATEGIES5 if f"cgo-{s}" in set(p.method)]
    f15 = []
    for k in range(6):
        for mth in methods:
            d = p[(p.cond == k) & (p.method == mth)]
            if len(d):
                e = d["error_compensated"].to_numpy()
                f15.append({"condition": k, "method": mth, "mae": np.abs(e).mean(), "rmse": np.sqrt((e * e).mean())})
    f15 = pd.DataFrame(f15)
    f15.to_csv(out / "fig15.csv", index=False)
    plt = plt_agg()
    fig, axes = plt.subplots(2, 3, figsize=(13, 6.5))
    for k, ax in enumerate(axes.ravel()):
        for mth in methods:
            d = p[(p.cond == k) & (p.method == mth)].sort_values("station")
            if len(d):
                s = mth[4:]
                mae = f15[(f15.condition == k) & (f15.method == mth)]["mae"].iloc[0]
                ax.plot(np.arange(len(d)), d["error_compensated"], lw=0.9, label=f"{LABEL[s]} (MAE {mae:.3f})")
        inc, az = PAPER["table4"][k][:2]
        ax.set_title(f"I = {inc} deg, A = {az} deg", fontsize=9)
        ax.legend(fontsize=6)
    fig.supxlabel("test sample (sorted by station)")
    fig.supylabel("compensated azimuth error (deg)")
    stamp.save(fig, out / "fig15.png", "Fig. 15: five 4th-seed strategies under six well conditions")
    return True
