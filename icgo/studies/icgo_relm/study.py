"""The ICGO-RELM study (ICGO paper sections 3.1-3.4), plain Python, no Hydra.

Pipeline, per repeat (one PRNG key each, ``fold_in(PRNGKey(seed), repeat_id)``):

1. 3-sigma filter (host-side, once for the data set; :func:`icgo.studies.icgo_relm.prepare.sigma_filter`);
2. the split (``protocol``, :mod:`icgo.studies.common.splits`): the paper's random 7:3 split
   (a permutation of the rows, the first ``round(0.7 N)`` are training rows)
   or a generalisation protocol (whole azimuths or well conditions held out,
   or a second instrument build as the test set). Each fitted model is a
   *member* with 0/1 row masks, so shapes stay fixed across members;
3. multi-station analysis on the training rows only (:mod:`icgo.models.msa`);
4. target = azimuth error left after MSA, ``wrap(A_msa - A_true)`` (deg);
5. model: RELM on the six raw sensor values standardised with training
   statistics; hidden parameters drawn at random (plain RELM) or searched by an
   optimizer of :mod:`icgo.optim` on a training-only fitness (:mod:`icgo.models.relm`);
6. output weights refit on all training rows; compensated azimuth
   ``A_msa - predicted error`` scored on the test rows (:mod:`icgo.physics.metrics`).

Test rows never steer anything: MSA, standardisation, fitness and output
weights see them only with zero weight. Stages 2-6 run as three jitted calls:
the preparation (:func:`icgo.studies.icgo_relm.prepare.prepare`, mapped over repeats: split, MSA, features), a
host-side MSA observability check, the search (:mod:`icgo.studies.icgo_relm.search`: the optimizer's runner
:func:`icgo.optim.sharded.run_grid`, one program over repeats and CGO strategies, sharded over the devices), then
:func:`icgo.studies.icgo_relm.result.score_all` (refit vmapped over strategies and mapped over repeats; predictions by
:func:`icgo.models.compensation.predict_methods`, the forward pass the saved model
applies to the same params; metrics); the tables and fitted models: :mod:`icgo.studies.icgo_relm.result`.
Repeat k of a batched run equals the same repeat run alone (``repeat_ids``).

Fold protocols fit one member per (repeat, fold); a repeat's metrics pool its
folds' test rows (each row is held out by exactly one fold), so every protocol
gives one number per method and repeat.

Entry point: :func:`run_study` ``(frame, StudyConfig) -> StudyResult``; the settings are
:class:`icgo.studies.icgo_relm.config.StudyConfig`.
"""

from __future__ import annotations

import time
from typing import Any, NamedTuple

import jax
import numpy as np
import pandas as pd

from icgo.studies.common import timing
from icgo.studies.common import splits as _splits
from icgo.studies.icgo_relm.config import StudyConfig
from icgo.studies.icgo_relm.prepare import (Prepared, exclude_failed_repeats, filtered, pad_rows, prepare,
                                            reference_field, rows_per_fit)
from icgo.studies.icgo_relm.result import StudyResult, collect, score_all
from icgo.studies.icgo_relm.search import check_search, execution_record, plan_devices, search, tune
from icgo.studies.common.study import Study


class SurveyData(NamedTuple):
    """The ICGO-RELM study's data: a data-contract frame and its metadata.

    Attributes:
        frame: DataFrame with gx, gy, gz (g), bx, by, bz (nT), azimuth_deg (deg);
            ``condition`` for ``protocol="leave_condition_out"``.
        meta: metadata dict (``total_field_nT``, ``dip_deg`` for msa.reference="known") or None.
        target: ``protocol="transfer"`` only: the second instrument's survey (same
            columns; :func:`icgo.studies.common.splits.transfer_survey` simulates one), every row a test row.
    """

    frame: pd.DataFrame
    meta: dict | None = None
    target: pd.DataFrame | None = None


def run(data: SurveyData, config: StudyConfig, key, *, wrap_fitness=None) -> StudyResult:
    """The registered study's ``run(data, config, key)``: repeat k uses ``fold_in(key, k)``.

    Args:
        data: :class:`SurveyData`.
        config: :class:`StudyConfig` (its ``split.seed`` is recorded; the randomness comes from ``key``).
        key: JAX PRNG key.
        wrap_fitness: see :func:`run_study`.
    """
    return _run(data.frame, config, data.meta, key, wrap_fitness, data.target)


def run_study(frame: pd.DataFrame, config: StudyConfig | None = None, metadata: dict | None = None, *,
              wrap_fitness=None, target: pd.DataFrame | None = None, timings: dict | None = None,
              progress=None) -> StudyResult:
    """Run an ICGO-RELM study on a data-contract frame with the key ``PRNGKey(config.split.seed)``.

    Args:
        frame: DataFrame with gx, gy, gz (g), bx, by, bz (nT), azimuth_deg (the
            reference azimuth); optional station, toolface_deg.
        config: StudyConfig (defaults if None).
        metadata: the data set's metadata (needed for msa.reference="known").
        wrap_fitness: optional ``f -> f'`` applied to the search's fitness
            ``f(pop, aux)`` (e.g. to instrument it). A wrapped fitness is a new
            static argument of the runner, so that run compiles afresh; for progress
            use ``progress``, which keeps the compiled programs cacheable.
        target: the second instrument's survey (``split.protocol="transfer"`` only).
        timings: a dict to fill with where the time went: per stage (``prepare``: split and MSA;
            ``search``; ``score``: refit and metrics; ``tables``) its wall seconds ``<stage>_s`` and the
            part spent compiling or loading programs ``<stage>_compile_s`` (:mod:`icgo.studies.common.timing`);
            ``execution``: the plan run (:meth:`icgo.studies.icgo_relm.config.StudyConfig.execution`, with the
            fitness function's name and the dtype).
        progress: optional ``progress(done, total)`` called on the host as the search's iterations complete
            (:func:`icgo.optim.sharded.run_members`); it never enters the compiled programs, so they stay in
            the compilation cache.
    Returns:
        StudyResult.
    Raises:
        ValueError: bad data (missing columns, NaN), bad config (lambda <= 0,
            fewer training rows than hidden units, unknown names), or stations
            that cannot determine the MSA parameters.
    """
    cfg = StudyConfig() if config is None else config
    return _run(frame, cfg, metadata, jax.random.PRNGKey(cfg.split.seed), wrap_fitness, target, timings, progress)


class Staged(NamedTuple):
    """A study up to its search (:func:`stage`): the filtered rows, the checked members and their prepared arrays.

    ``cfg`` holds the repeats kept (``repeat_ids``) and, with ``tune``, the chosen cell; ``n_source``: transfer's
    source rows (the target's follow), else all rows; ``capacity``: None, or the rows G, B, a_true and ``prep`` are
    padded to (:func:`icgo.studies.icgo_relm.prepare.prepare`)."""

    cfg: StudyConfig
    rows: pd.DataFrame
    kept: np.ndarray
    G: np.ndarray
    B: np.ndarray
    a_true: np.ndarray
    n_source: int
    mem: _splits.Members
    prep: Prepared
    excluded: tuple
    tuning: Any
    capacity: int | None = None


def stage(frame, cfg: StudyConfig, metadata, base_key, target=None, stages=None, capacity=None) -> Staged:
    """Filter, split, MSA and features of every member (rows padded to ``capacity``:
    :func:`icgo.studies.icgo_relm.prepare.prepare`), the failed repeats left out, plain RELM tuned."""
    if (cfg.split.protocol == "transfer") != (target is not None):
        raise ValueError("study: protocol 'transfer' needs the second instrument's survey (target) and no other "
                         f"protocol takes one; got protocol {cfg.split.protocol!r} with"
                         f"{'out' if target is None else ''} a target")
    rows, G, B, a_true, kept = filtered(frame, cfg)
    n_source = len(a_true)
    if target is not None:  # the sigma filter is applied to each instrument's survey on its own
        t_rows, Gt, Bt, at, _ = filtered(target, cfg)
        rows = pd.concat([rows, t_rows])
        G, B, a_true = np.vstack([G, Gt]), np.vstack([B, Bt]), np.concatenate([a_true, at])
    reference = reference_field(cfg, metadata)
    if cfg.msa.model == "biases_scales" and reference is None:
        raise ValueError("study: msa.model='biases_scales' needs msa.reference='known'")
    stages = timing.Stages() if stages is None else stages
    with stages("prepare"):
        prep, mem = prepare(rows, G, B, a_true, cfg, base_key, reference, n_source, capacity)
        prep, mem, cfg, excluded = exclude_failed_repeats(prep, mem, cfg, reference)
        jax.block_until_ready(prep)
    tuning = None
    if cfg.model.tune:
        cfg, tuning = tune(cfg, prep, rows_per_fit(cfg, mem))
    if capacity is not None:
        G, B, a_true = pad_rows(capacity, G, B, a_true)
    return Staged(cfg, rows, kept, G, B, a_true, n_source, mem, prep, excluded, tuning, capacity)


def finish(st: Staged, thetas, curve, evals, t0: float, stages) -> StudyResult:
    """The searched members checked, refitted and scored, and the study's tables (``t0``: its start, for the wall
    time; ``stages``: the :class:`icgo.studies.common.timing.Stages` that time it)."""
    cfg, mem = st.cfg, st.mem
    check_search(np.asarray(curve), cfg.method_names(), [f"{r}" if cfg.split.protocol not in _splits.FOLD_PROTOCOLS
                                                          else f"{r}, {mem.fold_label[f]}"
                                                          for r, f in zip(mem.repeat, mem.fold)])
    with stages("score"):
        scored = jax.block_until_ready(score_all(thetas, st.prep, st.G, st.B, st.a_true, cfg.model.lam,
                                       cfg.model.hidden,
                                                 cfg.model.features == "raw"))
    wall = time.perf_counter() - t0
    prep = st.prep._replace(data=None)  # the features (members x rows x 6) are done with: free them before the tables
    G, B, a_true = st.G, st.B, st.a_true
    if st.capacity is not None:  # the padded rows dropped: every table holds the data set's own rows
        n = len(st.kept.nonzero()[0])
        G, B, a_true = G[:n], B[:n], a_true[:n]
        prep = prep._replace(train=prep.train[:, :n], test=prep.test[:, :n], target=prep.target[:, :n])
        scored = scored._replace(a_msa=scored.a_msa[..., :n], pred=scored.pred[..., :n], a_comp=scored.a_comp[..., :n])
    with stages("tables"):
        res = collect(cfg, st.rows, st.kept, a_true, G, B, st.n_source, mem, prep, thetas, scored, curve, evals,
                      wall)
    return res._replace(tuning=st.tuning, excluded=st.excluded)


def _run(frame, cfg: StudyConfig, metadata, base_key, wrap_fitness, target=None, timings=None,
         progress=None) -> StudyResult:
    t0 = time.perf_counter()
    stages = timing.Stages()
    st = stage(frame, cfg, metadata, base_key, target, stages)
    plan = st.cfg.execution(cells=len(st.mem.repeat))
    with stages("search"):
        thetas, curve, evals = jax.block_until_ready(search(st.cfg, st.prep, wrap_fitness, plan.kernel, progress,
                                                            plan_devices(plan)))
    res = finish(st, thetas, curve, evals, t0, stages)
    if timings is not None:
        timings.update(stages.times, execution=execution_record(st.cfg, plan))
    return res


def example() -> tuple:
    """A tiny ICGO-RELM study (seconds): lab_casing at a 45 deg toolface step, PSO, 2 repeats."""
    from icgo.datasets import casing_stations as datasets

    frame = datasets.lab_casing(0, toolface_step_deg=45.0).frame
    return SurveyData(frame), StudyConfig(split=dict(n_repeats=2), model=dict(hidden=8),
                                          budget=dict(pop_size=6, iterations=3), optimizer="pso")


STUDY = Study("icgo_relm", StudyConfig, run, "MSA + RELM whose hidden weights an optimizer searches "
              "(ICGO paper sections 3.1-3.4)", example, seed_key="split.seed")
