"""The accelerator's RELM fitness: the search's fitness from weighted Gram sums, one pass over the rows.

:func:`gram_fitness` (any fold mode, on :class:`icgo.models.relm.FitData`) and :func:`gram_train_fitness`
(the paper's train mode on gathered :class:`icgo.models.relm.TrainRows`) give the fitness of
:func:`icgo.models.relm.fitness` as batched matrix products over row blocks of bounded size: under
``vmap`` (the runner's repeats and strategies) the whole batch is one call, which is what an accelerator
needs. The CPU's kernels are :func:`icgo.models.relm.train_fitness` and :func:`icgo.models.relm.fitness`;
the paper's default on an accelerator is :func:`icgo.models.relm_fused.fused_train_fitness`.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp

from icgo.models.relm import FitData, TrainRows, cho_solve, cholesky, input_weights, row_blocks, scan_sum

#: Elements (batch members x rows x hidden units) of one block of hidden outputs in :func:`gram_fitness`:
#: its memory bound whatever the batch (2**26 float64 values: 512 MiB, the float32 features beside them
#: half that), large enough that one block is millions of products for an accelerator.
BLOCK_ELEMENTS = 2**26
#: Fewest rows a block of :func:`gram_fitness` holds before the batch's members are split into groups.
MIN_BLOCK_ROWS = 8
#: Float32 products at full float32 precision: a GPU would otherwise round their operands to TF32
#: (10-bit mantissa) by default, 1e-3 relative, far outside the kernel's tolerance. No effect on CPU.
_EXACT = jax.lax.Precision.HIGHEST


def _gram_sums(pop, Xa, T, w, hidden: int, feature_dtype, rows_per_block: int):
    """One pass over the rows, ``rows_per_block`` at a time (``lax.scan``): per batch member and weight vector,
    ``sum_n w_n h_n h_n^T`` (B, P, J, L, L) and ``sum_n w_n h_n T_n`` (B, P, J, L) in the dtype of ``w``.

    pop (B, P, D); Xa (B, n, d1) with the column of ones last; T (B, n); w (B, J, n). ``h_n`` is eq. (8)
    in ``feature_dtype``, cast up before the products (a product of two float32 values is exact in float64).
    """
    B, P, D = pop.shape
    d1 = Xa.shape[2]
    acc = w.dtype
    W = input_weights(pop.reshape(B * P, D), d1, hidden, feature_dtype).reshape(B, P, d1, hidden)
    # rows first, so that row_blocks splits them: (nblocks, rows_per_block, B, ...)
    Xb, Tb, wb, _ = row_blocks(rows_per_block, jnp.swapaxes(Xa, 0, 1), jnp.swapaxes(T, 0, 1), jnp.moveaxis(w, 2, 0))

    def block(x, t, wt):  # x (nb, B, d1), t (nb, B), wt (nb, B, J); padded rows have weight 0
        Z = jnp.einsum("nbd,bpdl->bpnl", x.astype(W.dtype), W, precision=_EXACT)
        H = jax.nn.sigmoid(Z).astype(acc)                                              # eq. (8)
        Hw = jnp.einsum("nbj,bpni->bpjni", wt, H)
        return (jnp.einsum("bpjni,bpnk->bpjik", Hw, H, precision=_EXACT),
                jnp.einsum("bpjni,nb->bpji", Hw, t, precision=_EXACT))

    J = w.shape[1]
    init = (jnp.zeros((B, P, J, hidden, hidden), acc), jnp.zeros((B, P, J, hidden), acc))
    return scan_sum(block, init, (Xb, Tb, wb))


def _gram_rmse(pop, Xa, T, fw, sw, lam, hidden: int, feature_dtype, rows_per_block: int):
    """Mean over folds of the scored RMSE (B, P) from the Gram sums of :func:`_gram_sums` (``sw`` None:
    scored on the fit rows). Per fold: ``beta = (G_fit + lam I)^-1 c_fit`` (eq. 9, Cholesky) and the
    scored sum of squares ``beta^T (G_score beta - 2 c_score) + sum_n w_n T_n^2``, all in the dtype of ``fw``."""
    K = fw.shape[1]
    G, c = _gram_sums(pop, Xa, T, fw if sw is None else jnp.concatenate([fw, sw], axis=1), hidden, feature_dtype,
                      rows_per_block)
    Gf, cf = G[:, :, :K], c[:, :, :K]
    Gs, cs, ws = (Gf, cf, fw) if sw is None else (G[:, :, K:], c[:, :, K:], sw)
    beta = cho_solve(cholesky(Gf, lam[:, None, None, None, None]), cf)             # eq. (9), (B, P, K, L)
    tt = jnp.einsum("bkn,bn->bk", ws, T * T, precision=_EXACT)
    quad = jnp.einsum("bpki,bpkij,bpkj->bpk", beta, Gs, beta, precision=_EXACT)
    sse = quad - 2.0 * jnp.einsum("bpki,bpki->bpk", beta, cs, precision=_EXACT) + tt[:, None]
    f = jnp.mean(jnp.sqrt(jnp.maximum(sse, 0.0) / jnp.sum(ws, axis=-1)[:, None]), axis=-1)
    return jnp.where(jnp.isfinite(f), f, jnp.inf)


def _gram_batched(pop, Xa, T, fw, sw, lam, hidden: int, feature_dtype, block_elements: int):
    """:func:`_gram_rmse` of a batch (leading axis B) with at most ``block_elements`` hidden outputs in a block.

    Rows per block: as many as the budget allows for the whole batch. When even
    :data:`MIN_BLOCK_ROWS` rows of the whole batch exceed it, the batch is split into groups of members
    run one after another (``lax.map``): a population larger than a group is cut into parts (its rows
    repeated for each part), smaller ones are grouped whole.
    """
    B, P, D = pop.shape
    n = Xa.shape[1]
    min_rows = min(n, MIN_BLOCK_ROWS)
    if B * P * hidden * min_rows <= block_elements:
        return _gram_rmse(pop, Xa, T, fw, sw, lam, hidden, feature_dtype, min(n, block_elements // (B * P * hidden)))
    group = max(1, block_elements // (hidden * min_rows))                            # members per group
    if P > group:  # cut each population into k parts of `group` members, each part its own batch entry
        k = -(-P // group)
        pop = jnp.pad(pop, ((0, 0), (0, k * group - P), (0, 0))).reshape(B * k, group, D)
        rep = [jnp.repeat(a, k, axis=0) for a in (Xa, T, fw, lam)] + [None if sw is None else jnp.repeat(sw, k, 0)]
        out = _gram_batched(pop, *rep[:3], rep[4], rep[3], hidden, feature_dtype, block_elements)
        return out.reshape(B, k * group)[:, :P]
    e = max(1, group // P)                                                             # batch entries per group
    g = -(-B // e)

    def grouped(a):
        return None if a is None else jnp.pad(a, ((0, g * e - B),) + ((0, 0),) * (a.ndim - 1)).reshape(
            (g, e) + a.shape[1:])

    rows = min(n, block_elements // (e * P * hidden))
    args = tuple(grouped(a) for a in (pop, Xa, T, fw, sw, lam))
    out = jax.lax.map(lambda a: _gram_rmse(a[0], a[1], a[2], a[3], a[4], a[5], hidden, feature_dtype, rows), args)
    return out.reshape(g * e, P)[:B]


def _gram_kernel(hidden: int, feature_dtype: str, block_elements: int, same: bool):
    """:func:`_gram_batched` behind batching rules that hand every vmap's axis to it as one batch.

    ``entry(pop (P, D), Xa (n, d1), T (n,), fw (K, n), sw (K, n), lam ())`` -> (P,). Under ``vmap``
    (the runner's repeats and strategies) its rule calls the batched function once with the mapped
    axis as the batch, whose own rule folds a further vmap's axis into that batch: one call sees
    strategies x repeats x population, and bounds its memory itself.
    """
    fd = jnp.dtype(feature_dtype)

    @jax.custom_batching.custom_vmap
    def batched(pop, Xa, T, fw, sw, lam):
        return _gram_batched(pop, Xa, T, fw, None if same else sw, lam, hidden, fd, block_elements)

    @batched.def_vmap
    def _fold(axis_size, in_batched, *args):
        B = args[0].shape[1] if in_batched[0] else args[0].shape[0]
        full = [a if b else jnp.broadcast_to(a, (axis_size,) + a.shape) for a, b in zip(args, in_batched)]
        out = batched(*(a.reshape((axis_size * B,) + a.shape[2:]) for a in full))
        return out.reshape(axis_size, B, -1), True

    @jax.custom_batching.custom_vmap
    def entry(pop, Xa, T, fw, sw, lam):
        return batched(pop[None], Xa[None], T[None], fw[None], sw[None], lam[None])[0]

    @entry.def_vmap
    def _batch(axis_size, in_batched, *args):
        return batched(*(a if b else jnp.broadcast_to(a, (axis_size,) + a.shape)
                         for a, b in zip(args, in_batched))), True

    return entry


def _gram_call(pop, Xa, T, fw, sw, lam, hidden, feature_dtype, solve_dtype, block_elements, same):
    dt = jnp.dtype(solve_dtype)
    f = _gram_kernel(hidden, str(jnp.dtype(feature_dtype)), int(block_elements), same)
    return f(pop.astype(dt), Xa.astype(dt), T.astype(dt), fw.astype(dt), sw.astype(dt), jnp.asarray(lam, dt))


@partial(jax.jit, static_argnames=("hidden", "feature_dtype", "solve_dtype", "block_elements"))
def gram_fitness(pop, data: FitData, lam, hidden: int, feature_dtype: str = "float32",
                 solve_dtype: str = "float64", block_elements: int = BLOCK_ELEMENTS):
    """The accelerator kernel: :func:`icgo.models.relm.fitness` (any fold mode) from weighted Gram sums, one pass over the rows.

    For each theta and fold, one pass over the rows in blocks accumulates ``G = H^T diag(w) H`` and
    ``c = H^T diag(w) T`` for the fold's fit weights and its score weights (``lax.scan``); then
    ``beta = (G_fit + lam I)^-1 c_fit`` (eq. 9, Cholesky) and the scored sum of squares
    ``sum_n s_n (h_n beta - T_n)^2 = beta^T G_score beta - 2 beta^T c_score + sum_n s_n T_n^2``, so the
    hidden outputs are never revisited and never held for the whole batch: a block holds at most
    ``block_elements`` of them (:data:`BLOCK_ELEMENTS`), whatever the batch (members are grouped
    when even :data:`MIN_BLOCK_ROWS` rows of the whole batch would exceed it). Under ``vmap`` (the
    runner's repeats and strategies) the whole strategies x repeats x population batch is one call
    of batched matrix products: no ``lax.map`` over small chunks as on the CPU (:func:`icgo.models.relm.train_fitness`).

    Precision: eq. (8) (pre-activation and sigmoid) in ``feature_dtype``; the products, sums, Cholesky
    and RMSE in ``solve_dtype`` (a product of two float32 features is exact in float64, so with
    float64 sums the result is the float64 ridge fit of the float32-rounded hidden outputs, like
    :func:`icgo.models.relm.train_fitness`'s float32 features, without its refinement passes); float32 products run at
    full float32 precision (never TF32). Tolerance against :func:`icgo.models.relm.fitness` (float64), tested on the
    study's data: 5e-6 relative with float32 features, 1e-9 with float64 ones. The scored sum of
    squares is a difference of terms of size ``sum s T^2``: its rounding is ``eps`` times
    ``sum s T^2 / sum s r^2`` (about 1e3 on the study's data: 1e-13 in float64).

    Args:
        pop: (P, 7 L) hidden parameters. data: FitData of one repeat (K folds over N rows).
        lam: ridge lambda. hidden: L.
        feature_dtype: ``"float32"`` (default) or ``"float64"`` hidden outputs.
        solve_dtype: ``"float64"`` (default) or ``"float32"`` (everything in float32).
        block_elements: the memory bound above (static).
    Returns:
        (P,) fitness in ``solve_dtype``; +inf where not finite.
    """
    X = jnp.asarray(data.X)
    Xa = jnp.concatenate([X, jnp.ones((X.shape[0], 1), X.dtype)], axis=1)
    return _gram_call(pop, Xa, data.T, data.fit_w, data.score_w, lam, hidden, feature_dtype, solve_dtype,
                      block_elements, False)


@partial(jax.jit, static_argnames=("hidden", "feature_dtype", "solve_dtype", "block_elements"))
def gram_train_fitness(pop, rows: TrainRows, lam, hidden: int, feature_dtype: str = "float32",
                       solve_dtype: str = "float64", block_elements: int = BLOCK_ELEMENTS):
    """:func:`gram_fitness` of the paper's train mode on gathered training rows (one fold, scored on its fit
    rows: one Gram per theta). Same result as :func:`icgo.models.relm.train_fitness` within the tolerances of :func:`gram_fitness`.

    Args:
        pop: (P, 7 L). rows: TrainRows of one repeat (weights None or 0/1). lam, hidden, feature_dtype,
            solve_dtype, block_elements: see :func:`gram_fitness`.
    Returns:
        (P,) training RMSE (deg); +inf where not finite.
    """
    w = jnp.ones(rows.T.shape, rows.T.dtype) if rows.w is None else rows.w
    return _gram_call(pop, rows.Xa, rows.T, w[None], w[None], lam, hidden, feature_dtype, solve_dtype,
                      block_elements, True)


def make_gram_fitness(lam: float, hidden: int, train: bool, feature_dtype: str = "float32",
                      solve_dtype: str = "float64", block_elements: int = BLOCK_ELEMENTS):
    """``fitness(pop (P, D), aux) -> (P,)`` closure for optimizers: :func:`gram_train_fitness` on TrainRows
    (``train``) or :func:`gram_fitness` on FitData."""
    kernel = gram_train_fitness if train else gram_fitness

    def f(pop, aux):
        return kernel(pop, aux, lam, hidden, feature_dtype, solve_dtype, block_elements)
    return f
