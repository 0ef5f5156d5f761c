"""Runs tracked in MLflow: a run directory logged as an MLflow run, a sweep as a parent run of its jobs.

A door's job writes its run directory first (the record that counts); then :func:`log_run_dir` logs it into an
MLflow store: the typed config as params (dotted keys), the metrics (ICGO-RELM: per repeat as steps and their mean
per method and split; over worlds: each world's value, steps by world, and the pooled mean; the validation
objective of an Optuna sweep), the convergence curves as step metrics (mean best fitness over the members per
iteration) and the files (models, figures, tables) as artifacts. A sweep is a parent run
(:func:`start_parent`); each job's run names it (``mlflow.parentRunId``), so the UI nests the jobs under it.

The ``tracking`` setting (:func:`tracking_uri`): ``auto`` (default) logs to the local store :func:`default_uri`
(``mlruns/`` under the working directory: ``mlflow ui --backend-store-uri sqlite:///mlruns/mlflow.db``) where
MLflow is installed (``pip install icgo[tracking]``) and not otherwise; ``false`` turns it off; any other value is
a tracking URI (``sqlite:///path.db``, ``http://host:5000``). The environment variable :data:`ENV` gives the
setting wherever the config says ``auto`` or has no ``tracking`` key (a test suite sets ``ICGO_TRACKING=false``).

Tracking never fails a run: an MLflow error is logged as a warning (the run directory is already written).
MLflow is imported only when a run is logged.
"""

from __future__ import annotations

import importlib.util
import logging
import math
import os
from pathlib import Path

from icgo.core.errors import SettingError

log = logging.getLogger(__name__)

#: The environment variable with the ``tracking`` setting of doors whose config has none.
ENV = "ICGO_TRACKING"
#: The local store's folder (under the working directory) and its files.
STORE_DIR, DB_FILE, ARTIFACTS_DIR = "mlruns", "mlflow.db", "artifacts"
#: Tag naming the run directory an MLflow run was logged from, and the sweep directory of a parent run.
TAG_RUN_DIR, TAG_SWEEP_DIR = "icgo.run_dir", "icgo.sweep_dir"
#: The file in a sweep directory holding its parent run's id (jobs of any launcher read it).
PARENT_FILE = ".mlflow_parent_run"
#: The experiment tag that shows an experiment in MLflow's classic model-development view.
KIND_TAG, KIND = "mlflow.experimentKind", "custom_model_development"
#: Largest param value MLflow keeps (longer values are cut, marked with an ellipsis).
PARAM_CHARS = 6000
#: Files logged as artifacts (by suffix); Hydra's record is logged under ``.hydra``.
ARTIFACT_SUFFIXES = (".png", ".md", ".csv", ".json", ".npz", ".yaml", ".log", ".txt")


def installed() -> bool:
    """Whether MLflow can be imported (the ``tracking`` extra)."""
    return importlib.util.find_spec("mlflow") is not None


def default_uri(root: Path | None = None) -> str:
    """The local store: a SQLite database in ``<root>/mlruns/`` (``root`` default: the working directory)."""
    root = Path.cwd() if root is None else Path(root)
    return f"sqlite:///{(root / STORE_DIR / DB_FILE).resolve()}"


def tracking_uri(setting=None, root: Path | None = None) -> str | None:
    """The tracking URI of a ``tracking`` setting, or None for no tracking. ``auto`` (and None) take the
    environment's :data:`ENV` where it is set, else log to :func:`default_uri` where MLflow is installed.

    Raises:
        SettingError: a setting that is neither auto, a boolean nor a URI-like string (one line).
    """
    if setting is None or (isinstance(setting, str) and setting.strip().lower() == "auto"):
        setting = os.environ.get(ENV, "auto")  # auto: the environment's setting where it gives one
    if isinstance(setting, str) and setting.strip().lower() in ("false", "off", "no", "0", "null", "none", ""):
        return None
    if setting is False:
        return None
    if setting is True or (isinstance(setting, str) and setting.strip().lower() in ("auto", "true", "on")):
        if not installed():
            if setting is True or setting.strip().lower() in ("true", "on"):
                raise SettingError("tracking=true needs MLflow: pip install 'icgo[tracking]' (or tracking=false)")
            return None
        return default_uri(root)
    if not isinstance(setting, str) or ":" not in setting:
        raise SettingError(f"tracking must be auto, true, false or a tracking URI (sqlite:///mlflow.db, "
                           f"http://host:5000), got {setting!r}")
    if not installed():
        raise SettingError(f"tracking={setting} needs MLflow: pip install 'icgo[tracking]' (or tracking=false)")
    return setting.strip()


def flatten(mapping: dict, prefix: str = "") -> dict[str, str]:
    """``{"a": {"b": 1}}`` -> ``{"a.b": "1"}``: a nested config as MLflow params (values as text, cut at
    :data:`PARAM_CHARS`)."""
    out = {}
    for k, v in mapping.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict) and v:
            out.update(flatten(v, f"{key}."))
        else:
            text = str(v)
            out[key] = text if len(text) <= PARAM_CHARS else text[: PARAM_CHARS - 3] + "..."
    return out


def _client(uri: str):
    """An MLflow client on ``uri``; a local SQLite store's folder is created first."""
    from mlflow.tracking import MlflowClient

    if uri.startswith("sqlite:///"):
        Path(uri[len("sqlite:///"):]).parent.mkdir(parents=True, exist_ok=True)
    return MlflowClient(uri)


def _experiment_id(client, uri: str, name: str) -> str:
    """The id of experiment ``name``, created if absent (a local store keeps its artifacts beside the database)."""
    exp = client.get_experiment_by_name(name)
    if exp is not None:
        return exp.experiment_id
    location = None
    if uri.startswith("sqlite:///"):
        location = (Path(uri[len("sqlite:///"):]).parent / ARTIFACTS_DIR / name).resolve().as_uri()
    try:
        # the UI's classic view (runs, metrics, charts), not its GenAI overview
        return client.create_experiment(name, artifact_location=location, tags={KIND_TAG: KIND})
    except Exception:  # noqa: BLE001  (a sweep's other job created it meanwhile)
        exp = client.get_experiment_by_name(name)
        if exp is None:
            raise
        return exp.experiment_id


def run_metrics(run_dir: Path) -> list[tuple[str, float, int]]:
    """(name, value, step) of every metric a run directory holds (:mod:`icgo.studies.common.tracking_tables`)."""
    from icgo.studies.common.tracking_tables import directory_metrics

    return [(k, float(v), int(s)) for k, v, s in directory_metrics(Path(run_dir)) if math.isfinite(float(v))]


def log_run_dir(uri: str, run_dir: Path, *, experiment: str, params: dict, run_name: str | None = None,
                tags: dict | None = None, parent_run_id: str | None = None,
                extra_metrics: dict | None = None, files=None) -> str | None:
    """Log one run directory as an MLflow run (params, metrics, curves, artifacts); returns its run id, or None when
    MLflow failed (a warning: the run directory is the record).

    Args:
        uri: the tracking URI (:func:`tracking_uri`). run_dir: the written run directory. experiment: the MLflow
            experiment (one per door). params: the typed config as a nested mapping. run_name: shown in the UI.
            tags: further tags. parent_run_id: the sweep's run. extra_metrics: further scalars (e.g. the
            objective an Optuna sweep minimises). files: the artifacts, relative to ``run_dir`` (None: every file
            of it with a suffix of :data:`ARTIFACT_SUFFIXES`).
    """
    import time

    t0 = time.perf_counter()
    try:
        rid = _log(uri, Path(run_dir), experiment, params, run_name, tags or {}, parent_run_id, extra_metrics or {},
                   files)
        log.info("tracking: logged %s as MLflow run %s in %.1f s (%s)", run_dir, rid, time.perf_counter() - t0, uri)
        return rid
    except Exception as e:  # noqa: BLE001  (tracking never fails a run)
        log.warning("tracking: the run in %s was not logged to %s: %s: %s", run_dir, uri, type(e).__name__,
                    str(e).splitlines()[0] if str(e) else "")
        return None


def _log(uri, run_dir: Path, experiment, params, run_name, tags, parent_run_id, extra_metrics, files) -> str:
    import time

    from mlflow.entities import Metric, Param

    client = _client(uri)
    exp = _experiment_id(client, uri, experiment)
    all_tags = {TAG_RUN_DIR: str(run_dir.resolve()), **{k: str(v) for k, v in tags.items()}}
    if parent_run_id:
        all_tags["mlflow.parentRunId"] = parent_run_id
    run = client.create_run(exp, run_name=run_name, tags=all_tags)
    rid = run.info.run_id
    now = int(time.time() * 1000)
    metrics = [Metric(k, v, now, s) for k, v, s in run_metrics(run_dir)]
    metrics += [Metric(k, float(v), now, 0) for k, v in extra_metrics.items() if v is not None]
    flat = [Param(k, v) for k, v in flatten(params).items()]
    for i in range(0, len(flat), 100):  # MLflow's batch limits: 100 params, 1000 metrics
        client.log_batch(rid, params=flat[i:i + 100])
    for i in range(0, len(metrics), 1000):
        client.log_batch(rid, metrics=metrics[i:i + 1000])
    paths = sorted(run_dir.rglob("*")) if files is None else [run_dir / f for f in files]
    for path in paths:
        if path.is_file() and path.suffix in ARTIFACT_SUFFIXES and not path.name.startswith("."):
            rel = path.relative_to(run_dir).parent
            client.log_artifact(rid, str(path), None if str(rel) == "." else str(rel))
    client.set_terminated(rid, "FINISHED")
    return rid


def start_parent(uri: str, sweep_dir: Path, *, experiment: str, params: dict, run_name: str | None = None) -> \
        str | None:
    """Open a sweep's parent run and leave its id in ``sweep_dir/`` :data:`PARENT_FILE` for the jobs (None, with a
    warning, when MLflow failed)."""
    try:
        client = _client(uri)
        exp = _experiment_id(client, uri, experiment)
        run = client.create_run(exp, run_name=run_name or f"sweep {Path(sweep_dir).name}",
                                tags={TAG_SWEEP_DIR: str(Path(sweep_dir).resolve())})
        from mlflow.entities import Param

        flat = [Param(k, v) for k, v in flatten(params).items()]
        for i in range(0, len(flat), 100):
            client.log_batch(run.info.run_id, params=flat[i:i + 100])
        Path(sweep_dir).mkdir(parents=True, exist_ok=True)
        (Path(sweep_dir) / PARENT_FILE).write_text(run.info.run_id + "\n")
        return run.info.run_id
    except Exception as e:  # noqa: BLE001
        log.warning("tracking: no parent run for the sweep in %s: %s: %s", sweep_dir, type(e).__name__, e)
        return None


def parent_of(sweep_dir: Path) -> str | None:
    """The parent run id a sweep directory holds, or None."""
    try:
        return (Path(sweep_dir) / PARENT_FILE).read_text().strip() or None
    except OSError:
        return None


def end_parent(uri: str, sweep_dir: Path, objective: float | None = None) -> None:
    """Close a sweep's parent run: its report files as artifacts, the best objective of its jobs (when given)."""
    rid = parent_of(sweep_dir)
    if rid is None:
        return
    try:
        client = _client(uri)
        for name in ("sweep_results.md", "sweep_results.csv", "sweep_report.json", "optimization_results.yaml"):
            if (Path(sweep_dir) / name).is_file():
                client.log_artifact(rid, str(Path(sweep_dir) / name))
        if objective is not None and math.isfinite(objective):
            client.log_metric(rid, "best_objective", float(objective))
        client.set_terminated(rid, "FINISHED")
    except Exception as e:  # noqa: BLE001
        log.warning("tracking: the sweep's parent run %s was not closed: %s: %s", rid, type(e).__name__, e)
