"""The fused accelerator kernel of the paper's training fitness (eqs. 8-9): hidden layer and Gram in bounded row blocks.

For every theta of a batch (members x population) and its member's gathered training rows
(:class:`icgo.models.relm.TrainRows`), the training RMSE of the ridge fit, computed in passes over blocks of
:data:`BLOCK_ROWS` rows (``lax.scan``); a block's hidden outputs ``H = sigmoid(Xa W)`` (eq. 8) exist only inside
its step, so no member's H is ever held for more than one block, and the batch is cut into groups of members run
one after another (``lax.map``), a population larger than a block allows into parts, when one block of the whole
batch would exceed :data:`BLOCK_ELEMENTS` hidden outputs: any batch runs in bounded memory.

1. **Gram pass.** Per block b: its column means ``m_b`` (float64), the Gram of its centred columns
   ``Hc_b^T Hc_b`` on the matrix units at ``gram`` precision (float32 products accumulated in float32 over the
   block), plus ``n_b m_b m_b^T`` in float64, and ``H^T T``; summed over blocks in float64. Centring keeps the
   low-precision part small against the columns' large common mean (:func:`icgo.models.relm.normal_equations`).
2. **Solve.** Cholesky of the float64 Gram + lambda I and ``beta = C^-T C^-1 H^T T`` (eq. 9), float64.
3. **Refinement** (``refine`` passes): ``beta += (C C^T)^-1 (H^T r - lambda beta)`` with the float64 residual
   ``r = w (T - H beta)`` of the exact normal equations, H recomputed block by block. Each pass shrinks the error
   the low-precision Gram left by about its relative error times the conditioning, so ``beta`` reaches the float64
   ridge solution of the float32 hidden outputs.
4. **RMSE pass**: ``sqrt(sum w (H beta - T)^2 / n)``, float64 residuals.

Gram precisions (:data:`GRAM_PRECISIONS`), the same numbers on every backend (up to summation order):

* ``"float32"``: float32 operands, products at full float32 precision (no TF32);
* ``"tf32"``: operands rounded to TF32's 10-bit mantissa (:func:`round_mantissa`), then multiplied at the backend's
  default precision: on an NVIDIA GPU the TF32 tensor cores, which multiply such operands exactly; on a CPU the
  same numbers in float32;
* ``"bfloat16"``: operands rounded to bfloat16 (7-bit mantissa), products accumulated in float32 (the bfloat16
  tensor cores of a GPU or TPU).

Measured tolerances against the float64 library fitness (:func:`icgo.models.relm.fitness`) on the study's data,
and the default: ``docs/performance.md`` ("The fused accelerator kernel"); tested in ``tests/test_relm_fused.py``.
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp

from icgo.models.relm import TrainRows, cho_solve, cholesky, input_weights, row_blocks

#: Precisions of the Gram's products (see the module docstring).
GRAM_PRECISIONS = ("float32", "tf32", "bfloat16")
#: The default Gram precision and refinement passes (chosen on the measured tolerance: docs/performance.md).
DEFAULT_GRAM, DEFAULT_REFINE = "tf32", 2
#: Rows per block: fixed (not from the batch), so a member's arithmetic does not depend on its batch-mates (up to
#: the order XLA gives a batched float32 product's sums for another batch size: 1e-16 to 1e-8 relative, tested
#: within 1e-6).
BLOCK_ROWS = 256
#: Most hidden outputs (members x population x block rows x hidden units) one block of a group holds: 2**24 float32
#: values (64 MiB, a few times that with the block's temporaries); larger batches run in groups.
BLOCK_ELEMENTS = 2**24
_HIGHEST = jax.lax.Precision.HIGHEST
_MANTISSA = {"float32": 23, "tf32": 10}


def round_mantissa(x, bits: int):
    """float32 ``x`` rounded to ``bits`` mantissa bits (round to nearest, ties to even), as float32.

    ``bits=10`` gives the TF32 value a tensor core multiplies. Finite inputs only (the kernel's are in [-1, 1]).
    """
    u = jax.lax.bitcast_convert_type(x.astype(jnp.float32), jnp.uint32)
    drop = 23 - bits
    half = jnp.uint32((1 << (drop - 1)) - 1)
    u = (u + half + ((u >> drop) & jnp.uint32(1))) & jnp.uint32(~((1 << drop) - 1) & 0xFFFFFFFF)
    return jax.lax.bitcast_convert_type(u, jnp.float32)


def _gram(Hc, gram: str):
    """``Hc^T Hc`` per (member, theta) of a block of centred hidden outputs Hc (G, P, nb, L) float32, in float32."""
    if gram == "bfloat16":
        h = Hc.astype(jnp.bfloat16)
        return jnp.einsum("gpni,gpnj->gpij", h, h, preferred_element_type=jnp.float32)
    if gram == "tf32":
        h = round_mantissa(Hc, _MANTISSA["tf32"])
        return jnp.einsum("gpni,gpnj->gpij", h, h, preferred_element_type=jnp.float32)
    return jnp.einsum("gpni,gpnj->gpij", Hc, Hc, precision=_HIGHEST, preferred_element_type=jnp.float32)


def _group_rmse(pop, Xa, T, w, lam, hidden: int, gram: str, refine: int, block_rows: int):
    """Training RMSE (G, P) of a group: pop (G, P, D), Xa (G, n, d1), T (G, n), w (G, n) 0/1, lam (G,); float64."""
    G, P, D = pop.shape
    d1 = Xa.shape[2]
    W = input_weights(pop.reshape(G * P, D), d1, hidden, jnp.float32).reshape(G, P, d1, hidden)
    Xb, Tb, wb, _ = row_blocks(block_rows, jnp.swapaxes(Xa, 0, 1), jnp.swapaxes(T, 0, 1), jnp.swapaxes(w, 0, 1))
    blocks = (Xb, Tb, wb)                                       # (nblocks, block_rows, G, ...); padded rows weigh 0

    def hidden_out(x):                                           # eq. (8): (G, P, nb, L) float32
        return jax.nn.sigmoid(jnp.einsum("ngd,gpdl->gpnl", x.astype(jnp.float32), W, precision=_HIGHEST))

    def scan_sum(f, init):
        return jax.lax.scan(lambda acc, blk: (jax.tree_util.tree_map(jnp.add, acc, f(*blk)), None), init, blocks)[0]

    def gram_block(x, t, wt):
        H = hidden_out(x)
        wg = jnp.swapaxes(wt, 0, 1)                              # (G, nb)
        nb = jnp.sum(wg, axis=1)                                 # (G,)
        mb = jnp.einsum("gpnl,gn->gpl", H.astype(jnp.float64), wg) / jnp.maximum(nb, 1.0)[:, None, None]
        Hc = (H - mb[:, :, None, :].astype(jnp.float32)) * wg[:, None, :, None].astype(jnp.float32)
        A = _gram(Hc, gram).astype(jnp.float64) + nb[:, None, None, None] * mb[..., :, None] * mb[..., None, :]
        b = jnp.einsum("gpnl,gn->gpl", H.astype(jnp.float64), (jnp.swapaxes(t, 0, 1) * wg))
        return A, b

    A, b = scan_sum(gram_block, (jnp.zeros((G, P, hidden, hidden)), jnp.zeros((G, P, hidden))))
    C = cholesky(A.reshape(G * P, hidden, hidden), jnp.repeat(lam, P)[:, None, None])
    C = C.reshape(G, P, hidden, hidden)
    beta = cho_solve(C.reshape(G * P, hidden, hidden), b.reshape(G * P, hidden)).reshape(G, P, hidden)  # eq. (9)

    def residual(x, t, wt, beta):                                # w (T - H beta), float64: (G, P, nb) and H
        H = hidden_out(x)
        r = jnp.swapaxes(t, 0, 1)[:, None, :] - jnp.einsum("gpnl,gpl->gpn", H.astype(jnp.float64), beta)
        return r * jnp.swapaxes(wt, 0, 1)[:, None, :], H

    for _ in range(refine):
        def correction(x, t, wt, beta=beta):
            r, H = residual(x, t, wt, beta)
            return jnp.einsum("gpnl,gpn->gpl", H.astype(jnp.float64), r)

        hr = scan_sum(correction, jnp.zeros((G, P, hidden)))
        step = cho_solve(C.reshape(G * P, hidden, hidden), (hr - lam[:, None, None] * beta).reshape(G * P, hidden))
        beta = beta + step.reshape(G, P, hidden)

    sse = scan_sum(lambda x, t, wt: jnp.sum(residual(x, t, wt, beta)[0] ** 2, axis=-1), jnp.zeros((G, P)))
    f = jnp.sqrt(sse / jnp.sum(w, axis=1)[:, None])
    return jnp.where(jnp.isfinite(f), f, jnp.inf)


def _batched(pop, Xa, T, w, lam, hidden: int, gram: str, refine: int, block_rows: int, block_elements: int):
    """:func:`_group_rmse` of a batch (B, P, D) in groups of members that keep one block within ``block_elements``
    hidden outputs (``lax.map`` over the groups; a batch of one group runs as one). A population whose one block
    alone exceeds it is first cut into parts, each part a member of its own (its rows repeated)."""
    B, P, D = pop.shape
    rows = min(block_rows, Xa.shape[1])
    if P * rows * hidden > block_elements:
        part = max(1, block_elements // (rows * hidden))
        k = -(-P // part)
        pop = jnp.concatenate([pop, jnp.broadcast_to(pop[:, :1], (B, k * part - P, D))], axis=1)
        out = _batched(pop.reshape(B * k, part, D), *(jnp.repeat(a, k, axis=0) for a in (Xa, T, w, lam)), hidden,
                       gram, refine, block_rows, block_elements)
        return out.reshape(B, k * part)[:, :P]
    group = max(1, block_elements // (P * rows * hidden))
    if B <= group:
        return _group_rmse(pop, Xa, T, w, lam, hidden, gram, refine, rows)
    k = -(-B // group)

    def grouped(a):
        a = jnp.concatenate([a, jnp.broadcast_to(a[:1], (k * group - B,) + a.shape[1:])])  # padded with member 0
        return a.reshape((k, group) + a.shape[1:])

    out = jax.lax.map(lambda g: _group_rmse(*g, hidden, gram, refine, rows), tuple(grouped(a) for a in
                                                                                      (pop, Xa, T, w, lam)))
    return out.reshape(k * group, P)[:B]


def _kernel(hidden: int, gram: str, refine: int, block_rows: int, block_elements: int):
    """The one-member entry ``(pop (P, D), Xa, T, w, lam) -> (P,)`` whose batching rules hand every vmap's axis to
    :func:`_batched` as one batch (as :func:`icgo.models.relm_gram.gram_fitness` does)."""
    args = (hidden, gram, refine, block_rows, block_elements)

    @jax.custom_batching.custom_vmap
    def batched(pop, Xa, T, w, lam):
        return _batched(pop, Xa, T, w, lam, *args)

    @batched.def_vmap
    def _fold(axis_size, in_batched, *xs):
        B = xs[0].shape[1] if in_batched[0] else xs[0].shape[0]
        full = [x if b else jnp.broadcast_to(x, (axis_size,) + x.shape) for x, b in zip(xs, in_batched)]
        return batched(*(x.reshape((axis_size * B,) + x.shape[2:]) for x in full)).reshape(axis_size, B, -1), True

    @jax.custom_batching.custom_vmap
    def entry(pop, Xa, T, w, lam):
        return batched(pop[None], Xa[None], T[None], w[None], lam[None])[0]

    @entry.def_vmap
    def _batch(axis_size, in_batched, *xs):
        return batched(*(x if b else jnp.broadcast_to(x, (axis_size,) + x.shape) for x, b in zip(xs, in_batched))), True

    return entry


@partial(jax.jit, static_argnames=("hidden", "gram", "refine", "block_rows", "block_elements"))
def fused_train_fitness(pop, rows: TrainRows, lam, hidden: int, gram: str = DEFAULT_GRAM, refine: int = DEFAULT_REFINE,
                        block_rows: int = BLOCK_ROWS, block_elements: int = BLOCK_ELEMENTS):
    """The paper's training fitness (RMSE of the ridge fit on the training rows, deg) by the fused kernel.

    Args:
        pop: (P, 7 L) hidden parameters. rows: :class:`icgo.models.relm.TrainRows` of one member (weights None
            or 0/1). lam: ridge lambda. hidden: L.
        gram: :data:`GRAM_PRECISIONS`. refine: refinement passes. block_rows: rows per block (static, fixed).
        block_elements: the memory bound of one block of a group (static).
    Returns:
        (P,) float64; +inf where not finite. Under ``vmap`` (members) the whole batch is one call.
    """
    if gram not in GRAM_PRECISIONS:
        raise ValueError(f"fused kernel: gram must be one of {list(GRAM_PRECISIONS)}, got {gram!r}")
    w = jnp.ones(rows.T.shape, jnp.float64) if rows.w is None else rows.w.astype(jnp.float64)
    f = _kernel(hidden, gram, int(refine), int(block_rows), int(block_elements))
    return f(pop.astype(jnp.float64), rows.Xa.astype(jnp.float64), rows.T.astype(jnp.float64), w,
             jnp.asarray(lam, jnp.float64))
