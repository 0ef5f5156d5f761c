"""icgo.lsq.least_squares against closed-form references (numpy lstsq, Rosenbrock's optimum)."""

import numpy as np
import jax
import jax.numpy as jnp
import pytest

import icgo  # noqa: F401  (float64)
from icgo.lsq import LSQResult, least_squares


def _linear(x, args):
    A, b = args
    return A @ x - b


def _rosenbrock(x, args):
    return jnp.array([10.0 * (x[1] - x[0] ** 2), 1.0 - x[0]])


def _exp_decay(x, t_y):
    t, y = t_y
    return x[0] * jnp.exp(-x[1] * t) - y


def test_linear_least_squares_matches_numpy_lstsq():
    rng = np.random.default_rng(0)
    A = rng.standard_normal((40, 4))
    b = A @ np.array([1.0, -2.0, 0.5, 3.0]) + 0.1 * rng.standard_normal(40)
    ref, res, *_ = np.linalg.lstsq(A, b, rcond=None)
    r = least_squares(_linear, np.zeros(4), (jnp.asarray(A), jnp.asarray(b)))
    assert isinstance(r, LSQResult)
    assert r.x.dtype == jnp.float64
    assert bool(r.ok)
    np.testing.assert_allclose(np.asarray(r.x), ref, rtol=0, atol=1e-10)
    assert float(r.cost) == pytest.approx(float(res[0]), rel=1e-10)
    assert 1 <= int(r.n_steps) < 100


def test_rosenbrock_reaches_its_optimum_under_jit():
    r = jax.jit(lambda x0: least_squares(_rosenbrock, x0))(jnp.array([-1.2, 1.0]))
    assert bool(r.ok)
    np.testing.assert_allclose(np.asarray(r.x), [1.0, 1.0], rtol=0, atol=1e-10)
    assert float(r.cost) < 1e-20


def test_vmapped_batch_equals_one_by_one():
    t = jnp.linspace(0.0, 3.0, 25)
    truths = np.array([[2.0, 0.7], [1.0, 1.5], [3.0, 0.2]])
    rng = np.random.default_rng(1)
    ys = jnp.asarray(truths[:, :1] * np.exp(-truths[:, 1:] * np.asarray(t)) + 0.01 * rng.standard_normal((3, 25)))
    x0 = jnp.array([1.0, 1.0])
    batched = jax.vmap(lambda y: least_squares(_exp_decay, x0, (t, y)))(ys)
    for k in range(3):
        one = least_squares(_exp_decay, x0, (t, ys[k]))
        assert bool(one.ok) and bool(batched.ok[k])
        np.testing.assert_allclose(np.asarray(batched.x[k]), np.asarray(one.x), rtol=1e-12, atol=1e-12)
        assert float(batched.cost[k]) == pytest.approx(float(one.cost), rel=1e-12)
        # and both are near the generating parameters (noise 0.01)
        np.testing.assert_allclose(np.asarray(one.x), truths[k], atol=0.05)


def test_nan_residual_is_not_reported_as_converged():
    nan_fn = lambda x, _: jnp.array([x[0] - 1.0, jnp.nan * x[1]])  # noqa: E731
    r = least_squares(nan_fn, jnp.array([0.0, 0.0]))
    assert not bool(r.ok)
    assert not np.isfinite(float(r.cost))
    # in a vmapped batch only the problem with NaN data is flagged
    A = jnp.asarray(np.random.default_rng(2).standard_normal((6, 2)))
    bs = jnp.stack([jnp.ones(6), jnp.ones(6).at[3].set(jnp.nan)])
    rb = jax.vmap(lambda b: least_squares(_linear, jnp.zeros(2), (A, b)))(bs)
    assert np.asarray(rb.ok).tolist() == [True, False]


def test_step_budget_exhausted_is_not_ok():
    r = least_squares(_rosenbrock, jnp.array([-1.2, 1.0]), max_steps=2)
    assert not bool(r.ok)
    assert int(r.n_steps) == 2
