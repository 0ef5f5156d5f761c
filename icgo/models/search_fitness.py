"""The fitness a study's search calls: one function whose data name the kernel that computes it.

:func:`search_fitness` ``(pop, aux: SearchData) -> (P,)`` dispatches on ``aux.kernel`` (:data:`SEARCH_KERNELS`) to
:func:`icgo.models.relm.fitness` (row-weighted, any fold mode), :func:`icgo.models.relm.train_fitness` (the CPU's
cache-chunked training fitness), :func:`icgo.models.relm_gram.gram_fitness` / :func:`icgo.models.relm_gram.gram_train_fitness`
(batched Gram sums) or :func:`icgo.models.relm_fused.fused_train_fitness` (the fused accelerator kernel). Every
search passes the same static fitness; the kernel, its precisions and L travel in the data's static fields.
"""

from __future__ import annotations

import dataclasses
from functools import partial
from typing import Any

import jax

from icgo.models import relm_fused
from icgo.models.relm import fitness, train_fitness
from icgo.models.relm_gram import gram_fitness, gram_train_fitness

#: The fitness kernels a search can run (:func:`search_fitness`), by their function's name.
SEARCH_KERNELS = ("fitness", "train_fitness", "gram_fitness", "gram_train_fitness", "fused_train_fitness")


@partial(jax.tree_util.register_dataclass, data_fields=["rows", "lam"],
         meta_fields=["hidden", "kernel", "feature_dtype", "solve_dtype"])
@dataclasses.dataclass(frozen=True)
class SearchData:
    """One repeat's data for :func:`search_fitness` (the optimizer's ``aux``).

    ``rows`` and ``lam`` are data (traced, vmapped over repeats), so one compiled search serves every
    ridge lambda; the other fields select code and are static (part of the pytree's structure, so JAX's
    own jit cache compiles once per setting).

    Attributes:
        rows: :class:`icgo.models.relm.TrainRows` (the ``*train_fitness`` kernels) or
            :class:`icgo.models.relm.FitData`.
        lam: ridge lambda, () per repeat.
        hidden: L.
        kernel: one of :data:`SEARCH_KERNELS`.
        feature_dtype: precision of eq. (8) (``train_fitness``, ``gram_*``; ``fused_train_fitness``: float32).
        solve_dtype: precision of the solve and the RMSE (``fitness``: ``"float32"`` casts everything to
            float32; ``gram_*``); ``train_fitness`` and ``fused_train_fitness`` solve in float64 always.
    """

    rows: Any
    lam: Any
    hidden: int
    kernel: str = "fitness"
    feature_dtype: str = "float64"
    solve_dtype: str = "float64"


def search_fitness(pop, aux: SearchData):
    """The fitness ``(P, 7 L) -> (P,)`` an optimizer calls with ``aux`` = :class:`SearchData`: the kernel it
    names (:data:`SEARCH_KERNELS`) on its rows, lambda and precisions. A plain function, so every search passes the
    same static fitness."""
    if aux.kernel == "fused_train_fitness":
        return relm_fused.fused_train_fitness(pop, aux.rows, aux.lam, aux.hidden)
    if aux.kernel == "train_fitness":
        return train_fitness(pop, aux.rows, aux.lam, aux.hidden, feature_dtype=aux.feature_dtype)
    if aux.kernel in ("gram_fitness", "gram_train_fitness"):
        kernel = gram_train_fitness if aux.kernel == "gram_train_fitness" else gram_fitness
        return kernel(pop, aux.rows, aux.lam, aux.hidden, aux.feature_dtype, aux.solve_dtype)
    if aux.kernel != "fitness":
        raise ValueError(f"unknown search kernel {aux.kernel!r}; choose one of {list(SEARCH_KERNELS)}")
    return fitness(pop, aux.rows, aux.lam, aux.hidden, None if aux.solve_dtype == "float64" else aux.solve_dtype)
