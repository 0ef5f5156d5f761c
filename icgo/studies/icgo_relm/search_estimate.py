"""A search's time estimated before it runs: its planned fitness evaluations times the rate measured here before.

The plan fixes the evaluations (members x (initial + per-iteration evaluations x iterations), the optimizer's own
count: :attr:`icgo.optim.base.Algorithm.evals`); the rate is the one the last search of the same kind measured on
this machine (evaluations per second after its first chunk, :mod:`icgo.studies.icgo_relm.progress`), kept in
``search_rates.json`` beside the JAX compilation cache (keyed by backend, kernel, devices, precision, fitness mode,
hidden units and population; scaled by the training rows, since a fitness evaluation's work grows with them).
The first search of a kind has no estimate; its ETA comes from its progress lines.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import NamedTuple

log = logging.getLogger(__name__)

#: The rates' file, beside the directory of the JAX compilation cache.
RATES_FILE = "search_rates.json"


class Estimate(NamedTuple):
    """A search's plan: ``evaluations`` in all, ``evals_per_iteration`` over every member, the rate it is estimated
    at (evaluations per second, or None), its seconds (or None), the store and key the measured rate is kept
    under and the training rows it is scaled by."""

    evaluations: int
    evals_per_iteration: float
    rate: float | None
    seconds: float | None
    store: Path | None
    key: str
    rows: int

    def record(self, evals_per_s: float) -> None:
        """Keep a measured rate for the next estimate of this kind of search (scaled to one training row)."""
        if self.store is not None and evals_per_s > 0:
            save_rate(self.store, self.key, evals_per_s * max(self.rows, 1))


def planned_evaluations(scfg, members: int) -> tuple[int, float]:
    """(evaluations in all, evaluations per iteration over all members) of a search of ``members`` members
    (methods x cells) under :class:`icgo.studies.icgo_relm.config.StudyConfig` ``scfg``."""
    from icgo.optim import get
    from icgo.optim.base import resolve_iterations

    alg = get(scfg.optimizer)
    config = alg.config_cls() if scfg.optimizer_config is None else scfg.optimizer_config
    initial, per_iteration = alg.evals(scfg.budget.pop_size, config)
    n_iter = resolve_iterations(alg, scfg.budget.pop_size, scfg.budget.iterations, scfg.budget.max_evals, config)
    return int(members * (initial + per_iteration * n_iter)), float(members * per_iteration)


def rates_path(jax_cache_dir: str | None) -> Path | None:
    """The rates' file beside ``jax_cache_dir`` (None without a cache directory)."""
    return None if not jax_cache_dir else Path(jax_cache_dir).expanduser().parent / RATES_FILE


def load_rates(path: Path | None) -> dict:
    """The stored rates (an unreadable file is no rates: an estimate is never worth an error)."""
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError, AttributeError):
        return {}
    return data if isinstance(data, dict) else {}


def save_rate(path: Path, key: str, row_evals_per_s: float) -> None:
    """Store one rate (training-row evaluations per second), replacing the file atomically; failures are logged."""
    rates = load_rates(path)
    rates[key] = float(row_evals_per_s)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp.write_text(json.dumps(rates, indent=1, sort_keys=True) + "\n")
        os.replace(tmp, path)
    except OSError as e:
        tmp.unlink(missing_ok=True)
        log.warning("search rate not kept in %s: %s", path, e.strerror)


def rate_key(scfg, plan) -> str:
    """The kind of search a rate holds for: backend, kernel, devices, precision, fitness mode, hidden units,
    population."""
    return (f"{plan.backend}/{plan.kernel}/{plan.devices}dev/{scfg.precision}/{scfg.fitness.mode}/"
            f"L{scfg.model.hidden}/P{scfg.budget.pop_size}")


def estimate(scfg, plan, cells: int, rows: int, jax_cache_dir: str | None) -> Estimate:
    """The :class:`Estimate` of a search of ``cells`` cells (repeats, or worlds x repeats) on ``rows`` data rows
    (the training rows are ``scfg.split.train_fraction`` of them)."""
    members = len(scfg.method_names()) * int(cells)
    total, per_it = planned_evaluations(scfg, members)
    train = max(1, int(round(rows * scfg.split.train_fraction)))
    store, key = rates_path(jax_cache_dir), rate_key(scfg, plan)
    stored = load_rates(store).get(key)
    rate = float(stored) / train if isinstance(stored, (int, float)) and stored > 0 else None
    return Estimate(total, per_it, rate, None if rate is None else total / rate, store, key, train)


def sentence(est: Estimate) -> str:
    """``search plan: 601,500 fitness evaluations; at 16.9k evals/s (measured here before): about 0:00:36``."""
    from icgo.studies.common.run_log import clock, count

    head = f"search plan: {est.evaluations:,} fitness evaluations"
    if est.seconds is None:
        return f"{head}; no rate measured here yet for this kind of search ({est.key}): the progress gives the ETA"
    return (f"{head}; at {count(est.rate)} evals/s (measured here before, {est.key}): about {clock(est.seconds)} "
            f"of search after the program is compiled or loaded")


def announce(scfg, plan, cells: int, rows: int, jax_cache_dir: str | None) -> Estimate:
    """:func:`estimate`, printed (stdout, with the plan line) and logged."""
    est = estimate(scfg, plan, cells, rows, jax_cache_dir)
    text = sentence(est)
    print(text)
    from icgo.studies.common.run_log import to_log_files

    to_log_files(text)
    return est
