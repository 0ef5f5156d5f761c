"""Tests for icgo.optim.misma: interface, determinism, batching, bounds, and a small calibration."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import icgo  # noqa: F401
from icgo.models import calibration as cal
from icgo.models.misma_objective import MismaObjective
from icgo.optim import base, misma
from icgo.optim.registry import get
from icgo.physics.frames import sensors_from_attitude


def _problem(n=40, seed=0):
    rng = np.random.default_rng(seed)
    A, I, T = rng.uniform(0, 360, n), rng.uniform(10, 170, n), rng.uniform(0, 360, n)
    s = sensors_from_attitude(A, I, T, 50_000.0, 60.0)
    R = np.array([[1.04, 0.02, -0.01], [-0.02, 0.97, 0.03], [0.01, -0.02, 1.02]])
    b = np.array([1500.0, -900.0, 600.0])
    G, B = np.asarray(s.G), np.asarray(cal.distort(R, b, s.B))
    obj = MismaObjective(cal.make_caldata(G, B, 50_000.0))
    return obj, np.asarray(cal.params_from_error_model(R, b)), G, B


OBJ, X_TRUE, G, B = _problem()
U = cal.modulus_fit(B, 50_000.0)
BOUNDS = misma.misma_bounds(U, 50_000.0)


def test_registered_with_the_common_interface():
    alg = get("misma")
    assert alg.config_cls is misma.MISMAConfig
    st = alg.init(jax.random.PRNGKey(0), OBJ, BOUNDS, 8)
    assert st.pop.shape == (8, 12) and st.fit.shape == (8,) and int(st.n_evals) == 8
    st2 = alg.step(st, jax.random.PRNGKey(1), 0, 5, OBJ)
    assert int(st2.n_evals) == 16 and float(st2.best_f) <= float(st.best_f)
    lb, ub = BOUNDS
    assert np.all(np.asarray(st2.pop) >= lb - 1e-9) and np.all(np.asarray(st2.pop) <= ub + 1e-9)


def test_deterministic_and_batch_equals_single():
    keys = jax.random.split(jax.random.PRNGKey(3), 3)
    rb = base.run_batch(get("misma"), OBJ, BOUNDS, keys, 8, 15)
    r1 = base.run(get("misma"), OBJ, BOUNDS, keys[1], 8, 15)
    r1b = base.run(get("misma"), OBJ, BOUNDS, keys[1], 8, 15)
    np.testing.assert_array_equal(np.asarray(r1.best_x), np.asarray(r1b.best_x))
    np.testing.assert_allclose(np.asarray(rb.best_x[1]), np.asarray(r1.best_x), rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(np.asarray(rb.curve[1]), np.asarray(r1.curve), rtol=1e-10)
    assert np.all(np.diff(np.asarray(rb.curve), axis=1) <= 0)  # best-so-far never rises


@pytest.mark.slow
def test_plain_fitness_fallback_runs_and_improves():
    shift = jnp.linspace(-1.0, 1.0, 5)
    sphere = lambda p: jnp.sum((p - shift) ** 2, axis=1)  # noqa: E731
    r = base.run(get("misma"), sphere, (-5 * np.ones(5), 5 * np.ones(5)), jax.random.PRNGKey(0), 12, 150)
    assert float(r.best_f) < 1e-3 < float(r.curve[0])


@pytest.mark.slow
def test_misma_calibrates_better_than_its_starting_box():
    keys = jax.random.split(jax.random.PRNGKey(0), 2)
    r = base.run_batch(get("misma"), OBJ, BOUNDS, keys, 30, 200)
    f_u = float(OBJ(jnp.asarray(U)[None])[0])
    assert np.all(np.asarray(r.best_f) < f_u)
    err = np.abs(np.asarray(r.best_x) - X_TRUE)
    assert err[:, :9].max() < 0.02 and err[:, 9:].max() < 300.0


def test_bad_config_and_bounds():
    with pytest.raises(ValueError, match="p_mode"):
        misma.MISMAConfig(p_mode="greedy")
    with pytest.raises(ValueError, match="d must be in"):
        misma.MISMAConfig(d=1.5)
    with pytest.raises(ValueError, match="U must be a finite"):
        misma.misma_bounds(np.zeros(11), 1.0)
    lb, ub = misma.misma_bounds(U, 50_000.0, 0.05, 0.02)
    np.testing.assert_allclose(0.5 * (lb + ub), U)
    np.testing.assert_allclose((ub - lb)[9:], 2 * 0.02 * 50_000.0)
