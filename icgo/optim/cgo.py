"""Chaos game optimization (CGO) with the ICGO 4th-seed mutations.

ICGO paper section 2.2, eqs. 10-18; Talatahari & Azizi (2021). Every seed i
of the population builds a temporary triangle (GB, MG_i, X_i) and spawns four
new seeds per iteration (eqs. 12-15); the 4th is replaced by a chaotic,
Gaussian or wavelet mutation (eqs. 16-18) or by all three in a three-stage
schedule (see :mod:`icgo.optim.mutation`). Four fitness evaluations per seed
per iteration.

Three variants, each built by its factory ``CGOConfig.paper()`` (the
defaults), ``CGOConfig.matlab()``, ``CGOConfig.mealpy()``; the factory sets
the variant's fields (:data:`VARIANT_SETTINGS`: the alpha forms, the seed
2/3 formulas, the selection, the die, the mean group, the 4th seed of
``original``), so each difference between the variants is also an option of
its own. ``CGO.axis`` is ``"strategy"``: a
study runs 4th-seed strategies side by side with
``run_batch(configs=CGO.axis_configs(config, strategies))``.

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
``fourth_seed=False`` drops the 4th seed (three seeds, three evaluations per
member and iteration): the control of the Fig. 9 ablation. :func:`advance`
is one step together with what happened to each seed (:class:`SeedOutcome`:
did it improve on its parent, was it selected), for the diagnostic that
counts them (:mod:`icgo.studies.icgo_relm.cgo_seeds`).
"""

from __future__ import annotations

import dataclasses
from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from icgo.optim import mutation as mut
from icgo.optim.base import Algorithm, State, evaluate, first_state, uniform_population, update_best

VARIANTS = ("paper", "matlab", "mealpy")
SELECTIONS = ("greedy", "truncation")
BOUND_MODES = ("clip", "midpoint", "random")
#: Step sizes alpha of seeds 1-3: one scalar per seed from the original CGO's four forms, the same forms per
#: dimension (the MATLAB code), or mealpy's three fixed forms.
ALPHAS = ("seed", "dimension", "mealpy")
#: Seeds 2 and 3: eqs. 13-14 as printed (``paper``) or the MATLAB code's operands (``matlab``).
SEED_FORMS = ("paper", "matlab")

#: What each variant sets: the published setting that ``CGOConfig.paper() / .matlab() / .mealpy()`` fill in.
VARIANT_SETTINGS = {
    "paper": {"selection": "greedy", "bg_low": 1, "mg_size": 0, "original_uniform": False, "alpha": "seed",
              "seed_form": "paper"},
    "matlab": {"selection": "truncation", "bg_low": 1, "mg_size": 0, "original_uniform": True, "alpha": "dimension",
               "seed_form": "matlab"},
    "mealpy": {"selection": "greedy", "bg_low": 0, "mg_size": 3, "original_uniform": False, "alpha": "mealpy",
               "seed_form": "paper"},
}
VARIANT_FIELDS = ("selection", "bg_low", "mg_size", "original_uniform", "alpha", "seed_form")


def _scalar(v) -> bool:
    """True for a concrete Python/numpy number (not a bool, array or tracer)."""
    return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))


def _differs(a, b) -> bool:
    """``a != b`` for concrete values; anything that cannot be compared (arrays, tracers) counts as different."""
    try:
        return bool(a != b)
    except Exception:  # noqa: BLE001  (array truth value, tracer conversion)
        return True


def _choice(name, value, choices):
    if not isinstance(value, str) or value not in choices:
        raise ValueError(f"unknown CGO {name} {value!r}; choose one of {choices} (static option)")
    return value


def _flag(name, value):
    if not isinstance(value, (bool, np.bool_)):
        raise ValueError(f"CGO {name} must be True or False (static option), got {value!r}")
    return bool(value)


@partial(jax.tree_util.register_dataclass,
         data_fields=["strategy", "bg_low", "mg_size", "step_scale", "sigma", "mu", "wavelet_g", "wavelet_zeta",
                      "stage_bounds", "stage_order"],
         meta_fields=["variant", "selection", "dims", "original_uniform", "wavelet_bounded", "bound_mode",
                      "chaos_guard", "wavelet_stage_clock", "wavelet_amplitude", "alpha", "seed_form", "fourth_seed",
                      "overrides", "mutations"])
@dataclasses.dataclass(frozen=True)
class CGOConfig:
    """CGO hyperparameters: data fields are traced (and may be vmapped), static fields select code.

    The defaults are the ``paper`` variant. Build a variant with its factory,
    :meth:`paper`, :meth:`matlab` or :meth:`mealpy` (or :meth:`build` with the
    variant as a keyword, for config files); each sets every field in
    :data:`VARIANT_FIELDS` to the variant's published setting
    (:data:`VARIANT_SETTINGS`), and the keywords given to it win. A config whose
    variant fields differ from its variant's setting must name them in
    ``overrides`` (the factories do this for the keywords they are given);
    otherwise ``__post_init__`` raises. So ``dataclasses.replace(CGOConfig.paper(),
    variant="matlab")`` and ``CGOConfig(variant="mealpy")`` raise instead of
    silently mixing one variant's code with another's settings.

    Attributes:
        strategy: 4th-seed strategy (data), name or index into the registry ``mutation.MUTATIONS``
            (0 original, 1 chaos, 2 gaussian, 3 wavelet, 4 three_stage, then a user's own); the
            axis a study runs side by side (``CGO.axis``).
        variant: ``paper``, ``matlab`` or ``mealpy`` (static; the preset of
            :data:`VARIANT_FIELDS`, see the module docstring).
        selection: ``greedy`` (best of X_i and its 4 seeds) or ``truncation``
            (best N of the N + 4N pool) (static). By variant: truncation for
            ``matlab``, greedy otherwise.
        bg_low: beta, gamma drawn from {bg_low, bg_low + 1} (data). By variant:
            1 for ``paper`` (its "random integer 1 or 2") and ``matlab``, 0 for
            ``mealpy`` (the {0, 1} die of Fig. 4).
        mg_size: MG_i is the mean of this many distinct random seeds (data,
            capped at the population size); 0 draws the count k_i ~ U{1..N}
            per seed. By variant: 0 for ``paper`` and ``matlab``, 3 for ``mealpy``.
        dims: mutated coordinates of the 4th seed (static): ``subset`` (random
            subset of random size >= 1), ``all``, ``one``.
        original_uniform: 4th seed ``original`` is a uniform random point (the
            MATLAB code) instead of eq. 15 (static). By variant: True for ``matlab``.
        step_scale: multiplier of the 4th-seed perturbation (scalar or (D,)),
            in units of the variables; 1 = the paper's literal amplitudes.
        sigma: Gaussian mutation standard deviation (eq. 16), before scaling.
        mu: logistic map parameter in [3.57, 4] (eq. 17).
        chaos_guard: short-cycle guard of the logistic map (static).
        wavelet_g: upper limit g of the wavelet dilation (Ling et al.: 10000).
        wavelet_zeta: shape zeta of the dilation schedule.
        wavelet_bounded: Ling's bound-relative step x + s (ub - x) / x + s (x - lb)
            instead of the paper's additive x + psi (static).
        stage_bounds: fractions of the run where stages 2 and 3 of
            ``three_stage`` start (default thirds; data).
        stage_order: operator indices (or names) of stages 1-3 (default chaos, gaussian,
            wavelet; data).
        wavelet_stage_clock: in ``three_stage``, the wavelet's dilation runs on its
            stage's own clock (:func:`icgo.optim.mutation.stage_clock`) instead of
            the whole run's ``t/T`` (static; default False, the run's clock).
        wavelet_amplitude: ``ling`` (the step carries Ling et al.'s ``a^(-1/2)``)
            or ``none`` (the Morlet value alone) (static).
        bound_mode: out-of-box coordinates of a new seed are ``clip``-ped (both
            reference codes), set to the ``midpoint`` of the parent and the
            violated bound, or redrawn uniformly in the box (``random``) (static).
        alpha: step sizes of seeds 1-3 (static, :data:`ALPHAS`): ``seed`` (one
            scalar per seed and member, from the original CGO's four forms),
            ``dimension`` (the same forms per dimension) or ``mealpy`` (rand,
            2 rand, 1 + rand rand). By variant: seed, dimension, mealpy.
        seed_form: seeds 2 and 3 (static, :data:`SEED_FORMS`): ``paper``
            (eqs. 13-14, ``GB + a(b X - g MG)``, ``MG + a(b X - g GB)``) or
            ``matlab`` (``GB + a(b MG - g X)``, ``MG + a(b GB - g X)``). By
            variant: matlab for ``matlab``, paper otherwise.
        fourth_seed: spawn the 4th seed (static; default True). False leaves
            three seeds per member (3 evaluations per member and iteration):
            a control, not a reading of the paper.
        overrides: the variant fields deliberately set away from the variant's
            setting (static, sorted names; filled in by the factories).
        mutations: the registry's strategy names in index order when the config was built (static; filled in
            whenever ``strategy`` is given by name, or when empty): the branches of the 4th seed's
            ``lax.switch`` (:func:`icgo.optim.mutation.mutate`), so a program compiled before a user registered
            a strategy is never reused for one built after.
    """

    strategy: Any = 0
    variant: str = "paper"
    selection: str = "greedy"
    bg_low: Any = 1
    mg_size: Any = 0
    dims: str = "subset"
    original_uniform: bool = False
    step_scale: Any = 1.0
    sigma: Any = 1.0
    mu: Any = 4.0
    chaos_guard: bool = True
    wavelet_g: Any = 10000.0
    wavelet_zeta: Any = 5.0
    wavelet_bounded: bool = False
    stage_bounds: Any = (1.0 / 3.0, 2.0 / 3.0)
    stage_order: Any = mut.STAGE_ORDER
    wavelet_stage_clock: bool = False
    wavelet_amplitude: str = "ling"
    bound_mode: str = "clip"
    alpha: str = "seed"
    seed_form: str = "paper"
    fourth_seed: bool = True
    overrides: tuple = ()
    mutations: tuple = ()

    def __post_init__(self):
        set_ = partial(object.__setattr__, self)
        _choice("variant", self.variant, VARIANTS)
        _choice("selection", self.selection, SELECTIONS)
        _choice("dims mode", self.dims, mut.DIM_MODES)
        _choice("bound_mode", self.bound_mode, BOUND_MODES)
        _choice("wavelet_amplitude", self.wavelet_amplitude, mut.WAVELET_AMPLITUDES)
        _choice("alpha", self.alpha, ALPHAS)
        _choice("seed_form", self.seed_form, SEED_FORMS)
        set_("fourth_seed", _flag("fourth_seed", self.fourth_seed))
        set_("original_uniform", _flag("original_uniform", self.original_uniform))
        set_("wavelet_bounded", _flag("wavelet_bounded", self.wavelet_bounded))
        set_("chaos_guard", _flag("chaos_guard", self.chaos_guard))
        set_("wavelet_stage_clock", _flag("wavelet_stage_clock", self.wavelet_stage_clock))
        set_("mutations", tuple(self.mutations))
        if isinstance(self.strategy, str) or not self.mutations:
            set_("mutations", tuple(mut.MUTATIONS))  # the registry only grows: earlier indices keep their names
        if tuple(mut.MUTATIONS)[:len(self.mutations)] != self.mutations:
            raise ValueError(f"CGO mutations {self.mutations} are not the registry's strategies in index order "
                             f"{tuple(mut.MUTATIONS)}; register a strategy of your own before building its config")
        if isinstance(self.strategy, str) or _scalar(self.strategy):
            set_("strategy", mut.strategy_index(self.strategy))
            if self.strategy >= len(self.mutations):
                raise ValueError(f"CGO strategy {self.strategy} is not among this config's strategies "
                                 f"{self.mutations}; give it by name")
        if _scalar(self.mg_size) and (self.mg_size < 0 or self.mg_size != int(self.mg_size)):
            raise ValueError(f"CGO mg_size must be an integer >= 0 (0 = random group size), got {self.mg_size}")
        if isinstance(self.stage_order, (tuple, list)):
            order = tuple(mut.strategy_index(x) if isinstance(x, str) else x for x in self.stage_order)
            if len(order) != 3 or any(_scalar(x) and not (0 <= x < len(self.mutations) and mut.is_operator(x))
                                      for x in order):
                ops = [n for n in self.mutations if mut.MUTATIONS[n].operator is not None]
                raise ValueError(f"CGO stage_order must name 3 single strategies (operators: {'/'.join(ops)})")
            set_("stage_order", order)
        if _scalar(self.mu) and not 3.57 <= self.mu <= 4.0:
            raise ValueError(f"CGO mu must be in [3.57, 4], got {self.mu}")
        over = self.overrides
        if isinstance(over, str) or not isinstance(over, (tuple, list)) or any(f not in VARIANT_FIELDS for f in over):
            raise ValueError(f"CGO overrides must be a tuple of names from {VARIANT_FIELDS}, got {over!r}")
        set_("overrides", tuple(sorted(set(over))))
        want = VARIANT_SETTINGS[self.variant]
        bad = [f for f in VARIANT_FIELDS if f not in self.overrides and _concrete_differs(getattr(self, f), want[f])]
        if bad:
            got = ", ".join(f"{f}={getattr(self, f)!r}" for f in bad)
            need = ", ".join(f"{f}={want[f]!r}" for f in bad)
            raise ValueError(f"CGO variant {self.variant!r} sets {need}, this config has {got}: build it with "
                             f"CGOConfig.{self.variant}(...), which records deliberate changes in overrides")

    @classmethod
    def paper(cls, **kw) -> "CGOConfig":
        """The ICGO paper's text (the default); keywords override any field."""
        return cls._variant("paper", kw)

    @classmethod
    def matlab(cls, **kw) -> "CGOConfig":
        """The original MATLAB code; keywords override any field."""
        return cls._variant("matlab", kw)

    @classmethod
    def mealpy(cls, **kw) -> "CGOConfig":
        """mealpy 3.x ``OriginalCGO``; keywords override any field."""
        return cls._variant("mealpy", kw)

    @classmethod
    def build(cls, variant: str = "paper", **kw) -> "CGOConfig":
        """The factory of ``variant`` called with ``kw`` (for config files: ``optimizer.params``)."""
        _choice("variant", variant, VARIANTS)
        return cls._variant(variant, kw)

    @classmethod
    def _variant(cls, variant: str, kw: dict) -> "CGOConfig":
        if "variant" in kw:
            raise ValueError("CGOConfig factories take the variant from their name; do not pass variant=")
        want = VARIANT_SETTINGS[variant]
        changed = {f for f in VARIANT_FIELDS if f in kw and _differs(kw[f], want[f])}
        overrides = tuple(sorted(changed | set(kw.pop("overrides", ()))))
        return cls(**{**want, **kw, "variant": variant, "overrides": overrides})


def _concrete_differs(value, want) -> bool:
    """A concrete value that differs from ``want``; traced or stacked values are not checked."""
    if isinstance(value, (str, bool, np.bool_)) or _scalar(value):
        return _differs(value, want)
    return False


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


def repair(key, S, parent, lb, ub, mode: str = "clip") -> jax.Array:
    """Bring new seeds back into the box [lb, ub].

    Args:
        key: PRNG key (``random`` mode).
        S: new seeds, shape (..., D).
        parent: the seeds' parent X_i, broadcastable to ``S``.
        lb, ub: bounds, (D,).
        mode: static, one of :data:`BOUND_MODES`: ``clip``, ``midpoint`` (of
            the parent and the violated bound) or ``random`` (uniform redraw of
            the violated coordinates).

    Returns:
        Seeds inside the box, same shape as ``S``.
    """
    _choice("bound_mode", mode, BOUND_MODES)
    if mode == "midpoint":
        S = jnp.where(S < lb, 0.5 * (parent + lb), jnp.where(S > ub, 0.5 * (parent + ub), S))
    elif mode == "random":
        S = jnp.where((S < lb) | (S > ub), lb + jax.random.uniform(key, S.shape, S.dtype) * (ub - lb), S)
    return jnp.clip(S, lb, ub)


def _chosen(f, fs, selection: str):
    """Which candidates the selection keeps: greedy, the index j in [parent, seeds] of each member's best (P,);
    truncation, the indices of the best P of the pool [parents, seed 1 of every member, seed 2, ...] (P,)."""
    if selection == "greedy":
        return jnp.argmin(jnp.concatenate([f[:, None], fs], axis=1), axis=1)
    return jnp.argsort(jnp.concatenate([f, fs.T.reshape(-1)]), stable=True)[:f.shape[0]]


def select(X, f, seeds, fs, selection: str = "greedy"):
    """The next population from the parents and their seeds.

    Args:
        X: parents, shape (P, D); f: their fitness, (P,).
        seeds: the K new seeds of each parent (4, or 3 without the 4th seed), (P, K, D); fs: their fitness, (P, K).
        selection: static, ``greedy`` (each X_i is replaced by the best of
            itself and its K seeds) or ``truncation`` (the best P of the
            P + KP pool, ascending; a stable sort keeps parents first on ties).

    Returns:
        ``(new_X (P, D), new_f (P,))``.
    """
    _choice("selection", selection, SELECTIONS)
    P, K, D = seeds.shape
    j = _chosen(f, fs, selection)
    if selection == "greedy":
        cand = jnp.concatenate([X[:, None], seeds], axis=1)  # (P, K + 1, D)
        cand_f = jnp.concatenate([f[:, None], fs], axis=1)
        return (jnp.take_along_axis(cand, j[:, None, None], axis=1)[:, 0],
                jnp.take_along_axis(cand_f, j[:, None], axis=1)[:, 0])
    pool_f = jnp.concatenate([f, fs.T.reshape(-1)])
    pool = jnp.concatenate([X, jnp.transpose(seeds, (1, 0, 2)).reshape(K * P, D)])
    return pool[j], pool_f[j]


class SeedOutcome(NamedTuple):
    """What happened to each seed of one iteration, shape (P, K) each (K = 4, or 3 without the 4th seed).

    Attributes:
        improved: the seed's fitness is below its parent's.
        chosen: the selection kept the seed (greedy: it replaced its parent; truncation: it is among the best P).
    """

    improved: jax.Array
    chosen: jax.Array


def seed_outcome(f, fs, selection: str = "greedy") -> SeedOutcome:
    """:class:`SeedOutcome` of seeds with fitness ``fs`` (P, K) spawned by parents with fitness ``f`` (P,)."""
    P, K = fs.shape
    j = _chosen(f, fs, selection)
    if selection == "greedy":
        chosen = (j[:, None] - 1) == jnp.arange(K)[None, :]
    else:
        kept = jnp.zeros(P + K * P, bool).at[j].set(True)
        chosen = kept[P:].reshape(K, P).T
    return SeedOutcome(fs < f[:, None], chosen)


def _init(key, fitness, lb, ub, pop_size, config, aux) -> State:
    k_pop, k_chaos = jax.random.split(key)
    pop = uniform_population(k_pop, lb, ub, pop_size)  # eq. 11
    chaos = mut.chaos_init(k_chaos, pop.shape, pop.dtype)
    return first_state(fitness, lb, ub, pop, config, aux, chaos)


def advance(state: State, key, t, T, fitness) -> tuple[State, SeedOutcome]:
    """One CGO iteration (eqs. 12-18, then the selection) and what happened to each of its seeds.

    Args:
        state: the optimizer state; key: this iteration's PRNG key; t, T: iteration and run length;
        fitness: ``fitness(pop, aux) -> (P,)``.
    Returns:
        (the next state, :class:`SeedOutcome` of this iteration's seeds).
    """
    cfg: CGOConfig = state.ctx.config
    lb, ub, aux = state.ctx.lb, state.ctx.ub, state.ctx.aux
    X, f = state.pop, state.fit
    P, D = X.shape
    ks = jax.random.split(key, 7)

    GB = state.best_x[None, :]
    MG = mean_groups(ks[0], X, cfg.mg_size)
    if cfg.alpha == "mealpy":
        alpha = _alphas_mealpy(ks[1], P, X.dtype)
    else:
        alpha = _alphas(ks[1], P, D if cfg.alpha == "dimension" else 1, X.dtype)
    bg = jax.random.randint(ks[2], (P, 6, 1), cfg.bg_low, cfg.bg_low + 2).astype(X.dtype)
    a1, a2, a3 = alpha[:, 0], alpha[:, 1], alpha[:, 2]
    b1, g1, b2, g2, b3, g3 = (bg[:, j] for j in range(6))

    S1 = X + a1 * (b1 * GB - g1 * MG)  # eq. 12
    if cfg.seed_form == "matlab":
        S2 = GB + a2 * (b2 * MG - g2 * X)
        S3 = MG + a3 * (b3 * GB - g3 * X)
    else:
        S2 = GB + a2 * (b2 * X - g2 * MG)  # eq. 13
        S3 = MG + a3 * (b3 * X - g3 * GB)  # eq. 14
    new = [S1, S2, S3]
    if cfg.fourth_seed:
        eff = mut.effective_strategy(cfg.strategy, t, T, cfg.stage_bounds, cfg.stage_order)
        mask = mut.dims_mask(ks[3], (P, D), cfg.dims)
        t_m, T_m = mut.stage_clock(cfg.strategy, t, T, cfg.stage_bounds) if cfg.wavelet_stage_clock else (t, T)
        new.append(mut.mutate(ks[4], X, mask, state.extra, eff, t_m, T_m, lb, ub, cfg))  # eqs. 15-18
    K = len(new)
    seeds = repair(ks[6], jnp.stack(new, axis=1), X[:, None], lb, ub, cfg.bound_mode)  # (P, K, D)
    fs = evaluate(fitness, seeds.reshape(K * P, D), aux).reshape(P, K)

    new_X, new_f = select(X, f, seeds, fs, cfg.selection)
    chaos = mut.logistic_step(ks[5], state.extra, cfg.mu, cfg.chaos_guard)
    best_x, best_f = update_best(state.best_x, state.best_f, new_X, new_f)
    return (State(new_X, new_f, best_x, best_f, state.n_evals + K * P, chaos, state.ctx),
            seed_outcome(f, fs, cfg.selection))


def _step(state: State, key, t, T, fitness) -> State:
    return advance(state, key, t, T, fitness)[0]


def _evals(pop_size: int, config) -> tuple[int, int]:
    seeds = 4 if config is None or config.fourth_seed else 3
    return pop_size, seeds * pop_size


CGO = Algorithm("cgo", CGOConfig, _init, _step, _evals, axis="strategy", config_factory=CGOConfig.build)
