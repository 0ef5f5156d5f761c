"""One calibration run of grouped shots, end to end; the front door ``experiments.calibrate`` reads the settings
and calls :func:`run` with plain values.

Reads the shots (:func:`icgo.studies.common.shots.read_shots`: a known layout's groups checked against the data, the
rolls found where no layout is known, or groups given), fits every method (ellipsoid, 12-parameter least
squares + axis, MISMA + axis, the regularised joint fit, least squares + axis + a RELM on the residual, the
peer package side by side), scores each in-sample, held out and inside each held-out split, checks each for
physical sanity and against the site, recommends one by a rule with its nested accuracy
(:func:`icgo.studies.calibration.select.recommend`), and writes into the run directory ``report.md``
(:mod:`icgo.studies.calibration.report`: the grouping, the rolls, the site, the scores, the recommendation),
``calibration.csv`` (every fit: score, sanity, site), ``calibration.json`` (the run's record, with
``recommendation``), one figure per recording and ``models/<recording>_<method>.json`` (the in-sample
calibrations; ``python -m experiments.apply model=<run dir> data=...`` applies the recommended one); for the
bundled devices also ``results/calibration_devices.{md,csv}``. Files are staged and moved into place only when
all are written; a used run directory is refused unless ``overwrite=true``.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from pathlib import Path

from icgo.core.errors import DataError, GroupingError, SettingError
from icgo.core.settings import first_line

#: Seed of the fits' PRNG key (split once per recording and split; MISMA is the only fit that draws from it).
SEED = 0


def check_groups_size(rec, src: str, max_groups: int) -> None:
    """DataError naming the file when a recording has no rolled group or more than ``max_groups``."""
    from icgo.physics.rolls import MIN_ROLLED_SHOTS

    counts = rec.frame["group"].value_counts() if "group" in rec.frame.columns else None
    rolled = 0 if counts is None else int((counts >= MIN_ROLLED_SHOTS).sum())
    if rolled == 0:
        raise DataError(f"{src}: no rolled group ({MIN_ROLLED_SHOTS} or more shots about one pointing direction, "
                        f"turned about it); calibration needs at least one")
    if rolled > max_groups:
        raise DataError(f"{src}: {rolled} rolled groups; calibrate takes at most max_groups={max_groups} (its time and "
                        "memory grow with them; docs/data.md): split the recording, or raise max_groups=")


def check_settings(data, max_shots, max_groups) -> None:
    """SettingError unless ``data`` is a non-empty path or ``"bundled"`` and ``max_shots``, ``max_groups`` (the
    largest recording taken, its shots and its rolled groups) are integers >= 1. Each group is one
    leave-one-group-out fold of every method, and the inner splits refit every method inside each held-out split:
    defaults in conf/calibrate.yaml, the memory measured at them in docs/data.md."""
    from icgo.core.settings import is_int

    if data is None or str(data) == "":
        raise SettingError("data= is required: a contract CSV with a group column, a circuitpython-mag-cal JSON, "
                           "or 'bundled'")
    if not isinstance(data, str):
        raise SettingError(f"data={data!r}: must be a path (a contract CSV or a circuitpython-mag-cal JSON) or "
                           f"'bundled'")
    for k, v in (("max_shots", max_shots), ("max_groups", max_groups)):
        if not (is_int(v) and v >= 1):
            raise SettingError(f"{k}={v!r}: must be an integer >= 1")


def load_recordings(data: str, settings: dict, columns: dict, max_shots: int, max_groups: int) -> dict:
    """name -> Recording with a checked ``group`` column (raises SettingError / DataError).

    Args:
        data: a contract CSV, a circuitpython-mag-cal JSON, or ``"bundled"`` (the 9 bundled devices), checked by
            :func:`check_settings` with ``max_shots`` and ``max_groups``.
        settings: ``mag_axes``, ``grav_axes``, ``groups`` as given (None: not given).
        columns: the column map (:func:`icgo.io.recording.column_map`).
    """
    from icgo.io import mag_cal_bundled
    from icgo.io.grouping import layout_groups
    from icgo.models.grouping import by_layout
    from icgo.studies.common.shots import read_shots

    if data == "bundled":
        if any(v is not None for v in settings.values()) or columns:
            raise SettingError("mag_axes / grav_axes / groups / columns apply to a file, not to data=bundled (the 9 "
                               "devices are in the circuitpython-mag-cal layout: rolls at shots 8-15 and 16-23)")
        out = {}
        for name in mag_cal_bundled.mag_cal_devices():
            rec = mag_cal_bundled.load_mag_cal_device(name)
            g = by_layout(rec.G, rec.B, rec.frame["station"].to_numpy(), rec.frame["group"].to_numpy(),
                          layout_groups("circuitpython-mag-cal", len(rec.frame)).describe(), name)
            out[name] = rec._replace(meta={**rec.meta, "grouping": g.record}, notices=list(g.notices) + rec.notices)
        return out
    rec = read_shots(data, columns=columns or None, max_shots=max_shots, **settings)
    check_groups_size(rec, data, max_groups)
    return {Path(data).stem: rec}


def sites_of(recordings: dict, site) -> dict:
    """name -> Site: the ``site.*`` settings, else the recording's own reference field (a contract CSV's metadata:
    total_field_nT and dip_deg, or its place and date), else None."""
    from icgo.io.site import Site

    out = {}
    for name, rec in recordings.items():
        f = rec.field
        out[name] = site if site is not None else (
            None if f is None else Site(f.dip_deg, f.total_field_nT, f"the recording's metadata ({f.origin})"))
    return out


def run(data: str, config, site, output, load: Callable[[], dict], write_record: Callable[[Path], None],
        results_dir: Path | None, t0: float) -> int:
    """Load, fit, score, check, recommend, and write the run directory (all or nothing: :class:`icgo.io.files.Output`,
    checked before anything is computed) and print the report, the run line and the verdict.

    Every recording that is read leaves its report, recommended or not: where no calibration can be recommended
    (no sound fit, none consistent with the site, or shots whose geometry the fits refuse) the files are written
    all the same, the one-line reason printed, and the status is
    :data:`icgo.survey.verdict.EXIT_NO_RECOMMENDATION`.

    Args:
        data: the ``data=`` setting. config: the :class:`icgo.studies.calibration.study.CalibrationConfig`.
        site: the Site given, or None. output: the run directory's unchecked :class:`icgo.io.files.Output`.
        load: reads the recordings (:func:`load_recordings` with the door's settings). write_record: writes the
        door's own record of its settings into the staging directory. results_dir: where ``data=bundled`` writes
        its tables (None for a file). t0: ``time.perf_counter()`` when the run started (seconds).

    Returns:
        the exit status: 0, or :data:`icgo.survey.verdict.EXIT_NO_RECOMMENDATION`.
    """
    import jax
    import pandas as pd

    import icgo  # noqa: F401  (float64)
    from icgo.io.files import Output, json_text
    from icgo.reporting.records import CALIBRATION_FILE
    from icgo.studies.calibration import study as calibration
    from icgo.studies.calibration.report import figure, protocol, record, report, report_refused, settings
    from icgo.studies.calibration.select import recommend
    from icgo.survey.verdict import EXIT_NO_RECOMMENDATION, calibrate_verdict

    out = output.path
    output.check()
    bundled = data == "bundled"
    if bundled:  # results/ checked now, not after the fits
        Output(results_dir, setting="results_dir", shared=True).check()
    try:
        recordings = load()
    except GroupingError as e:  # the shots were read, but no groups can be made of them: the report says why
        return refused_run(data, config, output, write_record, first_line(e), time.perf_counter() - t0)
    sites = sites_of(recordings, site)
    sites_given = {n: (s.dip_deg, s.field_nT) for n, s in sites.items() if s is not None}
    try:
        df, models = calibration.evaluate(recordings, config, jax.random.PRNGKey(SEED), check=False, sites=sites_given)
        recs = {name: recommend(df, name) for name in recordings}
    except calibration.GeometryError as e:  # nothing could be fitted: the report says why
        why = first_line(e)
        df, models = pd.DataFrame(columns=["recording", "split", "outer", "method", "score_deg", "degenerate"]), {}
        recs = {name: {"model": None, "method": None, "criterion": why, "held_out_deg": None, "spread_deg": None,
                       "clear_winner": False, "runner_up": None, "accuracy_deg": None, "accuracy_spread_deg": None,
                       "accuracy_splits": [], "refused": why,
                       "sentence": f"No calibration recommended: the fits refuse the shots: {why}."}
                for name in recordings}
    summ = calibration.summary(df) if len(df) else pd.DataFrame()
    models = carried(models, df, recordings, recs, sites)
    chosen = {name: (models[calibration.model_label(name, r["method"])] if r["method"] else None)
              for name, r in recs.items()}
    label = "the 9 bundled circuitpython-mag-cal devices" if bundled else data
    text = (report(df, summ, recordings, label, recs, chosen, sites, protocol(df, config, SEED) if bundled else None,
                   settings(config) if bundled else None)
            if len(df) else report_refused(recordings, label, recs, chosen, sites))
    run_record = record(data, config, recordings, recs, sites, time.perf_counter() - t0)
    outer = calibration.outer_rows(df) if len(df) else df
    one = chosen.get(next(iter(recordings))) if len(recordings) == 1 else None
    verdict = calibrate_verdict(recommendation=run_record.get("recommendation"), n_models=len(models),
                                accuracy=None if one is None else one.accuracy,
                                field_reference=None if one is None else one.field_reference,
                                run_dir=str(out), n_degenerate=int(outer["degenerate"].astype(bool).sum()),
                                n_fits=len(outer), refused=run_record.get("refused"),
                                held_out=outer[outer["split"] != "in-sample"].groupby("method")["score_deg"]
                                .mean().to_dict() if len(outer) else {})
    with output.staged(last=(CALIBRATION_FILE,)) as stage:  # the record last: a run directory with it is complete
        (stage / "models").mkdir()
        write_record(stage)
        (stage / "report.md").write_text(text + "\n" + "\n".join(verdict.markdown()) + "\n")
        df.to_csv(stage / "calibration.csv", index=False, float_format="%.6g")
        for name, rec in recordings.items():
            figure(rec, {m: models[calibration.model_label(name, m)] for m in calibration.METHODS
                         if calibration.model_label(name, m) in models}, stage / f"{name}.png")
        for label_, model in models.items():
            model.save(stage / "models" / label_)
        (stage / CALIBRATION_FILE).write_text(json_text(run_record))
    if bundled:
        from icgo.io.recording import atomic_write_texts

        results_dir.mkdir(parents=True, exist_ok=True)
        atomic_write_texts([(results_dir / "calibration_devices.md", text.replace(
                                "# Magnetometer calibration:", "# Magnetometer calibration (`python -m experiments."
                                "calibrate data=bundled`):")),
                            (results_dir / "calibration_devices.csv", df.to_csv(index=False, float_format="%.6g"))])
        print(f"wrote {results_dir / 'calibration_devices.md'}")
    print(text)
    print(f"run directory: {out} ({len(models)} calibrations in models/; {time.perf_counter() - t0:.1f} s)")
    print(verdict.text())
    refused = [f"for {n}: {r['refused']}" for n, r in recs.items() if r["refused"]]
    if refused and not bundled:
        print(f"error: no calibration recommended {refused[0]} (report: {out / 'report.md'})", file=sys.stderr)
        return EXIT_NO_RECOMMENDATION
    return 0


def carried(models: dict, df, recordings: dict, recs: dict, sites: dict) -> dict:
    """The in-sample calibrations as they are saved: each scaled to its recording's site where one is known
    (:func:`icgo.artifacts.calibration.in_earth_units`; relative otherwise) and carrying its expected accuracy
    (:func:`icgo.studies.calibration.select.model_accuracy`; the recommended one also the rule's nested score, named
    as such), the accuracy every later door prints for it."""
    from icgo.artifacts.calibration import in_earth_units, with_accuracy
    from icgo.studies.calibration.study import METHODS, model_label
    from icgo.studies.calibration.select import model_accuracy

    out = dict(models)
    for name, rec in recordings.items():
        r = recs.get(name) or {}
        for method in METHODS:
            label = model_label(name, method)
            if label not in out:
                continue
            acc = model_accuracy(df, name, method)
            if acc is not None and method == r.get("method") and r.get("accuracy_deg") is not None:
                acc.update({"nested_deg": r["accuracy_deg"], "nested_spread_deg": r.get("accuracy_spread_deg"),
                            "nested_what": "the recommendation rule's nested score (the rule applied inside each "
                                           "held-out split's training shots, its choice scored on the shots it did "
                                           "not see): what choosing by the rule delivers, not this method alone"})
            out[label] = with_accuracy(in_earth_units(out[label], rec.G, rec.B, sites.get(name)), acc)
    return out


def refused_run(data: str, config, output, write_record: Callable[[Path], None], reason: str, seconds: float) -> int:
    """The run directory of a recording whose shots were read but could not be grouped: ``report.md`` and
    ``calibration.json`` with the reason (``"refused"``), an empty ``calibration.csv``; one line on stderr; exit 4."""
    from icgo.core.settings import config_to_mapping
    from icgo.io.files import json_text
    from icgo.reporting.records import CALIBRATION_FILE
    from icgo.survey.verdict import EXIT_NO_RECOMMENDATION, calibrate_verdict

    verdict = calibrate_verdict(recommendation=None, n_models=0, n_degenerate=0, n_fits=0, run_dir=str(output.path),
                                refused=reason)
    text = (f"# Magnetometer calibration: {data}\n\n## Recommendation\n\n- No calibration recommended: the shots "
            f"were read, but no rolls could be made of them: {reason}\n\n" + "\n".join(verdict.markdown()) + "\n")
    record = {"kind": "calibration_run", "data": data, "config": config_to_mapping(config), "recordings": {},
              "recommendations": {}, "recommendation": None, "refused": reason, "wall_time_s": seconds}
    with output.staged(last=(CALIBRATION_FILE,)) as stage:
        write_record(stage)
        (stage / "report.md").write_text(text)
        (stage / "calibration.csv").write_text("recording,split,outer,method,score_deg,degenerate,reasons\n")
        (stage / CALIBRATION_FILE).write_text(json_text(record))
    print(text)
    print(verdict.text())
    print(f"error: no calibration recommended: {reason} (report: {output.path / 'report.md'})", file=sys.stderr)
    return EXIT_NO_RECOMMENDATION
