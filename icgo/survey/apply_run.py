"""One survey corrected by one saved model, written and reported: what ``python -m experiments.apply`` does with its
checked settings.

:func:`apply_survey` reads the survey (in chunks above a size: :func:`icgo.io.stream.read_chunks`), corrects it with
:func:`icgo.survey.apply.correct_rows` (a streamed survey chunk by chunk: each chunk's rows written as they come and
its stations folded into survey-level sums, :class:`icgo.survey.apply_stream.StreamedSurvey`, so memory is bounded by
the chunk, not the file), and writes ``<survey>_corrected.csv`` and ``<survey>_corrected.meta.json``
(the model, the QC counts before/after, the metrics where the survey has a reference azimuth, the notices) through
an :class:`icgo.io.files.Output`, both or neither; :func:`report` prints the summary. A survey that already holds a
correction's output columns (a corrected survey) is refused: its columns would mix with the new model's.
"""

from __future__ import annotations

from collections.abc import Callable
from contextlib import ExitStack
from pathlib import Path

from icgo.core.errors import DataError


def model_path(path: Path) -> Path:
    """The model file a ``model=`` setting names: a header, a run directory's main model (the first of its
    ``run.json``'s ``models``, which must be a file in that directory), or the calibration a calibrate run
    directory recommends."""
    from icgo.artifacts.format import run_model_path
    from icgo.reporting import records

    if path.is_dir() and (path / records.CALIBRATION_FILE).is_file():
        return records.recommended_model(path)
    if path.is_dir() and ((path / records.RUN_FILE).exists() or (path / records.RUN_FILE).is_symlink()):
        return run_model_path(path)
    return path


def apply_survey(output, model, mpath: Path, data: Path, survey_path: str, *, columns: dict, max_bytes: int,
                 stream_above: int, chunk_rows: int, require_meta: bool, method: str | None, bands, qc_bands: dict,
                 write_record: Callable[[Path], None], site=None) -> dict:
    """Correct the survey ``data`` with ``model`` (loaded from ``mpath``) and write the two files (all or none); return the meta
    dict.

    Args:
        output: the checked :class:`icgo.io.files.Output` of the run directory. survey_path: ``data`` as given.
        columns: the column map. max_bytes, stream_above, chunk_rows: the largest survey read (bytes), the size above
            which it streams (bytes) and the rows per chunk. require_meta: the metadata header required.
        method: the model's method to use (None: its selected one). bands: the QC bands
            (:class:`icgo.physics.qc.QCBands`); qc_bands: the same as given (the meta record's ``qc_bands``).
        write_record: writes the door's own record of its settings into the staging directory.
        site: the ``site.*`` settings' :class:`icgo.io.site.Site`, or None. QC's reference is the site, else the
            survey's metadata, else the site a calibration was fitted at (:func:`icgo.survey.apply.qc_reference`;
            the meta's ``reference`` names it).
    Raises:
        ValueError (ModelError, DataError, RecordError, OutputError): one line.
    """
    from icgo.io.files import json_text
    from icgo.io.stream import read_chunks
    from icgo.survey.apply import correct_rows, output_columns_in, qc_reference, relative_to_reference, summarise
    from icgo.survey.apply_stream import StreamedSurvey
    from icgo.survey.verdict import survey_verdict

    out_dir = output.path
    chunks = read_chunks(data, max_bytes=max_bytes, stream_above=stream_above, chunk_rows=chunk_rows,
                         require_meta=require_meta, require_reference=False, columns=columns)
    stem = data.stem
    with output.staged(last=(f"{stem}_corrected.meta.json",)) as stage, ExitStack() as scratch:
        out_csv, first, streamed, notices, rec = stage / f"{stem}_corrected.csv", None, None, [], None
        n_rows = n_chunks = 0
        field = reference = None
        for k, rec in enumerate(chunks):  # a small survey is one chunk; a large one streams in bounded memory
            if k == 0:
                held = output_columns_in(rec.frame.columns)
                if held:
                    raise DataError(f"{data}: already holds the output columns of a correction ({', '.join(held[:4])}"
                                    f"{', ...' if len(held) > 4 else ''}): it is a corrected survey; apply the model "
                                    f"to the original survey (mixing two models' columns is refused)")
                field, reference = qc_reference(site, rec.field, model)  # one reference for every chunk
                model, line = relative_to_reference(model, rec.frame, field)
                notices += [line] if line else []
            notices += rec.notices
            n_rows += len(rec.frame)
            n_chunks += 1
            rows = correct_rows(model, rec.frame, field, method=method, bands=bands)
            if k == 0:  # held until a second chunk says the survey streams
                first = rows
                continue
            if k == 1:  # streaming: the first chunk's table goes out now, its stations into the sums
                streamed = scratch.enter_context(StreamedSurvey(stage / f"{stem}_positions.csv"))
                first.table.to_csv(out_csv, index=False, lineterminator="\n")
                streamed.add(first)
                first = None
            rows.table.to_csv(out_csv, index=False, lineterminator="\n", header=False, mode="a")
            streamed.add(rows)  # every later chunk as it comes: its table written, its stations summed, then dropped
            del rows
        out_csv_name = str(out_dir / f"{stem}_corrected.csv")
        if streamed is None:  # one chunk: its table, positions included, is the file
            res = summarise(model, first, field)
            res.table.to_csv(out_csv, index=False, lineterminator="\n")
            verdict = survey_verdict(res, model, bands, out_csv=out_csv_name, model_path=str(mpath),
                                     survey_path=survey_path, method=method, reference=reference)
        else:
            res = streamed.result(model, field)
            verdict = streamed.verdict(res, model, bands, out_csv=out_csv_name, model_path=str(mpath),
                                       survey_path=survey_path, method=method, reference=reference)
        meta = {"source": rec.source, "model": str(mpath), "model_kind": model.KIND,
                "method": method if method is not None else getattr(model, "selected", None),
                "model_data_hash": model.data_hash, "rows": n_rows,
                "chunks": n_chunks, "metrics": res.metrics, "qc": res.qc,
                "qc_bands": qc_bands, "reference": reference,
                "notices": notices + res.notices, "doubts": res.doubts,
                "units": {"angles": "deg", "B": "nT", "G": "g"},
                "trajectory": res.trajectory, "verdict": verdict.as_dict()}
        if streamed is not None and res.trajectory:
            meta["positions_file"] = f"{stem}_positions.csv"
        if rec.field is not None and field is not None and field.origin.startswith("the survey's"):
            meta.update({k: getattr(rec.field, k) for k in ("total_field_nT", "dip_deg", "declination_deg",
                                                             "gravity_g")})
        (stage / f"{stem}_corrected.meta.json").write_text(json_text(meta))
        write_record(stage)
    return meta


def report(meta: dict, out_dir: Path, stem: str) -> None:
    """The printed summary: metrics (or QC only), QC counts, notices, files."""
    m = meta["metrics"]
    if "reference_units" in (meta.get("doubts") or {}):  # no MAE above a verdict that says it means nothing
        print(f"corrected survey: {meta['rows']} stations; no MAE: the survey's reference angles look like radians "
              f"(see the verdict)")
    elif m:
        c = m["compensated"]
        raw = m.get("raw")
        print(f"corrected survey: {meta['rows']} stations, MAE {c['mae']:.4f} deg, RMSE {c['rmse']:.4f} deg, "
              f"R^2 {c['r2']:.4f}" + (f" (raw MAE {raw['mae']:.4f} deg)" if raw else ""))
    else:
        print(f"corrected survey: {meta['rows']} stations; no reference azimuth, QC only")
    ref = meta.get("reference")
    if ref:
        print(f"QC reference: |B| {ref['total_field_nT']:.0f} nT, dip {ref['dip_deg']:.2f} deg, |G| "
              f"{ref['gravity_g']:g} g, from {ref['origin']}")
    for stage, counts in (meta["qc"] or {}).items():
        print(f"QC {stage}: {counts['any']} of {counts['n']} stations flagged "
              f"(|G| {counts['g']}, |B| {counts['b']}, dip {counts['dip']})")
    for n in meta["notices"]:
        print(f"notice: {n}")
    print(f"wrote {out_dir / (stem + '_corrected.csv')} and {stem}_corrected.meta.json")
    from icgo.survey.verdict import from_dict

    print(from_dict(meta["verdict"]).text())
