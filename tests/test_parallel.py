"""One sharded program: a study's search over 2 host devices is bitwise the one-device search (CPU kernel),
uneven batches are padded, and the sharded runner equals the batched runner member for member."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest

import icgo  # noqa: F401  (float64)
from icgo.optim import get, run_batch
from icgo.optim.base import stack_configs
from icgo.optim.sharded import balanced_devices, run_members
from icgo.studies.icgo_relm import study
from icgo.studies.icgo_relm.config import StudyConfig
from tests.test_study import sim_frame

TINY = StudyConfig(split=dict(n_repeats=3, seed=2), model=dict(hidden=10), budget=dict(pop_size=6, iterations=3),
                   optimizer="cgo", strategies=("original", "wavelet"))

needs_two = pytest.mark.skipif(len(jax.devices()) < 2, reason="needs 2 devices (tests/conftest.py sets 2 host "
                                                               "devices on a CPU)")


def _same(a, b):
    """Two studies' searches and scores are bitwise equal."""
    for name in ("best_fitness", "evals"):
        np.testing.assert_array_equal(a.curves[name], b.curves[name])
    np.testing.assert_array_equal(a.model.params.theta, b.model.params.theta)
    np.testing.assert_array_equal(a.model.params.beta, b.model.params.beta)
    pd.testing.assert_frame_equal(a.metrics, b.metrics)
    pd.testing.assert_frame_equal(a.predictions, b.predictions)


@needs_two
@pytest.mark.skipif(jax.default_backend() != "cpu", reason="bitwise across devices holds for the CPU kernel (members "
                                                           "one after another); accelerators: within tolerance")
def test_two_host_devices_give_the_one_device_study_bitwise():
    """2 strategies x 3 repeats = 6 members in 2 shards of 3; then 1 x 3 = 3 members padded to 4 (uneven);
    both bitwise the study on one device; the plan and the progress reports say what ran."""
    frame = sim_frame()
    one_t, two_t, ticks = {}, {}, []
    one = study.run_study(frame, dataclasses.replace(TINY, devices=1), timings=one_t)
    two = study.run_study(frame, TINY, timings=two_t, progress=lambda d, t: ticks.append((d, t)))
    _same(one, two)
    assert one_t["execution"]["devices"] == 1 and two_t["execution"]["devices"] == 2
    assert two_t["execution"]["members"] == 6 and "6 member(s) in 2 shard(s) of at most 3" in two_t["execution"]["why"]
    assert ticks[-1] == (TINY.budget.iterations, TINY.budget.iterations) and [d for d, _ in ticks] == sorted(d for d,
                         _ in ticks)
    uneven = dataclasses.replace(TINY, strategies=("wavelet",))
    _same(study.run_study(frame, dataclasses.replace(uneven, devices=1)), study.run_study(frame, uneven))


@needs_two
def test_a_fold_protocol_shards_too():
    """leave_azimuth_out pads every member's training rows to the batch's largest count before sharding, so the
    shapes (and the results) do not depend on the devices."""
    frame = sim_frame()
    cfg = TINY.replace(split={"protocol": "leave_azimuth_out", "n_repeats": 1}, strategies=("original",))
    _same(study.run_study(frame, dataclasses.replace(cfg, devices=1)), study.run_study(frame, cfg))


@pytest.mark.parametrize("members, devices, used", [(50, 16, 13), (50, 2, 2), (3, 2, 2), (1, 16, 1), (10, 16, 10),
                                                    (64, 16, 16), (0, 4, 1)])
def test_balanced_devices_keep_the_largest_shard_smallest(members, devices, used):
    n = balanced_devices(members, devices)
    assert n == used and n <= devices
    assert -(-max(members, 1) // n) == -(-max(members, 1) // devices)      # the largest shard as with every device


@pytest.mark.parametrize("n_devices", [1, 2])
@pytest.mark.parametrize("progress", [False, True])
def test_the_sharded_runner_equals_the_batched_runner(n_devices, progress):
    """run_members over (strategy, repeat) members == run_batch over strategies x repeats, bitwise, on 1 or 2
    devices, in one program or in chunks of iterations with progress reports."""
    if len(jax.devices()) < n_devices:
        pytest.skip("needs 2 devices")
    alg = get("cgo")
    D, R = 5, 3
    bounds = (np.full(D, -1.0), np.full(D, 1.0))
    keys = jax.random.split(jax.random.PRNGKey(0), R)
    aux = jnp.linspace(-0.5, 0.5, R)[:, None] * jnp.ones((R, D))

    def f(pop, a):
        return jnp.sum((pop - a) ** 2, axis=-1)

    configs = alg.axis_configs(None, ("original", "wavelet"))
    ref = run_batch(alg, f, bounds, keys, 8, 5, configs=configs, aux=aux)
    s_idx, r_idx = np.repeat(np.arange(2), R), np.tile(np.arange(R), 2)
    per_member = jax.tree_util.tree_map(lambda x: np.asarray(x)[s_idx], stack_configs(alg, configs))
    ticks = []
    out = run_members(alg, f, bounds, np.asarray(keys)[r_idx], 8, 5, configs=per_member, aux=np.asarray(aux)[r_idx],
                      devices=jax.devices()[:n_devices], progress=(lambda d, t: ticks.append(d)) if progress else None)
    for got, want in zip(out, ref):
        np.testing.assert_array_equal(got.reshape(np.shape(want)), np.asarray(want))
    assert ticks == ([1, 2, 3, 4, 5] if progress else [])


def test_the_sharded_runner_refuses_misshapen_members():
    alg = get("pso")
    keys = np.asarray(jax.random.split(jax.random.PRNGKey(0), 3))
    with pytest.raises(ValueError, match="leading axis 3"):
        run_members(alg, lambda p, a: jnp.sum(p ** 2, -1), (np.zeros(2), np.ones(2)), keys, 4, 2, aux=np.zeros((2, 2)))
