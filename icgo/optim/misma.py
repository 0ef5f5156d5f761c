"""MISMA: the magneto-inertial slime mould algorithm (Yang & Cai; seeds/002).

Built on the standard SMA (Li et al. 2020; :mod:`icgo.optim.sma`) and
listed as ``misma`` in :data:`icgo.optim.registry.OPTIMIZERS`, with the same
``init/step`` interface, so :func:`icgo.optim.run_batch` runs it.

The paper's formulas did not survive its text extraction; each update below is
reconstructed from its description (paragraph "2.3" of the paper, the section on
the global search, local search and deep exploitation) and numbered as in the
paper. ``docs/misma.md`` lists every reconstruction with the reasons.

* **Bounds VUB / VLB (eqs. 9-11).** The search box is centred on ``U``, the
  12 parameters that make the corrected modulus equal the gyro-derived
  reference ``|M_omega|`` in the least-squares sense (an ellipsoid fit, see
  :func:`misma_bounds`), with a configurable half-width. They are the ``bounds``
  passed to :func:`icgo.optim.run`: initial population, restarts and clipping.
* **Adaptive z (eq. 13).** Restart probability of member i
  ``z_i = z_max (F_i - H) / (|F_i| + |H|)`` (H the best fitness of the current
  iteration): poor members restart (global search), the best never does.
* **Restart (eq. 12).** ``X_i = VLB + r (VUB - VLB)`` with probability ``z_i``.
* **GMR and random step (eqs. 14-16).** ``GMR`` of the best-so-far solution
  (:func:`icgo.models.cal_objectives.magnitude_ratio`) picks the random step of the
  approach move ``X = B + RS (W X_A - X_B)`` (eq. 14): a large
  ``RS2 ~ U(-a, a)`` (SMA's ``vb``) while ``GMR < gmr_threshold`` (poor best,
  jump out), a small ``RS1 ~ U(-b, b)`` (``b = 1 - t/T``) once the best is good.
* **Deep exploitation (eqs. 17-19).** Min-max normalised fitness of member i,
  ``a1_i``, and of the best, ``a2``; ``delta_i = |a1_i - a2|``. Where SMA
  contracts ``X = vc X`` (towards the origin), MISMA moves
  ``X = B + U(-b, b) (X_i - B)`` if ``delta_i <= d`` (close to the best: search
  around it) else ``X = X_i + U(0, 1) (B - X_i)`` (pull towards it).
* **Branch probability.** As in SMA, per dimension the approach move (14) is
  taken with probability ``p_i``; ``p_mode="normalized"`` (default) uses
  ``p_i = tanh(delta_i)`` on the normalised fitness of eq. 17 so that the
  branch does not depend on the fitness unit; ``p_mode="sma"`` uses SMA's
  ``tanh|F_i - B_f|``.

The GMR needs the magnetometer data: the fitness object supplies it as
``fitness.gmr(x, aux)`` (:class:`icgo.models.misma_objective.MismaObjective` does). For a
plain fitness (benchmarks) GMR falls back to ``t / T`` (large steps early,
small late), documented in ``docs/misma.md``.
"""

from __future__ import annotations

import dataclasses
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from icgo.optim.base import Algorithm, State, evaluate, finite_fitness, first_state, uniform_population, update_best

_TINY = 1e-300


@partial(jax.tree_util.register_dataclass,
         data_fields=["z_max", "d", "gmr_threshold"], meta_fields=["p_mode"])
@dataclasses.dataclass(frozen=True)
class MISMAConfig:
    """MISMA hyperparameters.

    Attributes:
        z_max: scale of the adaptive restart probability (eq. 13), in [0, 1].
        d: deep-exploitation threshold on normalised fitness differences
            (eqs. 17-19), ``0 <= d <= 1``.
        gmr_threshold: GMR below which the best solution counts as poor and the
            large random step RS2 is used (eq. 16).
        p_mode: ``"normalized"`` or ``"sma"`` (branch probability, see module doc).
    """

    z_max: float = 0.1
    d: float = 0.1
    gmr_threshold: float = 0.99
    p_mode: str = "normalized"

    def __post_init__(self):
        if isinstance(self.p_mode, str) and self.p_mode not in ("normalized", "sma"):
            raise ValueError(f"MISMA p_mode {self.p_mode!r}: choose 'normalized' or 'sma'")
        for name in ("z_max", "d", "gmr_threshold"):
            v = getattr(self, name)
            if isinstance(v, (int, float)) and not 0.0 <= float(v) <= 1.0:
                raise ValueError(f"MISMA {name} must be in [0, 1], got {v}")


def _init(key, fitness, lb, ub, pop_size, config, aux) -> State:
    pop = uniform_population(key, lb, ub, pop_size)
    return first_state(fitness, lb, ub, pop, config, aux, extra=jnp.zeros((), lb.dtype))


def _gmr(fitness, x, aux, t, T):
    g = getattr(fitness, "gmr", None)
    if g is None:
        return (t + 1.0) / T
    return g(x, aux)


def _step(state: State, key, t, T, fitness) -> State:
    cfg = state.ctx.config
    lb, ub, aux = state.ctx.lb, state.ctx.ub, state.ctx.aux
    fit = finite_fitness(state.fit)
    # Work in box-normalised coordinates u = (x - VLB) / (VUB - VLB): SMA's
    # W X_A - X_B term depends on where the origin is; here the origin is VLB.
    span_x = ub - lb
    pop = (state.pop - lb) / span_x
    P, D = pop.shape
    dt = pop.dtype
    k = jax.random.split(key, 9)
    tt = jnp.asarray(t, dt)
    frac = (tt + 1.0) / T
    best_f = jnp.where(jnp.isfinite(state.best_f), state.best_f, jnp.min(fit))
    best_u = (state.best_x - lb) / span_x

    # SMA weights W (Li et al. 2020, eq. 2.5): rank-based, better half > 1.
    order = jnp.argsort(fit)
    rank = jnp.zeros(P, jnp.int32).at[order].set(jnp.arange(P, dtype=jnp.int32))
    bF, wF = fit[order[0]], fit[order[-1]]
    ratio = (bF - fit) / (bF - wF - 1e-300)
    logt = jnp.log10(jnp.clip(ratio, 0.0, 1.0) + 1.0)[:, None]
    r_w = jax.random.uniform(k[0], (P, D), dt)
    W = jnp.where((rank < P // 2)[:, None], 1.0 + r_w * logt, 1.0 - r_w * logt)
    a = jnp.arctanh(jnp.clip(1.0 - frac, 0.0, 1.0 - 1e-12))
    b = 1.0 - frac

    # eq. 13: adaptive restart probability; H = best of this iteration.
    H = bF
    z = cfg.z_max * (fit - H) / (jnp.abs(fit) + jnp.abs(H) + _TINY)
    # eq. 17: min-max normalised fitness of each member (a1) and of the best (a2).
    fmin = jnp.minimum(jnp.min(fit), best_f)
    span = jnp.maximum(jnp.max(fit) - fmin, _TINY)
    a1 = (fit - fmin) / span
    a2 = (best_f - fmin) / span
    delta = jnp.abs(a1 - a2)  # eq. 18
    p = jnp.tanh(delta) if cfg.p_mode == "normalized" else jnp.tanh(jnp.abs(fit - best_f))

    # eqs. 14-16: random step chosen by the GMR of the best-so-far solution.
    gmr = _gmr(fitness, state.best_x, aux, tt, T)
    rs2 = jax.random.uniform(k[1], (P, D), dt, -1.0, 1.0) * a
    rs1 = jax.random.uniform(k[2], (P, D), dt, -1.0, 1.0) * b
    rs = jnp.where(gmr < cfg.gmr_threshold, rs2, rs1)
    ia = jax.random.randint(k[3], (P,), 0, P)
    ib = jax.random.randint(k[4], (P,), 0, P)
    x_approach = best_u + rs * (W * pop[ia] - pop[ib])  # eq. 14
    # eq. 19: deep exploitation instead of SMA's vc * X.
    around = best_u + jax.random.uniform(k[5], (P, D), dt, -1.0, 1.0) * (pop - best_u)
    toward = pop + jax.random.uniform(k[6], (P, D), dt) * (best_u - pop)
    x_exploit = jnp.where((delta <= cfg.d)[:, None], around, toward)
    new = jnp.where(jax.random.uniform(k[7], (P, D), dt) < p[:, None], x_approach, x_exploit)
    # eq. 12: restart inside [VLB, VUB].
    k_r1, k_r2 = jax.random.split(k[8])
    restart = jax.random.uniform(k_r1, (P,), dt) < z
    new = jnp.where(restart[:, None], jax.random.uniform(k_r2, (P, D), dt), new)
    new = lb + jnp.clip(new, 0.0, 1.0) * span_x

    f_new = evaluate(fitness, new, aux)
    bx, bf = update_best(state.best_x, state.best_f, new, f_new)
    return State(new, f_new, bx, bf, state.n_evals + P, jnp.asarray(gmr, dt), state.ctx)


def _evals(pop_size, config):
    return pop_size, pop_size


MISMA = Algorithm("misma", MISMAConfig, _init, _step, _evals)


# ------------------------------------------------------------------ bounds
def misma_bounds(u, ref_nT, matrix_halfwidth=0.05, bias_halfwidth=0.02):
    """VUB / VLB (eqs. 9-11): a box around ``U``, the modulus-matching solution.

    ``U`` is the 12-vector that makes the corrected modulus equal the
    gyro-derived ``|M_omega|`` (least squares, i.e. the ellipsoid fit of
    :func:`icgo.models.calibration.ellipsoid_fit`). The paper argues the wanted
    solution lies "near U" and redefines the bounds around it; we take
    ``U_j -/+ h_j`` with ``h = matrix_halfwidth * max_j |U_matrix|`` for the nine
    ``R^-1`` entries and ``h = bias_halfwidth * |M_omega|`` for the three biases.

    Args:
        u: (12,) parameters U.
        ref_nT: |M_omega| (nT).
        matrix_halfwidth: half-width of the R^-1 entries, relative to max |R^-1_ij| of U.
        bias_halfwidth: half-width of the biases, relative to |M_omega|.
    Returns:
        (VLB, VUB), two (12,) numpy arrays.
    """
    u = np.asarray(u, np.float64)
    if u.shape != (12,) or not np.all(np.isfinite(u)):
        raise ValueError(f"misma_bounds: U must be a finite (12,) vector, got shape {u.shape}")
    if matrix_halfwidth <= 0 or bias_halfwidth <= 0 or ref_nT <= 0:
        raise ValueError("misma_bounds: half-widths and ref_nT must be > 0")
    h = np.concatenate([np.full(9, matrix_halfwidth * np.abs(u[:9]).max()), np.full(3, bias_halfwidth * ref_nT)])
    return u - h, u + h


#: The paper's search bounds (section 3, table 3: "search upper / lower bound 128 / -68 uT").
PAPER_BOUNDS_UT = (-68.0, 128.0)


def paper_bounds():
    """The paper's box, literally, for all 12 parameters: (lb, ub), two (12,) arrays.

    The paper gives one pair of numbers for its 12-vector; we read the biases
    in uT (-68 000 .. 128 000 nT, our unit) and the nine ``R^-1`` entries as the
    same plain numbers (-68 .. 128), about 100 times wider than :func:`misma_bounds`.
    """
    lo, hi = PAPER_BOUNDS_UT
    return np.r_[np.full(9, lo), np.full(3, lo * 1e3)], np.r_[np.full(9, hi), np.full(3, hi * 1e3)]
