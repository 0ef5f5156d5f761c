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

#: Columns a model's ``apply`` writes (every kind), besides ``station`` and the gyro tools' own ``azimuth_raw_deg``,
#: which are inputs too.
MODEL_OUTPUT_COLUMNS = (
    "inclination_compensated", "toolface_compensated", "azimuth_raw", "azimuth_msa", "predicted_error",
    "azimuth_compensated", "azimuth_spread_deg", "azimuth_interval_deg", *CORRECTED_B, "b_total_nT", "gx_corrected",
    "gy_corrected", "gz_corrected", "dip_compensated_deg", "inclination_raw", "toolface_raw")
#: The QC columns :func:`icgo.physics.qc.survey_qc` writes (prefixed ``raw_`` and ``corrected_`` here).
QC_COLUMNS = ("g_total_g", "dg_g", "b_total_nT", "db_nT", "dip_deg", "ddip_deg", "qc_g", "qc_b", "qc_dip", "qc_pass")
#: Every column :func:`correct_survey` adds to a survey.
OUTPUT_COLUMNS = frozenset(MODEL_OUTPUT_COLUMNS + tuple(p + c for p in ("raw_", "corrected_") for c in QC_COLUMNS)
                           + ("error_compensated",))


def output_columns_in(columns) -> list[str]:
    """The columns of a survey that :func:`correct_survey` writes: a survey holding any is the output of an
    earlier correction, and correcting it again would mix two models' columns (refused)."""
    return [c for c in columns if c in OUTPUT_COLUMNS]


#: One earth field is constant over the stations of one survey. A corrected field whose spread (std over the
#: stations: |B| relative, dip deg) exceeds the raw field's by more than SPREAD_MARGIN was made worse by the
#: model; a calibration's corrected field (a kind with ``ONE_FIELD``) spreading more than ONE_FIELD_SPREAD is
#: not one field at all. Measured on the 9 bundled devices with device ab's 12-parameter calibration: on ab
#: itself 0.3 % and 0.28 deg; on the 8 others 19 to 36 % and 10 to 19 deg (their raw fields: 25 to 35 %, 23 to
#: 30 deg, so "less consistent than raw" alone misses most of them).
SPREAD_MARGIN = {"b_rel": 0.02, "dip_deg": 1.0}
ONE_FIELD_SPREAD = {"b_rel": 0.05, "dip_deg": 3.0}


def consistency_notice(model: FittedModel, G, B_raw, B_corr, G_corr=None) -> str | None:
    """One line when the model's corrected field is not one earth field over the survey's stations (see
    :data:`SPREAD_MARGIN`, :data:`ONE_FIELD_SPREAD`), else None.

    Args:
        G: (N, 3) raw gravity, g. B_raw, B_corr: (N, 3) raw and corrected field, nT. G_corr: the model's
            corrected gravity, if it corrects it (the dip after the model uses it).
    """
    from icgo.physics.qc import measured_dip_deg

    if len(G) < 3:
        return None

    def spread(Gv, Bv):
        bn = np.linalg.norm(Bv, axis=1)
        return float(np.std(bn) / max(np.mean(bn), 1e-300)), float(np.std(measured_dip_deg(Gv, Bv)))

    (b0, d0), (b1, d1) = spread(G, B_raw), spread(G if G_corr is None else G_corr, B_corr)
    worse = b1 > b0 + SPREAD_MARGIN["b_rel"] or d1 > d0 + SPREAD_MARGIN["dip_deg"]
    not_one = getattr(model, "ONE_FIELD", False) and (b1 > ONE_FIELD_SPREAD["b_rel"] or d1 > ONE_FIELD_SPREAD["dip_deg"])
    if worse or not_one:
        return (f"the corrected field is not one earth field over the survey's stations (|B| spread {100 * b0:.2g} % "
                f"raw -> {100 * b1:.2g} % corrected, dip spread {d0:.3g} -> {d1:.3g} deg): the model may belong to "
                f"another tool or device; check it before using the corrected azimuths")
    return None


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
    held = output_columns_in(frame.columns)
    if held:
        raise DataError(f"the survey already holds the output columns of a correction ({', '.join(held[:4])}"
                        f"{', ...' if len(held) > 4 else ''}); correct the original survey instead")
    out = model.apply(frame, method=method) if method is not None else model.apply(frame)
    _check_output(out, model)
    table = pd.concat([frame.reset_index(drop=True),
                       out.drop(columns=[c for c in out.columns if c in frame.columns])], axis=1)
    notices = []
    have_gb = all(c in frame.columns for c in ("gx", "gy", "gz", "bx", "by", "bz"))
    survey_domain = {k: [float(frame[k].min()), float(frame[k].max())] for k in model.domain
                     if k in frame.columns and pd.api.types.is_numeric_dtype(frame[k]) and len(frame)}
    if have_gb:
        G = frame[["gx", "gy", "gz"]].to_numpy(float)
        B = frame[["bx", "by", "bz"]].to_numpy(float)
        survey_domain.update(sensor_domain(G, B))
        if all(c in out.columns for c in CORRECTED_B):
            g_cols = ["gx_corrected", "gy_corrected", "gz_corrected"]
            line = consistency_notice(model, G, B, out[list(CORRECTED_B)].to_numpy(float),
                                      out[g_cols].to_numpy(float) if all(c in out.columns for c in g_cols) else None)
            if line:
                notices.append(line)
    notices += [f"outside the training domain: {n}" for n in domain_notices(model.domain, survey_domain)]
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


def _check_output(out: pd.DataFrame, model: FittedModel) -> None:
    """ModelError when a model gives NaN or inf for a survey with finite inputs (its parameters overflow)."""
    # the conformal interval is NaN where no training row was out of bag: not a failure
    num = out.select_dtypes(include=[np.number]).drop(columns=["azimuth_interval_deg"], errors="ignore")
    bad = ~np.isfinite(num.to_numpy(float))
    if bad.any():
        r, c = np.argwhere(bad)[0]
        raise ModelError(f"the {model.KIND} model gives NaN or inf for {int(bad.any(axis=1).sum())} of {len(out)} "
                         f"stations (first: row {r}, {num.columns[c]}); its parameters do not fit this survey")


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
