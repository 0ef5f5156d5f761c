"""Progress over an ICGO-RELM search's iterations, and the study run with it (the ``progress`` setting).

Two displays, fed the same way (``progress(done, total)`` on the host between chunks of iterations: nothing enters
the compiled programs, so the compilation cache keeps them):

* :class:`Progress`: a tqdm bar, on a terminal;
* :class:`ProgressLines`: off a terminal (nohup, CI, a SLURM log, a sweep's jobs), a line every ``every_s``
  seconds, ``search 40/100 it (40 %), 3.1 it/s, 16.9k evals/s, elapsed 0:00:13, ETA 0:00:19``, on stderr and in the
  run's log (the log files of the root logger: Hydra's ``<job>.log`` in the run directory). A chunk can outlast
  ``every_s`` (a search runs in about 10 chunks): a clock thread then writes the line between chunks, its count
  extrapolated from the measured rate and marked ``~`` (or, while the program compiles, the time spent compiling).

Both start after the first chunk, i.e. after compiling (or loading) the program, so their rate and ETA measure the
search alone; both hand the measured rate to the search's :class:`Estimate` when the search ends.

Before the search runs, its time is estimated (:func:`announce`): its planned fitness evaluations (members x
(initial + per-iteration evaluations x iterations), the optimizer's own count: :attr:`icgo.optim.base.Algorithm.evals`)
times the rate the last search of the same kind measured on this machine, kept in ``search_rates.json`` beside the
JAX compilation cache (keyed by backend, kernel, devices, precision, fitness mode, hidden units and population;
scaled by the training rows, since a fitness evaluation's work grows with them). The first search of a kind has no
estimate; its ETA comes from its progress lines.
"""

from __future__ import annotations

import json
import logging
import os
import sys
import threading
import time
from pathlib import Path
from typing import NamedTuple

from icgo.core.errors import SettingError
from icgo.studies.common.run_log import clock, count, to_log_files

log = logging.getLogger(__name__)

#: Seconds between two progress lines off a terminal under ``progress=auto`` (or ``true``).
EVERY_S = 30.0
#: Environment variable a launcher sets in its job processes (several jobs share one terminal): lines, never a bar,
#: each starting with its value (e.g. ``job 3``).
ENV_LINES = "ICGO_PROGRESS_LINES"


class _Measured:
    """The rate of the search after its first chunk: the iterations and seconds since then."""

    def __init__(self, desc: str, evals_per_iteration: float | None, on_rate=None):
        self.desc, self.per_it, self.on_rate = desc, evals_per_iteration, on_rate
        self.t_first = self.done_first = self.t_last = self.done_last = None
        self.t_start = time.perf_counter()

    def mark(self, done: int, now: float) -> bool:
        """Record ``done`` iterations at ``now`` (``time.perf_counter()``); True on the first call (the program
        was compiled or loaded)."""
        first = self.t_first is None
        if first:
            self.t_first, self.done_first = now, done
        self.t_last, self.done_last = now, done
        return first

    def iterations_per_s(self) -> float | None:
        """Iterations per second after the first chunk (None before a second chunk)."""
        if self.t_first is None or self.done_last <= self.done_first or self.t_last <= self.t_first:
            return None
        return (self.done_last - self.done_first) / (self.t_last - self.t_first)

    def finish(self) -> None:
        """Hand the measured evaluations per second to ``on_rate`` (when there is a rate to hand)."""
        rate = self.iterations_per_s()
        if rate is not None and self.per_it and self.on_rate is not None and self.t_last - self.t_first >= 0.5:
            self.on_rate(rate * self.per_it)


class Progress(_Measured):
    """A tqdm bar over the search's iterations, fed by ``run_study(progress=...)`` between chunks of iterations.

    The study runs its search in a few jitted chunks and calls this on the host after each
    (:func:`icgo.optim.sharded.run_members`); nothing enters the compiled programs, so the compilation
    cache keeps them. The bar starts after the first chunk, i.e. after
    compiling (or loading) the program, so its rate and ETA measure the search alone.
    """

    def __init__(self, desc: str, evals_per_iteration: float | None = None, on_rate=None):
        super().__init__(desc, evals_per_iteration, on_rate)
        self.bar = None
        print(f"{desc}: compiling or loading the search program, then the bar starts", file=sys.stderr)

    def __call__(self, done: int, total: int) -> None:
        self.mark(done, time.perf_counter())
        if self.bar is None:
            from tqdm.auto import tqdm

            self.bar = tqdm(total=total, initial=done, desc=self.desc, unit="it", mininterval=0.2,
                            dynamic_ncols=True, file=sys.stderr)
            return
        self.bar.update(done - self.bar.n)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
        self.finish()


class ProgressLines(_Measured):
    """Progress a log can hold: a line every ``every_s`` seconds (and the last chunk's), on stderr and in the log
    files of the root logger (:func:`to_log_files`). ``evals_per_iteration``: the search's fitness evaluations per
    iteration over all members (for the evaluation rate), or None. Between chunks a daemon clock thread writes the
    line that is due (:meth:`between_chunks`); :meth:`close` stops it."""

    def __init__(self, desc: str, every_s: float = EVERY_S, evals_per_iteration: float | None = None,
                 on_rate=None):
        job = os.environ.get(ENV_LINES, "").strip()
        super().__init__(f"{job}: {desc}" if job else desc, evals_per_iteration, on_rate)
        self.every_s = float(every_s)
        self.t_line, self.total = self.t_start, None
        self._lock, self._stop = threading.Lock(), threading.Event()
        self.emit(f"{self.desc}: compiling or loading the search program; progress every {self.every_s:g} s")
        self._clock = threading.Thread(target=self._tick, name="icgo-progress", daemon=True)
        self._clock.start()

    def emit(self, text: str) -> None:
        """One progress line on stderr and in the run's log."""
        print(text, file=sys.stderr, flush=True)
        to_log_files(text)

    def _tick(self) -> None:
        while not self._stop.wait(self.every_s / 4):
            with self._lock:
                now = time.perf_counter()
                if not self._stop.is_set() and now - self.t_line >= self.every_s:
                    self.t_line = now
                    self.emit(self.between_chunks(now))

    def between_chunks(self, now: float) -> str:
        """The line written between two chunks at ``now``: while compiling, the time spent; before a rate, the last
        chunk's count; then the count extrapolated at the measured rate (``~``, never past the total)."""
        elapsed = f"elapsed {clock(now - self.t_start)}"
        if self.t_first is None:
            return f"{self.desc}: compiling or loading the search program, {elapsed}"
        total, rate = self.total, self.iterations_per_s()
        if rate is None:
            return f"{self.desc}: {self.done_last}/{total} it at the last chunk, {elapsed}"
        done = min(total, self.done_last + rate * (now - self.t_last))
        evals = f", {count(rate * self.per_it)} evals/s" if self.per_it else ""
        return (f"{self.desc}: ~{done:.0f}/{total} it (~{100 * done / total:.0f} %), {rate:.3g} it/s{evals}, "
                f"{elapsed}, ETA ~{clock((total - done) / rate)}")

    def line(self, done: int, total: int, now: float) -> str:
        """``search 40/100 it (40 %), 3.1 it/s, 16.9k evals/s, elapsed 0:00:13, ETA 0:00:19``."""
        head = f"{self.desc}: {done}/{total} it ({100 * done / total:.0f} %)"
        elapsed = f"elapsed {clock(now - self.t_start)}"
        rate = self.iterations_per_s()
        if rate is None:
            return f"{head}, program ready after {clock(self.t_first - self.t_start)}, {elapsed}"
        evals = f", {count(rate * self.per_it)} evals/s" if self.per_it else ""
        return f"{head}, {rate:.3g} it/s{evals}, {elapsed}, ETA {clock((total - done) / rate)}"

    def __call__(self, done: int, total: int) -> None:
        with self._lock:
            now = time.perf_counter()
            self.total = total
            first = self.mark(done, now)
            if first or done >= total or now - self.t_line >= self.every_s:
                self.t_line = now
                self.emit(self.line(done, total, now))

    def close(self) -> None:
        self._stop.set()
        self._clock.join()
        self.finish()


def progress_enabled(setting, accelerator: bool = False) -> bool:
    """``progress`` option: ``auto`` (on a CPU: a bar on a terminal, else lines every :data:`EVERY_S` seconds; on an
    accelerator none: the host round trips between chunks would cost), true, false, or a number of seconds (lines
    that often, on a terminal too). Whether the search reports progress at all."""
    return progress_mode(setting, accelerator) is not None


def progress_mode(setting, accelerator: bool = False) -> tuple[str, float] | None:
    """(``"bar"`` or ``"lines"``, seconds between lines) for a ``progress`` setting, or None for no progress.

    Raises:
        SettingError: a setting that is none of auto, true, false or a positive number of seconds.
    """
    lines = bool(os.environ.get(ENV_LINES)) or not sys.stderr.isatty()
    if isinstance(setting, bool):
        return None if not setting else (("lines", EVERY_S) if lines else ("bar", EVERY_S))
    if setting in (None, "auto"):
        if accelerator:
            return None
        return ("lines", EVERY_S) if lines else ("bar", EVERY_S)
    if isinstance(setting, (int, float)) and setting > 0:
        return "lines", float(setting)
    raise SettingError(f"progress must be auto, true, false or a number of seconds > 0 between progress lines, "
                       f"got {setting!r}")


def make_progress(setting, desc: str, accelerator: bool = False, evals_per_iteration: float | None = None,
                  on_rate=None):
    """The progress display of a ``progress`` setting (:func:`progress_mode`), or None."""
    mode = progress_mode(setting, accelerator)
    if mode is None:
        return None
    if mode[0] == "bar":
        return Progress(desc, evals_per_iteration, on_rate)
    return ProgressLines(desc, mode[1], evals_per_iteration, on_rate)


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
    to_log_files(text)
    return est


def run_with_progress(frame, scfg, meta, progress, desc: str, target=None, timings: dict | None = None,
                      jax_cache_dir: str | None = None):
    """``icgo.studies.icgo_relm.study.run_study`` with progress over the optimizer's iterations (:func:`make_progress`).

    Prints the execution plan (``search: ...``) and the search's estimated time
    (:func:`announce`); without an optimizer (plain RELM), or on an accelerator under
    ``progress=auto``, there is no progress display. ``progress``: the ``progress`` setting. ``timings``: see
    ``run_study``. ``jax_cache_dir``: where the measured rates are kept (None: no estimate).
    """
    from icgo.core.execution import is_accelerator
    from icgo.studies.icgo_relm import study

    plan = scfg.execution()
    print(f"search: {plan.why}")  # information, on stdout: stderr is for the one error or interruption line
    if scfg.optimizer is None:
        return study.run_study(frame, scfg, meta, target=target, timings=timings)
    est = announce(scfg, plan, len(scfg.ids()), len(frame), jax_cache_dir)
    bar = make_progress(progress, desc, is_accelerator(plan.backend), est.evals_per_iteration, est.record)
    if bar is None:
        return study.run_study(frame, scfg, meta, target=target, timings=timings)
    try:
        return study.run_study(frame, scfg, meta, target=target, timings=timings, progress=bar)
    finally:
        bar.close()
