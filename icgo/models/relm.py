"""Regularized extreme learning machine (ICGO paper section 2.1, eqs. 8-9).

Inputs are the six raw sensor values (Gx, Gy, Gz in g; Bx, By, Bz in nT),
standardised with statistics of the training rows only. A hidden layer of L
sigmoid units (eq. 8) with input weights ``W`` (6, L) and biases ``b`` (L,)
maps them to ``H`` (N, L); the output weights solve the ridge problem of eq. (9),
read as the usual RELM ``min ||H beta - T||^2 + lambda ||beta||^2``:

    (H^T H + lambda I) beta = H^T T          (Cholesky, float64 by default)

``theta = concat(W.ravel(), b)`` of length ``7 L`` is what optimizers search;
plain RELM draws it once from U(low, high), default U(-1, 1) as in common ELM
codes. Row weights (0/1 masks) select the rows a fit uses, so every repeat and
fold keeps the same shapes and the fitness vmaps over repeats.

Fitness (:func:`fitness`): the RMSE of the ridge fit, as a mean over "folds",
each fold a pair of row-weight vectors (fit rows, score rows):

* ``train`` (paper): one fold, fit and score on all training rows;
* ``validation``: fit on part of the training rows, score on the rest;
* ``kfold``: K folds of the training rows.

Test rows have zero weight in every fold: they never steer a search.
Non-finite fitness values are returned as +inf.
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp

N_INPUTS = 6
FITNESS_MODES = ("train", "validation", "kfold")
#: The tuned plain-RELM baseline's grid: hidden units L and ridge lambda over six decades.
TUNE_HIDDEN = (10, 20, 30, 50, 80, 120)
TUNE_LAMBDA = (1e-6, 1e-5, 1e-4, 1e-3, 1e-2, 1e-1)
#: Largest ridge lambda a study or a model may carry. lambda is absolute (not scaled by the number of rows,
#: docs/relm_study.md): at 1 the validation RMSE on lab_casing is already 1.5 x that at 1e-3, and far above
#: 1e3 the output weights shrink to nothing and the RELM returns MSA's azimuth unchanged (docs/reliability.md).
MAX_LAM = 1e3
_STD_FLOOR = 1e-12
#: Rows per block (rows) of the row-blocked paths: above this many rows the fitness (:func:`fitness`,
#: :func:`train_fitness`), the refit and the prediction (:mod:`icgo.models.relm_fit`) never hold the
#: hidden outputs of all rows, only those of one block (chunk x ROW_BLOCK x L float64 for the fitness: 10 x 4096 x 30 x 8 B = 9.8 MB), and accumulate
#: the normal equations over blocks (``lax.scan``), so memory stays flat and time grows linearly in
#: rows. At or below it the unblocked code runs, unchanged (the study's 407 training rows).
ROW_BLOCK = 4096


def n_params(hidden: int, n_inputs: int = N_INPUTS) -> int:
    """Length of theta = (W (n_inputs, L), b (L,)) flattened: ``(n_inputs + 1) * L``."""
    return (n_inputs + 1) * hidden


def unpack(theta, hidden: int, n_inputs: int = N_INPUTS):
    """Split theta (..., (n_inputs+1) L) into W (..., n_inputs, L) and b (..., L)."""
    theta = jnp.asarray(theta)
    nw = n_inputs * hidden
    W = theta[..., :nw].reshape(theta.shape[:-1] + (n_inputs, hidden))
    return W, theta[..., nw:]


def random_theta(key, hidden: int, shape=(), low: float = -1.0, high: float = 1.0,
                 n_inputs: int = N_INPUTS, dtype=jnp.float64):
    """Plain-RELM hidden parameters: theta ~ U(low, high), shape ``shape + (7 L,)``."""
    return jax.random.uniform(key, tuple(shape) + (n_params(hidden, n_inputs),), dtype, low, high)


def standardize_stats(X, weights=None):
    """Weighted column mean and std (population) over the rows with weight > 0.

    Args:
        X: (N, d) features. weights: (N,) row weights or None.
    Returns:
        (mean (d,), std (d,)); std floored at 1e-12 to keep constant columns finite.
    """
    X = jnp.asarray(X)
    w = jnp.ones(X.shape[0], X.dtype) if weights is None else jnp.asarray(weights, X.dtype)
    sw = jnp.sum(w)
    mean = jnp.sum(w[:, None] * X, 0) / sw
    var = jnp.sum(w[:, None] * (X - mean) ** 2, 0) / sw
    return mean, jnp.sqrt(jnp.maximum(var, _STD_FLOOR**2))


def standardize(X, mean, std):
    """``(X - mean) / std``."""
    return (jnp.asarray(X) - mean) / std


def hidden_layer(theta, Xs, hidden: int):
    """Eq. (8): ``H = sigmoid(Xs W + b)``.

    Args:
        theta: (7 L,) hidden parameters. Xs: (N, 6) standardised inputs.
        hidden: L.
    Returns:
        H, (N, L).
    """
    W, b = unpack(theta, hidden, Xs.shape[-1])
    return jax.nn.sigmoid(Xs @ W + b)


def ridge_solve(H, T, lam, weights=None):
    """Eq. (9): ``(H^T diag(w) H + lam I) beta = H^T diag(w) T`` by Cholesky.

    Args:
        H: (N, L) hidden outputs. T: (N,) targets.
        lam: ridge parameter lambda > 0 (absolute, applied to the unnormalised Gram).
        weights: (N,) row weights or None.
    Returns:
        beta (L,).
    """
    H = jnp.asarray(H)
    T = jnp.asarray(T, H.dtype)
    Hw = H if weights is None else H * jnp.asarray(weights, H.dtype)[:, None]
    A = Hw.T @ H + jnp.asarray(lam, H.dtype) * jnp.eye(H.shape[1], dtype=H.dtype)
    c = jax.scipy.linalg.cho_factor(A, lower=True)
    return jax.scipy.linalg.cho_solve(c, Hw.T @ T)


def row_blocks(block: int, *arrays):
    """Arrays of N rows as (nb, block, ...) blocks, nb = ceil(N / block), the last block zero-padded.

    Args:
        block: rows per block. arrays: each (N, ...).
    Returns:
        tuple of (nb, block, ...) arrays, then the (nb, block) 0/1 mask of real rows.
    """
    n = arrays[0].shape[0]
    nb = -(-n // block)
    pad = nb * block - n

    def split(a):
        a = jnp.asarray(a)
        return jnp.pad(a, [(0, pad)] + [(0, 0)] * (a.ndim - 1)).reshape((nb, block) + a.shape[1:])

    real = (jnp.arange(nb * block) < n).reshape(nb, block)
    return tuple(split(a) for a in arrays) + (real,)


def scan_sum(f, init, blocks):
    """``sum_b f(*blocks[b])`` over the leading block axis (``lax.scan``; pytrees of sums)."""
    def body(acc, blk):
        return jax.tree_util.tree_map(jnp.add, acc, f(*blk)), None

    return jax.lax.scan(body, init, blocks)[0]


class FitData(NamedTuple):
    """Per-repeat data for the fitness (the optimizer's ``aux``).

    Attributes:
        X: (N, 6) standardised inputs (all rows; test rows carry zero weight).
        T: (N,) targets (deg).
        fit_w: (K, N) row weights of the rows each fold fits beta on.
        score_w: (K, N) row weights of the rows each fold is scored on.
    """

    X: jnp.ndarray
    T: jnp.ndarray
    fit_w: jnp.ndarray
    score_w: jnp.ndarray


def _rmse_one(theta, data: FitData, lam, hidden: int):
    H = hidden_layer(theta, data.X, hidden)

    def fold(fw, sw):
        beta = ridge_solve(H, data.T, lam, fw)
        r = H @ beta - data.T
        return jnp.sqrt(jnp.sum(sw * r * r) / jnp.sum(sw))

    f = jnp.mean(jax.vmap(fold)(data.fit_w, data.score_w))
    return jnp.where(jnp.isfinite(f), f, jnp.inf)


def _rmse_one_blocked(theta, data: FitData, lam, hidden: int, row_block: int):
    """:func:`_rmse_one` over row blocks: every fold's normal equations, then its scored residuals,
    summed block by block (``lax.scan``), so ``H`` (N, L) is never held whole."""
    dt = data.X.dtype
    K = data.fit_w.shape[0]
    Xb, Tb, fwb, swb, _ = row_blocks(row_block, data.X, data.T, data.fit_w.T, data.score_w.T)  # weights (nb, B, K)
    blocks = (Xb, Tb, fwb, swb)

    def normal(x, t, fw, sw):  # per fold: H^T diag(w_k) H (K, L, L) and H^T diag(w_k) T (K, L)
        H = hidden_layer(theta, x, hidden)
        return jnp.einsum("bk,bi,bj->kij", fw, H, H), jnp.einsum("bk,bi,b->ki", fw, H, t)

    A, b = scan_sum(normal, (jnp.zeros((K, hidden, hidden), dt), jnp.zeros((K, hidden), dt)), blocks)

    def solve(A, b):
        c = jax.scipy.linalg.cho_factor(A + lam * jnp.eye(hidden, dtype=dt), lower=True)
        return jax.scipy.linalg.cho_solve(c, b)

    beta = jax.vmap(solve)(A, b)                                                      # (K, L)

    def scored(x, t, fw, sw):  # per fold: sum of score-weighted squared residuals (K,)
        r = hidden_layer(theta, x, hidden) @ beta.T - t[:, None]
        return jnp.sum(sw * r * r, axis=0)

    sse = scan_sum(scored, jnp.zeros(K, dt), blocks)
    f = jnp.mean(jnp.sqrt(sse / jnp.sum(data.score_w, axis=1)))
    return jnp.where(jnp.isfinite(f), f, jnp.inf)


@partial(jax.jit, static_argnames=("hidden", "dtype", "row_block"))
def fitness(pop, data: FitData, lam, hidden: int, dtype=None, row_block: int = ROW_BLOCK):
    """Batched RELM fitness: mean over folds of the scored RMSE (deg) of each theta.

    Above ``row_block`` rows (all rows, test rows included) the thetas run one after another
    and each one's fold fits and scores are accumulated over row blocks (:data:`ROW_BLOCK`),
    so memory does not grow with population x rows x hidden; the same sums, in another order.

    Args:
        pop: (P, 7 L) population of hidden parameters.
        data: FitData of one repeat.
        lam: ridge lambda.
        hidden: L.
        dtype: None to keep the input dtype, or ``"float32"`` / ``"float64"``.
        row_block: rows per block (static).
    Returns:
        (P,) fitness; +inf where the solve is not finite.
    """
    if dtype is not None:
        dt = jnp.dtype(dtype)
        pop = pop.astype(dt)
        data = FitData(*(jnp.asarray(a).astype(dt) for a in data))
        lam = jnp.asarray(lam, dt)
    if data.X.shape[0] > row_block:  # one theta at a time: a block's (folds, rows, L) stays in cache
        return jax.lax.map(lambda th: _rmse_one_blocked(th, data, lam, hidden, row_block), pop)
    return jax.vmap(_rmse_one, in_axes=(0, None, None, None))(pop, data, lam, hidden)


def make_fitness(lam: float, hidden: int, dtype=None):
    """``fitness(pop (P, D), aux: FitData) -> (P,)`` closure for optimizers."""
    def f(pop, aux):
        return fitness(pop, aux, lam, hidden, dtype)
    return f


# ------------------------------------------------------------ fast train-mode path
class TrainRows(NamedTuple):
    """The training rows of one repeat, gathered (the fast fitness's ``aux``).

    Attributes:
        Xa: (n, 7) standardised inputs with a trailing column of ones (the bias).
        T: (n,) targets (deg).
        w: None (every row counts) or (n,) 0/1 row weights: batch members with
            different numbers of training rows (the folds of
            ``split=leave_azimuth_out``) are padded to one shape with weight-0 rows.
    """

    Xa: jnp.ndarray
    T: jnp.ndarray
    w: jnp.ndarray | None = None


def train_rows(data: FitData, n_train: int, padded: bool = False) -> TrainRows:
    """Gather the rows of a train-mode FitData (``fit_w`` of one fold) into TrainRows.

    Args:
        data: FitData with K = 1 whose ``fit_w[0]`` marks the training rows.
        n_train: number of training rows (static; every repeat has as many), or with
            ``padded`` the largest number over the batch.
        padded: gather ``n_train`` rows, the training rows first, and weight the rest 0.
    Returns:
        TrainRows, (n_train, 7) and (n_train,) (and (n_train,) weights when padded).
    """
    idx = jnp.nonzero(data.fit_w[0] > 0, size=n_train)[0]
    X = data.X[idx]
    w = (jnp.arange(n_train) < jnp.sum(data.fit_w[0] > 0)).astype(X.dtype) if padded else None
    return TrainRows(jnp.concatenate([X, jnp.ones((n_train, 1), X.dtype)], axis=1), data.T[idx], w)


def input_weights(pop, d1: int, hidden: int, feature_dtype):
    """W and b of each theta as one (P, d1, L) matrix in ``feature_dtype`` (b is the last row)."""
    P = pop.shape[0]
    W = jnp.concatenate([pop[:, : (d1 - 1) * hidden].reshape(P, d1 - 1, hidden),
                         pop[:, None, (d1 - 1) * hidden:]], axis=1)
    return W.astype(feature_dtype)


def pre_activation(Xa, W):
    """``Xa W`` (P, n, L) in the dtype of W, from Xa (n, d1) (inputs, then a column of ones) and W (P, d1, L)."""
    return jnp.einsum("nd,pdl->pnl", Xa.astype(W.dtype), W)


def _hidden_out(Xa, W):
    """Eq. (8): ``H = sigmoid(Xa W)`` (P, n, L) in the dtype of W."""
    return jax.nn.sigmoid(pre_activation(Xa, W))


def normal_equations(H, T, w, dt, gram_dtype):
    """One pass over H (P, n, L): the Gram ``H^T H`` (P, L, L) and ``H^T T`` (P, L), both in ``dt``, and n.

    Sigmoid columns share a large mean, which ruins a float32 Gram; centred columns do not,
    and ``H^T H = Hc^T Hc + n m m^T`` exactly: ``Hc^T Hc`` in ``gram_dtype``, the mean term in
    ``dt`` (float64). With float32 features H is centred on m rounded to float32 and the mean
    term keeps the float64 m: the identity then holds to second order in that rounding.
    ``w``: None, or (n,) 0/1 row weights (padded rows drop out of every sum, w^2 = w); n is then
    their sum, the number of real rows.
    """
    if w is None:
        n = H.shape[1]
        m = jnp.mean(H.astype(dt), axis=1)
        Hc = (H - m[:, None, :].astype(H.dtype)).astype(gram_dtype)
        Tw = T
    else:
        n = jnp.sum(w)
        m = jnp.einsum("pnl,n->pl", H.astype(dt), w) / n
        Hc = ((H - m[:, None, :].astype(H.dtype)) * w[None, :, None].astype(H.dtype)).astype(gram_dtype)
        Tw = T * w
    A = jnp.einsum("pni,pnj->pij", Hc, Hc).astype(dt) + n * m[:, :, None] * m[:, None, :]
    return A, jnp.einsum("pni,n->pi", H, Tw.astype(H.dtype)).astype(dt), n


def cholesky(A, lam):
    """Lower Cholesky factor (P, L, L) of ``A + lam I`` for Grams A (P, L, L)."""
    return jnp.linalg.cholesky(A + lam * jnp.eye(A.shape[-1], dtype=A.dtype))


def cho_solve(C, b):
    """``(C C^T)^-1 b`` (P, L) for factors C (P, L, L) and right-hand sides b (P, L)."""
    return jax.scipy.linalg.cho_solve((C, True), b[..., None])[..., 0]


def _h_beta(H, beta, exact: bool):
    """``H beta`` (P, n) in beta's dtype, from H (P, n, L) in any feature dtype and beta (P, L).

    ``exact``: H's stored values times beta, accumulated in beta's dtype (float64), for the
    RMSE. Otherwise the product in H's dtype, cast up: what a refinement step's residual needs
    (the RMSE is stationary in beta at the ridge solution; with float32 features measured on the
    study's data: the same largest fitness difference as exact residuals, 10% faster).
    """
    if exact:
        return jnp.einsum("pni,pi->pn", H.astype(beta.dtype), beta)
    return jnp.einsum("pni,pi->pn", H, beta.astype(H.dtype)).astype(beta.dtype)


def _ht_r(H, r, dt):
    """``H^T r`` (P, L) of a residual r (P, n), computed in H's dtype and returned in ``dt``."""
    return jnp.einsum("pni,pn->pi", H, r.astype(H.dtype)).astype(dt)


def refine_step(H, T, w, beta, C, lam):
    """One step of iterative refinement: ``beta + (H^T H + lam I)^-1 (H^T r - lam beta)``, r = w (T - H beta).

    The residual of the exact normal equations in beta's dtype (float64); C (P, L, L) factors
    the (approximate) Gram. H (P, n, L), T (n,), w None or (n,), beta (P, L).
    """
    r = T - _h_beta(H, beta, False)
    if w is not None:
        r = r * w
    return beta + cho_solve(C, _ht_r(H, r, beta.dtype) - lam * beta)


def rmse(H, T, w, n, beta):
    """Training RMSE (P,) of the fit ``H beta`` over n rows (float64 residual), +inf where not finite."""
    r = _h_beta(H, beta, True) - T
    f = jnp.sqrt(jnp.mean(r * r, axis=1)) if w is None else jnp.sqrt(jnp.einsum("pn,n->p", r * r, w) / n)
    return jnp.where(jnp.isfinite(f), f, jnp.inf)


def train_rmse_chunk(pop, rows: TrainRows, lam, hidden: int, refine: int, gram_dtype, feature_dtype):
    """Training RMSE (P,) of a chunk of thetas pop (P, 7 L): eqs. (8)-(9) and ``refine`` refinement steps."""
    H = _hidden_out(rows.Xa, input_weights(pop, rows.Xa.shape[1], hidden, feature_dtype))   # eq. (8), (P, n, L)
    A, HtT, n = normal_equations(H, rows.T, rows.w, pop.dtype, gram_dtype)
    C = cholesky(A, lam)
    beta = cho_solve(C, HtT)                                                        # eq. (9)
    for _ in range(refine):  # iterative refinement: float64 residual of the exact normal equations
        beta = refine_step(H, rows.T, rows.w, beta, C, lam)
    return rmse(H, rows.T, rows.w, n, beta)


def _train_rmse_chunk_blocked(pop, rows: TrainRows, lam, hidden: int, refine: int, gram_dtype, feature_dtype,
                              row_block: int):
    """:func:`train_rmse_chunk` over row blocks: the same normal equations, accumulated block by block.

    One pass forms, per block b, the block's column means ``m_b``, its Gram centred on them in
    ``gram_dtype`` and ``H^T T``; ``H_b^T H_b = Hc_b^T Hc_b + n_b m_b m_b^T`` exactly, so the
    sum over blocks is the Gram of all rows, with the float32 rounding relative to the centred
    columns as in the unblocked kernel (block means are at least as close to a block's rows as
    the global mean). Each refinement step and the final residual recompute ``H`` block by
    block. Rows past the end (the last block's padding) and rows of weight 0 drop out of every sum.
    """
    P = pop.shape[0]
    dt = pop.dtype
    W = input_weights(pop, rows.Xa.shape[1], hidden, feature_dtype)                # (P, 7, L): W and b
    Xb, Tb, real = row_blocks(row_block, rows.Xa, rows.T)
    wb = real.astype(dt) if rows.w is None else row_blocks(row_block, rows.w)[0]
    blocks = (Xb, Tb, wb)

    def gram(x, t, w):  # this block's H^T H (centred Gram in gram_dtype + float64 mean term) and H^T T
        H = _hidden_out(x, W)                                                        # eq. (8), (P, block, L)
        nb = jnp.sum(w)
        mb = jnp.einsum("pnl,n->pl", H.astype(dt), w) / jnp.maximum(nb, 1.0)
        Hc = ((H - mb[:, None, :].astype(H.dtype)) * w[None, :, None].astype(H.dtype)).astype(gram_dtype)
        A = jnp.einsum("pni,pnj->pij", Hc, Hc).astype(dt) + nb * mb[:, :, None] * mb[:, None, :]
        return A, jnp.einsum("pni,n->pi", H, (t * w).astype(H.dtype)).astype(dt)

    A, HtT = scan_sum(gram, (jnp.zeros((P, hidden, hidden), dt), jnp.zeros((P, hidden), dt)), blocks)
    n = jnp.sum(wb)
    C = cholesky(A, lam)
    beta = cho_solve(C, HtT)                                                        # eq. (9)
    for _ in range(refine):
        def h_r(x, t, w, beta=beta):  # H^T r of the float64 residual r = w (T - H beta)
            H = _hidden_out(x, W)
            return _ht_r(H, (t - _h_beta(H, beta, False)) * w, dt)

        beta = beta + cho_solve(C, scan_sum(h_r, jnp.zeros((P, hidden), dt), blocks) - lam * beta)

    def sse(x, t, w):
        r = _h_beta(_hidden_out(x, W), beta, True) - t
        return jnp.einsum("pn,n->p", r * r, w)

    f = jnp.sqrt(scan_sum(sse, jnp.zeros(P, dt), blocks) / n)
    return jnp.where(jnp.isfinite(f), f, jnp.inf)


def _train_fitness_impl(pop, Xa, T, lam, hidden: int, chunk: int, refine: int, gram_dtype, w=None,
                        row_block: int = ROW_BLOCK, feature_dtype=jnp.float64):
    rows = TrainRows(Xa, T, w)
    P, D = pop.shape
    args = dict(rows=rows, lam=lam, hidden=hidden, refine=refine, gram_dtype=gram_dtype, feature_dtype=feature_dtype)
    if Xa.shape[0] <= row_block:
        kernel = partial(train_rmse_chunk, **args)
    else:
        kernel = partial(_train_rmse_chunk_blocked, **args, row_block=row_block)
    if chunk >= P:
        return kernel(pop)
    k = -(-P // chunk)
    padded = jnp.concatenate([pop, jnp.zeros((k * chunk - P, D), pop.dtype)]).reshape(k, chunk, D)
    out = jax.lax.map(kernel, padded)
    return out.reshape(-1)[:P]


def _sequential_over_batches(hidden: int, chunk: int, refine: int, gram_dtype: str, weighted: bool = False,
                             row_block: int = ROW_BLOCK, feature_dtype: str = "float64"):
    """The kernel with a batching rule that runs batch members one after another.

    Under the runner's vmap over repeats and strategies a plainly batched kernel
    would process every repeat's chunk at once, and the chunk no longer fits the
    cache (measured: 100 repeats cost 182x one repeat). ``lax.map`` over the
    batch keeps each chunk cache-sized, makes the cost linear in the batch, and
    makes a batch member's result bitwise that of the same call alone.
    """
    dtypes = dict(gram_dtype=jnp.dtype(gram_dtype), feature_dtype=jnp.dtype(feature_dtype))
    if weighted:
        def one(pop, Xa, T, lam, w):
            return _train_fitness_impl(pop, Xa, T, lam, hidden, chunk, refine, w=w, row_block=row_block, **dtypes)
    else:
        def one(pop, Xa, T, lam):
            return _train_fitness_impl(pop, Xa, T, lam, hidden, chunk, refine, row_block=row_block, **dtypes)

    f = jax.custom_batching.custom_vmap(one)

    @f.def_vmap
    def _rule(axis_size, in_batched, *args):
        args = tuple(a if b else jnp.broadcast_to(a, (axis_size,) + jnp.shape(a)) for a, b in zip(args, in_batched))
        return jax.lax.map(lambda a: f(*a), args), True

    return f


@partial(jax.jit, static_argnames=("hidden", "chunk", "refine", "gram_dtype", "row_block", "feature_dtype"))
def train_fitness(pop, rows: TrainRows, lam, hidden: int, chunk: int = 10, refine: int = 2,
                  gram_dtype: str = "float32", row_block: int = ROW_BLOCK, feature_dtype: str = "float64"):
    """Fast batched training RMSE (deg): the paper's fitness on gathered training rows.

    Mixed precision (``gram_dtype="float32"``): the Gram product of the centred
    hidden outputs in float32, the Cholesky factor and ``refine`` steps of
    iterative refinement with float64 residuals, so the result is the float64
    ridge solution (tested against :func:`fitness` on the study's own data).
    The population is processed in chunks of ``chunk`` thetas (``lax.map``) so a
    chunk's hidden outputs stay in cache; under ``vmap`` (repeats, strategies)
    batch members run one after another for the same reason. Above ``row_block``
    training rows the rows are processed in blocks too (:data:`ROW_BLOCK`): the
    column means, the centred Gram and ``H^T T`` are accumulated over blocks and
    each refinement step recomputes the hidden outputs block by block, so memory
    does not grow with the rows (the same float64 solution; tested against the
    unblocked kernel and :func:`fitness`). Measurements: ``results/performance.md``.

    Float32 features (``feature_dtype="float32"``): the pre-activation ``Xa W``, the
    sigmoid and the matrix-vector products ``H^T T``, ``H beta`` (refinement) and
    ``H^T r`` run in float32 on a float32 H (P, n, L); the column means, the Gram's
    mean term, the Cholesky factor, the solves, beta, the refinement's residual
    ``r = T - H beta`` and the final residual (float32 H times float64 beta,
    accumulated in float64) and the RMSE stay float64. The result is the float64
    ridge fit of the float32-rounded hidden outputs. Cost in accuracy, measured on
    the study's data (10 repeats x 120 thetas drawn uniform in the box, at its
    corners, x 0.05 and x 3): at most 7.6e-7 relative to :func:`fitness` (tested
    <= 5e-6); gain: 1.6x evaluations/s at batch 1200 on one core. Enough to rank
    candidates in a search, not for a reported metric: the refit (:func:`fit`) and
    every score are float64 whatever this option. Thetas beyond float32's range
    (3.4e38) overflow: +inf or a finite value, never NaN. ``"float64"`` is the
    kernel above, bitwise.

    Args:
        pop: (P, 7 L) hidden parameters. rows: TrainRows of one repeat.
        lam: ridge lambda. hidden: L.
        chunk: thetas per ``lax.map`` step (>= P: no chunking).
        refine: iterative-refinement steps (2 reach float64 accuracy here).
        gram_dtype: ``"float32"`` (mixed precision) or ``"float64"``.
        row_block: rows per block above which (and in which) the rows are processed in blocks.
        feature_dtype: ``"float64"`` (default) or ``"float32"`` hidden outputs, see above.
    Returns:
        (P,) fitness; +inf where not finite.
    """
    weighted = rows.w is not None
    f = _sequential_over_batches(hidden, chunk, refine, str(jnp.dtype(gram_dtype)), weighted, row_block,
                                 str(jnp.dtype(feature_dtype)))
    return f(pop, rows.Xa, rows.T, jnp.asarray(lam, pop.dtype), *((rows.w,) if weighted else ()))


def make_train_fitness(lam: float, hidden: int, chunk: int = 10, refine: int = 2, gram_dtype: str = "float32",
                       row_block: int = ROW_BLOCK, feature_dtype: str = "float64"):
    """``fitness(pop (P, D), aux: TrainRows) -> (P,)`` closure for optimizers (see :func:`train_fitness`)."""
    def f(pop, aux):
        return train_fitness(pop, aux, lam, hidden, chunk, refine, gram_dtype, row_block, feature_dtype)
    return f


def fold_weights(key, train_mask, mode: str = "train", val_fraction: float = 0.3, k_folds: int = 5):
    """Row weights (fit_w, score_w), each (K, N), for a fitness mode; jittable.

    Only rows with ``train_mask > 0`` ever get weight. ``validation`` holds out
    ``round(val_fraction * n_train)`` random training rows; ``kfold`` deals the
    training rows at random into ``k_folds`` folds.

    Args:
        key: PRNG key (unused for ``train``).
        train_mask: (N,) 0/1 training mask.
        mode: ``"train"``, ``"validation"`` or ``"kfold"``.
        val_fraction: validation share of the training rows.
        k_folds: number of folds.
    Returns:
        (fit_w, score_w), each (K, N) with K = 1, 1 or k_folds.
    """
    m = jnp.asarray(train_mask)
    if mode == "train":
        return m[None], m[None]
    # Random rank of each training row among the training rows (test rows last).
    u = jnp.where(m > 0, jax.random.uniform(key, m.shape), 2.0)
    rank = jnp.argsort(jnp.argsort(u))
    n_train = jnp.sum(m > 0)
    if mode == "validation":
        n_val = jnp.round(val_fraction * n_train)
        val = (rank < n_val) & (m > 0)
        return (m * ~val)[None], (m * val)[None]
    if mode == "kfold":
        fold_id = jnp.where(m > 0, rank % k_folds, -1)
        score = (fold_id[None, :] == jnp.arange(k_folds)[:, None]).astype(m.dtype)
        return m[None] * (1 - score), score
    raise ValueError(f"fitness mode {mode!r}: expected one of {FITNESS_MODES}")
