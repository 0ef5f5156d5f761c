"""ICGO-RELM studies over independent simulated worlds, in one sharded search.

A *world* is one independent simulated data set: its own data seed (the instrument's noise and spikes:
:func:`icgo.datasets.casing_stations.lab_casing`), hence its own 3-sigma filter, multi-station analysis, splits and
search keys (``world_key(study seed, data seed)``). A claim about the methods is made over worlds, never from
one draw (DESIGN.md, Batching).

:func:`run_worlds` stages every world on its own (:func:`icgo.studies.icgo_relm.study.stage`: filter, split, MSA,
features, failed repeats left out), runs the search of every (world, repeat) cell and every method as one program
sharded over the devices (:func:`icgo.studies.icgo_relm.search.search_cells`), and scores each world on its own
(:func:`icgo.studies.icgo_relm.study.finish`). Every world's rows are padded (weight-0 rows) to one shape, so every
world runs the same compiled programs and a world's numbers do not depend on the other worlds: world k of a
worlds run is bitwise world k run alone through :func:`run_worlds` on a CPU in the same environment (tested), as a
repeat of a batch is the repeat alone. Bitwise holds within one environment only (:mod:`icgo.core.environment`:
the same Python, JAX/jaxlib, numpy, scipy, CPU or GPU and device count); in another, a one-ulp difference sends a
chaotic search down another path, so rows differ and the pooled claims over worlds are what holds
(docs/relm_study.md, "Worlds").

By default a world varies only the noise draw of one simulated instrument; with ``lab_casing``'s
``instrument="family"`` (``dataset.kwargs.instrument=family``, the ``*_instruments`` presets) each world also draws
its instrument from stated ranges (:mod:`icgo.datasets.instrument_family`).

The worlds reported exclude every data seed any choice was made on (:data:`DEVELOPMENT_SEEDS`); the worlds
presets start at :data:`FIRST_REPORTED_SEED`.
"""

from __future__ import annotations

import time
from typing import NamedTuple, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from icgo.reporting.choices import LAB_CASING_DEVELOPMENT_SEEDS
from icgo.studies.icgo_relm.worlds.stats import WORLD
from icgo.studies.icgo_relm import study as _study
from icgo.studies.common import timing
from icgo.studies.icgo_relm.config import StudyConfig
from icgo.studies.icgo_relm.prepare import filtered
from icgo.studies.icgo_relm.search import execution_record, plan_devices, search, search_aux, search_cells

#: ``lab_casing`` data seeds that choices were made on (never reported as worlds; docs/relm_study.md, "Worlds"):
#: 0: every one-draw result, the data set's design (docs/datasets.md, measured on seed 0), the sweeps and the
#: Fig. 9 ablation that were read before the defaults were kept, the noise floor; 1: the ridge lambda
#: (docs/relm_study.md) and the reliability checks; 1-5: the interval-coverage check (docs/qc.md) and the
#: transfer target's noise seed; 7: the documented apply example; 0-11: the spike rate and filter, matched to the
#: paper's 582 kept rows on these seeds (docs/datasets.md).
DEVELOPMENT_SEEDS = LAB_CASING_DEVELOPMENT_SEEDS
#: The first data seed of the reported worlds (``conf/experiment/*_worlds.yaml``: ``dataset.seed``).
FIRST_REPORTED_SEED = 100


class World(NamedTuple):
    """One simulated data set: its data seed, its data-contract frame and metadata."""

    seed: int
    frame: pd.DataFrame
    meta: dict | None = None


class WorldsResult(NamedTuple):
    """A study over worlds.

    Attributes:
        seeds: the worlds' data seeds, in order.
        results: one :class:`icgo.studies.icgo_relm.result.StudyResult` per world: what that world run alone with
            :func:`world_key` gives.
        config: the StudyConfig (every world's repeats; a world's own kept repeats are in its result's config).
        wall_time_s: wall time of the whole study (stage, search, score, tables), s.
    """

    seeds: tuple
    results: tuple
    config: StudyConfig
    wall_time_s: float

    def table(self, name: str) -> pd.DataFrame:
        """A table of every world (``metrics``, ``convergence``, ``msa``, ``coverage``, ``predictions``) with a
        :data:`icgo.studies.icgo_relm.worlds.stats.WORLD` column (the data seed) first."""
        parts = []
        for seed, res in zip(self.seeds, self.results):
            df = res.records[name]
            parts.append(df.assign(**{WORLD: seed})[[WORLD, *df.columns]])
        return pd.concat(parts, ignore_index=True)

    @property
    def excluded(self) -> list[tuple[int, int, str]]:
        """(world, repeat, reason) of every repeat left out because its MSA failed."""
        return [(seed, rid, why) for seed, res in zip(self.seeds, self.results) for rid, why in res.excluded]

    @property
    def development(self) -> list[int]:
        """The worlds' seeds that are :data:`DEVELOPMENT_SEEDS` (a report must say so)."""
        return [s for s in self.seeds if s in DEVELOPMENT_SEEDS]


def world_key(study_seed: int, data_seed: int):
    """The PRNG key of a world's study: ``fold_in(PRNGKey(study seed), data seed)`` (its repeats fold in their ids)."""
    return jax.random.fold_in(jax.random.PRNGKey(int(study_seed)), int(data_seed))


def world_seeds(first: int, n: int) -> tuple:
    """The data seeds of ``n`` worlds from ``first``: ``first, first + 1, ...``."""
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise ValueError(f"worlds: need an integer number of worlds >= 1, got {n!r}")
    return tuple(range(int(first), int(first) + int(n)))


def simulate(name: str, seeds: Sequence[int], **kwargs) -> list[World]:
    """The worlds of a simulated data set (``name`` in :data:`icgo.datasets.registry.DATASETS`), one per data seed.

    The noise-free stations are one compiled program (the same for every seed); each world draws its noise.
    """
    from icgo.datasets.registry import DATASETS

    fn = DATASETS.get(name)
    if fn is None:
        raise ValueError(f"worlds: icgo.datasets.registry.DATASETS has no data set {name!r}")
    out = []
    for s in seeds:
        d = fn(int(s), **kwargs)
        out.append(World(int(s), d.frame, dict(d.meta)))
    return out


#: Rows and training rows of a worlds run are padded up to multiples of these (weight-0 rows), so that worlds of
#: one data set share every program whatever their filters kept, and a world's numbers do not depend on the others.
ROW_QUANTUM, TRAIN_QUANTUM = 64, 16


def capacity(n: int, quantum: int) -> int:
    """``n`` rounded up to a multiple of ``quantum``."""
    return -(-int(n) // quantum) * quantum


def run_worlds(worlds: Sequence[World], config: StudyConfig | None = None, *, timings: dict | None = None,
               progress=None) -> WorldsResult:
    """An ICGO-RELM study on every world, the searches of all of them in one sharded program.

    Every world is staged on its own (filter, split, MSA, features: :func:`icgo.studies.icgo_relm.study.stage`), its
    rows padded with weight-0 rows to the worlds' largest row count rounded up to :data:`ROW_QUANTUM`, so that
    every world runs the same compiled programs; the search reads every member's training rows padded likewise
    (:data:`TRAIN_QUANTUM`). A world's numbers then depend only on its own data and key (and on these two
    quanta, not on the other worlds): world k of a worlds run is bitwise world k of any other worlds run, or
    alone (:func:`run_worlds` of one world); against the one-data-set study of the same seed and key
    (:func:`icgo.studies.icgo_relm.study.run`, unpadded) its fitness agrees within the kernel's tolerance.

    Args:
        worlds: the :class:`World` s (distinct data seeds).
        config: the StudyConfig (every world; ``protocol="transfer"`` is refused: it needs a target per world).
        timings: a dict to fill as :func:`icgo.studies.icgo_relm.study.run_study` does (stages summed over worlds;
            ``execution``: the plan of the whole search; ``capacity``: the padded (rows, training rows)).
        progress: ``progress(done, total)`` over the search's iterations.
    Returns:
        :class:`WorldsResult`.
    """
    cfg = StudyConfig() if config is None else config
    seeds = [int(w.seed) for w in worlds]
    if not seeds:
        raise ValueError("worlds: no world given")
    if len(set(seeds)) != len(seeds):
        raise ValueError(f"worlds: data seeds must be distinct, got {seeds}")
    if cfg.split.protocol == "transfer":
        raise ValueError("worlds: protocol 'transfer' needs a second instrument per world; run it one world at a time")
    t0 = time.perf_counter()
    stages = timing.Stages()
    rows = capacity(max(int(filtered(w.frame, cfg)[-1].sum()) for w in worlds), ROW_QUANTUM)
    staged = [_study.stage(w.frame, cfg, w.meta, world_key(cfg.split.seed, w.seed), None, stages, rows) for w in worlds]
    train = capacity(max(int(np.asarray(st.prep.train).sum(axis=1).max()) for st in staged), TRAIN_QUANTUM)
    plan = cfg.execution(cells=sum(len(st.mem.repeat) for st in staged))
    with stages("search"):
        if cfg.optimizer is None:
            found = [search(st.cfg, st.prep) for st in staged]
        else:
            found = _search_worlds(cfg, staged, plan, train, progress)
    results = tuple(_study.finish(st, *f, t0, stages) for st, f in zip(staged, found))
    if timings is not None:
        timings.update(stages.times, execution=execution_record(cfg, plan), capacity=[rows, train])
    return WorldsResult(tuple(seeds), results, cfg, time.perf_counter() - t0)


def _search_worlds(cfg, staged, plan, train: int, progress):
    """Every world's cells x methods as one sharded program: [(thetas (S, R_w, D), curves (S, R_w, T),
    evaluations (S, R_w, T)) per world]."""
    auxs = [search_aux(cfg, st.prep, plan.kernel, train) for st in staged]
    keys = np.concatenate([np.asarray(st.prep.key) for st in staged])
    aux = jax.tree_util.tree_map(lambda *xs: np.concatenate([np.asarray(x) for x in xs]), *auxs)
    found = search_cells(cfg, keys, aux, None, progress, plan_devices(plan))
    out, start = [], 0
    for st in staged:
        n = st.prep.key.shape[0]
        out.append(tuple(jnp.asarray(np.asarray(x)[:, start:start + n]) for x in found))
        start += n
    return out
