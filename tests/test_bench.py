"""Building blocks of experiments/bench.py at tiny sizes (no timing is tested)."""

import numpy as np
from conftest import relm_train_data as _data

from experiments import bench, bench_user
from icgo.methods import relm
from icgo.optim.registry import get


def test_flop_count_matches_hand_count():
    # n=10, L=2, d=6: 2ndL 240 + nL 20 + sigmoid 3nL 60 + Gram 2nL^2 80 + H^T T 40
    # + Cholesky L^3/3 -> 2 + solves 2L^2 8 + H beta 40 + residual 3n 30 + ridge L 2
    assert bench.flops_per_eval(10, hidden=2, d=6) == 522
    # the Gram term dominates at the paper's scale
    assert 2 * 407 * 30**2 / bench.flops_per_eval(407) > 0.7


def test_numpy_fitness_equals_jax_fitness():
    X, T, mask, pop, fit = _data()
    ref = np.asarray(relm.fitness(pop, fit, 1e-3, 5))
    idx = mask > 0
    got = np.array([bench.numpy_fitness(np.asarray(th), X[idx], T[idx], 1e-3, 5) for th in pop])
    np.testing.assert_allclose(got, ref, rtol=1e-10, atol=0)


def test_large_recording_and_measure(tmp_path):
    """--rows building blocks: a tiled contract CSV that reads back, and a child's time and peak memory."""
    import sys

    from icgo.io import recording as io

    rec = bench.write_large_recording(tmp_path / "big.csv", 1500)
    back = io.read_recording(tmp_path / "big.csv")
    assert len(back.frame) == 1500 and back.frame["station"].is_unique and back.field is not None
    np.testing.assert_array_equal(back.frame["azimuth_deg"], rec.frame["azimuth_deg"])
    m = bench_user.measure([sys.executable, "-c", "print('ok')"])
    assert m["rc"] == 0 and "ok" in m["tail"] and 0 < m["peak_rss_gb"] < 1 and m["wall_s"] > 0


def test_evosax_peers_spend_the_same_evaluations_and_icgo_pso_is_run_batch():
    """bench_user.peer_comparison at tiny sizes: equal budgets, finite results, icgo's row equals run_batch."""
    import jax
    import jax.numpy as jnp

    from experiments.bench_user import peer_comparison
    from icgo.optim import run_batch

    sd = bench.study_data(2)
    res = peer_comparison(sd.compact, bench.LAM, bench.HIDDEN, pop_size=8, iterations=3, reps=1)
    assert [r["name"] for r in res] == ["icgo PSO", "evosax PSO", "evosax DE"]
    assert all(r["evals"] == 8 * 4 and np.isfinite(r["best_f_mean"]) and r["best_f_mean"] > 0 for r in res)
    D = relm.n_params(bench.HIDDEN)
    ref = run_batch(get("pso"), relm.make_train_fitness(bench.LAM, bench.HIDDEN), (-jnp.ones(D), jnp.ones(D)),
                    jax.random.split(jax.random.PRNGKey(0), 2), 8, 3, aux=sd.compact).best_f
    assert res[0]["best_f_mean"] == float(np.mean(np.asarray(ref)))


def test_mealpy_in_its_parallel_mode_runs_the_same_search():
    sd = bench.study_data(1)
    single = bench.run_mealpy(sd, 1, pop_size=8, iterations=2)
    parallel = bench.run_mealpy(sd, 1, pop_size=8, iterations=2, mode="process", n_workers=2)
    assert single["evals_per_run"] == parallel["evals_per_run"] > 8
    assert np.isfinite(parallel["best_f"]).all()
