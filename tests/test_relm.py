"""RELM: ridge solve against lstsq / scikit-learn, fitness against numpy, folds, float32 path, errors."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import icgo  # noqa: F401  (float64)
from icgo.models import compensation, relm, relm_fit
from icgo.physics import effects, frames

L = 12


def sensor_data(n_rows=160, seed=0):
    rng = np.random.default_rng(seed)
    A = rng.choice([30.0, 120.0, 210.0, 300.0], n_rows)
    T = rng.uniform(0, 360, n_rows)
    I = np.full(n_rows, 90.0)
    s = frames.sensors_from_attitude(A, I, T, 50_000.0, 60.0)
    G, B = effects.apply_effects({"hard_iron": np.array([300.0, -200.0, 500.0]),
                                  "mag_cross_coupling": np.array([0.01, -0.006, 0.004])},
                                 s.G, s.B, frames.tool_to_earth(A, I, T))
    X = np.column_stack([G, B]) + rng.normal(0, [3e-4] * 3 + [15.0] * 3, (n_rows, 6))
    err = np.asarray(frames.angle_diff(frames.azimuth_from_gv(X[:, :3], X[:, 3:]), A))
    return X, err


def test_ridge_matches_lstsq_on_augmented_system_and_sklearn():
    rng = np.random.default_rng(0)
    H = rng.normal(size=(200, 20))
    T = rng.normal(size=200)
    lam = 0.7
    beta = np.asarray(relm.ridge_solve(jnp.asarray(H), jnp.asarray(T), lam))
    aug = np.vstack([H, np.sqrt(lam) * np.eye(20)])
    ref = np.linalg.lstsq(aug, np.concatenate([T, np.zeros(20)]), rcond=None)[0]
    np.testing.assert_allclose(beta, ref, atol=1e-8, rtol=0)
    from sklearn.linear_model import Ridge

    sk = Ridge(alpha=lam, fit_intercept=False).fit(H, T).coef_
    np.testing.assert_allclose(beta, sk, atol=1e-8, rtol=0)
    # Sigmoid features of real sensor data too.
    X, err = sensor_data()
    mean, std = relm.standardize_stats(X)
    theta = relm.random_theta(jax.random.PRNGKey(0), L)
    Hs = np.asarray(relm.hidden_layer(theta, relm.standardize(jnp.asarray(X), mean, std), L))
    b2 = np.asarray(relm.ridge_solve(jnp.asarray(Hs), jnp.asarray(err), 1e-3))
    sk2 = Ridge(alpha=1e-3, fit_intercept=False, solver="svd").fit(Hs, err).coef_
    np.testing.assert_allclose(b2, sk2, atol=1e-8 * max(1.0, np.abs(sk2).max()), rtol=0)


def test_weighted_ridge_equals_row_subset():
    rng = np.random.default_rng(1)
    H = rng.normal(size=(100, 8))
    T = rng.normal(size=100)
    w = (rng.random(100) < 0.6).astype(float)
    a = relm.ridge_solve(jnp.asarray(H), jnp.asarray(T), 0.1, jnp.asarray(w))
    b = relm.ridge_solve(jnp.asarray(H[w > 0]), jnp.asarray(T[w > 0]), 0.1)
    np.testing.assert_allclose(a, b, atol=1e-12)


def numpy_fitness(theta, X, T, fit_w, score_w, lam):
    W, b = theta[: 6 * L].reshape(6, L), theta[6 * L:]
    H = 1.0 / (1.0 + np.exp(-(X @ W + b)))  # eq. (8)
    out = []
    for fw, sw in zip(fit_w, score_w):
        beta = np.linalg.solve(H.T @ (fw[:, None] * H) + lam * np.eye(L), H.T @ (fw * T))
        out.append(np.sqrt(np.sum(sw * (H @ beta - T) ** 2) / sw.sum()))
    return np.mean(out)


@pytest.mark.parametrize("mode", relm.FITNESS_MODES)
def test_fitness_matches_numpy_and_never_uses_test_rows(mode):
    X, err = sensor_data()
    train = (np.random.default_rng(2).random(len(err)) < 0.7).astype(float)
    mean, std = relm.standardize_stats(jnp.asarray(X), jnp.asarray(train))
    Xs = np.asarray(relm.standardize(jnp.asarray(X), mean, std))
    fw, sw = relm.fold_weights(jax.random.PRNGKey(3), jnp.asarray(train), mode, 0.3, 4)
    fw, sw = np.asarray(fw), np.asarray(sw)
    assert np.all(fw[:, train == 0] == 0) and np.all(sw[:, train == 0] == 0)
    if mode == "kfold":
        np.testing.assert_array_equal(sw.sum(0), train)  # each training row scored exactly once
        assert np.all(fw + sw == train)
    if mode == "validation":
        assert sw.sum() == round(0.3 * train.sum()) and np.all(fw + sw == train)
    pop = np.asarray(relm.random_theta(jax.random.PRNGKey(4), L, (5,)))
    data = relm.FitData(jnp.asarray(Xs), jnp.asarray(err), jnp.asarray(fw), jnp.asarray(sw))
    f = np.asarray(relm.fitness(jnp.asarray(pop), data, 1e-3, L))
    ref = [numpy_fitness(p, Xs, err, fw, sw, 1e-3) for p in pop]
    np.testing.assert_allclose(f, ref, rtol=1e-9)
    # Changing test-row targets changes nothing.
    err2 = np.where(train > 0, err, err + 100.0)
    f2 = relm.fitness(jnp.asarray(pop), data._replace(T=jnp.asarray(err2)), 1e-3, L)
    np.testing.assert_array_equal(f, f2)


def test_fitness_nonfinite_is_inf_and_float32_path_agrees():
    X, err = sensor_data()
    mean, std = relm.standardize_stats(jnp.asarray(X))
    ones = jnp.ones((1, len(err)))
    data = relm.FitData(relm.standardize(jnp.asarray(X), mean, std), jnp.asarray(err), ones, ones)
    pop = relm.random_theta(jax.random.PRNGKey(5), L, (8,))
    pop = pop.at[0, 3].set(jnp.nan)
    f64 = np.asarray(relm.fitness(pop, data, 1e-3, L))
    assert np.isinf(f64[0]) and np.all(np.isfinite(f64[1:]))
    f32 = np.asarray(relm.fitness(pop, data, 1e-3, L, dtype="float32"))
    assert f32.dtype == np.float32 and np.isinf(f32[0])
    # Stated tolerance for the float32 path at lambda = 1e-3 (docs/relm_study.md): 1e-3 relative.
    np.testing.assert_allclose(f32[1:], f64[1:], rtol=1e-3)


def test_fit_predict_and_bad_inputs():
    """compensation.fit of a RELM on the sensor values (no MSA) and its predict against a float64 numpy forward
    pass; bad inputs refused one line each."""
    X, err = sensor_data()
    theta = relm.random_theta(jax.random.PRNGKey(6), L)
    model = compensation.fit(theta, X, err, 1e-3, L)
    out = compensation.predict(jax.tree.map(lambda a: a[None], model), jnp.asarray(X))
    pred = np.asarray(out.error[0])
    assert np.sqrt(np.mean((pred - err) ** 2)) < np.std(err)
    W, b = np.asarray(theta[:6 * L]).reshape(6, L), np.asarray(theta[6 * L:])
    Xs = (X - X.mean(0)) / X.std(0)
    H = 1.0 / (1.0 + np.exp(-(Xs @ W + b)))                                           # eq. (8)
    beta = np.linalg.solve(H.T @ H + 1e-3 * np.eye(L), H.T @ err)                     # eq. (9)
    np.testing.assert_allclose(np.asarray(model.beta), beta, rtol=1e-7)
    np.testing.assert_allclose(pred, H @ beta, rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.asarray(out.a_msa[0]), frames.azimuth_from_gv(X[:, :3], X[:, 3:]), atol=1e-9)
    with pytest.raises(ValueError, match="lambda"):
        compensation.fit(theta, X, err, 0.0, L)
    with pytest.raises(ValueError, match="hidden units"):
        compensation.fit(theta, X[:10], err[:10], 1e-3, L)
    Xn = X.copy()
    Xn[7, 4] = np.nan
    with pytest.raises(ValueError, match="row 7, column 4"):
        compensation.fit(theta, Xn, err, 1e-3, L)
    with pytest.raises(ValueError, match="targets"):
        compensation.fit(theta, X, err[:-1], 1e-3, L)
    with pytest.raises(ValueError, match="features"):
        compensation.fit(theta, X[:, :5], err, 1e-3, L)
    with pytest.raises(ValueError, match="theta"):
        compensation.fit(theta[:-1], X, err, 1e-3, L)
    with pytest.raises(ValueError, match="fitness mode"):
        relm.fold_weights(jax.random.PRNGKey(0), jnp.ones(5), "loo")


# ------------------------------------------------------- fast train-mode fitness
from conftest import relm_train_data  # noqa: E402


def test_train_rows_keeps_exactly_the_training_rows():
    X, T, mask, _, fit = relm_train_data()
    rows = relm.train_rows(fit, int(mask.sum()))
    np.testing.assert_array_equal(np.asarray(rows.Xa[:, :6]), X[mask > 0])
    np.testing.assert_array_equal(np.asarray(rows.Xa[:, 6]), 1.0)
    np.testing.assert_array_equal(np.asarray(rows.T), T[mask > 0])


@pytest.mark.parametrize("scale", [1.0, 0.05])  # 0.05: near-linear sigmoids, ill-conditioned Gram
def test_mixed_precision_train_fitness_matches_float64(scale):
    _, _, mask, pop, fit = relm_train_data(scale=scale)
    ref = np.asarray(relm.fitness(pop, fit, 1e-3, 5))
    rows = relm.train_rows(fit, int(mask.sum()))
    got = np.asarray(relm.train_fitness(pop, rows, 1e-3, 5, chunk=3, refine=2))
    np.testing.assert_allclose(got, ref, rtol=1e-9)
    f64 = np.asarray(relm.train_fitness(pop, rows, 1e-3, 5, chunk=3, refine=0, gram_dtype="float64"))
    np.testing.assert_allclose(f64, ref, rtol=1e-10)


def test_refinement_is_what_recovers_float64():
    # Without refinement the float32 Gram is visibly off on ill-conditioned
    # features; two refinement steps bring it back (so the check above can fail).
    _, _, mask, pop, fit = relm_train_data(scale=0.05, seed=1)
    ref = np.asarray(relm.fitness(pop, fit, 1e-3, 5))
    rows = relm.train_rows(fit, int(mask.sum()))
    err = [np.max(np.abs(np.asarray(relm.train_fitness(pop, rows, 1e-3, 5, 3, k)) / ref - 1)) for k in (0, 2)]
    assert err[1] < 1e-9 < err[0]


def test_train_fitness_nonfinite_is_inf():
    _, _, mask, pop, fit = relm_train_data()
    rows = relm.train_rows(fit, int(mask.sum()))
    f = np.asarray(relm.train_fitness(pop.at[0, 0].set(jnp.nan), rows, 1e-3, 5, chunk=3))
    assert f[0] == np.inf and np.isfinite(f[1:]).all()


def test_train_fitness_vmapped_runs_members_one_by_one_bitwise():
    """Under vmap each batch member is computed alone (custom batching rule): bitwise equal results."""
    _, _, mask, pop, fit = relm_train_data()
    rows = relm.train_rows(fit, int(mask.sum()))
    pops = jnp.stack([pop, pop[::-1] * 0.5, pop * 0.9])
    batched = jax.vmap(lambda p: relm.train_fitness(p, rows, 1e-3, 5, chunk=3))(pops)
    for k in range(3):
        np.testing.assert_array_equal(np.asarray(batched[k]), np.asarray(relm.train_fitness(pops[k], rows, 1e-3, 5, chunk=3)))


# ------------------------------------------------------------ row-blocked paths (issue: rows in bounded memory)
@pytest.mark.parametrize("scale", [1.0, 0.05])
@pytest.mark.parametrize("padded", [False, True])
def test_row_blocked_train_fitness_matches_unblocked_and_float64(scale, padded):
    """A small row_block forces the blocked kernel (last block padded, weight-0 rows): the float64 solution."""
    _, _, mask, pop, fit = relm_train_data(n=200, scale=scale, seed=2)
    n = int(mask.sum()) + (5 if padded else 0)
    rows = relm.train_rows(fit, n, padded=padded)
    assert n > 16 and n % 16
    ref = np.asarray(relm.fitness(pop, fit, 1e-3, 5))
    unblocked = np.asarray(relm.train_fitness(pop, rows, 1e-3, 5, chunk=3))
    blocked = np.asarray(relm.train_fitness(pop, rows, 1e-3, 5, chunk=3, row_block=16))
    np.testing.assert_allclose(blocked, unblocked, rtol=1e-11)
    np.testing.assert_allclose(blocked, ref, rtol=1e-9)
    # a block size at least the row count runs the unblocked kernel itself, bitwise
    np.testing.assert_array_equal(np.asarray(relm.train_fitness(pop, rows, 1e-3, 5, chunk=3, row_block=n)), unblocked)


def test_row_blocked_train_fitness_without_refinement_is_no_worse():
    # Each block's Gram is centred on the block's own means, so even with no refinement the
    # float32 error stays at the unblocked kernel's level (the refinement then removes it).
    _, _, mask, pop, fit = relm_train_data(n=200, scale=0.05, seed=1)
    rows = relm.train_rows(fit, int(mask.sum()))
    ref = np.asarray(relm.fitness(pop, fit, 1e-3, 5))
    err = lambda rb: np.max(np.abs(np.asarray(relm.train_fitness(pop, rows, 1e-3, 5, 3, 0, row_block=rb)) / ref - 1))  # noqa: E731
    assert err(16) <= 2 * err(10_000)


def test_row_blocked_train_fitness_at_scale_and_under_vmap():
    """20,000 rows with the default ROW_BLOCK: blocked, equal to float64; batch members equal runs alone."""
    rng = np.random.default_rng(3)
    n, hidden = 20_000, 6
    assert n > relm.ROW_BLOCK
    X = rng.standard_normal((n, 6))
    T = np.sin(X[:, 0]) + 0.3 * X[:, 1] * X[:, 2]
    ones = jnp.ones((1, n))
    fit = relm.FitData(jnp.asarray(X), jnp.asarray(T), ones, ones)
    pop = jnp.asarray(rng.uniform(-1, 1, (4, relm.n_params(hidden))))
    rows = relm.train_rows(fit, n)
    got = relm.train_fitness(pop, rows, 1e-3, hidden, chunk=2)
    np.testing.assert_allclose(np.asarray(got), np.asarray(relm.fitness(pop, fit, 1e-3, hidden)), rtol=1e-9)
    pops = jnp.stack([pop, pop * 0.5])
    batched = jax.vmap(lambda p: relm.train_fitness(p, rows, 1e-3, hidden, chunk=2))(pops)
    np.testing.assert_array_equal(np.asarray(batched[0]), np.asarray(got))


# ------------------------------------------------ float32 features (issue: per-stage roofline, item 4)
@pytest.mark.parametrize("scale", [1.0, 0.05])
@pytest.mark.parametrize("padded", [False, True])
@pytest.mark.parametrize("row_block", [relm.ROW_BLOCK, 16])
def test_float32_features_match_the_float64_library(scale, padded, row_block):
    """feature_dtype="float32" (pre-activation, sigmoid, matrix-vector products in float32): within 5e-6
    of the float64 library fitness, unweighted and padded, unblocked and row-blocked (last block padded)."""
    _, _, mask, pop, fit = relm_train_data(n=200, scale=scale, seed=2)
    n = int(mask.sum()) + (5 if padded else 0)
    rows = relm.train_rows(fit, n, padded=padded)
    ref = np.asarray(relm.fitness(pop, fit, 1e-3, 5))
    got = relm.train_fitness(pop, rows, 1e-3, 5, chunk=3, row_block=row_block, feature_dtype="float32")
    assert got.dtype == jnp.float64
    np.testing.assert_allclose(np.asarray(got), ref, rtol=5e-6)


@pytest.mark.parametrize("padded", [False, True])
def test_default_features_are_float64_bitwise(padded):
    """The default is feature_dtype="float64", bitwise, unblocked and blocked; float32 features differ."""
    _, _, mask, pop, fit = relm_train_data(n=200, seed=2)
    rows = relm.train_rows(fit, int(mask.sum()) + (5 if padded else 0), padded=padded)
    for rb in (relm.ROW_BLOCK, 16):
        default = np.asarray(relm.train_fitness(pop, rows, 1e-3, 5, chunk=3, row_block=rb))
        f64 = np.asarray(relm.train_fitness(pop, rows, 1e-3, 5, chunk=3, row_block=rb, feature_dtype="float64"))
        np.testing.assert_array_equal(default, f64)
        f32 = np.asarray(relm.make_train_fitness(1e-3, 5, 3, row_block=rb, feature_dtype="float32")(pop, rows))
        assert not np.array_equal(f32, default)


@pytest.mark.parametrize("row_block", [relm.ROW_BLOCK, 16])
def test_float32_features_nonfinite_is_inf_never_nan(row_block):
    """A NaN theta gives +inf; thetas beyond float32's range (1e39) give +inf or a finite value, never NaN."""
    _, _, mask, pop, fit = relm_train_data(n=200, seed=2)
    rows = relm.train_rows(fit, int(mask.sum()))
    bad = pop.at[0, 0].set(jnp.nan).at[1].set(1e39).at[2, 3].set(-1e39)
    f = np.asarray(relm.train_fitness(bad, rows, 1e-3, 5, chunk=3, row_block=row_block, feature_dtype="float32"))
    assert f[0] == np.inf and not np.isnan(f).any() and (np.isfinite(f) | (f == np.inf)).all()
    assert np.isfinite(f[3:]).all()


@pytest.mark.parametrize("row_block", [relm.ROW_BLOCK, 16])
def test_float32_features_vmapped_equal_calls_alone(row_block):
    """Under vmap the float32-feature kernel runs batch members one by one too: bitwise the calls alone."""
    _, _, mask, pop, fit = relm_train_data(n=200, seed=2)
    rows = relm.train_rows(fit, int(mask.sum()))
    pops = jnp.stack([pop, pop[::-1] * 0.5, pop * 0.9])
    kw = dict(chunk=3, row_block=row_block, feature_dtype="float32")
    batched = jax.vmap(lambda p: relm.train_fitness(p, rows, 1e-3, 5, **kw))(pops)
    for k in range(3):
        alone = relm.train_fitness(pops[k], rows, 1e-3, 5, **kw)
        np.testing.assert_array_equal(np.asarray(batched[k]), np.asarray(alone))


@pytest.mark.parametrize("mode", relm.FITNESS_MODES)
def test_row_blocked_library_fitness_matches_unblocked(mode):
    """relm.fitness above row_block rows: the fold fits and scores summed over row blocks, one theta at a time."""
    X, T, mask, pop, _ = relm_train_data(n=200)
    fw, sw = relm.fold_weights(jax.random.PRNGKey(0), jnp.asarray(mask), mode)
    fit = relm.FitData(jnp.asarray(X), jnp.asarray(T), fw, sw)
    ref = np.asarray(relm.fitness(pop, fit, 1e-3, 5))
    np.testing.assert_allclose(np.asarray(relm.fitness(pop, fit, 1e-3, 5, row_block=48)), ref, rtol=1e-10)
    np.testing.assert_allclose(np.asarray(relm.fitness(pop, fit, 1e-3, 5, "float32", row_block=48)), ref, rtol=1e-3)
    bad = np.asarray(relm.fitness(pop.at[0, 0].set(jnp.nan), fit, 1e-3, 5, row_block=48))
    assert bad[0] == np.inf and np.isfinite(bad[1:]).all()


def test_row_blocked_refit_and_prediction_match_the_whole_matrix():
    X, err = sensor_data(300)
    w = (np.arange(300) % 3 > 0).astype(float)
    theta = relm.random_theta(jax.random.PRNGKey(4), L)
    mean, std = relm.standardize_stats(jnp.asarray(X), jnp.asarray(w))
    Xs = relm.standardize(jnp.asarray(X), mean, std)
    H = relm.hidden_layer(theta, Xs, L)
    ref = relm.ridge_solve(H, jnp.asarray(err), 1e-3, jnp.asarray(w))
    np.testing.assert_array_equal(np.asarray(relm_fit.ridge_beta(theta, Xs, err, 1e-3, L, w)), np.asarray(ref))
    beta = relm_fit.ridge_beta(theta, Xs, err, 1e-3, L, w, row_block=64)
    np.testing.assert_allclose(np.asarray(beta), np.asarray(ref), rtol=1e-9, atol=1e-9 * np.abs(ref).max())
    np.testing.assert_allclose(np.asarray(relm_fit.predict_rows(theta, beta, Xs, L, row_block=64)),
                               np.asarray(H @ beta), rtol=0, atol=1e-12)
    blocks = relm.row_blocks(64, Xs, jnp.asarray(err))
    assert blocks[0].shape == (5, 64, 6) and blocks[1].shape == (5, 64)
    np.testing.assert_array_equal(np.asarray(blocks[2]).ravel(), np.arange(320) < 300)
