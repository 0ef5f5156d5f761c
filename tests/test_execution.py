"""Backend-aware execution: the plan for every backend name, the accelerator kernel against the float64
library fitness (run here on the CPU), its bounded-memory paths, and no recompilation per repeat."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import relm_train_data

import icgo  # noqa: F401  (float64)
from icgo.core import execution as ex
from icgo.models import relm, relm_gram
from icgo.studies.icgo_relm.config import StudyConfig
from icgo.studies.icgo_relm.prepare import frame_arrays, prepare
from icgo.studies.icgo_relm.search import search

ACCELERATORS = ("gpu", "cuda", "rocm", "tpu", "METAL", "Metal", "neuron", " GPU ")


@pytest.mark.parametrize("backend", ("cpu", "CPU", " cpu"))
def test_a_cpu_shards_the_members_over_its_host_devices(backend):
    plan = ex.execution_plan(backend, available=16, members=50, cores=16)
    assert (plan.backend, plan.kernel, plan.devices, plan.processes) == ("cpu", ex.CPU_KERNEL, 13, 1)
    assert "one per core of the job's 16" in plan.why and "50 member(s) in 13 shard(s) of at most 4" in plan.why
    assert not ex.is_accelerator(backend)
    assert ex.execution_plan(backend, 2, 50).devices == 2
    assert ex.execution_plan(backend, 2, 1).devices == 1                        # one member: one device
    assert ex.execution_plan(backend, 2, 0).devices == 1 and "no search" in ex.execution_plan(backend, 2, 0).why
    assert ex.execution_plan(backend, 16, 50, devices=4).devices == 4           # the setting caps it
    assert ex.execution_plan(backend, 16, 50, devices=64).devices == 13         # never more than available
    assert ex.execution_plan(backend, 16, 10).devices == 10
    assert ex.execution_plan(backend, 4, 10, processes=2).processes == 2
    assert "across 2 processes" in ex.execution_plan(backend, 4, 10, processes=2).why


@pytest.mark.parametrize("backend", ACCELERATORS)
@pytest.mark.parametrize("devices", (None, 1, 8))
def test_an_accelerator_gets_the_batched_kernel_over_its_devices(backend, devices):
    plan = ex.execution_plan(backend, available=8, members=50, devices=devices)
    assert plan.kernel == ex.ACCELERATOR_KERNEL and ex.is_accelerator(backend)
    assert plan.devices == (1 if devices == 1 else 8)
    assert plan.backend == backend.strip().lower() and plan.backend in plan.why


def test_the_study_plans_methods_times_repeats_members():
    from icgo.optim import STRATEGIES

    table3 = StudyConfig(strategies=STRATEGIES)
    plan = table3.execution(backend="cpu")
    assert plan.members == 50 and plan.devices == min(len(jax.devices("cpu")), 50)
    assert table3.execution(backend="cpu", cells=300).members == 5 * 300                    # worlds x repeats cells
    assert dataclasses.replace(table3, optimizer=None).execution(backend="cpu").members == 0  # plain RELM: no search
    assert dataclasses.replace(table3, devices=1).execution(backend="cpu").devices == 1


@pytest.mark.parametrize("backend", ("", "  ", None, 3))
def test_a_backend_without_a_name_is_refused(backend):
    with pytest.raises(ValueError, match="backend"):
        ex.execution_plan(backend, 2, 10)


def test_bad_devices_settings_are_refused():
    for d in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match="devices"):
            ex.execution_plan("cpu", 2, 10, devices=d)
        with pytest.raises(ValueError, match="devices"):
            StudyConfig(devices=d)


# -------------------------------------------------------------- the accelerator kernel, run on the CPU
def _fold_data(mode, n=200, scale=1.0, seed=2):
    X, T, mask, pop, _ = relm_train_data(n=n, scale=scale, seed=seed)
    fw, sw = relm.fold_weights(jax.random.PRNGKey(seed), jnp.asarray(mask), mode, 0.3, 4)
    return pop, relm.FitData(jnp.asarray(X), jnp.asarray(T), fw, sw), mask


@pytest.mark.parametrize("mode", relm.FITNESS_MODES)
@pytest.mark.parametrize("scale", [1.0, 0.05, 3.0])  # 0.05: near-linear sigmoids, an ill-conditioned Gram
@pytest.mark.parametrize("features, rtol", [("float32", 5e-6), ("float64", 1e-9)])
def test_gram_fitness_equals_the_float64_library_fitness(mode, scale, features, rtol):
    """The documented tolerances: 5e-6 relative with float32 features, 1e-9 with float64 ones, every fold mode;
    and the same with blocks of a few rows and with the members split into groups (tiny memory bounds)."""
    pop, data, _ = _fold_data(mode, scale=scale)
    ref = np.asarray(relm.fitness(pop, data, 1e-3, 5))
    for block in (relm_gram.BLOCK_ELEMENTS, 8 * 5 * 24, 5 * relm_gram.MIN_BLOCK_ROWS * 3):  # whole, 24-row blocks, groups of 3
        got = relm_gram.gram_fitness(pop, data, 1e-3, 5, features, block_elements=block)
        assert got.dtype == jnp.float64
        np.testing.assert_allclose(np.asarray(got), ref, rtol=rtol)


@pytest.mark.parametrize("padded", [False, True])
def test_gram_train_fitness_on_gathered_rows_equals_the_library_and_the_cpu_kernel(padded):
    _, _, mask, pop, fit = relm_train_data(n=200, seed=2)
    rows = relm.train_rows(fit, int(mask.sum()) + (5 if padded else 0), padded=padded)
    ref = np.asarray(relm.fitness(pop, fit, 1e-3, 5))
    for features, rtol in (("float32", 5e-6), ("float64", 1e-9)):
        got = np.asarray(relm_gram.gram_train_fitness(pop, rows, 1e-3, 5, features))
        np.testing.assert_allclose(got, ref, rtol=rtol)
        cpu = np.asarray(relm.train_fitness(pop, rows, 1e-3, 5, chunk=3, feature_dtype=features))
        np.testing.assert_allclose(got, cpu, rtol=2 * rtol)


def test_gram_fitness_in_float32_is_float32_within_the_float32_paths_tolerance():
    pop, data, _ = _fold_data("train")
    got = relm_gram.gram_fitness(pop, data, 1e-3, 5, "float32", "float32")
    assert got.dtype == jnp.float32
    np.testing.assert_allclose(np.asarray(got), np.asarray(relm.fitness(pop, data, 1e-3, 5)), rtol=1e-3)


def test_gram_fitness_nonfinite_is_inf_never_nan():
    pop, data, _ = _fold_data("kfold")
    bad = pop.at[0, 0].set(jnp.nan).at[1].set(1e39)
    f = np.asarray(relm_gram.gram_fitness(bad, data, 1e-3, 5))
    assert f[0] == np.inf and not np.isnan(f).any() and np.isfinite(f[2:]).all()


def test_gram_fitness_under_nested_vmap_is_one_batch_equal_to_calls_alone():
    """The runner's vmap over strategies of a vmap over repeats: each member equals its call alone to rounding
    (one batch of products, not one member after another: the float32 pre-activation's sums may run in another
    order), also when the batch is split into groups."""
    X, T, mask, pop, _ = relm_train_data(n=120, seed=4)
    fits = [relm.train_rows(relm.FitData(jnp.asarray(X), jnp.asarray(np.roll(T, k)), jnp.asarray(mask)[None],
                                         jnp.asarray(mask)[None]), int(mask.sum())) for k in range(3)]
    rows = jax.tree_util.tree_map(lambda *a: jnp.stack(a), *fits)                  # 3 repeats
    pops = jnp.stack([jnp.stack([pop * (1 + 0.1 * s + 0.01 * r) for r in range(3)]) for s in range(2)])  # (2, 3, 8, D)
    for block, features, rtol in ((relm_gram.BLOCK_ELEMENTS, "float64", 1e-12), (5 * relm_gram.MIN_BLOCK_ROWS * 5, "float64", 1e-12),
                                  (relm_gram.BLOCK_ELEMENTS, "float32", 1e-6)):
        f = relm_gram.make_gram_fitness(1e-3, 5, True, features, block_elements=block)
        both = jax.jit(jax.vmap(jax.vmap(f)))(pops, jax.tree_util.tree_map(lambda a: jnp.stack([a, a]), rows))
        strategies = jax.jit(jax.vmap(jax.vmap(f, in_axes=(0, 0)), in_axes=(0, None)))(pops, rows)
        for s in range(2):
            for r in range(3):
                alone = np.asarray(f(pops[s, r], jax.tree_util.tree_map(lambda a: a[r], rows)))
                np.testing.assert_allclose(np.asarray(both[s, r]), alone, rtol=rtol)
                np.testing.assert_allclose(np.asarray(strategies[s, r]), alone, rtol=rtol)


# ------------------------------------------------------------------------------ compilation
def _compiles():
    """A counter of XLA compilations (or persistent-cache loads) from now on."""
    count = [0]

    def listen(event, duration, **_):
        if event == "/jax/core/compile/backend_compile_duration":
            count[0] += 1

    jax.monitoring.register_event_duration_secs_listener(listen)
    return count


@pytest.mark.parametrize("kernel", (ex.CPU_KERNEL, ex.ACCELERATOR_KERNEL))
def test_no_recompilation_per_repeat(kernel):
    """The search of other repeats (same shapes) reuses the compiled program, on either kernel."""
    from tests.test_study import sim_frame

    cfg = StudyConfig(split=dict(n_repeats=4, seed=1), model=dict(hidden=6), budget=dict(pop_size=5, iterations=2),
                      optimizer="cgo", strategies=("original", "wavelet"))
    G, B, a = frame_arrays(sim_frame())
    key = jax.random.PRNGKey(0)
    preps = [prepare(None, G, B, a, dataclasses.replace(cfg, repeat_ids=ids), key)[0] for ids in ((0, 1), (2, 3))]
    jax.block_until_ready(search(cfg, preps[0], kernel=kernel))
    count = _compiles()
    out = jax.block_until_ready(search(cfg, preps[1], kernel=kernel))
    assert count[0] == 0 and np.isfinite(np.asarray(out[1])).all()
