"""The ICGO-RELM study's search (ICGO paper section 3.4): the hidden parameters of every (method, member), found by an
optimizer of :mod:`icgo.optim` on a training-only fitness (one program over members and CGO strategies, sharded over
the devices: :func:`icgo.optim.sharded.run_grid`), or drawn at random for plain RELM (tuned on a grid with
``tune``); the fitness kernel each precision and backend runs.
"""

from __future__ import annotations

import functools
import logging
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from icgo.core.execution import ACCELERATOR_KERNEL, CPU_KERNEL, ExecutionPlan
from icgo.models import relm as _relm
from icgo.models.search_fitness import SearchData, search_fitness
from icgo.optim.sharded import run_grid
from icgo.studies.icgo_relm.config import PRECISIONS, StudyConfig
from icgo.studies.icgo_relm.prepare import Prepared

log = logging.getLogger(__name__)


class SearchKernel(NamedTuple):
    """The search's fitness kernel: its name in :mod:`icgo.models.relm` (one of
    :data:`icgo.models.search_fitness.SEARCH_KERNELS`), whether it reads the gathered training rows
    (:func:`train_rows`)
    or the row-weighted FitData, and its precisions (:class:`icgo.models.search_fitness.SearchData`)."""

    name: str
    train_rows: bool
    feature_dtype: str
    solve_dtype: str

    def aux(self, rows, lam, hidden: int) -> SearchData:
        """The optimizer's ``aux`` for :func:`icgo.models.search_fitness.search_fitness`: ``rows`` (TrainRows or
        FitData)
        and ``lam`` (an array with the rows' leading axes: (R,) for a search, () for one repeat) as data."""
        return SearchData(rows, lam, int(hidden), self.name, self.feature_dtype, self.solve_dtype)


def search_kernel(precision: str, fitness: str, kernel: str) -> SearchKernel:
    """The fitness kernel a search runs for a precision (:data:`icgo.studies.icgo_relm.config.PRECISIONS`), fitness
    mode and backend kernel.

    ``kernel`` :data:`icgo.core.execution.ACCELERATOR_KERNEL`: the fused kernel
    :func:`icgo.models.relm_fused.fused_train_fitness` (train mode with float32 features: the default),
    :func:`icgo.models.relm_gram.gram_train_fitness` (train mode, other precisions) or
    :func:`icgo.models.relm_gram.gram_fitness`. CPU: the train-mode kernel
    :func:`icgo.models.relm.train_fitness` for ``fitness="train"`` with a float64 solve, else the
    row-weighted :func:`icgo.models.relm.fitness` (float64; float32 for ``precision="float32"``).
    """
    features, solve = PRECISIONS[precision]
    train = fitness == "train"
    if kernel == ACCELERATOR_KERNEL:
        if train and (features, solve) == ("float32", "float64"):
            return SearchKernel("fused_train_fitness", True, features, solve)
        return SearchKernel("gram_train_fitness" if train else "gram_fitness", train, features, solve)
    if kernel != CPU_KERNEL:
        raise ValueError(f"study: unknown search kernel {kernel!r}")
    if train and solve == "float64":
        return SearchKernel("train_fitness", True, features, solve)
    return SearchKernel("fitness", False, "float64", solve)


def _plain_dtype(cfg: StudyConfig) -> str | None:
    """Plain RELM's fitness precision: ``float32`` when asked, else None (the float64 library path)."""
    return "float32" if cfg.precision == "float32" else None


@functools.partial(jax.jit, static_argnames=("hidden", "low", "high", "dtype"))
def _plain(keys, data, lam, hidden, low, high, dtype):
    """Plain RELM: theta ~ U(low, high) per repeat and its fitness (mapped over repeats)."""
    def one(kd):
        theta = _relm.random_theta(kd[0], hidden, (), low, high)
        return theta, _relm.fitness(theta[None], kd[1], lam, hidden, dtype)[0]

    return jax.lax.map(one, (keys, data))


@functools.partial(jax.jit, static_argnames=("n_train", "padded"))
def _train_rows(data, n_train, padded):
    return jax.vmap(lambda d: _relm.train_rows(d, n_train, padded))(data)


def search(cfg: StudyConfig, prep: Prepared, wrap_fitness=None, kernel: str = CPU_KERNEL, progress=None,
           devices=None):
    """Hidden parameters per (method, repeat): (S, R, D), curves (S, R, T), evals (S, R, T).

    Plain RELM (no optimizer): one random theta per repeat. Else :func:`search_cells` of the members' keys and
    training data (:func:`search_aux`); ``kernel`` (:meth:`StudyConfig.execution`) chooses the fitness kernel
    (:func:`search_kernel`).
    """
    if cfg.optimizer is None:
        low, high = cfg.model.theta_bounds
        theta, f = _plain(prep.key, prep.data, cfg.model.lam, cfg.model.hidden, float(low), float(high),
                          _plain_dtype(cfg))
        return theta[None], f[None, :, None], jnp.ones((1, prep.key.shape[0], 1), jnp.int32)
    return search_cells(cfg, prep.key, search_aux(cfg, prep, kernel), wrap_fitness, progress, devices)


def search_aux(cfg: StudyConfig, prep: Prepared, kernel: str, capacity: int | None = None) -> SearchData:
    """The search's data for each member of ``prep`` (leading axis: its members): the rows the fitness kernel of
    ``kernel`` reads (gathered training rows, ``capacity`` of them when given, or the row-weighted FitData),
    lambda and the precisions."""
    sk = search_kernel(cfg.precision, cfg.fitness.mode, kernel)
    return sk.aux(train_rows(prep, capacity) if sk.train_rows else prep.data,
                  np.full(prep.key.shape[0], cfg.model.lam, prep.data.X.dtype), cfg.model.hidden)


def plan_devices(p: ExecutionPlan) -> list:
    """The devices the search of plan ``p`` is sharded over: the first ``p.devices`` of its backend (every process's,
    in JAX's global order)."""
    return jax.devices(p.backend)[: p.devices]


def search_cells(cfg: StudyConfig, keys, aux, wrap_fitness=None, progress=None, devices=None):
    """Every method on every cell (``keys`` (C, 2), ``aux`` leading axis C: :func:`search_aux`), as one program
    (:func:`icgo.optim.sharded.run_grid`: ``lax.scan`` over iterations, the methods x cells members sharded over
    ``devices``, default every device, vmapped on each): (S, C, D) thetas, (S, C, T) curves and evaluations.
    ``progress``: see :func:`icgo.optim.sharded.run_members`."""
    from icgo.optim import get

    low, high = cfg.model.theta_bounds
    D = _relm.n_params(cfg.model.hidden)
    alg = get(cfg.optimizer)
    configs = alg.axis_configs(cfg.optimizer_config, cfg.strategies) if alg.axis else None
    fitness = search_fitness if wrap_fitness is None else wrap_fitness(search_fitness)
    res = run_grid(alg, fitness, (np.full(D, low), np.full(D, high)), keys, cfg.budget.pop_size, cfg.budget.iterations,
                   max_evals=cfg.budget.max_evals, config=None if configs else cfg.optimizer_config,
                   configs=configs, aux=aux, devices=devices, progress=progress)
    return jnp.asarray(res.best_x), jnp.asarray(res.curve), jnp.asarray(res.evals_curve)


def train_rows(prep: Prepared, capacity: int | None = None):
    """The fast fitness's data (:class:`icgo.models.relm.TrainRows`, leading member axis): each member's training
    rows gathered, padded with weight-0 rows where members have different numbers of them (or, with ``capacity``,
    always padded to that many rows)."""
    n_train = np.asarray(prep.train).sum(axis=1).astype(int)
    if capacity is not None:
        return _train_rows(prep.data, int(capacity), True)
    return _train_rows(prep.data, int(n_train.max()), bool(n_train.min() != n_train.max()))


def check_search(curve, methods, ids) -> None:
    """A search in which no candidate was ever finite is a failed run, not a result.

    Args:
        curve: (S, R, T) best-so-far fitness. methods: the S labels. ids: the R repeat ids.
    Raises:
        ValueError: one line naming the first (method, repeat) whose best fitness is not finite.
    """
    bad = np.argwhere(~np.isfinite(np.asarray(curve)[..., -1]))
    if bad.size:
        s, r = bad[0]
        raise ValueError(f"study: the search of {methods[s]} (repeat {ids[r]}) never found a finite fitness "
                         f"({len(bad)} of {curve.shape[0] * curve.shape[1]} searches): every candidate's ridge "
                         f"solve failed; check the data (constant or non-finite features) and model.lam")


def tune(cfg: StudyConfig, prep: Prepared, n_fit: int):
    """Plain RELM's (hidden, lam) by the mean validation fitness over repeats on the grid (training rows only).

    Each cell draws theta from the repeat's model key (so the lambdas of one L
    share their theta, and the chosen cell's run reuses it) and scores it with the
    study's fitness mode (``validation``/``kfold``: fitted on part of the training
    rows, scored on the rest). Widths above ``n_fit`` (rows per fit) are left out,
    as the study refuses them. Returns (config at the chosen cell, tuning record).
    """
    low, high = (float(v) for v in cfg.model.theta_bounds)
    dtype = _plain_dtype(cfg)
    grid = []
    for hidden in (h for h in _relm.TUNE_HIDDEN if h <= n_fit):
        for lam in _relm.TUNE_LAMBDA:
            _, f = _plain(prep.key, prep.data, lam, hidden, low, high, dtype)
            f = np.asarray(f)
            grid.append({"hidden": hidden, "lam": lam, "val_mean": float(f.mean()), "val_std": float(f.std(ddof=1))
                         if f.size > 1 else 0.0})
    best = min(grid, key=lambda g: g["val_mean"])
    log.info("tuned plain RELM: hidden %d, lam %g (mean validation fitness %.4g)", best["hidden"], best["lam"],
             best["val_mean"])
    return (cfg.replace(model={"hidden": best["hidden"], "lam": best["lam"]}),
            {"hidden": best["hidden"], "lam": best["lam"], "grid": grid})


def execution_record(cfg: StudyConfig, plan: ExecutionPlan) -> dict:
    """run.json's ``execution``: the plan, the fitness function that ran and its precision (record key ``dtype``)."""
    if cfg.optimizer is None:
        return {**plan._asdict(), "fitness": "icgo.models.relm.fitness (plain RELM, no search)", "dtype": cfg.precision}
    name = search_kernel(cfg.precision, cfg.fitness.mode, plan.kernel).name
    module = {"fused_train_fitness": "relm_fused", "gram_fitness": "relm_gram", "gram_train_fitness": "relm_gram"}.get(
        name, "relm")
    return {**plan._asdict(), "fitness": f"icgo.models.{module}.{name}", "dtype": cfg.precision}
