"""Benchmark functions vs opfunu's CEC 2017 implementations (same shift/rotation data)."""

import numpy as np
import opfunu.cec_based.cec2017 as opfunu_cec
import pytest
from opfunu.utils import operator

import icgo  # noqa: F401  (float64)
from icgo.optim import benchmarks as bm

# functions with a CEC 2017 class in opfunu: compare with class.evaluate(x) - bias
CLASSES = {"bent_cigar": "F12017", "zakharov": "F22017", "rosenbrock": "F32017", "rastrigin": "F42017",
           "levy": "F82017", "schwefel": "F92017"}
# functions that only appear inside CEC 2017 hybrids: opfunu's operator on the slot's data
OPERATORS = {"sphere": operator.sphere_func, "ellipsoid": operator.elliptic_func,
             "ackley": operator.ackley_func, "griewank": operator.griewank_func}


def _points(b, n=6, seed=0):
    rng = np.random.default_rng(seed)
    x = rng.uniform(-100, 100, (n, len(b.x_opt)))
    near = b.x_opt + rng.normal(0, 0.5, (n, len(b.x_opt)))  # near the optimum, where errors are small
    return np.concatenate([x, near])


@pytest.mark.parametrize("dim", [10, 30])
@pytest.mark.parametrize("name", sorted(CLASSES))
def test_matches_opfunu_class(name, dim):
    b = bm.make(name, dim)
    ref = getattr(opfunu_cec, CLASSES[name])(ndim=dim)
    np.testing.assert_array_equal(ref.f_shift, b.shift)
    np.testing.assert_array_equal(ref.f_matrix, b.rotation)
    x = _points(b)
    want = np.array([ref.evaluate(xi) for xi in x]) - ref.f_bias
    got = np.asarray(b.fn(x))
    np.testing.assert_allclose(got, want, rtol=1e-6, atol=1e-9 * max(1.0, np.abs(want).max()))


@pytest.mark.parametrize("dim", [10, 30])
@pytest.mark.parametrize("name", sorted(OPERATORS))
def test_matches_opfunu_operator(name, dim):
    b = bm.make(name, dim)
    slot = bm.SPECS[name][1]
    ref = getattr(opfunu_cec, f"F{slot}2017")(ndim=dim)  # the slot's shift/rotation, loaded by opfunu
    x = _points(b)
    want = np.array([OPERATORS[name](ref.f_matrix @ (b.scale * (xi - ref.f_shift))) for xi in x])
    np.testing.assert_allclose(np.asarray(b.fn(x)), want, rtol=1e-6)


@pytest.mark.parametrize("name", bm.STUDY)
def test_optimum_is_zero_and_positive_elsewhere(name):
    b = bm.make(name, 10)
    assert abs(float(b.fn(b.x_opt[None])[0])) < 1e-8
    x = _points(b, seed=1)[:6]
    assert np.all(np.asarray(b.fn(x)) > 0)


def test_random_data_is_orthogonal_and_shifted():
    b = bm.make("rastrigin", 7, data="random", seed=3)
    np.testing.assert_allclose(b.rotation @ b.rotation.T, np.eye(7), atol=1e-12)
    assert abs(float(b.fn(b.x_opt[None])[0])) < 1e-9


def test_bad_inputs():
    with pytest.raises(ValueError, match="unknown benchmark"):
        bm.make("nope", 10)
    with pytest.raises(ValueError, match="no rotation data"):
        bm.make("sphere", 7)
    with pytest.raises(ValueError, match="dimension"):
        bm.make("sphere", 1)


def test_suite_fitness_matches_make():
    import jax

    s = bm.suite(bm.STUDY, 10)
    x = np.random.default_rng(5).uniform(-100, 100, (4, 10))
    for i, name in enumerate(bm.STUDY):
        aux = jax.tree_util.tree_map(lambda a: a[i], s)
        np.testing.assert_allclose(np.asarray(bm.suite_fitness(x, aux)), np.asarray(bm.make(name, 10).fn(x)), rtol=1e-12)
