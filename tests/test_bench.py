"""Building blocks of experiments/bench.py at tiny sizes (no timing is tested)."""

import numpy as np

from conftest import relm_train_data as _data
from experiments import bench
from icgo import relm


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
