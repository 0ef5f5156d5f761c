"""4th-seed mutation operators of ICGO (ICGO paper eqs. 15-18, section 2.2).

All operators act on the whole population at once: ``x`` has shape (P, D) and a
boolean ``mask`` (P, D) says which dimensions of each row are mutated (eqs.
15-18 write ``x_i^k``; which ``k`` is not said, see :func:`dims_mask`). The
strategy is integer data selected with ``lax.switch``, so one compiled program
serves all five strategies (:data:`STRATEGIES`).

Amplitudes are in the units of the search variable, as written in the paper
(``R ~ U(0, 1)``, ``r_t in (0, 1)``, ``psi in [-1, 1]``); CGO multiplies them
by its ``step_scale`` option (default 1).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax import lax

#: Strategy names in index order; ``config.strategy`` holds the index.
STRATEGIES = ("original", "chaos", "gaussian", "wavelet", "three_stage")
ORIGINAL, CHAOS, GAUSSIAN, WAVELET, THREE_STAGE = range(5)

#: Dimension-selection modes for the mutated coordinates (CGO ``dims`` option).
DIM_MODES = ("subset", "all", "one")


def strategy_index(strategy) -> int:
    """Index of a strategy given by name or index; ValueError if unknown."""
    if isinstance(strategy, str):
        if strategy not in STRATEGIES:
            raise ValueError(f"unknown strategy {strategy!r}; choose one of {STRATEGIES}")
        return STRATEGIES.index(strategy)
    if isinstance(strategy, (int, np.integer)) and not isinstance(strategy, bool) and 0 <= strategy < len(STRATEGIES):
        return int(strategy)
    raise ValueError(f"unknown strategy {strategy!r}; choose a name in {STRATEGIES} or an index 0-4")


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
    """Map ``three_stage`` to the stage's single strategy (others unchanged).

    Args:
        strategy: int data, index into :data:`STRATEGIES`.
        t: iteration (0-based); T: iterations.
        stage_bounds: (2,) fractions of T where stages 2 and 3 start.
        stage_order: (3,) strategy indices used in stages 1-3
            (default chaos, gaussian, wavelet).

    Returns:
        Index in 0..3.
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


def mutate(key, x, mask, r_chaos, strategy, t, T, lb, ub, cfg) -> jax.Array:
    """Fourth seeds S^4 for the whole population (eqs. 15-18).

    Args:
        key: PRNG key.
        x: parents X_i, shape (P, D).
        mask: coordinates to mutate, (P, D) bool.
        r_chaos: current logistic-map state r_t, (P, D).
        strategy: effective strategy index 0..3 (see :func:`effective_strategy`).
        t, T: iteration and iteration count.
        lb, ub: bounds, (D,) (used by the ``matlab`` original seed and by the
            bound-relative wavelet step).
        cfg: CGO config (data fields ``step_scale``, ``sigma``, ``wavelet_g``,
            ``wavelet_zeta``; static flags ``wavelet_bounded`` and
            ``original_uniform`` pick the code of the wavelet and original
            operators).

    Returns:
        Unclipped S^4, shape (P, D).
    """
    scale = jnp.asarray(cfg.step_scale, x.dtype)

    def original(k):  # eq. 15: x_k + R, R ~ U(0,1); matlab: uniform random point
        u = jax.random.uniform(k, x.shape, x.dtype)
        if cfg.original_uniform:
            return lb + u * (ub - lb)
        return jnp.where(mask, x + scale * u, x)

    def chaos(k):  # eq. 17: x_k + r_t
        return jnp.where(mask, x + scale * r_chaos, x)

    def gaussian(k):  # eq. 16: x_k + N(0, sigma^2)
        return jnp.where(mask, x + scale * cfg.sigma * jax.random.normal(k, x.shape, x.dtype), x)

    def wavelet(k):  # eq. 18 with Ling et al. (2008) dilation and normalisation
        a = wavelet_dilation(t, T, cfg.wavelet_g, cfg.wavelet_zeta)
        s = wavelet_sigma(k, x.shape, a, x.dtype, cfg.wavelet_amplitude)
        if cfg.wavelet_bounded:
            return jnp.where(mask, jnp.where(s > 0, x + s * (ub - x), x + s * (x - lb)), x)
        return jnp.where(mask, x + scale * s, x)

    return lax.switch(jnp.clip(strategy, 0, 3), (original, chaos, gaussian, wavelet), key)
