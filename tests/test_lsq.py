"""icgo.maths.lsq.least_squares and least_squares_fixed against closed-form references (numpy lstsq,
Rosenbrock's optimum, a numpy transcription of the documented damping rule)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import icgo  # noqa: F401  (float64)
from icgo.maths.lsq import LSQResult, least_squares, least_squares_fixed


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


# ------------------------------------------------------------ least_squares_fixed (fixed-step Marquardt LM)
def _linear_problem(seed=0, m=40, p=4):
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((m, p)) * np.array([1.0, 100.0, 0.01, 3.0])[:p]  # badly scaled columns
    b = A @ rng.standard_normal(p) + 0.1 * rng.standard_normal(m)
    return A, b


def test_fixed_linear_matches_numpy_lstsq():
    A, b = _linear_problem()
    ref, res, *_ = np.linalg.lstsq(A, b, rcond=None)
    r = jax.jit(lambda x0: least_squares_fixed(_linear, x0, (jnp.asarray(A), jnp.asarray(b)), n_steps=10))(jnp.zeros(4))
    assert isinstance(r, LSQResult) and r.x.dtype == jnp.float64
    assert bool(r.ok) and int(r.n_steps) == 10
    np.testing.assert_allclose(np.asarray(r.x), ref, rtol=1e-10, atol=1e-10)
    assert float(r.cost) == pytest.approx(float(res[0]), rel=1e-10)
    # lam0 = 0: Gauss-Newton steps; on well-scaled columns the first one is the lstsq solution (the
    # 1e-10 ridge biases column j by ~1e-10 / H_jj relative: 3e-8 on the 0.01-scaled column above)
    A1 = A / np.array([1.0, 100.0, 0.01, 3.0])
    ref1, *_ = np.linalg.lstsq(A1, b, rcond=None)
    r1 = least_squares_fixed(_linear, jnp.zeros(4), (jnp.asarray(A1), jnp.asarray(b)), n_steps=1, lam0=0.0)
    np.testing.assert_allclose(np.asarray(r1.x), ref1, rtol=1e-10, atol=1e-10)


def _numpy_marquardt(fun, jac, x0, n_steps, lam0=1e-3):
    """The damping rule of least_squares_fixed's docstring, transcribed in numpy (all parameters free)."""
    x, lam = np.array(x0, float), lam0
    c = np.sum(fun(x) ** 2)
    for _ in range(n_steps):
        J, r = jac(x), fun(x)
        H = J.T @ J
        Hd = H + lam * np.diag(np.diag(H) + 1e-9) + 1e-10 * np.eye(len(x))
        xn = x - np.linalg.solve(Hd, J.T @ r)
        cn = np.sum(fun(xn) ** 2)
        if np.isfinite(cn) and cn < c:
            x, lam, c = xn, lam * 0.3, cn
        else:
            lam *= 10.0
    return x, c


def test_fixed_follows_the_documented_damping_rule():
    # Rosenbrock from (-1.2, 1): the first steps include rejected ones (lam x10) and accepted ones (x0.3)
    fun = lambda x: np.array([10.0 * (x[1] - x[0] ** 2), 1.0 - x[0]])  # noqa: E731
    jac = lambda x: np.array([[-20.0 * x[0], 10.0], [-1.0, 0.0]])  # noqa: E731
    for n in (1, 2, 3, 5, 8):
        ref, cref = _numpy_marquardt(fun, jac, [-1.2, 1.0], n)
        r = least_squares_fixed(_rosenbrock, jnp.array([-1.2, 1.0]), n_steps=n)
        np.testing.assert_allclose(np.asarray(r.x), ref, rtol=1e-12, atol=1e-14)
        assert float(r.cost) == pytest.approx(cref, rel=1e-12)


def test_fixed_rosenbrock_reaches_optimum_with_enough_steps():
    run = jax.jit(lambda x0: least_squares_fixed(_rosenbrock, x0, n_steps=40))
    r = run(jnp.array([-1.2, 1.0]))
    assert bool(r.ok)
    np.testing.assert_allclose(np.asarray(r.x), [1.0, 1.0], rtol=0, atol=1e-10)
    assert float(r.cost) < 1e-20
    # too few steps: still on the way (the budget is exactly n_steps, no early stop)
    r5 = least_squares_fixed(_rosenbrock, jnp.array([-1.2, 1.0]), n_steps=5)
    assert int(r5.n_steps) == 5 and float(r5.cost) > 1e-3


def test_fixed_free_mask_keeps_fixed_parameters_exactly():
    A, b = _linear_problem(seed=3)
    x0 = jnp.array([0.3, -1.7, 2.5, 0.1])
    free = jnp.array([True, False, True, False])
    r = least_squares_fixed(_linear, x0, (jnp.asarray(A), jnp.asarray(b)), n_steps=15, free=free)
    xr = np.asarray(r.x)
    assert xr[1] == float(x0[1]) and xr[3] == float(x0[3])  # bitwise: fixed parameters never move
    # the free ones solve the reduced problem b - A_fixed x_fixed = A_free x_free
    fi, fx = [0, 2], [1, 3]
    ref, *_ = np.linalg.lstsq(A[:, fi], b - A[:, fx] @ np.asarray(x0)[fx], rcond=None)
    np.testing.assert_allclose(xr[fi], ref, rtol=1e-10, atol=1e-10)
    # 0/1 float masks (as lm_fit passes them) mean the same
    rf = least_squares_fixed(_linear, x0, (jnp.asarray(A), jnp.asarray(b)), n_steps=15, free=free.astype(float))
    assert np.asarray(rf.x).tobytes() == xr.tobytes()
    # nothing free: x0 back, bitwise
    r0 = least_squares_fixed(_linear, x0, (jnp.asarray(A), jnp.asarray(b)), n_steps=5, free=jnp.zeros(4, bool))
    assert np.asarray(r0.x).tobytes() == np.asarray(x0).tobytes()


def test_fixed_vmapped_batch_equals_one_by_one_bitwise():
    t = jnp.linspace(0.0, 3.0, 25)
    truths = np.array([[2.0, 0.7], [1.0, 1.5], [3.0, 0.2], [0.5, 2.5]])
    rng = np.random.default_rng(1)
    ys = jnp.asarray(truths[:, :1] * np.exp(-truths[:, 1:] * np.asarray(t)) + 0.01 * rng.standard_normal((4, 25)))
    masks = jnp.array([[True, True], [True, True], [False, True], [True, True]])
    one_fit = jax.jit(lambda y, m: least_squares_fixed(_exp_decay, jnp.array([1.0, 1.0]), (t, y), n_steps=30, free=m))
    batched = jax.jit(jax.vmap(one_fit))(ys, masks)
    for k in range(4):
        one = one_fit(ys[k], masks[k])
        assert np.asarray(batched.x[k]).tobytes() == np.asarray(one.x).tobytes(), (batched.x[k], one.x)
        assert np.asarray(batched.cost[k]).tobytes() == np.asarray(one.cost).tobytes()
        assert bool(one.ok) and bool(batched.ok[k])
    # the fully free fits reach the minimum that the converging LM finds
    for k in (0, 1, 3):
        ref = least_squares(_exp_decay, jnp.array([1.0, 1.0]), (t, ys[k]))
        assert bool(ref.ok)
        np.testing.assert_allclose(np.asarray(batched.x[k]), np.asarray(ref.x), rtol=1e-8)
    assert float(batched.x[2, 0]) == 1.0


def test_fixed_nan_residual_is_not_ok_and_nan_trial_points_are_rejected():
    nan_fn = lambda x, _: jnp.array([x[0] - 1.0, jnp.nan * x[1]])  # noqa: E731
    r = least_squares_fixed(nan_fn, jnp.array([0.0, 0.0]), n_steps=5)
    assert not bool(r.ok)
    assert np.asarray(r.x).tolist() == [0.0, 0.0]  # nothing is accepted from a non-finite start
    # in a vmapped batch only the problem with NaN data is flagged
    A = jnp.asarray(np.random.default_rng(2).standard_normal((6, 2)))
    bs = jnp.stack([jnp.ones(6), jnp.ones(6).at[3].set(jnp.nan)])
    rb = jax.vmap(lambda b: least_squares_fixed(_linear, jnp.zeros(2), (A, b), n_steps=5))(bs)
    assert np.asarray(rb.ok).tolist() == [True, False]
    # log(x) = log(0.1) from x = 1: the first steps land at x < 0 (NaN residual) and are rejected;
    # the raised damping then reaches the solution
    log_fn = lambda x, _: jnp.log(x) - jnp.log(0.1)  # noqa: E731
    rl = least_squares_fixed(log_fn, jnp.array([1.0]), n_steps=30)
    assert bool(rl.ok)
    np.testing.assert_allclose(np.asarray(rl.x), [0.1], rtol=1e-10)
    # with lam0 = 0 the damping stays 0 (0 x 10), so the rejected Gauss-Newton step repeats: x stays at x0
    r0 = least_squares_fixed(log_fn, jnp.array([1.0]), n_steps=30, lam0=0.0)
    assert bool(r0.ok) and float(r0.x[0]) == 1.0


@pytest.mark.parametrize("fn, x0", [("linear", np.zeros(4)), ("exp_decay", np.array([1.0, 1.0]))])
def test_fixed_lm_over_row_blocks_equals_unblocked(fn, x0):
    """blocks=: the same steps with JᵀJ, Jᵀr and the cost summed over row blocks (rounding only)."""
    rng = np.random.default_rng(3)
    n, nb = 48, 4
    if fn == "linear":
        A = rng.standard_normal((n, 4))
        data = (A, A @ np.array([1.0, -2.0, 0.5, 3.0]) + 0.1 * rng.standard_normal(n))
        res = _linear
    else:
        t = np.linspace(0.0, 3.0, n)
        data = (t, 2.0 * np.exp(-0.7 * t) + 0.01 * rng.standard_normal(n))
        res = _exp_decay
    data = tuple(jnp.asarray(d) for d in data)
    free = jnp.array([1.0, 0.0, 1.0, 1.0]) if fn == "linear" else None
    one = least_squares_fixed(res, x0, data, n_steps=8, free=free)
    blocks = tuple(d.reshape((nb, n // nb) + d.shape[1:]) for d in data)
    blocked = least_squares_fixed(lambda x, a: res(x, a[1]), x0, None, n_steps=8, free=free, blocks=blocks)
    np.testing.assert_allclose(np.asarray(blocked.x), np.asarray(one.x), rtol=1e-12, atol=1e-12)
    assert float(blocked.cost) == pytest.approx(float(one.cost), rel=1e-12)
    if free is not None:
        assert float(blocked.x[1]) == 0.0


def test_stops_after_the_steps_the_problem_needs_whatever_the_last_bits_of_the_cost():
    """A large-residual linear problem (cost ~4e9) whose residuals carry ~100 ulps of x-dependent rounding, as
    another summation order would: near the minimum every cost comparison is then decided by that rounding.
    The stopping rule reads the Gauss-Newton step from J and r instead, so each of 50 such problems stops within
    a few steps at the lstsq solution. (optimistix's LM, used before, left 1 of 50 running to 1000 steps at
    10,000 ulps, docs/relm_study.md.)"""
    rng = np.random.default_rng(0)
    A = jnp.asarray(rng.standard_normal((400, 3)) * 5e4)
    b = jnp.asarray(np.asarray(A) @ np.array([0.02, -0.01, 0.03]) + 300.0 * rng.standard_normal(400) + 4e4)

    def wobbly(x, args):
        A, b, k = args
        r = A @ x - b
        last_bits = jax.lax.stop_gradient(jnp.sin(1e13 * jnp.sum(x) + k * jnp.arange(r.shape[0])))
        return r + 100 * jnp.finfo(r.dtype).eps * jnp.abs(b) * last_bits

    ref = np.linalg.lstsq(np.asarray(A), np.asarray(b), rcond=None)[0]
    res = jax.jit(jax.vmap(lambda k: least_squares(wobbly, jnp.zeros(3), (A, b, k), max_steps=1000)))(jnp.arange(50.0))
    assert np.asarray(res.ok).all()
    assert int(np.max(res.n_steps)) <= 4
    np.testing.assert_allclose(np.asarray(res.x), np.broadcast_to(ref, (50, 3)), rtol=1e-9)


def test_gauss_newton_gap_quadratic_equals_the_projection_onto_the_jacobian():
    """gᵀ(JᵀJ)⁺g (icgo.maths.lsq._pinv_quadratic, no LAPACK) against numpy's float64 least squares: the part of
    |r|² in J's column space, for scaled, rank-deficient and fixed-column Jacobians."""
    from icgo.maths.lsq import _pinv_quadratic, gauss_newton_gap

    rng = np.random.default_rng(0)
    pinv_quadratic = jax.jit(_pinv_quadratic)  # as the solver calls it: inside a compiled program
    sizes = (2, 5, 13, 29)  # a few Jacobian widths, each compiled once (a new width is a new program)
    for t in range(60):
        P = sizes[t % 4]
        M = int(rng.integers(P, 3 * P))
        J = rng.normal(size=(M, P)) * 10.0 ** rng.uniform(-4, 4, size=P)
        if t % 3 == 0:
            J[:, rng.integers(P)] = 0.0
        if t % 3 == 1:
            J[:, -1] = 2.0 * J[:, 0]
        r = rng.normal(size=M)
        ref = np.linalg.norm(J @ np.linalg.lstsq(J, r, rcond=1e-12)[0]) ** 2
        got = float(pinv_quadratic(jnp.asarray(J.T @ J), jnp.asarray(J.T @ r)))
        assert abs(got - ref) <= 1e-6 * (r @ r)
    # a linear problem: the gap is the fitted share of |r|² at 0 and vanishes at the least-squares solution
    A = rng.normal(size=(20, 4))
    b = rng.normal(size=20)
    res = lambda x, _: A @ x - b
    x_ls = np.linalg.lstsq(A, b, rcond=None)[0]
    share = np.linalg.norm(A @ x_ls) ** 2 / (b @ b)
    assert abs(float(gauss_newton_gap(res, jnp.zeros(4))) - share) < 1e-9
    assert float(gauss_newton_gap(res, jnp.asarray(x_ls))) < 1e-12
