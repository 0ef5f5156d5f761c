"""The verdict an engineer acts on: expected accuracy, domain, QC explained, the model to use, the next command.

``run``, ``apply`` and ``calibrate`` each print one block of five lines built here (and write it into
their summary / meta / report), from the numbers of the run they just made:

1. **expected accuracy**: the azimuth error to expect with its interval (the model's split-conformal
   half-width at its nominal level) and the coverage measured where a reference exists;
2. **domain**: in the training domain, at its edge, or far outside it, and what that means for trust
   (:func:`domain_status`; the thresholds are :data:`FAR_TOLERANCE` and the training range's width);
3. **QC**: the survey-QC counts in one line that says why they can sit beside a small error
   (:func:`qc_line`: an azimuth compensation corrects the azimuth, not the field the QC checks);
4. **model**: the model to use and why (a study's selected method, or the calibration recommendation);
5. **next**: the exact command to run next, runnable as printed (:func:`icgo.core.commands.door_command`).

``apply`` exits with :data:`EXIT_OUT_OF_DOMAIN` after writing its files when the verdict says the result is
not to be used as it stands (docs/qc.md, "The verdict"): the survey is far outside the training domain (the
correction there is an extrapolation), the corrected field is not one earth field (the model belongs to
another device), or the survey's reference angle looks like radians (its error metrics would be meaningless).
Pure functions over numbers and small dicts; nothing here reads files.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from icgo.artifacts.format import DOMAIN_TOLERANCE, domain_overshoots
from icgo.artifacts.registry import MODEL_KINDS
from icgo.core.commands import door_command
from icgo.reporting.records import RECOMMENDATION_KEYS

#: ``apply``'s exit status when its verdict says not to use the result as it stands (files still written): far
#: outside the model's training domain, a model of another device, a reference in radians.
EXIT_OUT_OF_DOMAIN = 3
#: ``calibrate``'s exit status when it recommends no calibration (report and calibrations still written).
EXIT_NO_RECOMMENDATION = 4
#: An overshoot of the training range beyond the larger of this and the range's own width is "far outside"
#: (units of each quantity): ten times the noise-level tolerance of :data:`icgo.artifacts.format.DOMAIN_TOLERANCE`.
FAR_TOLERANCE = {k: 10.0 * v for k, v in DOMAIN_TOLERANCE.items()}
#: Model kinds whose output corrects the magnetic field itself (their corrected field is what QC checks): the
#: registry's (:data:`icgo.artifacts.registry.MODEL_KINDS`, each kind's ``CORRECTS_FIELD``).
FIELD_CORRECTING_KINDS = tuple(k for k, cls in MODEL_KINDS.items() if cls.CORRECTS_FIELD)


class Verdict(NamedTuple):
    """One verdict block.

    Attributes:
        accuracy, domain, qc, model, next: one line each (see the module docstring).
        status: ``"in domain"``, ``"edge"``, ``"far outside"`` or ``"n/a"``.
        exit_code: 0, or :data:`EXIT_OUT_OF_DOMAIN`.
        numbers: the numbers the lines were built from (JSON).
    """

    accuracy: str
    domain: str
    qc: str
    model: str
    next: str
    status: str = "n/a"
    exit_code: int = 0
    numbers: dict | None = None

    def lines(self) -> list[str]:
        """The block as printed: a heading and the five labelled lines."""
        return ["verdict:", f"  expected accuracy: {self.accuracy}", f"  domain: {self.domain}", f"  QC: {self.qc}",
                f"  model to use: {self.model}", f"  next: {self.next}"]

    def text(self) -> str:
        return "\n".join(self.lines())

    def markdown(self) -> list[str]:
        """The block as Markdown lines (a section for summary.md / report.md)."""
        return ["## Verdict", "", f"- **Expected accuracy**: {self.accuracy}", f"- **Domain**: {self.domain}",
                f"- **QC**: {self.qc}", f"- **Model to use**: {self.model}", f"- **Next**: `{self.next}`"
                if self.next.startswith("python ") else f"- **Next**: {self.next}"]

    def as_dict(self) -> dict:
        return {"accuracy": self.accuracy, "domain": self.domain, "qc": self.qc, "model": self.model,
                "next": self.next, "status": self.status, "exit_code": self.exit_code, "numbers": self.numbers}


def _f(x, d: int = 3) -> str:
    return "n/a" if x is None or not math.isfinite(float(x)) else f"{float(x):.{d}f}"


def _pm(mean, std, d: int = 3) -> str:
    """``mean +/- std``, or the mean alone when the std is undefined (one repeat)."""
    return _f(mean, d) if std is None or not math.isfinite(float(std)) else f"{_f(mean, d)} +/- {_f(std, d)}"


# ------------------------------------------------------------------ domain
def domain_status(trained: dict | None, survey: dict | None) -> tuple[str, list[str], dict]:
    """How far a survey lies from a model's training domain.

    Args:
        trained: the model's ``domain`` (quantity -> [low, high]). survey: the same quantities of the
            survey (:func:`icgo.artifacts.format.sensor_domain`).
    Returns:
        (status, one phrase per quantity outside, {quantity: overshoot}): status ``"in domain"`` (no
        quantity beyond :data:`icgo.artifacts.format.DOMAIN_TOLERANCE`), ``"far outside"`` (some quantity beyond the larger of
        :data:`FAR_TOLERANCE` and the width of its training range) or ``"edge"``; ``"n/a"`` when either is missing.
    """
    if not trained or not survey:
        return "n/a", [], {}
    over = domain_overshoots(trained, survey)
    if not over:
        return "in domain", [], {}
    far, phrases = False, []
    for name, o in over.items():
        lo, hi = survey[name]
        tlo, thi = trained[name]
        beyond = max(o["below"], o["above"])
        far_here = beyond > max(FAR_TOLERANCE.get(name, 0.0), float(thi) - float(tlo))
        far = far or far_here
        phrases.append(f"{name} {lo:.5g} to {hi:.5g} against {float(tlo):.5g} to {float(thi):.5g} trained "
                       f"({beyond:.4g} beyond{', far' if far_here else ''})")
    return ("far outside" if far else "edge"), phrases, {k: max(v["below"], v["above"]) for k, v in over.items()}


def domain_line(status: str, phrases: list[str], trained: dict | None) -> str:
    """The domain line: where the survey lies and what that means for trust."""
    if status == "n/a":
        return "not compared (the model records no training domain, or the survey has no G and B)"
    if status == "in domain":
        rng = ", ".join(f"{k} {float(v[0]):.5g}-{float(v[1]):.5g}" for k, v in (trained or {}).items()
                        if k != "azimuth_deg")
        return f"IN the training domain ({rng}): the expected accuracy above applies"
    if status == "edge":
        return ("AT THE EDGE of the training domain: " + "; ".join(phrases)
                + ". Trust the correction less than the interval says; check it against a reference where you can")
    return ("FAR OUTSIDE the training domain: " + "; ".join(phrases) + ". The correction there is an extrapolation "
            "of what the model learned elsewhere: do not use it (exit status " f"{EXIT_OUT_OF_DOMAIN})")


# ---------------------------------------------------------------------- QC
def qc_line(qc: dict | None, corrects_field: bool, *, after: str = "corrected", db_nT=None, ddip_deg=None,
            bands=None, reference: dict | None = None) -> str:
    """The QC result in one line that says what it means beside the azimuth error.

    Args:
        qc: stage -> counts (:class:`icgo.physics.qc.QCResult` ``counts``), or None (no reference field).
        corrects_field: whether the model corrects the field QC checks (:data:`FIELD_CORRECTING_KINDS`);
            an azimuth compensation does not: MSA removes constant biases, the rest stays in B.
        after: the stage to explain (``corrected``, ``msa``).
        db_nT, ddip_deg: per-station |B| and dip deviations after correction (nT, deg), for their medians.
        bands: :class:`icgo.physics.qc.QCBands` (their half-widths are named).
        reference: the reference field the counts were taken against (``total_field_nT``, ``dip_deg``,
            ``origin``), named in the line; None: not named.
    """
    if not qc:
        return ("no QC: no reference field (give site.dip= site.field= or site.lat= site.lon= site.date=, or add "
                "total_field_nT and dip_deg, or the latitude, longitude and date, to the survey's metadata)")
    stage = after if after in qc else next(iter(qc))
    c = qc[stage]
    raw = qc.get("raw")
    med = ""
    if db_nT is not None and len(db_nT):
        med = (f" (median |B| deviation {float(np.median(np.abs(db_nT))):.0f} nT, dip "
               f"{float(np.median(np.abs(ddip_deg))):.2f} deg")
        med += (f" against bands of {bands.b_tol_nT:g} nT and {bands.dip_tol_deg:g} deg)" if bands else ")")
    after_what = {"corrected": "the correction", "msa": "MSA", "raw": "nothing (raw)"}.get(stage, stage)
    head = (f"{c['any']} of {c['n']} stations flagged after {after_what}"
            + (f" ({raw['any']} raw)" if raw and stage != "raw" else "") + med
            + (f", against |B| {reference['total_field_nT']:.0f} nT and dip {reference['dip_deg']:.2f} deg from "
               f"{reference['origin']}" if reference else ""))
    if c["any"] == 0:
        return head + ": the field agrees with the reference at every station"
    if corrects_field:
        return (head + ": this model corrects the field itself, so flagged stations are disturbed beyond what it "
                "removes; treat their azimuths with care")
    return (head + ": QC checks the magnetic field, and this model corrects the azimuth, not the field (only MSA's "
            "constant biases touch B); the disturbance it learned (e.g. casing) stays in B, so the flags say the "
            "field is disturbed, not that the corrected azimuth is wrong: judge that by the expected accuracy")


# -------------------------------------------------------------------- apply
def apply_verdict(*, model_kind: str, method: str | None, interval_deg: float | None, interval_level: float | None,
                  metrics: dict | None, covered: float | None, qc: dict | None, db_nT=None, ddip_deg=None,
                  bands=None, trained: dict | None, survey: dict | None, out_csv: str, model_path: str,
                  survey_path: str, trajectory: dict | None = None, doubts: dict | None = None,
                  accuracy: dict | None = None, reference: dict | None = None) -> Verdict:
    """The verdict of ``experiments.apply`` on one survey.

    Args:
        model_kind, method: the model's kind and the method applied. interval_deg, interval_level: the
            model's conformal half-width (deg) and level, or None. metrics: ``{"raw", "compensated"}`` metrics
            where the survey has a reference azimuth, else None. covered: fraction of stations whose
            compensated error lies inside the interval (None without a reference). qc, db_nT, ddip_deg,
            bands: see :func:`qc_line`. trained, survey: domains (:func:`domain_status`). out_csv: the
            corrected file. model_path, survey_path: for the next command. trajectory: the bottom-hole
            summary of :func:`icgo.survey.trajectory.position_change` where the survey has measured depth.
        doubts: :attr:`icgo.survey.apply.CorrectedSurvey.doubts`: ``other_device`` makes the status
            ``"other device"`` (the model is not to be used here), ``reference_units`` makes it ``"reference in
            doubt"`` (nothing is measured against that reference); both exit with :data:`EXIT_OUT_OF_DOMAIN`.
        accuracy: the expected accuracy a calibration model carries (its ``accuracy``: the one calibrate printed),
            or None. reference: the QC reference used (:func:`icgo.survey.apply.qc_reference`), named in the QC line.
    """
    doubts = doubts or {}
    status, phrases, over = domain_status(trained, survey)
    if interval_deg is not None and math.isfinite(interval_deg):
        acc = (f"azimuth within +/- {interval_deg:.3f} deg at {100 * interval_level:.0f} % per station (the model's "
               f"split-conformal interval from its out-of-bag errors)")
        if status == "far outside":
            acc += "; it does not hold outside the training domain"
    elif model_kind == "mag_calibration":
        acc = accuracy_line(accuracy, model_kind)
    else:
        acc = f"no interval: a {model_kind} model carries none"
    if "reference_units" in doubts:
        acc += f"; NOT measured on this survey: {doubts['reference_units']}"
    elif metrics:
        c, r = metrics["compensated"], metrics.get("raw")
        acc += (f"; measured on this survey: MAE {c['mae']:.3f} deg" + (f" (raw {r['mae']:.3f})" if r else "")
                + (f", {100 * covered:.1f} % of stations inside the interval" if covered is not None else ""))
        if r and c["mae"] > r["mae"]:
            acc += "; the correction made it WORSE than the raw azimuth"
    else:
        acc += "; no reference azimuth in the survey, so not measured"
    if trajectory:
        from icgo.survey.trajectory import trajectory_sentence

        acc += "; " + trajectory_sentence(trajectory)
    corrects = model_kind in FIELD_CORRECTING_KINDS
    qline = qc_line(qc, corrects, after="corrected", db_nT=db_nT, ddip_deg=ddip_deg, bands=bands, reference=reference)
    mline = f"{method or 'its only method'} of the {model_kind} model {model_path}" + (
        " (the study's selected method: lowest mean training RMSE over repeats, training rows only)"
        if model_kind == "relm_compensation" else "")
    dline = domain_line(status, phrases, trained)
    if status == "far outside":
        mline = f"none for this survey: {mline} was trained elsewhere"
    if "other_device" in doubts:
        status = "other device"
        dline = (f"NOT this model's device: {doubts['other_device']}. The corrected azimuths are not to be used "
                 f"(exit status {EXIT_OUT_OF_DOMAIN})")
        mline = f"none for this survey: {mline} does not fit this device"
    elif "reference_units" in doubts and status != "far outside":
        status = "reference in doubt"
    if status == "far outside":
        nxt = (f"train on data like this survey (with a reference attitude): {door_command('run')} dataset=csv "
               f"dataset.path={survey_path}; then apply that model")
    elif status == "other device":
        nxt = (f"calibrate this device ({door_command('calibrate')} data=<its grouped shots>) or find its own model; "
               "then apply that")
    elif status == "reference in doubt":
        nxt = f"convert the survey's reference angles to degrees, then apply again: {door_command('apply')} " \
              f"model={model_path} data={survey_path}"
    else:
        nxt = f"use {out_csv} (azimuth_compensated" + (", azimuth_interval_deg" if interval_deg is not None else "") + ")"
    numbers = {"interval_deg": interval_deg, "interval_level": interval_level, "covered": covered,
               "accuracy": accuracy, "reference": reference,
               "mae": metrics["compensated"]["mae"] if metrics else None,
               "raw_mae": (metrics.get("raw") or {}).get("mae") if metrics else None,
               "overshoot": over, "qc": qc, "trajectory": trajectory, "doubts": doubts}
    return Verdict(acc, dline, qline, mline, nxt, status,
                   EXIT_OUT_OF_DOMAIN if status in ("far outside", "other device", "reference in doubt") else 0,
                   numbers)


# ---------------------------------------------------------------------- run
def run_verdict(*, maes: dict, selected: str, halfwidth_deg: float | None, coverage: float | None, level: float,
                n_repeats: int, protocol: str, qc: dict | None, trained: dict | None, run_dir: str,
                model_interval_deg: float | None = None) -> Verdict:
    """The verdict of ``experiments.run``: what its fitted model is expected to do on a new survey.

    Args:
        maes: method -> (test MAE mean, std) over repeats (deg), including ``raw`` and ``msa``.
        selected: the model's default method. halfwidth_deg, coverage, level: the selected method's mean
            conformal half-width (deg) and mean coverage of the test rows at ``level``.
        n_repeats: repeats of the study. protocol: its train/test protocol (``random`` = 7:3 rows).
        qc: ``{"raw", "msa"}`` QC counts of the study's stations, or None. trained: the model's domain.
        run_dir: the run directory (the next command's ``model=``).
        model_interval_deg: the half-width the saved model carries for ``selected`` (its out-of-bag interval at
            ``level``: the one ``apply`` prints for it). Given, it is the interval stated, and the repeats' own mean
            half-width is named beside it as another quantity (one accuracy per model).
    """
    m, s = maes.get(selected, (float("nan"), float("nan")))
    acc = f"test MAE {_pm(m, s)} deg over {n_repeats} repeat(s)"
    if model_interval_deg is not None and math.isfinite(model_interval_deg):
        acc += (f"; per station +/- {model_interval_deg:.3f} deg at {100 * level:.0f} % (the interval the saved "
                f"model carries, from the repeats' out-of-bag errors of their ensemble: the one apply prints)")
        if halfwidth_deg is not None and math.isfinite(halfwidth_deg):
            acc += (f"; not to be confused with one repeat's own interval, +/- {halfwidth_deg:.3f} deg on average"
                    + (f" ({100 * coverage:.1f} % of test rows inside)" if coverage is not None and
                       math.isfinite(coverage) else "") + ": a single fit's, where the model averages the repeats")
    elif halfwidth_deg is not None and math.isfinite(halfwidth_deg):
        acc += (f"; per station +/- {halfwidth_deg:.3f} deg at {100 * level:.0f} % (split-conformal, "
                f"{100 * coverage:.1f} % of test rows inside)" if coverage is not None and math.isfinite(coverage)
                else f"; per station +/- {halfwidth_deg:.3f} deg at {100 * level:.0f} %")
    if protocol == "random":
        acc += ("; a random row split tests interpolation between neighbouring stations: a new survey is held "
                "to it only inside the domain below (held-out protocols: split=leave_azimuth_out, transfer)")
    rng = ", ".join(f"{k} {float(v[0]):.5g}-{float(v[1]):.5g}" for k, v in (trained or {}).items())
    dom = (f"the model is trained on {rng}; apply it to surveys inside that (apply says how far a survey lies "
           f"outside and exits {EXIT_OUT_OF_DOMAIN} when it is far outside)") if rng else "no training domain recorded"
    qline = qc_line(qc, False, after="msa")
    others = {k: v for k, v in maes.items() if k not in (selected, "raw")}
    why = "lowest mean training RMSE over repeats (training rows only)"
    if others:
        best_other = min(others, key=lambda k: others[k][0])
        why += f"; test MAE {_f(m)} deg against {best_other} {_f(others[best_other][0])}"
    if "raw" in maes:
        why += f" and raw {_f(maes['raw'][0])}"
    model = f"{selected} in {run_dir}/relm_compensation.json ({why})"
    nxt = f"{door_command('apply')} model={run_dir} data=<your survey.csv>"
    numbers = {"mae": m, "mae_std": s, "halfwidth_deg": halfwidth_deg, "coverage": coverage, "level": level,
               "model_interval_deg": model_interval_deg,
               "n_repeats": n_repeats, "qc": qc, "selected": selected}
    return Verdict(acc, dom, qline, model, nxt, "n/a", 0, numbers)


# ---------------------------------------------------------------- calibrate
def accuracy_line(accuracy: dict | None, kind: str = "mag_calibration") -> str:
    """The expected accuracy a calibration model carries (:data:`icgo.artifacts.calibration.ACCURACY_KEYS`), in one
    line: its own score first, the recommendation rule's nested score beside it, named as such."""
    if not accuracy:
        return f"none stated: this {kind} model carries no expected accuracy (fitted by an older icgo, or not scored)"
    line = (f"pointing spread {_f(accuracy['deg'])}"
            + (f" +/- {_f(accuracy['spread_deg'])}" if accuracy.get("spread_deg") is not None else "")
            + f" deg ({accuracy['what']}; the accuracy this model carries)")
    if accuracy.get("nested_deg") is not None:
        line += (f"; beside it, the rule's nested score {_f(accuracy['nested_deg'])}"
                 + (f" +/- {_f(accuracy['nested_spread_deg'])}" if accuracy.get("nested_spread_deg") is not None
                    else "") + f" deg ({accuracy['nested_what']})")
    return line


def reference_phrase(field_reference: dict | None) -> str:
    """Where a calibration's corrected field stands: scaled to a site (earth units) or relative."""
    if field_reference is None:
        return ("its corrected field is RELATIVE (no site when it was fitted: the sensor's own scale, not earth "
                "units; give site.dip= site.field= or site.lat= site.lon= site.date= to calibrate in nT)")
    return (f"its corrected field is in earth units, scaled to the site's |B| {field_reference['total_field_nT']:.0f} "
            f"nT (dip {field_reference['dip_deg']:.2f} deg; {field_reference['origin']})")


def calibrate_verdict(*, recommendation: dict | None, n_models: int, n_degenerate: int, n_fits: int,
                      run_dir: str, held_out: dict | None = None, refused: str | None = None,
                      accuracy: dict | None = None, field_reference: dict | None = None) -> Verdict:
    """The verdict of ``experiments.calibrate``.

    Args:
        recommendation: the run record's ``recommendation`` (:data:`icgo.reporting.records.RECOMMENDATION_KEYS` and
            the nested ``accuracy_deg`` / ``accuracy_spread_deg``), or None.
        n_models: calibrations saved. n_degenerate, n_fits: fits flagged degenerate by the sanity check, of all.
        run_dir: the run directory (its ``models/`` folder).
        held_out: method -> mean held-out score (deg) of its sound fits, named when there is no recommendation.
        refused: why no calibration is recommended (the exit status is then :data:`EXIT_NO_RECOMMENDATION`).
        accuracy: the recommended model's ``accuracy`` (what it carries, and apply prints); None: the record's.
        field_reference: the recommended model's ``field_reference`` (None: relative).
    """
    qline = (f"{n_degenerate} of {n_fits} fits degenerate by the sanity check (dip spread, |B| spread, condition: "
             f"docs/calibrate.md); a degenerate fit is never recommended" if n_fits else "no fits")
    dom = ("a calibration holds for this device as mounted, in fields like the recording's; recalibrate after a "
           "change of tool, mounting or nearby steel")
    if not recommendation:
        scores = {k: float(v) for k, v in (held_out or {}).items() if v is not None and math.isfinite(v)}
        acc = ("no calibration recommended" + (f": {refused}" if refused else " in the run record") + "; " + (
            "mean held-out score of the sound fits: " + ", ".join(f"{k} {v:.3f} deg" for k, v in sorted(
                scores.items(), key=lambda kv: kv[1])) if scores else "no sound fit was scored held out"))
        nxt = (f"fix what the report names ({door_command('calibrate')} data=<a new recording>), or apply one of "
               f"{run_dir}/models/ knowing why none is recommended" if refused else
               f"{door_command('apply')} model={run_dir}/models/<calibration>.json data=<your survey.csv>")
        return Verdict(acc, dom, qline, f"none; {n_models} calibrations in {run_dir}/models/", nxt, "n/a",
                       EXIT_NO_RECOMMENDATION if refused else 0,
                       {"recommendation": None, "held_out": scores, "refused": refused})
    r = {k: recommendation.get(k) for k in RECOMMENDATION_KEYS}
    nested, nested_se = recommendation.get("accuracy_deg"), recommendation.get("accuracy_spread_deg")
    if accuracy is not None:
        acc = f"{r['method']}: " + accuracy_line(accuracy)
    elif nested is not None:
        acc = (f"the rule's nested score {_f(nested)} deg" + (f" +/- {_f(nested_se)}" if nested_se is not None else "")
               + " (the peer's accuracy metric; nested: the choice made inside each held-out split's training shots, "
               "scored on the shots it did not see)")
    else:
        acc = ("not estimated: no held-out split (one roll too short to halve); the in-sample pointing spread is "
               f"{_f(r['held_out_deg'])} deg")
    if recommendation.get("model"):
        dom += "; " + reference_phrase(field_reference)
    winner = ("a clear winner" if r.get("clear_winner") else
              f"not a clear winner: {r.get('runner_up')} is as good within the spread" if r.get("runner_up") else
              "the only sound method")
    model = f"{r['model']} ({r['method']}), chosen by the rule: {r['criterion']}; {winner}"
    nxt = f"{door_command('apply')} model={run_dir} data=<your survey.csv>"  # the run's recommended model
    return Verdict(acc, dom, qline, model, nxt, "n/a", 0, {"recommendation": r, "accuracy_deg": nested,
                                                          "accuracy_spread_deg": nested_se, "accuracy": accuracy})


def survey_verdict(res, model, bands, *, out_csv: str, model_path: str, survey_path: str,
                   method: str | None = None, reference: dict | None = None) -> Verdict:
    """:func:`apply_verdict` from what :func:`icgo.survey.apply.correct_survey` returned (its stations' arrays:
    the interval's coverage and the |B| / dip deviations taken from them; see :func:`summary_verdict`)."""
    from icgo.physics.frames import angle_diff

    k = res.stations
    interval = float(k["interval"][0]) if "interval" in k and len(k["interval"]) else None
    covered = None
    if interval is not None and "a_true" in k:
        err = np.abs(np.asarray(angle_diff(k["a_comp"], k["a_true"])))
        covered = float(np.mean(err <= k["interval"]))
    return summary_verdict(res, model, bands, interval=interval, covered=covered, db_nT=k.get("db_nT"),
                           ddip_deg=k.get("ddip_deg"), out_csv=out_csv, model_path=model_path,
                           survey_path=survey_path, method=method, reference=reference)


def summary_verdict(res, model, bands, *, interval: float | None, covered: float | None, db_nT, ddip_deg,
                    out_csv: str, model_path: str, survey_path: str, method: str | None = None,
                    reference: dict | None = None) -> Verdict:
    """:func:`apply_verdict` of a corrected survey from its survey-level numbers: a whole survey's
    (:func:`survey_verdict`) or a streamed one's sums (:class:`icgo.survey.apply_stream.StreamedSurvey`).

    Args:
        res: the :class:`icgo.survey.apply.CorrectedSurvey` (metrics, qc, domain, trajectory, doubts). model: the
            fitted model. bands: the QC bands used. interval: the model's half-width (deg) or None. covered: the
            fraction of stations inside it (None without a reference). db_nT, ddip_deg: the |B| and dip deviations
            (arrays; the QC line takes their median). out_csv, model_path, survey_path: for the lines. method: the
            method applied. reference: the QC reference used (named in the QC line).
    """
    survey = {q: res.domain[q] for q in ("inclination_deg", "g_norm_g", "b_norm_nT", "dip_deg") if q in res.domain}
    return apply_verdict(model_kind=model.KIND, method=method or getattr(model, "selected", None),
                         interval_deg=interval, interval_level=getattr(model, "interval_level", None),
                         metrics=res.metrics, covered=covered, qc=res.qc, db_nT=db_nT,
                         ddip_deg=ddip_deg, bands=bands, trained=getattr(model, "domain", None),
                         survey=survey or None, out_csv=out_csv, model_path=model_path, survey_path=survey_path,
                         trajectory={q: v for q, v in res.trajectory.items() if q != "table"} if res.trajectory else None,
                         doubts=res.doubts, accuracy=getattr(model, "accuracy", None), reference=reference)


def from_dict(d: dict) -> Verdict:
    """A :class:`Verdict` from :meth:`Verdict.as_dict` (e.g. read back from a meta file)."""
    return Verdict(**{k: d[k] for k in Verdict._fields})


def study_verdict(metrics, coverage, *, selected: str, n_repeats: int, protocol: str, qc: dict | None,
                  trained: dict | None, run_dir: str, model_interval_deg: float | None = None) -> Verdict:
    """:func:`run_verdict` from a study's tables.

    Args:
        metrics: per (method, repeat, split) MAE (``icgo.reporting.records`` ``metrics``; test rows used).
        coverage: per (method, repeat, fold) conformal ``halfwidth_deg``, ``coverage`` and ``level``, or None.
        selected ... run_dir, model_interval_deg: see :func:`run_verdict`.
    """
    test = metrics[metrics["split"] == "test"]
    maes = {}
    for m, g in test.groupby("method", sort=False):
        x = g["mae"].to_numpy(float)
        maes[m] = (float(x.mean()), float(x.std(ddof=1)) if x.size > 1 else float("nan"))
    hw = cov = None
    level = 0.9
    if coverage is not None and len(coverage):
        c = coverage[coverage["method"] == selected]
        if len(c):
            hw, cov, level = float(c["halfwidth_deg"].mean()), float(c["coverage"].mean()), float(c["level"].iloc[0])
    return run_verdict(maes=maes, selected=selected, halfwidth_deg=hw, coverage=cov, level=level, n_repeats=n_repeats,
                       protocol=protocol, qc=qc, trained=trained, run_dir=run_dir,
                       model_interval_deg=model_interval_deg)
