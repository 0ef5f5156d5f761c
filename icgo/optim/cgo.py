"""Chaos game optimization (CGO) with the ICGO 4th-seed mutations.

ICGO paper section 2.2, eqs. 10-18; Talatahari & Azizi (2021). Every seed i
of the population builds a temporary triangle (GB, MG_i, X_i) and spawns four
new seeds per iteration (eqs. 12-15); the 4th is replaced by a chaotic,
Gaussian or wavelet mutation (eqs. 16-18) or by all three in a three-stage
schedule (see :mod:`icgo.optim.mutation`). Four fitness evaluations per seed
per iteration.

Three variants (static ``variant`` option):

* ``paper`` (default): the ICGO paper's text. Seeds 2 and 3 as in eqs. 13-14
  (``GB + a(b X - g MG)``, ``MG + a(b X - g GB)``); one scalar alpha per seed
  drawn from the four forms of the original CGO; beta, gamma in {1, 2} (the
  paper's definition of gamma, applied to beta); 4th seed per eq. 15 (x_k + R
  on a random subset of dimensions); per-seed greedy selection (best of X_i
  and its four seeds replaces X_i); MG_i the mean of k_i distinct random
  seeds, k_i ~ U{1..N}.
* ``matlab``: the original MATLAB code: per-dimension alpha, seeds 2 and 3 as
  ``GB + a(b MG - g X)`` and ``MG + a(b GB - g X)``, seed 4 a uniform random
  point, and the (N + 4N) pool sorted with the best N kept; MG_i as ``paper``.
  One deviation: the MATLAB code re-reads GB after every seed (a sequential
  loop over seeds); here GB is the best at the start of the iteration, so the
  whole population is evaluated in one batched call.
* ``mealpy``: mealpy 3.x ``OriginalCGO``, the port of the original CGO paper's
  text (Talatahari & Azizi 2021) the optimizer study compares against: seeds
  as ``paper``; beta, gamma in {0, 1} (the die of the paper's Fig. 4, so a
  seed can be a plain copy of X_i, GB or MG_i); alpha1 = rand, alpha2 =
  2 rand, alpha3 = 1 + rand rand; MG_i the mean of exactly 3 distinct random
  seeds; 4th seed per eq. 15; greedy selection. Deviations: GB and MG_i come
  from the population at the start of the iteration (mealpy updates seeds in
  place, one after another), and the 4th seed mutates at least one dimension
  (mealpy draws k in {0..D-1}, so k = 0 spends an evaluation on X_i itself).

All new seeds are clipped to the bounds (``bound_mode`` offers two other repairs).
"""

from __future__ import annotations

import dataclasses
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp

from icgo.optim import mutation as mut
from icgo.optim.base import Algorithm, State, evaluate, first_state, register, uniform_population, update_best

VARIANTS = ("paper", "matlab", "mealpy")
SELECTIONS = ("greedy", "truncation")
BOUND_MODES = ("clip", "midpoint", "random")


@partial(jax.tree_util.register_dataclass,
         data_fields=["strategy", "selection", "bg_low", "mg_size", "dims", "original_uniform", "step_scale",
                      "sigma", "mu", "wavelet_g", "wavelet_zeta", "wavelet_bounded", "stage_bounds", "stage_order",
                      "bound_mode"],
         meta_fields=["variant", "chaos_guard"])
@dataclasses.dataclass(frozen=True)
class CGOConfig:
    """CGO hyperparameters (numeric fields are data and may be vmapped).

    Attributes:
        strategy: 4th-seed strategy, name or index into ``mutation.STRATEGIES``
            (0 original, 1 chaos, 2 gaussian, 3 wavelet, 4 three_stage).
        variant: ``paper``, ``matlab`` or ``mealpy`` (static; see module docstring).
        selection: ``greedy`` (0) or ``truncation`` (1); None -> by variant.
        bg_low: beta, gamma drawn from {bg_low, bg_low + 1}; None -> by
            variant: 1 for ``paper`` (its "random integer 1 or 2") and
            ``matlab``, 0 for ``mealpy`` (the {0, 1} die of Fig. 4).
        mg_size: MG_i is the mean of this many distinct random seeds (capped
            at the population size); 0 draws the count k_i ~ U{1..N} per seed.
            None -> by variant: 0 for ``paper`` and ``matlab``, 3 for ``mealpy``.
        dims: mutated coordinates of the 4th seed: ``subset`` (0, random
            subset of random size >= 1), ``all`` (1), ``one`` (2).
        original_uniform: 4th seed ``original`` is a uniform random point (the
            MATLAB code) instead of eq. 15; None -> by variant.
        step_scale: multiplier of the 4th-seed perturbation (scalar or (D,)),
            in units of the variables; 1 = the paper's literal amplitudes.
        sigma: Gaussian mutation standard deviation (eq. 16), before scaling.
        mu: logistic map parameter in [3.57, 4] (eq. 17).
        chaos_guard: short-cycle guard of the logistic map (static).
        wavelet_g: upper limit g of the wavelet dilation (Ling et al.: 10000).
        wavelet_zeta: shape zeta of the dilation schedule.
        wavelet_bounded: Ling's bound-relative step x + s (ub - x) / x + s (x - lb)
            instead of the paper's additive x + psi.
        stage_bounds: fractions of the run where stages 2 and 3 of
            ``three_stage`` start (default thirds).
        stage_order: strategy indices of stages 1-3 (default chaos, gaussian,
            wavelet).
        bound_mode: out-of-box coordinates of a new seed are ``clip``-ped (0,
            both reference codes), set to the ``midpoint`` of the parent and
            the violated bound (1), or redrawn uniformly in the box (2,
            ``random``).
    """

    strategy: Any = 0
    variant: str = "paper"
    selection: Any = None
    bg_low: Any = None
    mg_size: Any = None
    dims: Any = 0
    original_uniform: Any = None
    step_scale: Any = 1.0
    sigma: Any = 1.0
    mu: Any = 4.0
    chaos_guard: bool = True
    wavelet_g: Any = 10000.0
    wavelet_zeta: Any = 5.0
    wavelet_bounded: Any = False
    stage_bounds: Any = (1.0 / 3.0, 2.0 / 3.0)
    stage_order: Any = (mut.CHAOS, mut.GAUSSIAN, mut.WAVELET)
    bound_mode: Any = 0

    def __post_init__(self):
        if self.variant not in VARIANTS:
            raise ValueError(f"unknown CGO variant {self.variant!r}; choose one of {VARIANTS}")
        set_ = partial(object.__setattr__, self)
        if isinstance(self.strategy, str):
            set_("strategy", mut.strategy_index(self.strategy))
        if self.selection is None:
            set_("selection", 1 if self.variant == "matlab" else 0)
        elif isinstance(self.selection, str):
            if self.selection not in SELECTIONS:
                raise ValueError(f"unknown CGO selection {self.selection!r}; choose one of {SELECTIONS}")
            set_("selection", SELECTIONS.index(self.selection))
        if self.bg_low is None:
            set_("bg_low", 0 if self.variant == "mealpy" else 1)
        if self.mg_size is None:
            set_("mg_size", 3 if self.variant == "mealpy" else 0)
        elif isinstance(self.mg_size, (int, float)) and (self.mg_size < 0 or self.mg_size != int(self.mg_size)):
            raise ValueError(f"CGO mg_size must be an integer >= 0 (0 = random group size), got {self.mg_size}")
        if self.original_uniform is None:
            set_("original_uniform", self.variant == "matlab")
        if isinstance(self.dims, str):
            if self.dims not in mut.DIM_MODES:
                raise ValueError(f"unknown CGO dims mode {self.dims!r}; choose one of {mut.DIM_MODES}")
            set_("dims", mut.DIM_MODES.index(self.dims))
        if isinstance(self.bound_mode, str):
            if self.bound_mode not in BOUND_MODES:
                raise ValueError(f"unknown CGO bound_mode {self.bound_mode!r}; choose one of {BOUND_MODES}")
            set_("bound_mode", BOUND_MODES.index(self.bound_mode))
        if isinstance(self.stage_order, (tuple, list)):
            order = tuple(mut.strategy_index(x) if isinstance(x, str) else x for x in self.stage_order)
            if len(order) != 3 or any(isinstance(x, int) and not 0 <= x <= 3 for x in order):
                raise ValueError("CGO stage_order must name 3 single strategies (original/chaos/gaussian/wavelet)")
            set_("stage_order", order)
        if isinstance(self.mu, (int, float)) and not 3.57 <= self.mu <= 4.0:
            raise ValueError(f"CGO mu must be in [3.57, 4], got {self.mu}")

    @classmethod
    def matlab(cls, **kw) -> "CGOConfig":
        """Config of the original MATLAB code."""
        return cls(variant="matlab", **kw)


def _alphas(key, P: int, D_alpha: int, dtype) -> jax.Array:
    """Step sizes alpha for seeds 1-3, shape (P, 3, D_alpha).

    The four forms of the original CGO (its eq. 7): rand, 2 rand - 1,
    Ir rand + 1, Ir rand + (1 - Ir), Ir in {0, 1}; each of the three seeds
    takes one form chosen at random (the MATLAB ``ii = randi(4, 1, 3)``).
    """
    k_r, k_ir, k_ii = jax.random.split(key, 3)
    r = jax.random.uniform(k_r, (P, 4, D_alpha), dtype)
    ir = jax.random.randint(k_ir, (P, 2, 1), 0, 2).astype(dtype)
    forms = jnp.stack([r[:, 0], 2 * r[:, 1] - 1, ir[:, 0] * r[:, 2] + 1, ir[:, 1] * r[:, 3] + (1 - ir[:, 1])], axis=1)
    ii = jax.random.randint(k_ii, (P, 3), 0, 4)
    return jnp.take_along_axis(forms, ii[:, :, None], axis=1)


def _alphas_mealpy(key, P: int, dtype) -> jax.Array:
    """mealpy's step sizes (P, 3, 1): alpha1 = rand, alpha2 = 2 rand, alpha3 = 1 + rand rand."""
    r = jax.random.uniform(key, (P, 4, 1), dtype)
    return jnp.stack([r[:, 0], 2 * r[:, 1], 1 + r[:, 2] * r[:, 3]], axis=1)


def mean_groups(key, X: jax.Array, size=0) -> jax.Array:
    """MG_i: mean of k_i distinct random seeds, shape (P, D).

    Args:
        key: PRNG key.
        X: population, (P, D).
        size: group size (int data); 0 draws k_i ~ U{1..N} per seed, a value
            above N is capped at N.
    """
    P = X.shape[0]
    k_k, k_perm = jax.random.split(key)
    k = jax.random.randint(k_k, (P, 1), 1, P + 1)
    k = jnp.where(size > 0, jnp.minimum(size, P), k)
    rank = jnp.argsort(jnp.argsort(jax.random.uniform(k_perm, (P, P)), axis=1), axis=1)
    w = (rank < k).astype(X.dtype) / k.astype(X.dtype)
    return w @ X


def repair(key, S, parent, lb, ub, mode) -> jax.Array:
    """Bring new seeds back into the box [lb, ub].

    Args:
        key: PRNG key (``random`` mode).
        S: new seeds, shape (..., D).
        parent: the seeds' parent X_i, broadcastable to ``S``.
        lb, ub: bounds, (D,).
        mode: int data: 0 clip, 1 midpoint of parent and violated bound,
            2 uniform redraw of the violated coordinates.

    Returns:
        Seeds inside the box, same shape as ``S``.
    """
    low, high = S < lb, S > ub
    mid = jnp.where(low, 0.5 * (parent + lb), jnp.where(high, 0.5 * (parent + ub), S))
    rnd = jnp.where(low | high, lb + jax.random.uniform(key, S.shape, S.dtype) * (ub - lb), S)
    out = jnp.where(mode == 1, mid, jnp.where(mode == 2, rnd, S))
    return jnp.clip(out, lb, ub)


def _init(key, fitness, lb, ub, pop_size, config, aux) -> State:
    k_pop, k_chaos = jax.random.split(key)
    pop = uniform_population(k_pop, lb, ub, pop_size)  # eq. 11
    chaos = mut.chaos_init(k_chaos, pop.shape, pop.dtype)
    return first_state(fitness, lb, ub, pop, config, aux, chaos)


def _step(state: State, key, t, T, fitness) -> State:
    cfg: CGOConfig = state.ctx.config
    lb, ub, aux = state.ctx.lb, state.ctx.ub, state.ctx.aux
    X, f = state.pop, state.fit
    P, D = X.shape
    ks = jax.random.split(key, 7)

    GB = state.best_x[None, :]
    MG = mean_groups(ks[0], X, cfg.mg_size)
    if cfg.variant == "mealpy":
        alpha = _alphas_mealpy(ks[1], P, X.dtype)
    else:
        alpha = _alphas(ks[1], P, D if cfg.variant == "matlab" else 1, X.dtype)
    bg = jax.random.randint(ks[2], (P, 6, 1), cfg.bg_low, cfg.bg_low + 2).astype(X.dtype)
    a1, a2, a3 = alpha[:, 0], alpha[:, 1], alpha[:, 2]
    b1, g1, b2, g2, b3, g3 = (bg[:, j] for j in range(6))

    S1 = X + a1 * (b1 * GB - g1 * MG)  # eq. 12
    if cfg.variant == "matlab":
        S2 = GB + a2 * (b2 * MG - g2 * X)
        S3 = MG + a3 * (b3 * GB - g3 * X)
    else:
        S2 = GB + a2 * (b2 * X - g2 * MG)  # eq. 13
        S3 = MG + a3 * (b3 * X - g3 * GB)  # eq. 14
    eff = mut.effective_strategy(cfg.strategy, t, T, cfg.stage_bounds, cfg.stage_order)
    mask = mut.dims_mask(ks[3], (P, D), cfg.dims)
    S4 = mut.mutate(ks[4], X, mask, state.extra, eff, t, T, lb, ub, cfg)  # eqs. 15-18

    seeds = repair(ks[6], jnp.stack([S1, S2, S3, S4], axis=1), X[:, None], lb, ub, cfg.bound_mode)  # (P, 4, D)
    fs = evaluate(fitness, seeds.reshape(4 * P, D), aux).reshape(P, 4)

    cand = jnp.concatenate([X[:, None], seeds], axis=1)  # (P, 5, D)
    cand_f = jnp.concatenate([f[:, None], fs], axis=1)
    # greedy: best of parent and its 4 seeds
    j = jnp.argmin(cand_f, axis=1)
    g_x = jnp.take_along_axis(cand, j[:, None, None], axis=1)[:, 0]
    g_f = jnp.take_along_axis(cand_f, j[:, None], axis=1)[:, 0]
    # truncation: best N of the (N + 4N) pool (stable sort keeps parents first on ties)
    order = jnp.argsort(jnp.concatenate([f, fs.T.reshape(-1)]), stable=True)[:P]
    pool = jnp.concatenate([X, jnp.transpose(seeds, (1, 0, 2)).reshape(4 * P, D)])
    pool_f = jnp.concatenate([f, fs.T.reshape(-1)])
    trunc = cfg.selection == 1
    new_X = jnp.where(trunc, pool[order], g_x)
    new_f = jnp.where(trunc, pool_f[order], g_f)

    chaos = mut.logistic_step(ks[5], state.extra, cfg.mu, cfg.chaos_guard)
    best_x, best_f = update_best(state.best_x, state.best_f, new_X, new_f)
    return State(new_X, new_f, best_x, best_f, state.n_evals + 4 * P, chaos, state.ctx)


def _evals(pop_size: int, config) -> tuple[int, int]:
    return pop_size, 4 * pop_size


CGO = register(Algorithm("cgo", CGOConfig, _init, _step, _evals))
