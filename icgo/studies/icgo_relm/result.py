"""The ICGO-RELM study's scores and what it returns.

- The scores (ICGO paper section 3.4, eq. 9 and eq. 21, :func:`score_all`): the output weights refitted on all
  training rows of every (strategy, repeat), the compensated azimuths predicted through the forward pass the saved
  model applies (:func:`icgo.models.compensation.predict_methods`), and their test and training metrics.
- :class:`StudyResult`, its tables (metrics per method, repeat and split; convergence; per-row predictions; the MSA
  fits; conformal coverage) and the fitted models it saves, built host-side from the scored members
  (:func:`collect`).
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from icgo.physics.metrics import azimuth_metrics
from icgo.maths.stats import mean_std_table
from icgo.models import msa as _msa
from icgo.models import relm_fit
from icgo.models.compensation import RELMParams, predict_methods
from icgo.physics.frames import angle_diff, wrap360
from icgo.studies.common import splits as _splits
from icgo.studies.icgo_relm.config import StudyConfig
from icgo.studies.icgo_relm.prepare import Prepared, raw_errors


class Scored(NamedTuple):
    """Every (strategy, repeat) refitted, predicted and scored (:func:`score_all`)."""

    a_msa: jnp.ndarray      # (S, R, N) MSA azimuth, deg
    pred: jnp.ndarray       # (S, R, N) predicted error, deg
    a_comp: jnp.ndarray     # (S, R, N) compensated azimuth, deg
    test: Any               # Metrics (S, R)
    train: Any              # Metrics (S, R)
    params: RELMParams      # the fitted members (S strategies x R repeats) the saved model holds


@functools.partial(jax.jit, static_argnames=("hidden",))
def refit_all(thetas, prep: Prepared, lam, hidden):
    """Output weights beta (S, R, L) refitted on all training rows of each (strategy, repeat) (eq. 9; row blocks
    above :data:`icgo.models.relm.ROW_BLOCK` rows, so memory does not grow with strategies x rows x hidden)."""
    over_s = jax.vmap(lambda th, p: relm_fit.ridge_beta(th, p.data.X, p.target, lam, hidden, p.train),
                      in_axes=(0, None))
    # lax.map over repeats for bitwise batch-size independence (see icgo.studies.icgo_relm.prepare.prepare).
    return jnp.swapaxes(jax.lax.map(lambda tp: over_s(*tp), (jnp.swapaxes(thetas, 0, 1), prep)), 0, 1)


@jax.jit
def _metrics(a_comp, prep: Prepared, a_true):
    """Test and training metrics (S, R) of the compensated azimuths a_comp (S, R, N)."""
    def one(ap):
        a, p = ap
        return jax.vmap(lambda x: (azimuth_metrics(a_true, x, p.target, p.test),
                                   azimuth_metrics(a_true, x, p.target, p.train)))(a)

    test, train = jax.lax.map(one, (jnp.swapaxes(a_comp, 0, 1), prep._replace(data=None)))
    return jax.tree_util.tree_map(lambda x: jnp.swapaxes(x, 0, 1), (test, train))


def score_all(thetas, prep: Prepared, G, B, a_true, lam, hidden: int, raw_features: bool) -> Scored:
    """Refit, predict and score every (strategy, repeat).

    The predictions come from :func:`icgo.models.compensation.predict_methods` on the params the study saves
    (:attr:`Scored.params`), the forward pass its artifact applies, so a saved model reproduces them bitwise.

    Args:
        thetas: (S, R, 7 L) searched hidden weights. prep: the R repeats' :class:`Prepared`.
        G, B: (N, 3) the study's rows (g, nT). a_true: (N,) reference azimuth, deg.
        lam: ridge lambda. hidden: L. raw_features: the RELM reads (G, B), else (G, B_corr).
    """
    params = RELMParams(prep.msa.bias, prep.msa.scale, prep.x_mean, prep.x_std, thetas,
                        refit_all(thetas, prep, lam, hidden), int(hidden), bool(raw_features))
    a_msa, pred = predict_methods(params, jnp.concatenate([jnp.asarray(G), jnp.asarray(B)], axis=1))
    a_comp = wrap360(a_msa - pred)
    test, train = _metrics(a_comp, prep, jnp.asarray(a_true))
    return Scored(a_msa, pred, a_comp, test, train, params)


class StudyResult(NamedTuple):
    """Everything a study produces (numpy / pandas, host-side).

    Attributes:
        metrics: one row per (method, repeat, split): mae, rmse, r2 (eq. 21),
            r2_error; methods include ``raw`` (eq. 1 on raw data) and ``msa``
            (after MSA only) as baselines. Fold protocols: over every (fold, row)
            of the split, i.e. the test metrics of each row's held-out fold.
        summary: mean +/- std over repeats per (method, split).
        histories: long table (method, repeat, fold, iteration, evals, best_fitness).
        predictions: per (method, repeat, fold, row) azimuths and errors, with split
            (``train``, ``test``, or ``heldout``: transfer's unused source rows).
        msa: per member (repeat, fold): biases (nT), standard errors, condition number, V.
        coverage: per (method, repeat, fold): the member's conformal half-width
            (deg, :func:`icgo.maths.conformal.member_coverage`), its coverage of the test
            rows at :data:`icgo.artifacts.relm.INTERVAL_LEVEL`, the test and calibration row counts.
        curves: dict of arrays: ``best_fitness`` and ``evals`` (S, M, T) over members.
        kept: (N_in,) bool, rows of the input frame surviving the sigma filter
            (for transfer: of the source; the target's kept rows are the
            predictions' ``survey == "target"`` rows).
        config: the StudyConfig.
        wall_time_s: wall time of the jitted stages (incl. compile), s.
        n_evals: fitness evaluations per method and member (S, M).
        model: the fitted compensation (:class:`icgo.artifacts.relm.RELMCompensation`):
            MSA biases, input statistics, hidden and output weights per method
            and repeat; ``model.apply(frame)`` corrects a new survey.
        msa_model: the MSA-only fit (:class:`icgo.artifacts.relm.MSAModel`).
        tuning: with ``config.model.tune``: ``{"hidden", "lam", "grid": [{hidden, lam, val_mean, val_std}, ...]}``
            (the chosen cell is ``config.model.hidden`` / ``config.model.lam``); else None.
        excluded: ``((repeat id, reason), ...)``: the repeats left out because their MSA failed
            (:func:`icgo.studies.icgo_relm.prepare.exclude_failed_repeats`); every table, the summary and the
            models hold the others only, and ``config.repeat_ids`` names those. Empty when every repeat was usable.
    """

    metrics: pd.DataFrame
    summary: pd.DataFrame
    histories: pd.DataFrame
    predictions: pd.DataFrame
    msa: pd.DataFrame
    coverage: pd.DataFrame
    curves: dict
    kept: np.ndarray
    config: StudyConfig
    wall_time_s: float
    n_evals: np.ndarray
    model: Any
    msa_model: Any
    tuning: Any = None
    excluded: tuple = ()

    @property
    def records(self) -> dict:
        """The tables a run directory holds (names and columns: :mod:`icgo.reporting.records`)."""
        return {"metrics": self.metrics, "convergence": self.histories, "predictions": self.predictions,
                "msa": self.msa.rename(columns={"condition": "condition_number"}), "coverage": self.coverage}

    @property
    def models(self) -> dict:
        """The fitted models by kind."""
        return {self.model.KIND: self.model, self.msa_model.KIND: self.msa_model}


#: The tables' metrics and errors, one compiled program each (not one per array operation).
_table_metrics = jax.jit(azimuth_metrics)
_errors = jax.jit(angle_diff)


def collect(cfg, rows, kept, a_true, G, B, n_source, mem: _splits.Members, prep, thetas, scored, curve, evals,
            wall) -> StudyResult:
    """The study's tables and fitted models, host-side, from its scored members.

    Args:
        cfg: the StudyConfig. rows: the filtered rows (DataFrame). kept: (N_in,) bool, the sigma filter's mask.
        a_true: (N,) deg. G: (N, 3) g. B: (N, 3) nT. n_source: transfer's source rows (the target's follow).
        mem: the members. prep: their :class:`icgo.studies.icgo_relm.prepare.Prepared` (features dropped).
        thetas: (S, M, D) hidden weights. scored: :class:`Scored`.
        curve, evals: (S, M, T) best-so-far fitness and evaluations. wall: wall time of the jitted stages, s.
    """
    from icgo.maths.conformal import member_coverage
    from icgo.artifacts.relm import INTERVAL_LEVEL

    methods = cfg.method_names()
    ids = cfg.ids()
    curve, evals = np.asarray(curve), np.asarray(evals)
    train = np.asarray(prep.train) > 0
    test = np.asarray(prep.test) > 0
    target = np.asarray(prep.target)
    a_msa = np.asarray(scored.a_msa[0])  # every strategy of a repeat shares its MSA
    a_comp = np.asarray(scored.a_comp)
    a_raw, err_raw = (np.asarray(x) for x in raw_errors(G, B, a_true))
    one_member = len(mem.fold_label) == 1  # random / transfer: the jitted per-member metrics are the repeat's
    # a repeat's members side by side, repeats in ``ids`` order: (..., M, N) -> (..., R, F N), so that every
    # repeat's metrics over its pooled folds come from one batched call (not one call per repeat)
    position = {rid: i for i, rid in enumerate(ids)}
    order = np.argsort([position[int(r)] for r in mem.repeat], kind="stable")
    R, F = len(ids), len(order) // len(ids)

    def pooled(x):
        x = np.asarray(x)[..., order, :]
        return x.reshape(*x.shape[:-2], R, F * x.shape[-1])

    a_true_p, err_raw_p = np.tile(a_true, F), np.tile(err_raw, F)
    per_split = {}
    for split, mask in (("test", test), ("train", train)):
        w = pooled(mask.astype(float))
        per_method = {"raw": _table_metrics(a_true_p, np.broadcast_to(np.tile(a_raw, F), w.shape), err_raw_p, w),
                      "msa": _table_metrics(a_true_p, pooled(a_msa), err_raw_p, w)}
        if one_member:
            m = scored.test if split == "test" else scored.train
            per_method |= {name: type(m)(*(np.asarray(v)[s][order] for v in m)) for s, name in enumerate(methods)}
        else:
            m = _table_metrics(a_true_p, pooled(a_comp), pooled(target), w)
            per_method |= {name: type(m)(*(np.asarray(v)[s] for v in m)) for s, name in enumerate(methods)}
        per_split[split] = {name: {k: np.asarray(v, dtype=float) for k, v in m._asdict().items()}
                            for name, m in per_method.items()}
    out = [{"method": name, "repeat": rid, "split": split, **{k: float(v[i]) for k, v in vals.items()}}
           for i, rid in enumerate(ids) for split, by_method in per_split.items() for name, vals in by_method.items()]
    metrics = pd.DataFrame(out)
    summary = mean_std_table(metrics, ["method", "split"], ["mae", "rmse", "r2", "r2_error"])

    S, M, T = curve.shape
    histories = pd.DataFrame({
        "method": np.repeat(methods, M * T), "repeat": np.tile(np.repeat(mem.repeat, T), S),
        "fold": np.tile(np.repeat(mem.fold, T), S),
        "iteration": np.tile(np.arange(1, T + 1), S * M), "evals": evals.ravel(), "best_fitness": curve.ravel()})

    N = len(a_true)
    station = rows["station"].to_numpy() if "station" in rows.columns else np.arange(N)
    # S x M x N rows: the text columns are categoricals (one byte a row, not one string object a row)
    split = np.where(train, 0, np.where(test, 1, 2)).astype(np.int8)
    predictions = pd.DataFrame({
        "method": _categorical(np.repeat(np.arange(S, dtype=np.int8), M * N), methods),
        "repeat": np.tile(np.repeat(mem.repeat, N), S),
        "fold": np.tile(np.repeat(mem.fold, N), S),
        "row": np.tile(np.asarray(rows.index), S * M), "station": np.tile(station, S * M),
        "split": _categorical(np.tile(split.ravel(), S), ["train", "test", "heldout"]),
        "azimuth_true": np.tile(a_true, S * M), "azimuth_raw": np.tile(a_raw, S * M),
        "azimuth_msa": np.tile(a_msa.ravel(), S), "error_msa": np.tile(target.ravel(), S),
        "predicted_error": np.asarray(scored.pred).ravel(), "azimuth_compensated": a_comp.ravel(),
        "error_compensated": np.asarray(_errors(a_comp, a_true[None, None])).ravel()}, copy=False)
    if "toolface_deg" in rows.columns:
        predictions.insert(6, "toolface_deg", np.tile(rows["toolface_deg"].to_numpy(), S * M))
    if cfg.split.protocol == "transfer":
        predictions["survey"] = _categorical(np.tile((np.arange(N) >= n_source).astype(np.int8), S * M),
                                             ["source", "target"])

    names = _msa.MODELS[cfg.msa.model]
    m = prep.msa
    msa_df = pd.DataFrame({"repeat": mem.repeat, "fold": mem.fold, "cost_V": np.asarray(m.cost),
                           "condition": np.asarray(m.condition),
                           **{f"bias_{ax}": np.asarray(m.bias)[:, i] for i, ax in enumerate("xyz")},
                           **{f"scale_{ax}": np.asarray(m.scale)[:, i] for i, ax in enumerate("xyz")},
                           **{f"std_{n}": np.asarray(m.std_error)[:, i] for i, n in enumerate(names)}})
    pool = mem.repeat if cfg.split.protocol in _splits.FOLD_PROTOCOLS else np.zeros(M, int)
    q, cov, n_cal = member_coverage(a_comp, a_true, mem.train, mem.heldout, mem.test, pool, INTERVAL_LEVEL)
    coverage = pd.DataFrame({"method": np.repeat(methods, M), "repeat": np.tile(mem.repeat, S),
                             "fold": np.tile(mem.fold, S), "fold_label": np.tile(np.asarray(mem.fold_label)[mem.fold], S),
                             "level": INTERVAL_LEVEL, "halfwidth_deg": q.ravel(), "coverage": cov.ravel(),
                             "n_test": np.tile(mem.test.sum(axis=1).astype(int), S), "n_calibration": np.tile(n_cal, S)})
    return StudyResult(metrics, summary, histories, predictions, msa_df, coverage,
                       {"best_fitness": curve, "evals": evals}, kept, cfg, wall, evals[..., -1],
                       *_fitted_models(cfg, G[:n_source], B[:n_source], a_true, mem, prep, thetas, scored))


def _categorical(codes, categories) -> pd.Categorical:
    """A text column as a pandas Categorical of ``categories[codes]`` (written to CSV as the text)."""
    return pd.Categorical.from_codes(codes, categories=list(categories))


def _fitted_models(cfg: StudyConfig, G, B, a_true, mem: _splits.Members, prep: Prepared, thetas, scored: Scored):
    """The study's fitted artifacts: (RELMCompensation, MSAModel), host-side numpy.

    One member per fitted model (repeat, fold); G, B are the training survey's rows
    (for transfer: the source instrument's), which set the data hash and domain; the
    conformal half-width uses the rows each member held out of that survey only.
    """
    from icgo.artifacts.format import data_hash, sensor_domain
    from icgo.core.settings import config_to_mapping
    from icgo.artifacts.relm import MSAModel, RELMCompensation, out_of_bag_halfwidth

    methods = cfg.method_names()
    ids = [int(r) for r in mem.repeat]
    train_rmse = np.asarray(scored.train.rmse)
    selected = methods[int(np.argmin(train_rmse.mean(axis=1)))]
    a_src = a_true[:len(G)]
    common = dict(data_hash=data_hash(G, B, a_src),
                  domain={**sensor_domain(G, B), "azimuth_deg": [float(np.min(a_src)), float(np.max(a_src))]})
    params = jax.tree_util.tree_map(np.asarray, scored.params)
    settings = {**config_to_mapping(cfg), "optimizer_config": None if cfg.optimizer_config is None
                else repr(cfg.optimizer_config)}
    relm = RELMCompensation(config=settings, methods=list(methods), selected=selected, repeat_ids=ids,
                            hidden=int(cfg.model.hidden), lam=float(cfg.model.lam), features=cfg.model.features,
                            params=params,
                            train_rmse=train_rmse,
                            interval_halfwidth=out_of_bag_halfwidth(np.asarray(scored.a_comp), a_true,
                                                                    mem.heldout == 0), **common)
    msa = MSAModel(config={"msa": config_to_mapping(cfg.msa), "split": config_to_mapping(cfg.split)},
                   params=_msa.MSAParams(params.msa_bias, params.msa_scale), repeat_ids=ids, **common)
    return relm, msa
