"""Correct a new survey with a fitted model: the fit-once, apply-to-every-survey workflow (ICGO paper section 5).

:func:`correct_survey` applies any :class:`icgo.models.format.FittedModel` to a
recording in the data contract and returns the corrected survey: the model's
per-station output (compensated azimuth, inclination, toolface, corrections,
spread), survey QC against the reference field before and after the correction
(:mod:`icgo.physics.qc`), MAE / RMSE / R^2 of the azimuth error where the survey carries
a reference azimuth, and notices where the survey leaves the model's training
domain. No reference attitude is needed: without one, QC alone is reported.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pandas as pd

from icgo.core.errors import DataError, ModelError
from icgo.maths.metrics import azimuth_metrics
from icgo.models.format import CORRECTED_B, FittedModel, domain_notices, sensor_domain
from icgo.physics.frames import angle_diff
from icgo.physics.qc import QCBands, survey_qc
from icgo.survey.trajectory import MD_COLUMN, position_change


class CorrectedSurvey(NamedTuple):
    """Outcome of :func:`correct_survey`.

    Attributes:
        table: one row per station: the survey's own columns, the model's output
            and, with a reference field, the QC columns (``raw_*``, ``corrected_*``).
        metrics: ``{"raw": {...}, "compensated": {...}}`` with mae, rmse, r2, r2_error (deg),
            or None without a reference azimuth.
        qc: ``{"raw": counts, "corrected": counts}`` (see :class:`icgo.physics.qc.QCResult`), or None
            without a reference field.
        notices: one line each (training domain, what was not computed and why).
        trajectory: where the survey has measured depth (``md``), the bottom-hole positions by minimum
            curvature from the raw and the corrected attitude and the change the correction makes
            (:func:`icgo.survey.trajectory.position_change`), else None.
    """

    table: pd.DataFrame
    metrics: dict | None
    qc: dict | None
    notices: list
    trajectory: dict | None = None


def correct_survey(model: FittedModel, frame: pd.DataFrame, field=None, *, method: str | None = None,
                   bands: QCBands = QCBands()) -> CorrectedSurvey:
    """Apply ``model`` to a survey and check the result.

    Args:
        model: any fitted model (:func:`icgo.models.registry.load_model`).
        frame: the survey (data contract: gx, gy, gz in g, bx, by, bz in nT; optional
            azimuth_deg, station, ...).
        field: the survey's :class:`icgo.io.recording.ReferenceField` or None (no QC then).
        method: for a model holding several methods, which one (None: its default).
        bands: QC acceptance bands.
    Raises:
        icgo.models.format.ModelError: one line, e.g. the survey lacks a column the model needs.
    """
    if method is not None and not hasattr(model, "methods"):
        raise ModelError(f"method={method!r}: a {model.KIND} model holds one method; drop the method setting")
    out = model.apply(frame, method=method) if method is not None else model.apply(frame)
    table = pd.concat([frame.reset_index(drop=True),
                       out.drop(columns=[c for c in out.columns if c in frame.columns])], axis=1)
    notices = []
    have_gb = all(c in frame.columns for c in ("gx", "gy", "gz", "bx", "by", "bz"))
    if have_gb:
        G = frame[["gx", "gy", "gz"]].to_numpy(float)
        B = frame[["bx", "by", "bz"]].to_numpy(float)
        notices += [f"outside the training domain: {n}" for n in domain_notices(model.domain, sensor_domain(G, B))]
    qc = None
    if field is None or not have_gb:
        notices.append("no reference field in the survey's metadata: no QC (give total_field_nT, dip_deg, "
                       "gravity_g or the location and date)")
    else:
        raw = survey_qc(G, B, field.total_field_nT, field.dip_deg, field.gravity_g, bands, prefix="raw_")
        table = pd.concat([table, raw.table], axis=1)
        qc = {"raw": raw.counts}
        if all(c in out.columns for c in CORRECTED_B):
            cor = survey_qc(G, out[list(CORRECTED_B)].to_numpy(float), field.total_field_nT, field.dip_deg,
                            field.gravity_g, bands, prefix="corrected_")
            table = pd.concat([table, cor.table], axis=1)
            qc["corrected"] = cor.counts
    metrics = None
    if "azimuth_deg" in frame.columns and "azimuth_compensated" in out.columns:
        a_true = frame["azimuth_deg"].to_numpy(float)
        raw_col = "azimuth_raw" if "azimuth_raw" in out.columns else None
        err_raw = (np.asarray(angle_diff(out[raw_col].to_numpy(float), a_true)) if raw_col
                   else np.zeros(len(a_true)))
        table["error_compensated"] = np.asarray(angle_diff(out["azimuth_compensated"].to_numpy(float), a_true))
        metrics = {"compensated": _metrics(a_true, out["azimuth_compensated"].to_numpy(float), err_raw)}
        if raw_col:
            metrics["raw"] = _metrics(a_true, out[raw_col].to_numpy(float), err_raw)
    else:
        notices.append("no reference azimuth (azimuth_deg) in the survey: no error metrics, QC only")
    trajectory = None
    if MD_COLUMN in frame.columns and have_gb and "azimuth_compensated" in out.columns:
        try:
            pos, trajectory = _positions(frame, out, G, B)
            table = pd.concat([table, pos], axis=1)
        except DataError as e:
            notices.append(f"no positions: {e}")
    return CorrectedSurvey(table, metrics, qc, notices, trajectory)


def _positions(frame: pd.DataFrame, out: pd.DataFrame, G, B):
    """:func:`icgo.survey.trajectory.position_change` of a survey: raw attitude from its sensors (or the model's
    ``azimuth_raw``), corrected from the model's output, the reference where the survey has one."""
    from icgo.physics.frames import azimuth_from_gv, inclination_from_g

    inc_raw = np.asarray(inclination_from_g(G), float)
    azi_raw = out["azimuth_raw"].to_numpy(float) if "azimuth_raw" in out.columns else np.asarray(azimuth_from_gv(G, B))
    inc_cor = out["inclination_compensated"].to_numpy(float) if "inclination_compensated" in out.columns else inc_raw
    ref = (frame["inclination_deg"].to_numpy(float), frame["azimuth_deg"].to_numpy(float)) if all(
        c in frame.columns for c in ("inclination_deg", "azimuth_deg")) else (None, None)
    return position_change(frame[MD_COLUMN].to_numpy(float), inc_raw, azi_raw, inc_cor,
                           out["azimuth_compensated"].to_numpy(float), *ref)


def _metrics(a_true, a_est, err_before) -> dict:
    m = azimuth_metrics(a_true, a_est, err_before)
    return {k: float(v) for k, v in m._asdict().items()}


def study_qc(frame: pd.DataFrame, meta: dict, msa_model, bands: QCBands = QCBands()) -> dict | None:
    """QC counts of a study's stations before and after MSA, or None without a reference field.

    Args:
        frame: the stations the study used (data contract). meta: their metadata
            (``total_field_nT``, ``dip_deg``, optional ``gravity_g``).
        msa_model: the study's :class:`icgo.models.relm.MSAModel` (its corrected field is "after").
        bands: QC bands.
    Returns:
        ``{"raw": counts, "msa": counts}`` (see :class:`icgo.physics.qc.QCResult`).
    """
    if not meta or "total_field_nT" not in meta or "dip_deg" not in meta:
        return None
    G = frame[["gx", "gy", "gz"]].to_numpy(float)
    B = frame[["bx", "by", "bz"]].to_numpy(float)
    ref = (float(meta["total_field_nT"]), float(meta["dip_deg"]), float(meta.get("gravity_g", 1.0)))
    after = msa_model.apply(frame)[list(CORRECTED_B)].to_numpy(float)
    return {"raw": survey_qc(G, B, *ref, bands).counts, "msa": survey_qc(G, after, *ref, bands).counts}
