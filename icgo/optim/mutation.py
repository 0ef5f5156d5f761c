"""4th-seed mutation operators of ICGO (ICGO paper eqs. 15-18, section 2.2).

All operators act on the whole population at once: ``x`` has shape (P, D) and a
boolean ``mask`` (P, D) says which dimensions of each row are mutated (eqs.
15-18 write ``x_i^k``; which ``k`` is not said, see :func:`dims_mask`).

A strategy is a function registered by name in :data:`MUTATIONS` (one literal mapping; a researcher's own is
added with :func:`register`, docs/extending.md): ``operator(key, s: Fourth) -> S^4`` of shape (P, D), or a
schedule of operators (``three_stage``: ``cfg.stage_order``, one per stage). A config holds the strategy's
index in the registry (integer data), and :func:`mutate` picks the operator with ``lax.switch``, so one compiled
program serves every strategy of a batch side by side (vmapped).

Amplitudes are in the units of the search variable, as written in the paper
(``R ~ U(0, 1)``, ``r_t in (0, 1)``, ``psi in [-1, 1]``); CGO multiplies them
by its ``step_scale`` option (default 1).
"""

from __future__ import annotations

import re
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

#: Dimension-selection modes for the mutated coordinates (CGO ``dims`` option).
DIM_MODES = ("subset", "all", "one")


class Fourth(NamedTuple):
    """What a strategy's operator sees when it builds the fourth seeds S^4 of one iteration.

    Attributes:
        x: parents X_i, shape (P, D), in the units of the search variables.
        mask: coordinates to mutate, (P, D) bool (:func:`dims_mask`).
        r_chaos: the logistic-map state r_t, (P, D), in (0, 1) (eq. 17).
        t, T: iteration (0-based) and iteration count (the stage's own with ``wavelet_stage_clock``).
        lb, ub: bounds, (D,).
        cfg: the CGO config (``step_scale``, ``sigma``, ``wavelet_g``, ... ; :class:`icgo.optim.cgo.CGOConfig`).
    """

    x: Any
    mask: Any
    r_chaos: Any
    t: Any
    T: Any
    lb: Any
    ub: Any
    cfg: Any


class Mutation(NamedTuple):
    """One entry of :data:`MUTATIONS`.

    Attributes:
        operator: ``operator(key, s: Fourth) -> S^4``, shape (P, D), unclipped (CGO repairs it to the box); pure
            and traceable (it runs inside ``lax.switch`` under ``vmap``). None for a schedule of operators
            (``three_stage``: the operator of ``cfg.stage_order`` for the current stage, :func:`effective_strategy`).
        label: the strategy's name in tables and legends (``chaotic``).
    """

    operator: Callable | None
    label: str


def dims_mask(key, shape, mode: str = "subset") -> jax.Array:
    """Which coordinates of each row are mutated.

    Args:
        key: PRNG key.
        shape: (P, D).
        mode: static, one of :data:`DIM_MODES`: ``subset`` (a random subset of
            m_i ~ U{1..D} dimensions per row; at least one), ``all``, ``one``
            (a single random dimension).

    Returns:
        Boolean mask, shape (P, D).
    """
    if mode not in DIM_MODES:
        raise ValueError(f"unknown dims mode {mode!r}; choose one of {DIM_MODES} (static option)")
    P, D = shape
    if mode == "all":
        return jnp.ones(shape, bool)
    k_m, k_perm = jax.random.split(key)
    rank = jnp.argsort(jnp.argsort(jax.random.uniform(k_perm, (P, D)), axis=1), axis=1)
    m = 1 if mode == "one" else jax.random.randint(k_m, (P, 1), 1, D + 1)
    return rank < m


# --- chaos (eq. 17) -----------------------------------------------------------


def chaos_init(key, shape, dtype) -> jax.Array:
    """Initial logistic-map state in (0.01, 0.99), away from its fixed points."""
    return jax.random.uniform(key, shape, dtype, 0.01, 0.99)


def logistic_step(key, r, mu, guard=True) -> jax.Array:
    """One logistic-map step r <- mu r (1 - r) (eq. 17) with a short-cycle guard.

    In float32 the map falls into short cycles (period 436 or 4344 after
    31-2136 steps, ENGINEERING-NOTES) or onto the absorbing point 0. The guard
    (i) adds a jitter of 64 machine epsilons, which chaos amplifies, so a
    finite-precision cycle is left within a few steps, and (ii) re-seeds any
    value that has left (eps, 1 - eps) with a fresh U(0.01, 0.99) draw.

    Args:
        key: PRNG key.
        r: map state, any shape, in (0, 1).
        mu: map parameter in [3.57, 4].
        guard: apply the guard (False reproduces the bare map).

    Returns:
        Next state, same shape and dtype as ``r``.
    """
    r_next = mu * r * (1.0 - r)
    if not guard:
        return r_next
    eps = jnp.finfo(r.dtype).eps
    k_j, k_r = jax.random.split(key)
    r_next = r_next + 64 * eps * jax.random.uniform(k_j, r.shape, r.dtype, -1.0, 1.0)
    bad = (r_next <= 1e3 * eps) | (r_next >= 1.0 - 1e3 * eps)
    return jnp.where(bad, chaos_init(k_r, r.shape, r.dtype), r_next)


# --- wavelet (eq. 18, Ling et al. 2008) --------------------------------------


def wavelet_dilation(t, T, g, zeta) -> jax.Array:
    """Dilation a(t) = exp(-ln(g) (1 - t/T)^zeta + ln(g)): 1 at t=0 -> g at t=T."""
    s = jnp.clip(t / T, 0.0, 1.0)
    return jnp.exp(-jnp.log(g) * (1.0 - s) ** zeta + jnp.log(g))


def morlet(u) -> jax.Array:
    """Morlet mother wavelet psi(u) = exp(-u^2/2) cos(5u) (eq. 18 with u=(b-x)/a)."""
    return jnp.exp(-0.5 * u * u) * jnp.cos(5.0 * u)


#: Readings of the wavelet step's amplitude: Ling et al.'s ``a^(-1/2)`` factor, or none (psi alone).
WAVELET_AMPLITUDES = ("ling", "none")


def wavelet_sigma(key, shape, a, dtype, amplitude: str = "ling") -> jax.Array:
    """Wavelet step sigma = a^(-1/2) psi(phi/a), phi ~ U(-2.5a, 2.5a) (Ling et al.).

    Returns values in [-a^(-1/2), a^(-1/2)]: large moves early (a ~ 1), fine
    moves late (a -> g). ``amplitude="none"`` drops Ling's ``a^(-1/2)``: the
    step is ``psi(phi/a)`` in [-1, 1] throughout (eq. 18 as the paper prints it).
    """
    u = jax.random.uniform(key, shape, dtype, -2.5, 2.5)  # phi / a
    return morlet(u) / jnp.sqrt(a) if amplitude == "ling" else morlet(u)


# --- operators ----------------------------------------------------------------


def effective_strategy(strategy, t, T, stage_bounds, stage_order) -> jax.Array:
    """Map ``three_stage`` to the stage's operator (others unchanged).

    Args:
        strategy: int data, index into :data:`MUTATIONS`.
        t: iteration (0-based); T: iterations.
        stage_bounds: (2,) fractions of T where stages 2 and 3 start.
        stage_order: (3,) operator indices used in stages 1-3
            (default :data:`STAGE_ORDER`: chaos, gaussian, wavelet).

    Returns:
        An operator's index.
    """
    return jnp.where(strategy == THREE_STAGE, jnp.asarray(stage_order)[_stage(t, T, stage_bounds)], strategy)


def _stage(t, T, stage_bounds) -> jax.Array:
    """Index 0, 1 or 2 of the ``three_stage`` stage at iteration t of T (``stage_bounds``: fractions of T)."""
    return jnp.sum(t / T >= jnp.asarray(stage_bounds))


def stage_clock(strategy, t, T, stage_bounds) -> tuple:
    """(t, T) on the clock of the current ``three_stage`` stage; the run's clock for the other strategies.

    Stage s runs from ``start_s T`` to ``end_s T`` (starts 0, b1, b2; ends b1, b2, 1): its own
    clock is ``(t - start_s T, (end_s - start_s) T)``, so a wavelet placed in a stage sweeps its
    whole dilation schedule (Ling et al.) within that stage instead of its last part.
    """
    b = jnp.asarray(stage_bounds)
    stage = _stage(t, T, b)
    edges = jnp.concatenate([jnp.zeros(1, b.dtype), b, jnp.ones(1, b.dtype)])
    start, end = edges[stage], edges[stage + 1]
    own = strategy == THREE_STAGE
    return jnp.where(own, t - start * T, t), jnp.where(own, (end - start) * T, T)


def original(key, s: Fourth) -> jax.Array:
    """Eq. 15: x_k + R, R ~ U(0, 1) on the masked coordinates; ``original_uniform``: a uniform random point (MATLAB)."""
    u = jax.random.uniform(key, s.x.shape, s.x.dtype)
    if s.cfg.original_uniform:
        return s.lb + u * (s.ub - s.lb)
    return jnp.where(s.mask, s.x + jnp.asarray(s.cfg.step_scale, s.x.dtype) * u, s.x)


def chaos(key, s: Fourth) -> jax.Array:
    """Eq. 17: x_k + r_t, the logistic map's current state (:func:`logistic_step`)."""
    return jnp.where(s.mask, s.x + jnp.asarray(s.cfg.step_scale, s.x.dtype) * s.r_chaos, s.x)


def gaussian(key, s: Fourth) -> jax.Array:
    """Eq. 16: x_k + N(0, sigma^2)."""
    scale = jnp.asarray(s.cfg.step_scale, s.x.dtype)
    return jnp.where(s.mask, s.x + scale * s.cfg.sigma * jax.random.normal(key, s.x.shape, s.x.dtype), s.x)


def wavelet(key, s: Fourth) -> jax.Array:
    """Eq. 18 with Ling et al. (2008)'s dilation and normalisation (:func:`wavelet_sigma`); ``wavelet_bounded``:
    Ling's bound-relative step x + sigma (ub - x) / x + sigma (x - lb)."""
    cfg, x = s.cfg, s.x
    a = wavelet_dilation(s.t, s.T, cfg.wavelet_g, cfg.wavelet_zeta)
    sig = wavelet_sigma(key, x.shape, a, x.dtype, cfg.wavelet_amplitude)
    if cfg.wavelet_bounded:
        return jnp.where(s.mask, jnp.where(sig > 0, x + sig * (s.ub - x), x + sig * (x - s.lb)), x)
    return jnp.where(s.mask, x + jnp.asarray(cfg.step_scale, x.dtype) * sig, x)


# --- the registry ---------------------------------------------------------------

#: Every 4th-seed strategy by name, in index order (a config holds the index). The ICGO paper's five; a new
#: built-in is one more line here (and its ``conf/strategy/<name>.yaml``); a researcher's own is added with
#: :func:`register` (from their config: docs/extending.md), after these, so the built-ins keep their indices.
MUTATIONS: dict[str, Mutation] = {
    "original": Mutation(original, "original"),
    "chaos": Mutation(chaos, "chaotic"),
    "gaussian": Mutation(gaussian, "Gaussian"),
    "wavelet": Mutation(wavelet, "wavelet"),
    "three_stage": Mutation(None, "three-stage"),
}

#: The built-in strategies' names in index order (the registry as shipped, without a user's own).
STRATEGIES = tuple(MUTATIONS)
THREE_STAGE = STRATEGIES.index("three_stage")
#: ``three_stage``'s default stage order: chaos, Gaussian, wavelet (ICGO section 2.2).
STAGE_ORDER = tuple(STRATEGIES.index(n) for n in ("chaos", "gaussian", "wavelet"))

_NAME = re.compile(r"[a-z][a-z0-9_]*")


def register(name: str, operator: Callable, label: str | None = None) -> int:
    """Add a strategy to :data:`MUTATIONS` (after every one there) and return its index.

    Registering the same name again with the same operator (the same function, or a ``functools.partial`` of it
    with the same arguments) is a no-op, so a config read twice registers once.

    Args:
        name: lower-case identifier (``[a-z][a-z0-9_]*``; it becomes the method id ``cgo-<name>``).
        operator: ``operator(key, s: Fourth) -> S^4`` (see :class:`Mutation`).
        label: its name in tables and legends (default: ``name``).

    Raises:
        ValueError: a bad name, an operator that is not callable, or a name taken by another operator.
    """
    if not isinstance(name, str) or not _NAME.fullmatch(name):
        raise ValueError(f"strategy name {name!r} must be a lower-case identifier ([a-z][a-z0-9_]*)")
    if not callable(operator):
        raise ValueError(f"strategy {name!r}: the operator must be a function (key, s) -> S4, got {operator!r}")
    entry = Mutation(operator, name if label is None else str(label))
    if name in MUTATIONS:
        if not _same(MUTATIONS[name], entry):
            raise ValueError(f"strategy {name!r} is already registered with another operator; choose another name")
        return list(MUTATIONS).index(name)
    MUTATIONS[name] = entry
    return len(MUTATIONS) - 1


def _same(a: Mutation, b: Mutation) -> bool:
    """Two entries with the same label and the same operator (a partial compared by function and arguments)."""
    fa, fb = a.operator, b.operator
    if all(hasattr(f, "func") for f in (fa, fb)):
        fa, fb = (fa.func, fa.args, fa.keywords), (fb.func, fb.args, fb.keywords)
    return a.label == b.label and fa == fb


def strategy_index(strategy) -> int:
    """Index in :data:`MUTATIONS` of a strategy given by name or index; ValueError if unknown."""
    names = tuple(MUTATIONS)
    if isinstance(strategy, str):
        if strategy not in MUTATIONS:
            raise ValueError(f"unknown strategy {strategy!r}; choose one of {names}")
        return names.index(strategy)
    if isinstance(strategy, (int, np.integer)) and not isinstance(strategy, bool) and 0 <= strategy < len(names):
        return int(strategy)
    raise ValueError(f"unknown strategy {strategy!r}; choose a name in {names} or an index 0-{len(names) - 1}")


def is_operator(index) -> bool:
    """Whether the strategy at ``index`` is an operator (not a schedule of operators such as ``three_stage``)."""
    return MUTATIONS[tuple(MUTATIONS)[int(index)]].operator is not None


def label(name: str) -> str:
    """A strategy's name in tables and legends (the registry's label; a name not registered here is its own)."""
    return MUTATIONS[name].label if name in MUTATIONS else name


def mutate(key, x, mask, r_chaos, strategy, t, T, lb, ub, cfg) -> jax.Array:
    """Fourth seeds S^4 for the whole population (eqs. 15-18).

    The operators of the strategies ``cfg.mutations`` names (the registry when the config was built) are the
    branches of one ``lax.switch`` on the strategy's index; a schedule's index never reaches it
    (:func:`effective_strategy` maps it to its stage's operator first).

    Args:
        key: PRNG key.
        x: parents X_i, shape (P, D).
        mask: coordinates to mutate, (P, D) bool.
        r_chaos: current logistic-map state r_t, (P, D).
        strategy: effective strategy index, an operator's (see :func:`effective_strategy`).
        t, T: iteration and iteration count.
        lb, ub: bounds, (D,) (used by the ``matlab`` original seed and by the
            bound-relative wavelet step).
        cfg: CGO config (data fields ``step_scale``, ``sigma``, ``wavelet_g``,
            ``wavelet_zeta``; static flags ``wavelet_bounded`` and
            ``original_uniform`` pick the code of the wavelet and original
            operators; static ``mutations``, the registry's names in index order).

    Returns:
        Unclipped S^4, shape (P, D).
    """
    s = Fourth(x, mask, r_chaos, t, T, lb, ub, cfg)
    entries = [MUTATIONS[n] for n in cfg.mutations]
    ops = [e.operator for e in entries if e.operator is not None]
    branch = np.maximum(np.cumsum([e.operator is not None for e in entries]) - 1, 0)  # registry index -> branch
    return lax.switch(jnp.asarray(branch, jnp.int32)[strategy], [lambda k, op=op: op(k, s) for op in ops], key)
