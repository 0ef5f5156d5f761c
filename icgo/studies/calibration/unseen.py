"""The calibrate door on devices it has never seen (``python -m experiments.calibration_unseen``).

:func:`run_variants` makes :data:`icgo.datasets.mag_cal_variants.N_VARIANTS` perturbed copies of each bundled device,
writes each as a circuitpython-mag-cal raw-layout JSON and takes it through what ``experiments.calibrate`` does with
its defaults; :func:`report` builds the goals table and ``calibration_unseen.md`` (the goals on the variants beside the
same goals on the 9 bundled devices); :func:`write_results` writes ``calibration_unseen.md`` and ``.csv``.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

#: Seed of the variants (one generator per device and variant) and of the fits' PRNG key.
SEED = 0


def run_variants(peer: bool = False, devices=None, n: int | None = None):
    """(fits table, {variant name: Variant}, {variant name: recording as read}, wall seconds) of the door on the
    variants."""
    import jax

    import icgo  # noqa: F401  (float64)
    from icgo.datasets import mag_cal_variants as mv
    from icgo.studies.calibration import study as calibration
    from icgo.studies.common.shots import read_shots

    t0 = time.perf_counter()
    vs = mv.variants(devices, mv.N_VARIANTS if n is None else n, SEED)
    recs = {}
    with tempfile.TemporaryDirectory() as d:
        for v in vs:
            path = mv.write_raw(v, Path(d) / f"{v.name}.json")
            recs[v.name] = read_shots(path, mag_axes=v.mag_axes, grav_axes=v.grav_axes)
    config = calibration.CalibrationConfig(peer=peer)
    df, _ = calibration.evaluate(recs, config, jax.random.PRNGKey(SEED), check=False)
    return df, {v.name: v for v in vs}, recs, time.perf_counter() - t0


def _fmt(x, d=3):
    return "-" if x is None else f"{x:.{d}f}"


def summary_lines(title: str, s: dict) -> list[str]:
    """A goals summary (:func:`icgo.studies.calibration.goals.goals`) as Markdown bullets."""
    from icgo.studies.calibration.goals import GOAL_EXCESS_DEG, GOAL_MEAN_DEG

    fits = ", ".join(f"{m} {a} of {b}" for m, (a, b) in s["degenerate_fits"].items())
    rec = ", ".join(f"{m} {k}" for m, k in sorted(s["recommended"].items(), key=lambda kv: -kv[1]))
    return [f"### {title}", "",
            f"- recordings: {s['recordings']}; recommended: {rec}",
            f"- nested accuracy of the recommendation, mean: **{_fmt(s['nested_mean_deg'])} deg** (goal <= "
            f"{GOAL_MEAN_DEG:.2f}: {'met' if s['meets_mean'] else 'missed'}); twelve+axis held out, mean: "
            f"{_fmt(s['baseline_held_out_mean_deg'])} deg",
            f"- largest excess of the nested accuracy over twelve+axis held out on one recording: "
            f"**{_fmt(s['max_excess_deg'])} deg** (goal <= {GOAL_EXCESS_DEG:.2f}: "
            f"{'met' if s['meets_excess'] else 'missed'}; {s['over_excess']} recording(s) over it)",
            f"- degenerate recommendations: {s['degenerate_recommendations']}; recordings with no recommendation: "
            f"{s['no_recommendation']}",
            f"- joint fit: in-sample {_fmt(s['joint_in_sample_deg'])} / held out {_fmt(s['joint_held_out_deg'])} deg",
            f"- degenerate fits (in-sample and held out): {fits}", ""]


def report(df, vs: dict, recs: dict, seconds: float, peer: bool, bundled: Path | None):
    """(goals table, lines of calibration_unseen.md) of :func:`run_variants`' output.

    Args:
        df, vs, recs, seconds: :func:`run_variants`' fits table, variants, recordings and wall seconds.
        peer: whether circuitpython-mag-cal ran beside (named in the command and the stamp, which is the calibrate
            door's: :func:`icgo.studies.calibration.report.settings`). bundled: ``results/calibration_devices.csv``
            (its goals in a section of their own when the file exists).
    """
    import pandas as pd

    from icgo.reporting.protocol import protocol_line
    from icgo.studies.calibration.study import CalibrationConfig
    from icgo.studies.calibration.goals import goals, goals_table
    from icgo.studies.calibration.report import settings

    t = goals_table(df)
    t.insert(1, "device", [vs[n].device for n in t["recording"]])
    t.insert(2, "grouping", [recs[n].meta["grouping"]["origin"] for n in t["recording"]])
    lines = ["# The calibrate door on unseen devices (perturbed copies of the bundled ones)", "",
             protocol_line(
                 "`python -m experiments.calibration_unseen`" + (" --peer" if peer else ""),
                 f"one run of the door per variant ({len(t)} variants: {len(set(t['device']))} devices x "
                 f"{len(t) // max(1, len(set(t['device'])))}); a nested accuracy pools its variant's held-out splits, "
                 "each scored on the method chosen inside it; the means pool the variants, unpaired",
                 "as `experiments.calibrate`: in-sample, each roll held out, and inside each held-out split its "
                 "training shots split again for the nested choice",
                 f"variants from numpy generators seeded ({SEED}, variant, crc32(device)) "
                 "(`icgo.datasets.mag_cal_variants`); PRNGKey(" f"{SEED}) for MISMA; nothing in the door was chosen "
                 "on these variants; the perturbation sizes were revised once, after the first variant scored had "
                 "every fit degenerate and before any other was scored (docs/calibrate.md, Unseen devices)",
                 "none: no p-value; the goals are thresholds on means (docs/calibrate.md)"),
             settings(CalibrationConfig(peer=peer)), "",
             "## Goals", ""]
    lines += summary_lines("Unseen devices (these variants)", goals(t))
    if bundled is not None and Path(bundled).is_file():
        b = pd.read_csv(bundled, keep_default_na=True)
        if "outer" in b.columns:
            b["outer"] = b["outer"].fillna("")
            b["site_flag"] = b.get("site_flag", False)
            b["site_reason"] = b.get("site_reason", "")
            lines += summary_lines("The 9 bundled devices (results/calibration_devices.csv; the devices the door's "
                                   "earlier choices were made on: not a test)", goals(goals_table(b)))
    cols = ["recording", "device", "grouping", "recommended", "nested_deg", "chosen_mean_deg", "nested - baseline",
            "twelve+axis held-out", "misma+axis held-out", "joint in-sample", "joint held-out", "joint degenerate",
            "twelve+axis+relm held-out"]
    lines += ["## Per variant (deg)", "", t[cols].to_markdown(index=False, floatfmt=".3f"), "",
              f"Wall time {seconds:.0f} s (a shared 2-core machine)."]
    return t, lines


def write_results(t, lines: list[str], stage: Path) -> None:
    """calibration_unseen.md (``lines``) and calibration_unseen.csv (the goals table ``t``) into ``stage``."""
    (stage / "calibration_unseen.md").write_text("\n".join(lines) + "\n")
    t.to_csv(stage / "calibration_unseen.csv", index=False, float_format="%.6g")
