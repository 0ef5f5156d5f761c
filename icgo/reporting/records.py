"""The run-record schema: the files of a study's run directory, shared by writers and readers.

``experiments.run`` writes a run directory (``icgo.studies.icgo_relm.outputs.write_run_files``,
with :func:`tag_table` and :func:`check_table`) and :class:`icgo.reporting.run_collection.Runs` reads
it back with :func:`read_run` and :func:`read_table`; both take every file name, column name and run-record key
from here, so a renamed column is renamed once.

A run directory holds (ICGO-RELM study):

* ``run.json``: the run record (:data:`RUN_KEYS`), written last;
* one CSV per table of :data:`TABLES`, each starting with the tag columns
  :data:`TAG_COLUMNS` (label, dataset, condition, seed);
* the fitted models (``<kind>.json`` + ``<kind>.npz``, :mod:`icgo.artifacts.format`).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from icgo.core.errors import RecordError

#: Version of this schema, written into every run record.
RECORDS_VERSION = 2

RUN_FILE = "run.json"
#: The record of an ``experiments.calibrate`` run directory (its ``recommendation`` names the model to apply).
CALIBRATION_FILE = "calibration.json"
#: Keys of a calibration run's ``recommendation``.
RECOMMENDATION_KEYS = ("model", "method", "criterion", "held_out_deg", "spread_deg", "clear_winner", "runner_up")
FAILED_FILE = "FAILED"
CONFIG_FILE = "config.yaml"

#: Columns that tag every row of every table with its run.
TAG_COLUMNS = ("label", "dataset", "condition", "seed")

#: Table name -> the columns it must have after the tag columns (extra columns allowed).
TABLES = {
    "metrics": ("method", "repeat", "split", "mae", "rmse", "r2", "r2_error"),
    "convergence": ("method", "repeat", "iteration", "evals", "best_fitness"),
    "predictions": ("method", "repeat", "row", "station", "split", "azimuth_true", "azimuth_raw", "azimuth_msa",
                    "error_msa", "predicted_error", "azimuth_compensated", "error_compensated"),
    "msa": ("repeat", "cost_V", "condition_number", "bias_x", "bias_y", "bias_z"),
    "coverage": ("method", "repeat", "fold", "level", "halfwidth_deg", "coverage", "n_test"),
}

#: Keys every run record has. A study's record also names the repeats it left out
#: (``excluded_repeats``: ``[{"repeat", "reason"}, ...]``, empty when none; older records lack it) and
#: ``repeat_ids`` the repeats its tables hold.
RUN_KEYS = ("records_version", "status", "label", "dataset", "condition", "description", "optimizer", "strategies",
            "seed", "n_repeats", "methods", "n_evals", "n_rows", "wall_time_s", "total_time_s", "models", "qc")

#: Columns of the study's printed / Markdown summary table.
SUMMARY_COLUMNS = ("method", "label", "n", "MAE (deg)", "RMSE (deg)", "R^2", "R^2 of error", "evaluations")


def tag_table(df: pd.DataFrame, tags: dict) -> pd.DataFrame:
    """``df`` with the tag columns (in :data:`TAG_COLUMNS` order) in front; ``df`` itself is unchanged.

    The table's columns are shared, not copied, and each tag column is a one-value categorical
    (one byte a row; written to CSV exactly as the plain value, an empty cell for None), so
    tagging a table of millions of rows (the study's predictions) costs no second copy of it.
    """
    out = df.copy(deep=False)
    n = len(df)
    for k in reversed(TAG_COLUMNS):
        v = tags[k]
        codes = np.full(n, -1 if v is None else 0, np.int8)
        out.insert(0, k, pd.Categorical.from_codes(codes, categories=pd.Index([] if v is None else [v], dtype=object)))
    return out


def check_table(name: str, df: pd.DataFrame, source: str = "<table>") -> pd.DataFrame:
    """Raise :class:`RecordError` unless ``df`` has the tag columns and the columns of ``TABLES[name]``."""
    need = TAG_COLUMNS + TABLES[name]
    missing = [c for c in need if c not in df.columns]
    if missing:
        raise RecordError(f"{source}: table {name!r} lacks column(s) {missing}")
    return df


def read_table(run_dir, name: str) -> pd.DataFrame:
    """Read and check one table of a run directory."""
    path = Path(run_dir) / f"{name}.csv"
    try:
        with open(path, "rb") as fh:  # every table is written whole, ending in a newline; a cut file does not
            fh.seek(0, 2)
            if fh.tell() and (fh.seek(-1, 2), fh.read(1))[1] != b"\n":
                raise RecordError(f"{path}: does not end with a newline (a truncated file?)")
        df = pd.read_csv(path)
    except (OSError, ValueError, pd.errors.ParserError) as e:
        raise RecordError(f"{path}: unreadable table ({type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''})") from None
    return check_table(name, df, str(path))


def read_run(run_dir) -> dict:
    """Read and check a run record; RecordError naming the file if it is not one."""
    path = Path(run_dir) / RUN_FILE
    try:
        run = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as e:
        raise RecordError(f"{path}: unreadable run record ({type(e).__name__})") from None
    if not isinstance(run, dict):
        raise RecordError(f"{path}: a run record must be a JSON object")
    missing = [k for k in RUN_KEYS if k not in run]
    if missing:
        raise RecordError(f"{path}: run record lacks {missing} (written by an older icgo? re-run the study)")
    return run


def recommended_model(run_dir) -> Path:
    """The model file a calibration run directory recommends (its record's ``recommendation.model``).

    Raises:
        RecordError: an unreadable record, or one without a single recommendation (a run over several
            recordings: the message lists their models).
    """
    path = Path(run_dir) / CALIBRATION_FILE
    try:
        run = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as e:
        raise RecordError(f"{path}: unreadable calibration record ({type(e).__name__})") from None
    rec = run.get("recommendation") if isinstance(run, dict) else None
    if isinstance(run, dict) and rec is None and isinstance(run.get("refused"), str):
        raise RecordError(f"{path}: no calibration recommended ({run['refused'][:300]}); to apply one anyway, name its "
                          f"file: model={Path(run_dir) / 'models'}/<calibration>.json")
    if not isinstance(rec, dict):
        several = run.get("recommendations") if isinstance(run, dict) else None
        names = ", ".join(str(r.get("model")) for r in several.values()) if isinstance(several, dict) else ""
        raise RecordError(f"{path}: no single recommendation" + (f" (one per recording: {names}; name one model file)"
                                                                  if names else ""))
    missing = [k for k in RECOMMENDATION_KEYS if k not in rec]
    model = rec.get("model")
    if missing or not isinstance(model, str) or Path(model).is_absolute() or ".." in Path(model).parts:
        raise RecordError(f"{path}: a recommendation needs {list(RECOMMENDATION_KEYS)} with a model file inside the "
                          f"run directory (missing {missing})")
    return Path(run_dir) / model
