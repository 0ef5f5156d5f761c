"""The calibrate door's goals, measured on a table of :func:`icgo.studies.calibration.study.evaluate` fits.

Per recording (:func:`recording_row`): the calibration the door recommends and its nested accuracy
(:func:`icgo.studies.calibration.select.recommend`), ``twelve+axis``'s mean held-out score (the baseline), their
difference, each method's in-sample and held-out means and degenerate fits, whether the recommended method has
a degenerate fit anywhere. :func:`goals` sums them up against the goals of docs/calibrate.md: the nested
accuracy of the recommendation at most 0.60 deg on average and never more than 0.05 deg worse than
``twelve+axis`` on any recording, no degenerate recommendation.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from icgo.studies.calibration.study import METHODS, outer_rows
from icgo.studies.calibration.select import BASELINE, recommend

#: The goals (docs/calibrate.md, "Goals"): mean nested accuracy, deg; largest excess over the baseline, deg.
GOAL_MEAN_DEG = 0.60
GOAL_EXCESS_DEG = 0.05


def recording_row(df: pd.DataFrame, name: str) -> dict:
    """One recording's line of the goals table (module doc)."""
    r = recommend(df, name)
    g = outer_rows(df)
    g = g[g["recording"] == name]
    held, ins = g[g["split"] != "in-sample"], g[g["split"] == "in-sample"]
    row = {"recording": name, "recommended": r["method"] or "none", "nested_deg": r["accuracy_deg"],
           "chosen_mean_deg": r["held_out_deg"],
           "recommended_degenerate": bool(r["method"] and g.loc[g["method"] == r["method"], "degenerate"].any())}
    for m in METHODS[1:]:
        row[f"{m} in-sample"] = float(ins.loc[ins["method"] == m, "score_deg"].mean())
        row[f"{m} held-out"] = float(held.loc[held["method"] == m, "score_deg"].mean())
        row[f"{m} degenerate"] = int(g.loc[g["method"] == m, "degenerate"].astype(bool).sum())
        row[f"{m} fits"] = int((g["method"] == m).sum())
    base = row[f"{BASELINE} held-out"]
    row["nested - baseline"] = (None if r["accuracy_deg"] is None or not np.isfinite(base)
                                else r["accuracy_deg"] - base)
    return row


def goals_table(df: pd.DataFrame) -> pd.DataFrame:
    """:func:`recording_row` of every recording of ``df``."""
    return pd.DataFrame([recording_row(df, n) for n in pd.unique(df["recording"])])


def goals(t: pd.DataFrame) -> dict:
    """The summary of a :func:`goals_table`: means, the largest excess over the baseline, the counts."""
    nested = t["nested_deg"].dropna().astype(float)
    excess = t["nested - baseline"].dropna().astype(float)
    fits = {m: (int(t[f"{m} degenerate"].sum()), int(t[f"{m} fits"].sum())) for m in METHODS[1:]}
    return {
        "recordings": int(len(t)),
        "nested_mean_deg": float(nested.mean()) if len(nested) else None,
        "baseline_held_out_mean_deg": float(t[f"{BASELINE} held-out"].mean()),
        "max_excess_deg": float(excess.max()) if len(excess) else None,
        "over_excess": int((excess > GOAL_EXCESS_DEG).sum()),
        "degenerate_recommendations": int(t["recommended_degenerate"].sum()),
        "no_recommendation": int((t["recommended"] == "none").sum()),
        "recommended": t["recommended"].value_counts().to_dict(),
        "joint_in_sample_deg": float(t["joint in-sample"].mean()),
        "joint_held_out_deg": float(t["joint held-out"].mean()),
        "degenerate_fits": fits,
        "meets_mean": bool(len(nested) and nested.mean() <= GOAL_MEAN_DEG),
        "meets_excess": bool(len(excess) and excess.max() <= GOAL_EXCESS_DEG),
    }
