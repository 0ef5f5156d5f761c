"""What a calibration run writes about itself: report.md's sections, the figure, the run record (calibration.json).

Every recording gets its report, whether a calibration is recommended or not: the grouping used (and the one the
data suggest where they differ), the rolls, the site (each sound fit's mean dip and |B|, checked against the site
when it is given), the scores, and the recommendation or why there is none.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def figure(rec, models: dict, path: Path) -> None:
    """Per shot: pointing direction raw vs calibrated, dip and |B| per method (sound fits solid, degenerate dashed)."""
    from matplotlib.figure import Figure  # not pyplot: no backend machinery, half the import time

    from icgo.models.cal_pointing import pointing_directions
    from icgo.physics.qc import measured_dip_deg
    from icgo.studies.calibration.study import model_sanity

    G, B = rec.G, rec.B
    fig = Figure(figsize=(16, 4.5))
    ax = fig.subplots(1, 3)

    def direction(Gc, Bc):
        d = pointing_directions(Gc, Bc)
        return np.mod(np.degrees(np.arctan2(d[:, 1], d[:, 0])), 360.0), np.degrees(np.arcsin(np.clip(-d[:, 2], -1, 1)))

    az, inc = direction(G, B)
    ax[0].plot(az, inc, "kx", label="raw")
    shots = np.arange(len(G))
    for i, (m, c) in enumerate(models.items()):
        Gc, Bc = c.corrected(G, B)
        if not (np.all(np.isfinite(Gc)) and np.all(np.isfinite(Bc))):
            continue  # a fit that does not map every shot: nothing to draw (calibration.csv says why)
        ls = "--" if model_sanity(c, G, B).degenerate else "-"
        a, n = direction(Gc, Bc)
        ax[0].plot(a, n, "o", ms=3, color=f"C{i}", label=m)
        ax[1].plot(shots, measured_dip_deg(Gc, Bc), ls, marker=".", color=f"C{i}", label=m)
        bn = np.linalg.norm(Bc, axis=1)
        ax[2].plot(shots, bn / bn.mean(), ls, marker=".", color=f"C{i}", label=m)
    ax[0].set(xlabel="azimuth of the pointing axis (deg, magnetic)", ylabel="inclination (deg)",
              title="per-shot direction, raw and calibrated")
    ax[1].set(xlabel="shot", ylabel="dip (deg)", title="dip per shot (one field: flat)")
    ax[2].set(xlabel="shot", ylabel="|B| / mean", title="|B| per shot (one field: flat)")
    for a in ax:
        if a.get_legend_handles_labels()[0]:
            a.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def grouping_lines(name: str, rec) -> list[str]:
    """How the recording was grouped: the grouping used, where it came from, and what the data say against it."""
    g = rec.meta.get("grouping")
    if not g:
        return []
    origin = {"layout": "its instrument's layout", "data": "the rolls found in the data", "column": "its group column",
              "ranges": "the shot ranges given (groups=)"}.get(g["origin"], g["origin"])
    lines = [f"- grouping used for `{name}`: {g['used']}, by {origin}"
             + (f" ({g['layout']})" if g.get("layout") and g["origin"] == "layout" else "")]
    if g.get("data_suggest"):
        lines.append(f"- the data suggest: {g['data_suggest']} (not used: "
                     + ("groups=auto uses them)" if g["origin"] == "layout" else "the grouping above was given)"))
    for d in g.get("disagreements", []):
        lines.append(f"- the data disagree with the layout: {d}")
    if g.get("layout_grouping"):
        lines.append(f"- the layout's grouping, not used (groups=auto): {g['layout_grouping']}")
    return lines


def rolls_section(name: str, rec, model) -> list[str]:
    """The report's lines on one recording's groups: the grouping, every roll (shots, pointing direction, roll
    span, how far its shots leave the roll plane, the criteria it fails) and the reader's notices. ``model``: the
    calibration the directions are shown after, or None (the raw directions are then left out)."""
    from icgo.io.grouping import roll_table
    from icgo.studies.calibration.study import roll_directions

    t = roll_table(rec.frame)
    if model is not None:
        t = t.merge(roll_directions(model, rec.G, rec.B, rec.frame["group"].to_numpy()), on="group",
                    suffixes=("_raw", ""))
    t = t.rename(columns={"inclination_deg_raw": "raw inclination (deg)", "azimuth_deg": "azimuth (deg, magnetic)",
                          "inclination_deg": "inclination (deg)" if model is not None else "raw inclination (deg)",
                          "roll_span_deg": "roll span (deg)", "plane_g": "off plane G (g)",
                          "plane_b": "off plane B (|B|)", "axis_to_z_deg": "axis to tool z (deg)",
                          "spread_deg": "spread (deg)"})
    n_single = int((rec.frame.groupby("group").size() < 2).sum())
    lines = [(f"- `{name}`: {len(rec.frame)} shots, {len(t)} roll(s) and {n_single} single shot(s); "
              f"{rec.meta.get('description', '')}")]
    lines += grouping_lines(name, rec)
    lines += [f"  - notice: {n}" for n in rec.notices]
    after = (f"direction and spread after the recommended calibration, `{model.method}`" if model is not None
             else "no calibration recommended: raw geometry only")
    lines += ["", f"Rolls of `{name}` ({after}):", "", t.to_markdown(index=False, floatfmt=".4g"), ""]
    return lines


def site_section(df, name: str, site) -> list[str]:
    """Each sound in-sample fit's mean dip and |B| with their spreads; with the site, how far each is from it."""
    from icgo.models.cal_site import SITE_DIP_TOL_DEG, SITE_FIELD_TOL_PCT
    from icgo.studies.calibration.study import METHODS, outer_rows

    g = outer_rows(df)
    g = g[(g["recording"] == name) & (g["split"] == "in-sample") & ~g["degenerate"].astype(bool)
          & g["method"].isin(METHODS)]
    lines = ["", f"Site of `{name}`: what each sound in-sample fit says about the field it was calibrated in "
                 "(mean over the shots +/- their standard deviation; |B| in the sensor's own scale, "
                 "`icgo.models.cal_site`). "
             + (f"The site given: dip {site.dip_deg:.2f} deg, |B| {site.field_nT:.0f} nT ({site.origin}); a fit "
                f"more than {SITE_DIP_TOL_DEG:g} deg or {SITE_FIELD_TOL_PCT:g} % off is inconsistent with it "
                "(inconsistent axes or mounting) and never recommended."
                if site is not None else "No site given (site.lat= site.lon= site.date=, or site.dip= "
                                         "site.field=): nothing to check them against."), ""]
    if not len(g):
        return lines + ["(no sound fit)", ""]
    rows = []
    for r in g.itertuples():
        row = {"method": r.method, "dip (deg)": f"{r.dip_deg:.2f} +/- {r.dip_std_deg:.2f}",
               "|B| (nT)": f"{r.field_nT:.0f} +/- {r.field_std_nT:.0f}"}
        if site is not None:
            row.update({"dip - site (deg)": f"{r.site_dip_off_deg:+.2f}",
                        "|B| - site (%)": f"{r.site_field_off_pct:+.1f}",
                        "check": "INCONSISTENT: " + r.site_reason if r.site_flag else "consistent"})
        rows.append(row)
    import pandas as pd

    return lines + [pd.DataFrame(rows).to_markdown(index=False), ""]


def settings(config) -> str:
    """The stamp line of the calibration tables (:func:`icgo.reporting.protocol.settings_line`): each fit's budget
    (the converging least squares, the joint fit's and the residual RELM's LM steps and strength grids, MISMA's
    population x iterations x runs)."""
    from icgo.models import joint, mag_relm
    from icgo.reporting.protocol import settings_line

    return settings_line(
        f"twelve and twelve+axis: converging Levenberg-Marquardt; joint: {joint.N_STEPS} LM steps x "
        f"{len(joint.LAMBDAS)} strengths; twelve+axis+relm: {mag_relm.N_STEPS} LM steps x {len(mag_relm.LAMBDAS)} "
        f"ridges; misma+axis: population {config.misma_pop} x {config.misma_iter} iterations",
        f"one fit per recording, split and method ({config.misma_repeats} MISMA runs per fit, the lowest fitness kept)",
        "float64 fits",
        "No published protocol: the calibrate door is this project's (the MISMA paper calibrates online while "
        "drilling, not from static shots).")


def protocol(df, config, seed: int) -> str:
    """The protocol line of ``data=bundled``'s table (:func:`icgo.reporting.protocol.protocol_line`), from
    :func:`icgo.studies.calibration.study.evaluate`'s long table ``df``, the run's ``config`` and its key's seed."""
    from icgo.core.settings import config_overrides
    from icgo.reporting.protocol import protocol_line
    from icgo.studies.calibration.study import outer_rows

    extra = config_overrides(config)
    command = ("`make calibration` (`python -m experiments.calibrate data=bundled`)" if not extra else
               f"`python -m experiments.calibrate data=bundled {' '.join(extra)}`")
    outer = outer_rows(df)
    recordings = outer["recording"].unique()
    held = outer.loc[outer["split"] != "in-sample", ["recording", "split"]].drop_duplicates()
    per_rec = held.groupby("recording").size().reindex(recordings, fill_value=0)
    lo, hi = int(per_rec.min()), int(per_rec.max())
    return protocol_line(
        command,
        f"one fit per recording, split and method (a score cell pools no repeats); `misma+axis` keeps the lowest "
        f"fitness of {config.misma_repeats} MISMA runs (population {config.misma_pop}, {config.misma_iter} "
        f"iterations) per fit; a recommendation's accuracy pools its recording's {lo if lo == hi else f'{lo}-{hi}'} "
        f"held-out split(s), each scored on the method chosen inside it; the per-method means pool the sound fits "
        f"of all {len(recordings)} recordings ({len(recordings)} in-sample and {len(held)} held-out fits per "
        "method), unpaired (each method's degenerate fits are left out)",
        "in-sample: fitted and scored on every shot of a recording; held out (`icgo.studies.calibration.study.splits`): "
        "each rolled group left out of the fit in turn and scored alone (a recording with one roll: its "
        "interleaved halves), the single shots always fitted; the joint fit's strength is chosen by "
        "leave-one-roll-out and the RELM's ridge by leave-one-group-out inside each split's training shots; the "
        "recommendation's rule chooses on the held-out splits and its accuracy is nested (the rule applied inside "
        "each held-out split's training shots, its choice scored on the held-out shots: "
        "`icgo.studies.calibration.select`)",
        f"no data seed (the {len(recordings)} bundled recordings, real shots); PRNGKey({seed}) split once per "
        f"recording and split in table order, used only by MISMA (its {config.misma_repeats} runs split that key); "
        "every other fit and the peer are deterministic. No device is kept back, and these devices were used "
        "before: the joint fit's staging and penalty scales were chosen on their held-out means and the step "
        "counts checked on them; the sanity limits were written after they were first scored (docs/calibrate.md, "
        "docs/reporting.md). The recommendation rule and the joint fit's leave-one-roll-out were fixed before "
        "they were scored, and measured on perturbed copies (docs/calibrate.md)",
        "none: no p-value here; a recommendation's \"clear winner\" is a rule of thumb (its margin over the "
        "runner-up exceeds the standard error of their paired difference), not a significance test. The paired "
        "Wilcoxon of `twelve+axis+relm` against the other methods over the held-out splits, Holm over those tests, "
        "is in docs/calibrate.md (from calibration_devices.csv)")


def report(df, summ, recordings: dict, label: str, recs: dict, models: dict, sites: dict,
           protocol_line: str | None = None, settings_line: str | None = None) -> str:
    """The Markdown report: the recommendation (or why there is none), the grouping and rolls, the site, the scores
    (degenerate marked), the per-method summary; ``protocol_line`` and the stamp ``settings_line`` under the title
    when given.

    Args:
        models: recording name -> the recommended calibration, or None. sites: name -> Site or None.
    """
    from icgo.models.cal_sanity import limits_sentence
    from icgo.physics.rolls import AXIS_TO_Z_DEG, MIN_SPAN_DEG, PLANE_TOL_B, PLANE_TOL_G
    from icgo.studies.calibration.study import wide

    header = [line for line in (protocol_line, settings_line) if line]
    lines = [f"# Magnetometer calibration: {label}", ""] + (header + [""] if header else [])
    lines += ["## Recommendation", ""]
    lines += [f"- `{name}`: {r['sentence']}" for name, r in recs.items()]
    if any(r["method"] for r in recs.values()):
        lines += ["", "`python -m experiments.apply model=<this run directory> data=<survey.csv>` applies it"
                  + (" (the run holds several recordings: name one model file instead)" if len(recs) > 1 else "")
                  + "."]
    lines += ["", "## Shots and rolls", "",
              (f"A roll: consecutive shots whose raw gravity and field each stay within {PLANE_TOL_G:g} g and "
               f"{PLANE_TOL_B:g} |B| of one plane (the pointing axis' components constant), turning about one axis "
               f"within {AXIS_TO_Z_DEG:g} deg of tool z shared by all rolls, over at least {MIN_SPAN_DEG:g} deg "
               "(`icgo.physics.rolls`, docs/calibrate.md)."), ""]
    for name, rec in recordings.items():
        lines += rolls_section(name, rec, models.get(name))
    lines += ["## Site", ""]
    for name in recordings:
        lines += site_section(df, name, sites.get(name))
    lines += ["## Scores", "",
              "Score: the peer's metric (circuitpython-mag-cal `accuracy`, deg: spread of the pointing direction "
              "within each rolled group). In-sample: fitted and scored on every shot; held-out group g: fitted "
              "without group g, scored on it. " + limits_sentence(), "",
              wide(df).to_markdown(index=False), "",
              "## Per method (means over the sound fits; maxima over all fits)", "",
              summ.to_markdown(floatfmt=".3f"), ""]
    return "\n".join(lines) + "\n"


def record(data: str, config, recordings: dict, recs: dict, sites: dict, seconds: float) -> dict:
    """The run's machine-readable record (``calibration.json``): settings, recordings, their grouping and rolls, the
    site, and the recommendation (``recommendation`` for a one-recording run, ``recommendations`` per recording;
    a recording with nothing to recommend has ``model`` and ``method`` null and ``refused`` saying why).
    ``data``: the ``data=`` setting as given."""
    from icgo.core.settings import config_to_mapping
    from icgo.io.grouping import roll_table

    out = {"kind": "calibration_run", "data": data, "config": config_to_mapping(config),
           "recordings": {name: {"shots": int(len(rec.frame)), "description": rec.meta.get("description", ""),
                                 "grouping": rec.meta.get("grouping"),
                                 "rolls": roll_table(rec.frame).to_dict(orient="records"),
                                 "site": None if sites.get(name) is None else sites[name]._asdict(),
                                 "notices": list(rec.notices)} for name, rec in recordings.items()},
           "recommendations": {n: {k: v for k, v in r.items() if k != "sentence"} for n, r in recs.items()},
           "wall_time_s": seconds}
    if len(recs) == 1:
        one = next(iter(out["recommendations"].values()))
        out["recommendation"] = one if one["model"] else None
        if not one["model"]:
            out["refused"] = one["refused"]
    return out


def report_refused(recordings: dict, label: str, recs: dict, chosen: dict, sites: dict) -> str:
    """The report of a run where nothing could be fitted: the recommendation's refusal, the grouping and rolls."""
    lines = [f"# Magnetometer calibration: {label}", "", "## Recommendation", ""]
    lines += [f"- `{name}`: {r['sentence']}" for name, r in recs.items()]
    lines += ["", "## Shots and rolls", ""]
    for name, rec in recordings.items():
        lines += rolls_section(name, rec, None)
    return "\n".join(lines) + "\n"
