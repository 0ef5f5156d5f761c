"""What one ICGO-RELM job writes and prints: the summary table, the excluded repeats' sentence, and every file of
its run directory (tables, ``summary.md`` with the verdict, the fitted models, the figure, ``run.json`` last)."""

from __future__ import annotations

import json
import time
from pathlib import Path

from icgo.core.environment import environment


def method_label(method: str) -> str:
    """The method's name in every output (:func:`icgo.studies.icgo_relm.names.method_name`)."""
    from icgo.studies.icgo_relm.names import method_name

    return method_name(method)


def summary_table(result, split: str = "test"):
    """Printed/Markdown summary: per method MAE, RMSE, R^2 (mean +/- std over repeats) and evaluations."""
    import numpy as np
    import pandas as pd

    from icgo.reporting.records import SUMMARY_COLUMNS

    s = result.summary.xs(split, level="split")
    evals = dict(zip(result.config.method_names(), np.asarray(result.n_evals).mean(axis=1)))
    rows = []
    for m in s.index:
        rows.append({"method": m, "label": method_label(m), "n": int(s.loc[m, "n"]),
                     "MAE (deg)": s.loc[m, "mae"], "RMSE (deg)": s.loc[m, "rmse"], "R^2": s.loc[m, "r2"],
                     "R^2 of error": s.loc[m, "r2_error"],
                     "evaluations": int(evals[m]) if m in evals else 0})
    return pd.DataFrame(rows, columns=list(SUMMARY_COLUMNS))


def excluded_line(result) -> str | None:
    """The sentence naming the repeats a study left out (:func:`icgo.studies.icgo_relm.prepare.excluded_sentence`), or
    None."""
    from icgo.studies.icgo_relm.prepare import excluded_sentence

    return excluded_sentence(result.excluded, len(result.config.ids()) + len(result.excluded))


def model_interval(model) -> float | None:
    """The half-width (deg) the saved compensation model carries for its selected method (the one apply prints), or
    None where it has none (NaN: no row was out of bag)."""
    import numpy as np

    hw = getattr(model, "interval_halfwidth", None)
    if hw is None or model.selected not in model.methods:
        return None
    v = float(np.asarray(hw)[model.methods.index(model.selected)])
    return v if np.isfinite(v) else None


def write_run_files(outdir: Path, result, info: dict, frame, meta, plot, *, config_yaml: str, search: str,
                    config_sha256: str, run_dir=None) -> dict:
    """Every file of a run into ``outdir`` (the staging directory), run.json last; ``run_dir``: where they go.

    The staged write (:class:`icgo.io.files.Output`) is the caller's: only when every file is complete is the
    previous content moved aside and the new files moved in, ``run.json`` last. File and column names come from
    :mod:`icgo.reporting.records`; the fitted models are saved with :meth:`icgo.artifacts.format.FittedModel.save`.

    Args:
        result: the study's result (:func:`icgo.studies.icgo_relm.study.run_study`). info: the run record's fields
            known before the study (label, dataset, condition, timings, total_time_s, ...).
        frame, meta: the study's data and metadata; with a reference field in ``meta``, the survey-QC counts
            before and after MSA (:func:`icgo.survey.apply.study_qc`) go into the summary and the run record.
        plot: optional ``path -> None`` writing the study figure (``study.png``).
        config_yaml: the resolved config (``config.yaml``). search: the summary's sentence on the search
            settings. config_sha256: the config's hash in the run record.
    Returns:
        The run.json dictionary.
    """
    import numpy as np

    from icgo.physics.qc import qc_sentence
    from icgo.reporting import records as run_records
    from icgo.studies.common.splits import describe as describe_split
    from icgo.survey.apply import study_qc
    from icgo.survey.verdict import study_verdict

    t0 = time.perf_counter()
    qc = None if frame is None else study_qc(frame[result.kept].reset_index(drop=True), meta, result.msa_model)

    outdir.mkdir(parents=True, exist_ok=True)
    (outdir / run_records.CONFIG_FILE).write_text(config_yaml)
    tags = {"label": info["label"], "dataset": info["dataset"], "condition": info["condition"],
            "seed": result.config.split.seed}
    for name, df in result.records.items():
        checked = run_records.check_table(name, run_records.tag_table(df, tags), name)
        checked.to_csv(outdir / f"{name}.csv", index=False, float_format="%.10g")
    table = summary_table(result)
    table.to_csv(outdir / "summary.csv", index=False)
    excluded = excluded_line(result)
    md = [f"# ICGO-RELM study: {info['dataset']}", "",
          f"{describe_split(result.config.split.protocol, result.config.split.train_fraction).capitalize()}; "
          f"{len(result.config.ids())} repeats, mean +/- std (sample std). {search}", "",
          table.drop(columns=["method"]).to_markdown(index=False), "",
          *([f"**{excluded}**", ""] if excluded else []),
          f"Wall time of the study: {result.wall_time_s:.1f} s (compile included); "
          f"whole job {info['total_time_s']:.1f} s.", "",
          f"Fitted models: `{result.model.KIND}` (method used by default: {result.model.selected}) and "
          f"`{result.msa_model.KIND}`."]
    if qc:
        md += ["", qc_sentence(qc)]
    verdict = study_verdict(result.metrics, result.coverage, selected=result.model.selected,
                            n_repeats=result.config.split.n_repeats, protocol=result.config.split.protocol, qc=qc,
                            trained=result.model.domain, run_dir=str(run_dir or outdir),
                            model_interval_deg=model_interval(result.model))
    md += ["", *verdict.markdown()]
    (outdir / "summary.md").write_text("\n".join(md) + "\n")
    if plot is not None:
        plot(outdir / "study.png")
    models = [result.model.save(outdir / result.model.KIND).name,
              result.msa_model.save(outdir / result.msa_model.KIND).name]
    methods = result.config.method_names()
    if "timings" in info:  # everything above, the run record's own few bytes aside
        info = {**info, "timings": {**info["timings"], "write_s": time.perf_counter() - t0}}
    run = {**info, "records_version": run_records.RECORDS_VERSION, "status": "ok", "seed": result.config.split.seed,
           "wall_time_s": result.wall_time_s, "methods": methods,
           "n_evals": {m: int(v) for m, v in zip(methods, np.asarray(result.n_evals)[:, 0])},
           "n_rows": int(result.kept.sum()), "n_repeats": result.config.split.n_repeats,
           "repeat_ids": list(result.config.ids()), "models": models, "qc": qc, "config_sha256": config_sha256,
           "excluded_repeats": [{"repeat": int(r), "reason": why} for r, why in result.excluded]}
    if result.tuning is not None:
        run["tuning"] = result.tuning
    run["verdict"] = verdict.as_dict()
    run["environment"] = environment()  # what the numbers were made with (a table's stamp names it)
    missing = [k for k in run_records.RUN_KEYS if k not in run]
    assert not missing, f"run record lacks {missing}"  # a writer bug, not a user error
    (outdir / run_records.RUN_FILE).write_text(json.dumps(run, indent=2, default=str) + "\n")
    return run


def print_summary(result, desc: str, run: dict, outdir: Path, t0: float) -> None:
    """The summary table, the excluded repeats, where the files are, the wall time and the verdict, on stdout.

    Args:
        desc: the data set's description. run: the run record (its ``verdict``). t0: ``time.perf_counter()`` at the
            job's start (seconds).
    """
    from icgo.survey.verdict import from_dict

    table = summary_table(result).drop(columns=["method"])
    print(f"\nICGO-RELM study on {desc}: test split, {len(result.config.ids())} repeats (mean +/- std)")
    print(table.to_markdown(index=False))
    excluded = excluded_line(result)
    if excluded:
        print(excluded)
    print(f"outputs: {outdir}")
    print(f"wall time: {time.perf_counter() - t0:.1f} s (study {result.wall_time_s:.1f} s incl. compile)")
    print(from_dict(run["verdict"]).text())
