"""icgo.studies.icgo_relm.cgo_seeds (how often each CGO seed improves and is selected in the ICGO-RELM search) and its entry
point experiments.fig9_seeds: the counted runs are the runner's (and the study's) own searches, and the counts add
up."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import icgo  # noqa: F401  (float64)
from icgo.optim import get, run_batch
from icgo.optim.cgo import CGOConfig
from icgo.reporting.protocol import parse_protocols
from icgo.studies.icgo_relm import cgo_seeds

D, P, T = 4, 10, 12


def _shifted(pop, aux):
    return jnp.sum((pop - aux) ** 2, axis=1)


@pytest.mark.parametrize("config", [CGOConfig(fourth_seed=False), CGOConfig.matlab()])
def test_counted_runs_are_the_runners_runs_and_the_counts_add_up(config):
    keys = jax.random.split(jax.random.key(5), 3)
    aux = jnp.asarray(np.random.default_rng(0).uniform(-50, 50, (3, D)))
    bounds = (np.full(D, -100.0), np.full(D, 100.0))
    r = cgo_seeds.run_counted(keys, aux, bounds, P, T, config, fitness=_shifted)
    ref = run_batch(get("cgo"), _shifted, bounds, keys, P, T, config=config, aux=aux)
    np.testing.assert_array_equal(r.best_f, np.asarray(ref.best_f))  # the runner's run with the same key
    K = 4 if config.fourth_seed else 3
    assert r.improved.shape == r.chosen.shape == (3, T, K)
    if config.selection == "greedy":
        assert np.all(r.chosen <= r.improved + 1e-12)  # only a seed that beat its parent replaces it
        assert np.all(r.chosen.sum(axis=2) <= 1 + 1e-12)  # a member keeps at most one of its seeds
    else:  # truncation keeps P of the P + KP pool: the seeds kept are at most P per iteration
        assert np.all(r.chosen.sum(axis=2) <= 1 + 1e-12)
    table = cgo_seeds.rates_table({"x": r})
    assert list(table["seed"]) == list(range(1, K + 1))
    assert table.iloc[-1]["improved % (run)"] == pytest.approx(100 * r.improved[:, :, -1].mean())
    assert table.iloc[-1]["chosen % (last 6 iterations)"] == pytest.approx(100 * r.chosen[:, 6:, -1].mean())
    md = cgo_seeds.markdown(table, __import__("icgo.studies.icgo_relm", fromlist=["StudyConfig"]).StudyConfig(),
                            1.0, "python -m experiments.fig9_seeds")
    assert parse_protocols(md) and "Run settings: population 30 x 100 iterations, 10 repeats, search dtype" in md


@pytest.mark.slow
def test_counted_runs_are_the_icgo_relm_studys_searches():
    """On the RELM fitness: the counted run ends at the study's own final training RMSE, bit for bit."""
    from icgo.datasets import casing_stations
    from icgo.studies.icgo_relm import study as icgo_relm
    from icgo.studies.icgo_relm.config import StudyConfig

    ds = casing_stations.lab_casing(0, toolface_step_deg=45.0)
    cfg = StudyConfig(split=dict(n_repeats=2), model=dict(hidden=8), budget=dict(pop_size=6, iterations=4),
                      strategies=("original",))
    runs = cgo_seeds.study(ds.frame, ds.meta, {"default": CGOConfig()}, cfg)
    h = icgo_relm.run_study(ds.frame, cfg, ds.meta).histories
    final = h[h.method == "cgo-original"].sort_values("iteration").groupby("repeat").best_fitness.last().to_numpy()
    np.testing.assert_array_equal(runs["default"].best_f, final)
