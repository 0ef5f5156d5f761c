"""The ICGO-RELM study's data up to its search (ICGO paper sections 3.1-3.3): the frame read and checked, the 3-sigma
filter, the members of the split protocol, the multi-station analysis on each member's training rows, the targets
and the standardised features, the repeats whose MSA failed left out.

Test rows never steer anything: MSA, standardisation and fitness see them only with zero weight. The members are
prepared by one jitted call mapped over them (:func:`prepare`), so repeat k of a batch equals repeat k alone.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from icgo.models import msa as _msa
from icgo.models import relm as _relm
from icgo.physics.frames import angle_diff, azimuth_from_gv
from icgo.physics.qc import measured_dip_deg
from icgo.studies.common import splits as _splits
from icgo.studies.icgo_relm.config import StudyConfig

REQUIRED_COLUMNS = ("gx", "gy", "gz", "bx", "by", "bz", "azimuth_deg")

log = logging.getLogger(__name__)


def sigma_filter(G, B, azimuth_true, n_sigma: float = 3.0):
    """The 3-sigma rule (paper section 3.1), one pass, host-side.

    A row is dropped when any of these lies more than ``n_sigma`` standard
    deviations from its mean: |G|, |B| and the magnetic dip over the whole
    data set (sensor faults), and the raw azimuth error within its group of
    equal reference azimuth (the error varies by several degrees between
    azimuths, so a global rule on it would test the interference, not outliers).

    Args:
        G: (N, 3) g. B: (N, 3) nT. azimuth_true: (N,) deg.
        n_sigma: the rule's threshold.
    Returns:
        (N,) bool mask of kept rows.
    """
    G = np.asarray(G, float)
    B = np.asarray(B, float)
    a = np.asarray(azimuth_true, float)
    gn = np.linalg.norm(G, axis=1)
    bn = np.linalg.norm(B, axis=1)
    dip = measured_dip_deg(G, B)
    err = np.asarray(raw_errors(G, B, a)[1])
    keep = np.ones(len(a), bool)
    for q in (gn, bn, dip):
        s = q.std()
        if s > 0:
            keep &= np.abs(q - q.mean()) <= n_sigma * s
    # groups of equal azimuth by one stable sort (O(N log N) for any number of groups); each group's rows
    # keep their order, so its mean and std are those of err[group mask]
    az = np.round(a, 6)
    order = np.argsort(az, kind="stable")
    starts = np.flatnonzero(np.r_[True, az[order][1:] != az[order][:-1]])
    ends = np.r_[starts[1:], len(a)]
    for i0, i1 in zip(starts[ends - starts > 2], ends[ends - starts > 2]):
        g = order[i0:i1]
        e = err[g]
        s = e.std()
        if s > 0:
            keep[g] &= np.abs(e - e.mean()) <= n_sigma * s
    return keep


#: The host-side filter's and tables' raw azimuth errors, one compiled program (not one per array operation):
#: ((N,) raw azimuth, (N,) its error against the reference), deg.
raw_errors = jax.jit(lambda G, B, a: (azimuth_from_gv(G, B), angle_diff(azimuth_from_gv(G, B), a)))


class Prepared(NamedTuple):
    """Per-repeat arrays (leading axis R when batched)."""

    train: jnp.ndarray      # (N,) 0/1
    test: jnp.ndarray       # (N,) 0/1
    msa: _msa.MSAResult
    target: jnp.ndarray     # (N,) deg
    data: _relm.FitData     # standardised features, target, fold weights
    key: jnp.ndarray        # model key
    x_mean: jnp.ndarray     # (6,) feature mean over the training rows (g, nT)
    x_std: jnp.ndarray      # (6,) feature std over the training rows (g, nT)


@functools.partial(jax.jit, static_argnames=("msa_model", "msa_iter", "features", "mode", "val_fraction",
                                             "k_folds"))
def _prepare(keys, train, test, G, B, a_true, reference, *, msa_model, msa_iter, features, mode,
             val_fraction, k_folds) -> Prepared:
    """Per member (lax.map): MSA on its training rows, targets, standardised features, fold weights.

    keys: (M, 2); train, test: (M, N) 0/1 masks (:func:`icgo.studies.common.splits.members`).
    """
    def one(args):
        key, train, test = args
        _, k_fold, k_model = jax.random.split(key, 3)  # the first split drew the random protocol's permutation
        m = _msa.msa_solve(G, B, train, reference, model=msa_model, max_steps=msa_iter)
        b_corr = _msa.correct_field(B, m.bias, m.scale)
        target = angle_diff(azimuth_from_gv(G, b_corr), a_true)
        X = jnp.concatenate([G, B if features == "raw" else b_corr], axis=1)
        mean, std = _relm.standardize_stats(X, train)
        Xs = _relm.standardize(X, mean, std)
        fit_w, score_w = _relm.fold_weights(k_fold, train, mode, val_fraction, k_folds)
        return Prepared(train, test, m, target, _relm.FitData(Xs, target, fit_w, score_w), k_model, mean,
                        std)

    # lax.map, not vmap: the per-repeat program is then the same whatever the
    # number of repeats, so repeat k of a batch equals repeat k alone bitwise
    # (a vmapped reduction may be reordered by XLA for another batch size).
    # These stages are cheap; the search (the cost) is vmapped by the runner.
    return jax.lax.map(one, (keys, train.astype(G.dtype), test.astype(G.dtype)))


def _check_config(cfg: StudyConfig, mem: _splits.Members) -> None:
    """The data-dependent checks (the settings validated themselves in ``StudyConfig.__post_init__``)."""
    if not isinstance(cfg, StudyConfig):
        raise ValueError(f"config must be a StudyConfig, got {type(cfg).__name__}")
    n_train = mem.train.sum(axis=1)
    n_test = mem.test.sum(axis=1)
    m = int(np.argmin(n_train))
    n_fit = rows_per_fit(cfg, mem)
    hidden = min(_relm.TUNE_HIDDEN) if cfg.model.tune else cfg.model.hidden
    where = "" if cfg.split.protocol == "random" else f" ({cfg.split.protocol}, fold {mem.fold_label[mem.fold[m]]!r})"
    if n_fit < hidden or n_test.min() < 1:
        raise ValueError(f"study: a split{where} of {mem.train.shape[1]} rows gives {int(n_train[m])} training rows "
                         f"({n_fit} per fit) and {int(n_test.min())} test rows; need at least hidden = {hidden} "
                         f"rows per fit and one test row")


def rows_per_fit(cfg: StudyConfig, mem: _splits.Members) -> int:
    """Training rows the smallest member fits the output weights on (less the validation share or one fold)."""
    n_fit = int(mem.train.sum(axis=1).min())
    if cfg.fitness.mode == "validation":
        n_fit -= int(round(cfg.fitness.val_fraction * n_fit))
    elif cfg.fitness.mode == "kfold":
        n_fit -= int(np.ceil(n_fit / cfg.fitness.k_folds))
    return n_fit


def frame_arrays(frame: pd.DataFrame):
    """(G (N, 3) g, B (N, 3) nT, azimuth (N,) deg) from a data-contract frame, checked."""
    if not isinstance(frame, pd.DataFrame):
        raise ValueError(f"study: expected a pandas DataFrame, got {type(frame).__name__}")
    missing = [c for c in REQUIRED_COLUMNS if c not in frame.columns]
    if missing:
        raise ValueError(f"study: data frame lacks required column(s) {missing}")
    if len(frame) == 0:
        raise ValueError("study: data frame is empty")
    vals = frame[list(REQUIRED_COLUMNS)]
    try:
        arr = vals.to_numpy(dtype=float)
    except (TypeError, ValueError):
        raise ValueError("study: non-numeric value in the sensor/azimuth columns") from None
    bad = np.argwhere(~np.isfinite(arr))
    if bad.size:
        r, c = bad[0]
        raise ValueError(f"study: NaN/inf in row {r}, column {REQUIRED_COLUMNS[c]!r}")
    return arr[:, :3], arr[:, 3:6], arr[:, 6]


def reference_field(cfg: StudyConfig, metadata):
    """The MSA's reference field: None for ``msa.reference="station_mean"``, else the (3,) field (nT) of the
    metadata's ``total_field_nT`` and ``dip_deg``."""
    if cfg.msa.reference == "station_mean":
        return None
    md = metadata or {}
    if "total_field_nT" not in md or "dip_deg" not in md:
        raise ValueError("study: msa.reference='known' needs metadata with total_field_nT and dip_deg")
    return jnp.asarray(_msa.reference_from_field(float(md["total_field_nT"]), float(md["dip_deg"])))


def filtered(frame: pd.DataFrame, cfg: StudyConfig):
    """(kept rows of the frame, G, B, azimuth) after the sigma filter."""
    G, B, a = frame_arrays(frame)
    kept = sigma_filter(G, B, a, cfg.split.sigma_filter) if cfg.split.sigma_filter else np.ones(len(a), bool)
    return frame[kept], G[kept], B[kept], a[kept], kept


def prepare(rows: pd.DataFrame, G, B, a_true, cfg: StudyConfig, base_key, reference=None,
            n_source: int | None = None, capacity: int | None = None) -> tuple[Prepared, _splits.Members]:
    """The members of ``cfg.split.protocol`` and their prepared arrays (split, MSA, features), checked.

    Args:
        rows: the filtered rows (a DataFrame; fold protocols read their groups from it), or None
            (the random protocol on arrays).
        G: (N, 3) g. B: (N, 3) nT. a_true: (N,) deg; the filtered rows' arrays.
        cfg: StudyConfig. base_key: the study's PRNG key.
        reference: (3,) known reference field or None (station mean).
        n_source: transfer only: the source's row count (the target's rows follow).
        capacity: None, or the rows every array is padded to (copies of the last row, weight 0 in every mask), so
            that data sets of other sizes share the programs (:mod:`icgo.studies.icgo_relm.worlds.study`).
    Returns:
        (:class:`Prepared` with a leading member axis, :class:`icgo.studies.common.splits.Members`).
    """
    if rows is None:  # arrays only: enough for the random protocol
        rows = pd.DataFrame(index=pd.RangeIndex(len(a_true)))
    mem = _splits.members(cfg.split.protocol, rows, base_key, cfg.ids(), cfg.split.train_fraction, n_source)
    _check_config(cfg, mem)
    train, test = mem.train, mem.test
    if capacity is not None:
        G, B, a_true = pad_rows(capacity, G, B, a_true)
        train, test = (np.pad(np.asarray(x), ((0, 0), (0, int(capacity) - x.shape[1]))) for x in (train, test))
    prep = _prepare(jnp.asarray(mem.keys), jnp.asarray(train), jnp.asarray(test), jnp.asarray(G),
                    jnp.asarray(B), jnp.asarray(a_true), reference, msa_model=cfg.msa.model,
                    msa_iter=cfg.msa.iterations, features=cfg.model.features, mode=cfg.fitness.mode,
                    val_fraction=float(cfg.fitness.val_fraction), k_folds=int(cfg.fitness.k_folds))
    return prep, mem


def pad_rows(capacity: int, *arrays) -> tuple:
    """Each (N, ...) array padded to ``capacity`` rows with copies of its last row (finite; their weights are 0)."""
    return tuple(np.pad(np.asarray(x), [(0, int(capacity) - len(x))] + [(0, 0)] * (np.ndim(x) - 1), mode="edge")
                 for x in arrays)


def exclude_failed_repeats(prep: Prepared, mem: _splits.Members, cfg: StudyConfig, reference=None):
    """Leave out the repeats whose multi-station analysis failed, so that the others go on.

    A repeat is left out whole (all its folds) when the MSA of any of its members failed
    (:func:`icgo.models.msa.msa_failures`: parameters the training stations cannot determine, a
    non-finite solution, or no convergence within ``msa_iterations`` steps). Its numbers would
    rest on an unusable correction, so it is neither searched nor scored nor averaged in; the
    result names it (``StudyResult.excluded``) and so do the printed summary, ``summary.md`` and
    ``run.json``. Only when every repeat failed does the study stop (the same one-line
    ValueError as :func:`icgo.models.msa.check_observability`, naming the first).

    Args:
        prep, mem: the prepared members and their protocol (:func:`prepare`).
        cfg: the StudyConfig. reference: the MSA reference field or None.
    Returns:
        (prep, mem, cfg, excluded): the kept members; ``cfg`` with ``repeat_ids`` the kept ids
        (unchanged when none failed); ``excluded`` = ``((repeat id, reason), ...)``.
    Raises:
        ValueError: every repeat's MSA failed.
    """
    reasons = _msa.msa_failures(prep.msa, cfg.msa.model, reference)
    failed: dict[int, tuple[str, str]] = {}  # repeat id -> (fold label or "", reason)
    for k, why in enumerate(reasons):
        rid = int(mem.repeat[k])
        if why is not None and rid not in failed:
            failed[rid] = (mem.fold_label[mem.fold[k]] if cfg.split.protocol in _splits.FOLD_PROTOCOLS else "", why)
    if not failed:
        return prep, mem, cfg, ()
    kept_ids = tuple(r for r in cfg.ids() if r not in failed)
    if not kept_ids:
        rid, (fold, why) = next(iter(failed.items()))
        raise ValueError(f"multi-station analysis (repeat {rid}{', ' + fold if fold else ''}): {why}")
    sel = np.flatnonzero(np.isin(mem.repeat, kept_ids))
    prep = jax.tree_util.tree_map(lambda a: a[sel], prep)
    mem = mem._replace(keys=mem.keys[sel], repeat=mem.repeat[sel], fold=mem.fold[sel], train=mem.train[sel],
                       test=mem.test[sel], heldout=mem.heldout[sel])
    excluded = tuple((rid, f"MSA{f' ({fold})' if fold else ''}: {why}") for rid, (fold, why) in sorted(failed.items()))
    log.warning("%s", excluded_sentence(excluded, len(cfg.ids())))
    return prep, mem, dataclasses.replace(cfg, repeat_ids=kept_ids), excluded


def excluded_sentence(excluded, n_repeats: int, limit: int = 10) -> str | None:
    """One line naming the excluded repeats (the first ``limit``), or None when there are none.

    E.g. ``"1 of 1000 repeats excluded (their MSA failed, so they are in no number): repeat 61: MSA:
    Levenberg-Marquardt did not converge in 100 steps; raise max_steps (msa.iterations)"``.
    """
    if not excluded:
        return None
    named = "; ".join(f"repeat {rid}: {why}" for rid, why in list(excluded)[:limit])
    more = f"; and {len(excluded) - limit} more (run.json)" if len(excluded) > limit else ""
    return (f"{len(excluded)} of {n_repeats} repeats excluded (their MSA failed, so they are in no number): "
            f"{named}{more}")
