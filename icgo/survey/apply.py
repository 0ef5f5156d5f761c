"""Correct a new survey with a fitted model: the fit-once, apply-to-every-survey workflow (ICGO paper section 5).

:func:`correct_survey` applies any :class:`icgo.artifacts.format.FittedModel` to a
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
from icgo.physics.metrics import azimuth_metrics
from icgo.artifacts.format import CORRECTED_B, FittedModel, domain_notices, frame_values, sensor_domain
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



#: The notices of a survey without QC (the whole survey's and the streamed one's, word for word).
NO_REFERENCE_NOTICE = ("no reference field: no QC (give site.dip= site.field= or site.lat= site.lon= site.date=, or "
                       "total_field_nT, dip_deg, gravity_g or the location and date in the survey's metadata)")
NO_SENSORS_NOTICE = "no gx..bz in the survey: no QC"

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


def one_field_doubt(model: FittedModel, b_raw, dip_raw, b_corr, dip_corr) -> str | None:
    """One line when the model's corrected field is not one earth field over the survey's stations (see
    :data:`SPREAD_MARGIN`, :data:`ONE_FIELD_SPREAD`), else None: the model probably belongs to another device, and
    the verdict says so (:func:`icgo.survey.verdict.apply_verdict`: not to be used as it stands).

    Args:
        b_raw, dip_raw: (N,) raw |B| (nT) and dip (deg) per station. b_corr, dip_corr: the same after the model
            (the dip from the model's corrected gravity where it corrects it).
    """
    if len(b_raw) < 3:
        return None
    return field_doubt_line(model, _spreads(b_raw, dip_raw), _spreads(b_corr, dip_corr))


def field_doubt_line(model: FittedModel, raw: tuple[float, float], corrected: tuple[float, float]) -> str | None:
    """:func:`one_field_doubt`'s decision from the spreads (:func:`_spreads`) of the raw and the corrected field
    (also what a streamed survey's sums give: :mod:`icgo.survey.apply_stream`)."""
    (b0, d0), (b1, d1) = raw, corrected
    worse = b1 > b0 + SPREAD_MARGIN["b_rel"] or d1 > d0 + SPREAD_MARGIN["dip_deg"]
    not_one = getattr(model, "ONE_FIELD", False) and (b1 > ONE_FIELD_SPREAD["b_rel"] or d1 > ONE_FIELD_SPREAD["dip_deg"])
    if worse or not_one:
        return (f"the corrected field is not one earth field over the survey's stations (|B| spread {100 * b0:.2g} % "
                f"raw -> {100 * b1:.2g} % corrected, dip spread {d0:.3g} -> {d1:.3g} deg): the model belongs to "
                f"another tool or device, or this one changed since it was fitted")
    return None


def _spreads(bn, dip) -> tuple[float, float]:
    """(relative std of |B|, std of the dip in deg) over stations: one earth field has both near 0."""
    return float(np.std(bn) / max(np.mean(bn), 1e-300)), float(np.std(dip))


#: A reference angle column "looks like radians" (:func:`radians_doubt`) when every value lies within
#: [-RADIANS_MAX, RADIANS_MAX], the model's own angle is at least RADIANS_FAR_DEG (median) from it read as
#: degrees, and read as radians it is at least RADIANS_RATIO times closer.
RADIANS_MAX = 2.0 * np.pi + 1e-6
RADIANS_FAR_DEG = 10.0
RADIANS_RATIO = 3.0


def radians_doubt(reference, estimate_deg, column: str) -> str | None:
    """One line when a survey's reference angle (``azimuth_deg``, ``inclination_deg``) looks like radians, else None.

    Args:
        reference: (N,) the survey's reference column as given. estimate_deg: (N,) the same angle from the
            survey's own sensors or the model (deg), to compare with. column: its name, for the line.
    """
    ref = np.asarray(reference, float)
    est = np.asarray(estimate_deg, float)
    ok = np.isfinite(ref) & np.isfinite(est)
    ref, est = ref[ok], est[ok]
    if ref.size < 3 or np.max(np.abs(ref)) > RADIANS_MAX:
        return None
    return radians_line(float(np.median(np.abs(np.asarray(angle_diff(est, ref))))),
                        float(np.median(np.abs(np.asarray(angle_diff(est, np.degrees(ref)))))), column)


def radians_line(as_deg: float, as_rad: float, column: str) -> str | None:
    """:func:`radians_doubt`'s decision from the median |difference| (deg) between the survey's own angle and the
    reference read as degrees (``as_deg``) and as radians (``as_rad``)."""
    if as_deg >= RADIANS_FAR_DEG and as_rad * RADIANS_RATIO <= as_deg:
        return (f"the survey's {column} looks like radians (every value within +/- 2 pi; the median difference "
                f"from the survey's own angle is {as_deg:.1f} deg read as degrees, {as_rad:.2f} deg read as "
                f"radians): convert {column} to degrees and apply again")
    return None


def qc_reference(site, survey_field, model: FittedModel):
    """The reference field apply's QC compares the corrected survey with, and where it came from.

    In order: the ``site.*`` settings (:class:`icgo.io.site.Site`), the survey's own metadata
    (:class:`icgo.io.schema.ReferenceField`), the site a calibration was scaled to when it was fitted (its
    ``field_reference``); None when there is none (no QC then).

    Returns:
        (ReferenceField or None, {"total_field_nT", "dip_deg", "gravity_g", "origin"} or None).
    """
    from icgo.io.schema import ReferenceField

    if site is not None:
        f = ReferenceField(float(site.field_nT), float(site.dip_deg), float("nan"), 1.0,
                           f"the site given to apply: {site.origin}")
    elif survey_field is not None:
        f = survey_field._replace(origin=f"the survey's metadata ({survey_field.origin})")
    elif getattr(model, "field_reference", None) is not None:
        r = model.field_reference
        f = ReferenceField(float(r["total_field_nT"]), float(r["dip_deg"]), float("nan"), 1.0,
                           f"the site the calibration was fitted at ({r['origin']})")
    else:
        return None, None
    return f, {"total_field_nT": f.total_field_nT, "dip_deg": f.dip_deg, "gravity_g": f.gravity_g, "origin": f.origin}


def relative_to_reference(model: FittedModel, frame: pd.DataFrame, field):
    """A relative calibration (no site when it was fitted: :attr:`icgo.artifacts.calibration.MagCalibration.relative`)
    put in earth units for a survey with a reference: its field scaled so that the median corrected ``|B|`` of the
    survey's stations (``frame``: the first chunk of a streamed one) is the reference's ``|B|``. The level of the
    field is then not checked by QC, only its spread and the dip (the notice says so).

    Returns:
        (the model to apply, a notice or None); the model unchanged when it is not a relative calibration or
        there is no reference.
    """
    import dataclasses

    if field is None or not getattr(model, "relative", False) or not len(frame):
        return model, None
    _, Bc = model.corrected(None, frame_values(frame, ("bx", "by", "bz"), f"{model.KIND} model"))
    scale = float(field.total_field_nT) / float(np.median(np.linalg.norm(Bc, axis=1)))
    return dataclasses.replace(model, field_scale_nT=scale), (
        f"the calibration is relative (fitted without a site: its field in the sensor's own scale, "
        f"{model.field_scale_nT:.0f} nT per unit); scaled here to the reference's |B| {field.total_field_nT:.0f} nT "
        f"over this survey's stations, so QC checks the field's spread and dip, not its level: calibrate with "
        f"site.* for a calibration in earth units")


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
        doubts: what makes the result not usable as it stands, ``{kind: line}``: ``other_device`` (the
            corrected field is not one earth field: :func:`one_field_doubt`), ``reference_units`` (a
            reference angle that looks like radians: :func:`radians_doubt`; the metrics are then withheld).
            The verdict changes with them (:func:`icgo.survey.verdict.apply_verdict`).
        stations: the per-station arrays the verdict reads (:attr:`Rows.keep`). domain: the survey's ranges of
            the model's domain quantities (:attr:`Rows.domain`).
    """

    table: pd.DataFrame
    metrics: dict | None
    qc: dict | None
    notices: list
    trajectory: dict | None = None
    doubts: dict = {}
    stations: dict = {}
    domain: dict = {}


class Rows(NamedTuple):
    """What :func:`correct_rows` gives for some stations of a survey.

    Attributes:
        table: the stations' own columns, the model's output and, with a reference field, the QC columns.
        keep: per-station arrays the survey-level summary needs (:func:`summarise`), a few floats per station:
            reference and estimated angles, raw and corrected |B| and dip, QC deviations, positions' inputs.
        domain: {quantity: [min, max]} of the stations (the model's domain quantities).
        qc: {"raw": counts, "corrected": counts} of the stations, or None.
    """

    table: pd.DataFrame
    keep: dict
    domain: dict
    qc: dict | None


def correct_rows(model: FittedModel, frame: pd.DataFrame, field=None, *, method: str | None = None,
                 bands: QCBands = QCBands()) -> Rows:
    """The model applied to some stations of a survey, and what the survey-level checks need from them.

    Raises:
        ModelError / DataError: one line (a model setting it lacks, a column it needs, a corrected survey).
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
    keep = {}
    have_gb = all(c in frame.columns for c in ("gx", "gy", "gz", "bx", "by", "bz"))
    domain = {k: [float(frame[k].min()), float(frame[k].max())] for k in model.domain
              if k in frame.columns and pd.api.types.is_numeric_dtype(frame[k]) and len(frame)}
    qc = None
    if have_gb:
        from icgo.physics.qc import measured_dip_deg

        G = frame[["gx", "gy", "gz"]].to_numpy(float)
        B = frame[["bx", "by", "bz"]].to_numpy(float)
        domain.update(sensor_domain(G, B))
        keep["b_raw"], keep["dip_raw"] = np.linalg.norm(B, axis=1), measured_dip_deg(G, B)
        Gc = Bc = None
        if all(c in out.columns for c in CORRECTED_B):  # the corrected field with the corrected gravity, where the
            g_cols = ["gx_corrected", "gy_corrected", "gz_corrected"]  # model corrects it (|G| and dip after it)
            Bc = out[list(CORRECTED_B)].to_numpy(float)
            Gc = out[g_cols].to_numpy(float) if all(c in out.columns for c in g_cols) else G
            keep["b_corr"], keep["dip_corr"] = np.linalg.norm(Bc, axis=1), measured_dip_deg(Gc, Bc)
        if field is not None:
            raw = survey_qc(G, B, field.total_field_nT, field.dip_deg, field.gravity_g, bands, prefix="raw_")
            table = pd.concat([table, raw.table], axis=1)
            qc = {"raw": raw.counts}
            if Bc is not None:
                cor = survey_qc(Gc, Bc, field.total_field_nT, field.dip_deg, field.gravity_g, bands,
                                prefix="corrected_")
                table = pd.concat([table, cor.table], axis=1)
                qc["corrected"] = cor.counts
                keep["db_nT"] = cor.table["corrected_db_nT"].to_numpy(float)
                keep["ddip_deg"] = cor.table["corrected_ddip_deg"].to_numpy(float)
    if "azimuth_interval_deg" in out.columns:
        keep["interval"] = out["azimuth_interval_deg"].to_numpy(float)
    if "azimuth_deg" in frame.columns and "azimuth_compensated" in out.columns:
        a_true = frame["azimuth_deg"].to_numpy(float)
        keep["a_true"], keep["a_comp"] = a_true, out["azimuth_compensated"].to_numpy(float)
        if "azimuth_raw" in out.columns:
            keep["a_raw"] = out["azimuth_raw"].to_numpy(float)
        table["error_compensated"] = np.asarray(angle_diff(keep["a_comp"], a_true))
    if "inclination_deg" in frame.columns:
        est = (out["inclination_compensated"].to_numpy(float) if "inclination_compensated" in out.columns else
               np.degrees(np.arctan2(np.hypot(G[:, 0], G[:, 1]), G[:, 2])) if have_gb else None)
        if est is not None:
            keep["i_true"], keep["i_est"] = frame["inclination_deg"].to_numpy(float), est
    if MD_COLUMN in frame.columns and have_gb and "azimuth_compensated" in out.columns:
        from icgo.physics.frames import azimuth_from_gv, inclination_from_g

        keep["md"] = frame[MD_COLUMN].to_numpy(float)
        keep["inc_raw"] = np.asarray(inclination_from_g(G), float)
        keep["azi_raw"] = (out["azimuth_raw"].to_numpy(float) if "azimuth_raw" in out.columns
                           else np.asarray(azimuth_from_gv(G, B)))
        keep["inc_cor"] = (out["inclination_compensated"].to_numpy(float) if "inclination_compensated" in out.columns
                           else keep["inc_raw"])
        keep["azi_cor"] = out["azimuth_compensated"].to_numpy(float)
        if all(c in frame.columns for c in ("inclination_deg", "azimuth_deg")):
            keep["inc_ref"], keep["azi_ref"] = frame["inclination_deg"].to_numpy(float), frame["azimuth_deg"].to_numpy(float)
    # copies: a column taken from a frame is a view that would keep the whole frame (a streamed chunk) alive
    return Rows(table, {name: np.array(v, dtype=float, copy=True) for name, v in keep.items()}, domain, qc)


def summarise(model: FittedModel, rows: Rows, field, *, positions_table: bool = True) -> CorrectedSurvey:
    """The survey-level result of :func:`correct_rows`' output: metrics, QC, notices, doubts, trajectory.

    ``positions_table``: add the positions to ``rows.table`` (False for a streamed survey, whose table is
    written already: its positions are then returned in ``trajectory["table"]``).
    """
    k, table, notices, doubts = rows.keep, rows.table, [], {}
    line = one_field_doubt(model, k["b_raw"], k["dip_raw"], k["b_corr"], k["dip_corr"]) if "b_corr" in k else None
    if line:
        doubts["other_device"] = line
        notices.append(line)
    notices += [f"outside the training domain: {n}" for n in domain_notices(model.domain, rows.domain)]
    if rows.qc is None:
        notices.append(NO_REFERENCE_NOTICE if field is None else NO_SENSORS_NOTICE)
    for col, t, e in (("azimuth_deg", "a_true", "a_comp"), ("inclination_deg", "i_true", "i_est")):
        if t in k:
            line = radians_doubt(k[t], k[e], col)
            if line:
                doubts["reference_units"] = line
                notices.append(line)
                break
    metrics = None
    if "a_true" in k:
        err_raw = np.asarray(angle_diff(k["a_raw"], k["a_true"])) if "a_raw" in k else np.zeros(len(k["a_true"]))
        metrics = {"compensated": _metrics(k["a_true"], k["a_comp"], err_raw)}
        if "a_raw" in k:
            metrics["raw"] = _metrics(k["a_true"], k["a_raw"], err_raw)
    else:
        notices.append("no reference azimuth (azimuth_deg) in the survey: no error metrics, QC only")
    trajectory = None
    if "md" in k:
        try:
            pos, trajectory = position_change(k["md"], k["inc_raw"], k["azi_raw"], k["inc_cor"], k["azi_cor"],
                                              k.get("inc_ref"), k.get("azi_ref"))
            if positions_table:
                table = pd.concat([table, pos], axis=1)
            else:
                trajectory = {**trajectory, "table": pos}
        except DataError as e:
            notices.append(f"no positions: {e}")
    return CorrectedSurvey(table, metrics, rows.qc, notices, trajectory, doubts, k, rows.domain)


def correct_survey(model: FittedModel, frame: pd.DataFrame, field=None, *, method: str | None = None,
                   bands: QCBands = QCBands()) -> CorrectedSurvey:
    """Apply ``model`` to a survey and check the result (:func:`correct_rows`, then :func:`summarise`).

    Args:
        model: any fitted model (:func:`icgo.artifacts.registry.load_model`).
        frame: the survey (data contract: gx, gy, gz in g, bx, by, bz in nT; optional
            azimuth_deg, station, md, ...).
        field: the survey's :class:`icgo.io.schema.ReferenceField` or None (no QC then).
        method: for a model holding several methods, which one (None: its default).
        bands: QC acceptance bands.
    Raises:
        icgo.artifacts.format.ModelError: one line, e.g. the survey lacks a column the model needs.
    """
    return summarise(model, correct_rows(model, frame, field, method=method, bands=bands), field)


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
        msa_model: the study's :class:`icgo.artifacts.relm.MSAModel` (its corrected field is "after").
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
