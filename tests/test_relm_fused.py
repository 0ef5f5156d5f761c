"""The fused accelerator kernel (icgo.models.relm_fused), run here on the CPU: against the float64 library fitness
at every Gram precision, in bounded memory (small blocks, member groups), batch members equal to calls alone, the
TF32 / bfloat16 rounding against ml_dtypes, and never a NaN."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import ml_dtypes
import numpy as np
import pytest
from conftest import relm_train_data

import icgo  # noqa: F401  (float64)
from icgo.models import relm
from icgo.models import relm_fused as F

HIDDEN = 5


def _rows(padded=False, scale=1.0, seed=2):
    _, _, mask, pop, fit = relm_train_data(n=200, scale=scale, seed=seed)
    rows = relm.train_rows(fit, int(mask.sum()) + (5 if padded else 0), padded=padded)
    return pop, fit, rows


@pytest.mark.parametrize("gram, refine", [("float32", 2), ("tf32", 2), ("bfloat16", 3)])
def test_every_gram_precision_refines_to_the_float64_fitness(gram, refine):
    """5e-6 relative of the float64 library fitness (the float32 features' tolerance) with padded (weight-0) rows,
    on well- and ill-conditioned features (x 0.05: near-linear sigmoids); the default also without padding."""
    for scale in (1.0, 0.05, 3.0):
        pop, fit, rows = _rows(True, scale)
        ref = np.asarray(relm.fitness(pop, fit, 1e-3, HIDDEN))
        got = F.fused_train_fitness(pop, rows, 1e-3, HIDDEN, gram, refine, block_rows=32)
        assert got.dtype == jnp.float64
        np.testing.assert_allclose(np.asarray(got), ref, rtol=5e-6)
    if gram == F.DEFAULT_GRAM:
        pop, fit, rows = _rows(False)
        np.testing.assert_allclose(np.asarray(F.fused_train_fitness(pop, rows, 1e-3, HIDDEN, block_rows=32)),
                                   np.asarray(relm.fitness(pop, fit, 1e-3, HIDDEN)), rtol=5e-6)


def test_on_the_studys_data_the_refinement_is_what_meets_the_tolerance():
    """lab_casing (30 deg toolface steps), L = 30, the paper's lambda: the TF32 and bfloat16 Grams alone are off by
    more than 5e-6; two (TF32) or three (bfloat16) refinement passes bring them within it."""
    from icgo.datasets import casing_stations
    from icgo.studies.icgo_relm.config import StudyConfig
    from icgo.studies.icgo_relm.prepare import filtered, prepare
    from icgo.studies.icgo_relm.search import train_rows

    cfg = StudyConfig(split=dict(n_repeats=1))
    rows_df, G, B, a, _ = filtered(casing_stations.lab_casing(0, toolface_step_deg=30.0).frame, cfg)
    prep, _ = prepare(rows_df, G, B, a, cfg, jax.random.PRNGKey(0))
    rows = jax.tree_util.tree_map(lambda x: x[0], train_rows(prep))
    pop = relm.random_theta(jax.random.PRNGKey(1), 30, (8,))
    ref = np.asarray(relm.fitness(pop, jax.tree_util.tree_map(lambda x: x[0], prep.data), 1e-3, 30))

    def err(gram, refine):
        return np.max(np.abs(np.asarray(F.fused_train_fitness(pop, rows, 1e-3, 30, gram, refine)) / ref - 1))

    assert err("tf32", 0) > 5e-6 and err("bfloat16", 0) > 5e-6
    assert err("tf32", 2) <= 5e-6 and err("bfloat16", 3) <= 5e-6


def test_the_default_is_tf32_with_two_refinements():
    assert (F.DEFAULT_GRAM, F.DEFAULT_REFINE) == ("tf32", 2)
    pop, fit, rows = _rows()
    np.testing.assert_array_equal(np.asarray(F.fused_train_fitness(pop, rows, 1e-3, HIDDEN)),
                                  np.asarray(F.fused_train_fitness(pop, rows, 1e-3, HIDDEN, "tf32", 2)))


def test_bounded_memory_blocks_and_groups_agree():
    """Blocks of 7 rows (last one padded), member groups of one and a population cut into parts: the same fitness
    within 1e-6 relative (the float32
    sums of another block size; 2e-8 measured on jax 0.11.2, 1e-15 on 0.12.0.1)."""
    pop, fit, rows = _rows(padded=True)
    whole = np.asarray(F.fused_train_fitness(pop, rows, 1e-3, HIDDEN, block_rows=1024))
    small = F.fused_train_fitness(pop, rows, 1e-3, HIDDEN, block_rows=7)
    np.testing.assert_allclose(np.asarray(small), whole, rtol=1e-6)
    pops = jnp.stack([pop, pop * 0.5, pop[::-1]])
    grouped = jax.vmap(lambda p: F.fused_train_fitness(p, rows, 1e-3, HIDDEN, block_rows=7,
                                                       block_elements=pop.shape[0] * 7 * HIDDEN))(pops)
    np.testing.assert_allclose(np.asarray(grouped[0]), np.asarray(small), rtol=1e-6)
    # a population larger than one block allows: cut into parts of 2 thetas (4 parts of the 8)
    parts = F.fused_train_fitness(pop, rows, 1e-3, HIDDEN, block_rows=7, block_elements=2 * 7 * HIDDEN)
    np.testing.assert_allclose(np.asarray(parts), np.asarray(small), rtol=1e-6)


def test_batch_members_equal_calls_alone_under_nested_vmap():
    """Strategies x repeats under two vmaps is one batch; each member equals its call alone to 1e-6 relative (the
    row blocks are fixed, so only the order XLA gives a batched float32 product's sums may differ with the batch
    size: 1e-16 measured on jax 0.12.0.1, 1e-8 on 0.11.2)."""
    pop, fit, rows = _rows()
    pops = jnp.stack([jnp.stack([pop, pop * 0.7]), jnp.stack([pop * 1.3, pop[::-1]])])       # (S=2, R=2, P, D)
    rows2 = jax.tree_util.tree_map(lambda x: jnp.stack([x, x * 1.01]), rows)
    out = jax.vmap(jax.vmap(lambda p, r: F.fused_train_fitness(p, r, 1e-3, HIDDEN), in_axes=(0, 0)),
                   in_axes=(0, None))(pops, rows2)
    for s in range(2):
        for r in range(2):
            alone = F.fused_train_fitness(pops[s, r], jax.tree_util.tree_map(lambda x: x[r], rows2), 1e-3, HIDDEN)
            np.testing.assert_allclose(np.asarray(out[s, r]), np.asarray(alone), rtol=1e-6)


def test_round_mantissa_is_bfloat16_and_tf32_rounding():
    x = np.random.default_rng(0).uniform(-1, 1, 4096).astype(np.float32)
    x[:4] = [0.0, 1.0, -0.5, 2.0 ** -20]
    bf16 = np.asarray(F.round_mantissa(jnp.asarray(x), 7))
    np.testing.assert_array_equal(bf16, x.astype(ml_dtypes.bfloat16).astype(np.float32))  # ties to even, as ml_dtypes
    tf32 = np.asarray(F.round_mantissa(jnp.asarray(x), 10))
    assert np.all(np.abs(tf32 - x) <= np.abs(x) * 2.0 ** -11)                               # half a TF32 unit
    assert np.all(np.asarray(F.round_mantissa(jnp.asarray(tf32), 10)) == tf32)              # TF32 values stay
    np.testing.assert_array_equal(tf32[:4], x[:4])


def test_a_non_finite_fit_is_inf_never_nan():
    pop, fit, rows = _rows()
    huge = pop.at[0].set(1e300).at[1].set(jnp.nan)
    got = np.asarray(F.fused_train_fitness(huge, rows, 1e-3, HIDDEN))
    assert np.isinf(got[0]) or np.isfinite(got[0])
    assert np.isinf(got[1]) and not np.isnan(got).any()


def test_an_unknown_precision_is_refused():
    pop, fit, rows = _rows()
    with pytest.raises(ValueError, match="gram must be one of"):
        F.fused_train_fitness(pop, rows, 1e-3, HIDDEN, "float16")
