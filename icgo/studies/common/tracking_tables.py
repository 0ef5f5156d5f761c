"""The metrics a run directory holds, as (name, value, step) for MLflow (:mod:`icgo.studies.common.tracking`).

ICGO-RELM (``experiments.run``): ``metrics.csv`` per repeat (``<split>/<method>/<metric>``, step = repeat; a worlds
run's step = world x 1000 + repeat) and their mean over repeats (``.../<metric>_mean``); over worlds
(``worlds.csv``): each world's value (``world/<method>/<metric>``, step = its data seed) and the mean over worlds
(``pooled/<method>/<metric>``); ``convergence.csv``: the mean best training fitness per iteration
(``curve/<method>/best_fitness``, step = iteration); ``run.json``: the wall times (``time/...``). Any door: the
numbers of its ``run.json`` top level and ``timings``; ``experiments.apply``: a corrected survey's scores
(``survey/<name>/compensated/mae``, ...). Names use only characters MLflow accepts.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pandas as pd

#: The metric columns of an ICGO-RELM metrics table logged per repeat.
VALUES = ("mae", "rmse", "r2", "r2_error")


def name(*parts) -> str:
    """An MLflow metric name from parts (characters other than letters, digits, ``_-. /`` become ``_``)."""
    return "/".join(re.sub(r"[^A-Za-z0-9_\-. ]", "_", str(p)) for p in parts)


def _read(path: Path) -> pd.DataFrame | None:
    try:
        return pd.read_csv(path) if path.is_file() else None
    except (OSError, ValueError):
        return None


def relm_metrics(df: pd.DataFrame) -> list[tuple[str, float, int]]:
    """Per repeat and mean over repeats of each (split, method) of an ICGO-RELM metrics table."""
    out = []
    values = [v for v in VALUES if v in df.columns]
    for (split, method), g in df.groupby(["split", "method"], sort=True):
        for _, row in g.iterrows():
            step = int(row["repeat"]) + (1000 * int(row["world"]) if "world" in g.columns else 0)
            out += [(name(split, method, v), float(row[v]), step) for v in values]
        out += [(name(split, method, f"{v}_mean"), float(g[v].mean()), 0) for v in values]
    return out


def world_metrics(df: pd.DataFrame) -> list[tuple[str, float, int]]:
    """Each world's value (step: its data seed) and the mean over worlds of each method of ``worlds.csv``."""
    out = []
    values = [v for v in VALUES if v in df.columns]
    for method, g in df.groupby("method", sort=True):
        for _, row in g.iterrows():
            out += [(name("world", method, v), float(row[v]), int(row["world"])) for v in values]
        out += [(name("pooled", method, v), float(g[v].mean()), 0) for v in values]
    return out


def curve_metrics(df: pd.DataFrame) -> list[tuple[str, float, int]]:
    """The mean best training fitness over members per iteration of each method of ``convergence.csv``."""
    g = df.groupby(["method", "iteration"], sort=True)["best_fitness"].mean()
    return [(name("curve", method, "best_fitness"), float(v), int(it)) for (method, it), v in g.items()]


def record_metrics(record: dict) -> list[tuple[str, float, int]]:
    """The numbers at the top level of a run record and in its ``timings``."""
    out = [(name("time", k), float(v), 0) for k, v in (record.get("timings") or {}).items()
           if isinstance(v, (int, float)) and not isinstance(v, bool)]
    out += [(name("run", k), float(v), 0) for k, v in record.items()
            if isinstance(v, (int, float)) and not isinstance(v, bool) and k not in ("pid", "seed", "cpu_count")]
    return out


def survey_metrics(meta: dict, survey: str) -> list[tuple[str, float, int]]:
    """A corrected survey's scores (``experiments.apply``'s ``<survey>_corrected.meta.json``: ``metrics`` per kind,
    e.g. ``compensated`` and ``raw``, when the survey has a reference azimuth) as ``survey/<survey>/<kind>/<metric>``."""
    out = []
    for kind, values in (meta.get("metrics") or {}).items():
        if isinstance(values, dict):
            out += [(name("survey", survey, kind, k), float(v), 0) for k, v in values.items()
                    if isinstance(v, (int, float)) and not isinstance(v, bool)]
    return out


def directory_metrics(run_dir: Path) -> list[tuple[str, float, int]]:
    """Every metric of a run directory (the tables this module knows, where present)."""
    out = []
    metrics = _read(run_dir / "metrics.csv")
    if metrics is not None and {"split", "method", "repeat"} <= set(metrics.columns):
        out += relm_metrics(metrics)
    worlds = _read(run_dir / "worlds.csv")
    if worlds is not None and {"world", "method"} <= set(worlds.columns):
        out += world_metrics(worlds)
    curves = _read(run_dir / "convergence.csv")
    if curves is not None and {"method", "iteration", "best_fitness"} <= set(curves.columns):
        out += curve_metrics(curves)
    try:
        record = json.loads((run_dir / "run.json").read_text())
    except (OSError, ValueError):
        record = None
    if isinstance(record, dict):
        out += record_metrics(record)
    for path in sorted(run_dir.glob("*.meta.json")):
        try:
            meta = json.loads(path.read_text())
        except (OSError, ValueError):
            continue
        if isinstance(meta, dict) and isinstance(meta.get("metrics"), dict):
            out += survey_metrics(meta, path.name[: -len(".meta.json")])
    return out


def objective(run_dir: Path) -> float | None:
    """The objective a hyperparameter search (Optuna) minimises for an ICGO-RELM run directory: the search's own
    fitness at its end (the best RMSE, deg, on the rows the fitness mode scores: the training rows under
    ``fitness=train``, held-out validation rows of the training part under ``fitness=validation`` or ``kfold``),
    averaged over every method, repeat and world of ``convergence.csv``; never the test split. None when the
    directory has no convergence table (plain RELM without a search has its one-iteration curve)."""
    curves = _read(Path(run_dir) / "convergence.csv")
    if curves is None or not {"method", "iteration", "best_fitness"} <= set(curves.columns) or curves.empty:
        return None
    keys = [k for k in ("world", "method", "repeat", "fold") if k in curves.columns]
    last = curves.sort_values("iteration").groupby(keys, sort=True)["best_fitness"].last()
    return float(last.mean())
