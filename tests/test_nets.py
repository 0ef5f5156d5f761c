"""Tests for icgo.models.nets (the patent's BP network) and icgo.models.lookup_table (the baseline it replaced)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.interpolate import RegularGridInterpolator

import icgo  # noqa: F401  (float64)
from icgo.models import lookup_table, nets
from icgo.physics.frames import angle_diff


def _np_forward_backward(p, x, t):
    """Hand-written float64 forward pass (patent eqs. 8-12) and back-propagation."""
    w1, b1, w2, b2, v = (np.asarray(a) for a in p)
    sig = lambda z: 1.0 / (1.0 + np.exp(-z))  # noqa: E731
    o1 = sig(x @ w1.T + b1)
    o2 = sig(o1 @ w2.T + b2)
    y = o2 @ v
    n = x.shape[0]
    dy = -(t - y) / n                       # d/dy of mean 1/2 (t - y)^2
    gv = o2.T @ dy
    d2 = np.outer(dy, v) * o2 * (1 - o2)
    gw2, gb2 = d2.T @ o1, d2.sum(0)
    d1 = (d2 @ w2) * o1 * (1 - o1)
    gw1, gb1 = d1.T @ x, d1.sum(0)
    return y, (gw1, gb1, gw2, gb2, gv)


def _synthetic(n, seed=0):
    """Turntable-like points whose error is a smooth function of (I, T, A)."""
    rng = np.random.default_rng(seed)
    inc = rng.uniform(3, 75, n)
    tf = rng.uniform(0, 360, n)
    a_true = rng.uniform(0, 360, n)
    r = np.deg2rad
    err = 1.5 * np.sin(r(a_true)) * np.sin(r(inc)) + 0.8 * np.cos(r(tf)) + 0.5
    a_raw = np.mod(a_true - err, 360.0)
    return inc, tf, a_raw, a_true, err


def test_forward_and_gradient_match_hand_written_backprop():
    key = jax.random.PRNGKey(3)
    p = nets.init_params(key, 3, (8, 8))
    p = p._replace(b1=jnp.linspace(-0.5, 0.5, 8), b2=jnp.linspace(0.3, -0.2, 8))
    rng = np.random.default_rng(1)
    x = rng.uniform(-1, 1, (17, 3))
    t = rng.normal(size=17)
    y_ref, g_ref = _np_forward_backward(p, x, t)
    np.testing.assert_allclose(nets.forward(p, jnp.asarray(x)), y_ref, rtol=1e-13, atol=1e-14)
    g = jax.grad(nets.pattern_loss)(p, jnp.asarray(x), jnp.asarray(t))
    for a, b in zip(g, g_ref):
        np.testing.assert_allclose(np.asarray(a), b, rtol=1e-12, atol=1e-14)
    assert p.v.shape == (8,)  # eq. 12: no output threshold


def test_encodings():
    x = nets.encode_inputs(jnp.array([0.0, 90.0]), jnp.array([0.0, 359.999]),
                           jnp.array([-0.001, 180.0]), "scaled")
    assert x.shape == (2, 3)
    np.testing.assert_allclose(x[:, 0], [-1.0, 1.0])
    assert np.all(np.abs(x) <= 1.0)
    # scaled keeps the raw-angle seam; sincos is continuous across 0/360
    s = nets.encode_inputs(jnp.array([30.0, 30.0]), jnp.array([359.999, 0.001]),
                           jnp.array([359.999, 0.001]), "sincos")
    assert s.shape == (2, 5)
    np.testing.assert_allclose(s[0], s[1], atol=1e-4)
    with pytest.raises(ValueError, match="encoding"):
        nets.encode_inputs(1.0, 2.0, 3.0, "raw")


def test_targets_wrap():
    np.testing.assert_allclose(nets.target_deg(359.0, 1.0, "error"), 2.0)
    np.testing.assert_allclose(nets.target_deg(1.0, 359.0, "error"), -2.0)
    np.testing.assert_allclose(nets.target_deg(1.0, 360.5, "azimuth"), 0.5)
    np.testing.assert_allclose(nets.output_to_azimuth(2.0, 359.0, "error"), 1.0)
    np.testing.assert_allclose(nets.output_to_azimuth(-0.5, 0.0, "azimuth"), 359.5)


CFG = nets.NetConfig(epochs=150, batch_size=16, patience=40, learning_rate=0.02)


def test_fit_vmapped_equals_single_and_reduces_error():
    inc, tf, a_raw, a_true, err = _synthetic(400)
    keys = jax.random.split(jax.random.PRNGKey(0), 3)
    res = nets.fit(keys, inc, tf, a_raw, a_true, CFG)
    assert res.params.w1.shape == (3, 8, 3) and res.train_loss.shape == (3, CFG.epochs)
    alone = nets.fit(keys[1], inc, tf, a_raw, a_true, CFG)
    for a, b in zip(jax.tree.leaves(res.params), jax.tree.leaves(alone.params)):
        np.testing.assert_allclose(np.asarray(a[1]), np.asarray(b), rtol=1e-10, atol=1e-12)
    # held-out points of the same smooth error function
    ti, tt, tr, ta, te = _synthetic(300, seed=9)
    pred = nets.predict_seeds(res.params, np.column_stack([ti, tt, tr]))
    rmse = np.sqrt(np.mean(np.asarray(angle_diff(ta[None], pred)) ** 2, axis=1))
    raw = np.sqrt(np.mean(te ** 2))
    assert np.all(rmse < 0.2 * raw), (rmse, raw)  # >5x reduction in 150 epochs
    # early stopping keeps the best validation epoch
    for s in range(3):
        vl = np.asarray(res.val_loss[s])
        be = int(res.best_epoch[s])
        np.testing.assert_allclose(float(res.best_val_loss[s]), vl[be], rtol=1e-12)
        assert vl[be] <= vl[: int(res.stopped_epoch[s])].min() + 1e-15


def test_predict_is_the_patent_network_on_encoded_angles():
    """Independent reference: numpy float64 encoding (scaled / sincos), eqs. 8-12 and the target's map; each
    seed of predict_seeds is predict of that seed's params."""
    rng = np.random.default_rng(5)
    angles = np.column_stack([rng.uniform(3, 75, 50), rng.uniform(-180, 540, 50), rng.uniform(0, 360, 50)])
    for encoding, target in (("scaled", "error"), ("sincos", "azimuth")):
        n = nets.n_inputs(encoding)
        ps = [nets.init_params(k, n, (8, 8)) for k in jax.random.split(jax.random.PRNGKey(1), 2)]
        params = nets.NetParams(*(jnp.stack(x) for x in zip(*ps)), y_scale=jnp.array([2.5, 360.0]),
                                encoding=encoding, target=target)
        I, T, A = angles[:, 0], np.mod(angles[:, 1], 360.0), np.mod(angles[:, 2], 360.0)
        x = (np.column_stack([I / 45 - 1, T / 180 - 1, A / 180 - 1]) if encoding == "scaled" else
             np.column_stack([I / 45 - 1, np.sin(np.radians(T)), np.cos(np.radians(T)), np.sin(np.radians(A)),
                              np.cos(np.radians(A))]))
        got = np.asarray(nets.predict_seeds(params, angles))
        for s in range(2):
            y = _np_forward_backward(ps[s], x, np.zeros(50))[0] * float(params.y_scale[s])
            want = np.mod(y if target == "azimuth" else angles[:, 2] + y, 360.0)
            np.testing.assert_allclose(got[s], want, rtol=0, atol=1e-10)
            one = jax.tree.map(lambda a, s=s: a[s], params)
            np.testing.assert_allclose(np.asarray(nets.predict(one, angles)), got[s], rtol=0, atol=1e-12)


def test_compiles_once_per_config():
    inc, tf, a_raw, a_true, _ = _synthetic(400)
    keys = jax.random.split(jax.random.PRNGKey(1), 3)
    nets.fit(keys, inc, tf, a_raw, a_true, CFG)
    n0 = nets._train_batch._cache_size()
    nets.fit(jax.random.split(jax.random.PRNGKey(2), 3), inc + 1.0, tf, a_raw, a_true, CFG)
    assert nets._train_batch._cache_size() == n0


def test_early_stopping_freezes_after_patience():
    inc, tf, a_raw, _, _ = _synthetic(400)
    # pure-noise targets: nothing to learn, the validation loss stops improving early
    a_true = a_raw + np.random.default_rng(7).normal(0.0, 1.0, 400)
    res = nets.fit(jax.random.PRNGKey(0), inc, tf, a_raw, a_true, CFG)
    se = int(res.stopped_epoch)
    assert se < CFG.epochs
    assert se - int(res.best_epoch) == CFG.patience
    vl = np.asarray(res.val_loss)
    assert np.all(vl[se:] == vl[se])


def test_target_azimuth_fails_at_north_and_error_target_does_not():
    # constant +2 deg error: trivial for target=error, a seam for target=azimuth
    rng = np.random.default_rng(4)
    n = 400
    inc, tf, a_true = rng.uniform(3, 75, n), rng.uniform(0, 360, n), rng.uniform(0, 360, n)
    a_raw = np.mod(a_true - 2.0, 360.0)
    out = {}
    for target in ("azimuth", "error"):
        c = CFG._replace(target=target)
        res = nets.fit(jax.random.PRNGKey(5), inc, tf, a_raw, a_true, c)
        e = np.asarray(angle_diff(a_true, nets.predict(res.params, np.column_stack([inc, tf, a_raw]))))
        north = np.abs(angle_diff(a_true, 0.0)) < 10.0
        out[target] = (np.sqrt(np.mean(e[north] ** 2)), np.sqrt(np.mean(e[~north] ** 2)))
    n_az, far_az = out["azimuth"]
    n_er, far_er = out["error"]
    assert n_az > 20.0 and n_az > 2.5 * far_az, out  # error concentrated near north
    assert n_er < 0.2 and far_er < 0.2, out  # gone with the error target


def test_lookup_table_matches_scipy_bilinear_periodic():
    inc_nodes = np.array([3, 5, 10, 15, 25, 35, 45, 55, 65, 75.0])
    az_nodes = np.arange(0, 360, 30.0)
    tf_nodes = np.array([0.0, 120.0, 240.0])
    I, A, T = (g.ravel() for g in np.meshgrid(inc_nodes, az_nodes, tf_nodes, indexing="ij"))
    rng = np.random.default_rng(2)
    node_err = rng.normal(size=(10, 12))
    tf_effect = {0.0: 0.3, 120.0: -0.1, 240.0: -0.2}  # averages to zero over toolface
    err = node_err[np.searchsorted(inc_nodes, I), (A // 30).astype(int)] + np.vectorize(
        tf_effect.get)(T)
    table = lookup_table.fit(I, A, err)
    np.testing.assert_allclose(table.error, node_err, atol=1e-12)
    # reference: scipy's linear interpolator on the table padded periodically in azimuth
    ref = RegularGridInterpolator((inc_nodes, np.append(az_nodes, 360.0)),
                                  np.concatenate([node_err, node_err[:, :1]], 1))
    qi, qa = rng.uniform(3, 75, 500), rng.uniform(0, 360, 500)
    np.testing.assert_allclose(lookup_table.error_at(table, qi, qa),
                               ref(np.stack([qi, qa], -1)), atol=1e-12)
    # periodic: just below 360 approaches the 0-deg node; clamped outside the inclinations
    np.testing.assert_allclose(lookup_table.error_at(table, 3.0, 359.9999999),
                               node_err[0, 0], atol=1e-7)
    np.testing.assert_allclose(lookup_table.error_at(table, 80.0, 30.0), node_err[-1, 1])
    np.testing.assert_allclose(lookup_table.predict(table, np.array([[3.0, 77.0, 359.0]])),  # toolface unused
                               np.mod(359.0 + ref([[3.0, 359.0]]), 360.0), atol=1e-12)
    # fixed-toolface table (patent background)
    t0 = lookup_table.fit(I, A, err, toolface_deg=T, at_toolface_deg=120.0)
    np.testing.assert_allclose(t0.error, node_err - 0.1, atol=1e-12)


def test_bad_inputs_raise_one_line_errors():
    inc, tf, a_raw, a_true, err = _synthetic(100)
    with pytest.raises(ValueError, match="NaN"):
        nets.fit(jax.random.PRNGKey(0), np.where(inc > 50, np.nan, inc), tf, a_raw, a_true, CFG)
    with pytest.raises(ValueError, match="rows"):
        nets.fit(jax.random.PRNGKey(0), inc[:-1], tf, a_raw, a_true, CFG)
    with pytest.raises(ValueError, match="inclination"):
        nets.fit(jax.random.PRNGKey(0), inc + 200.0, tf, a_raw, a_true, CFG)
    with pytest.raises(ValueError, match="target"):
        nets.fit(jax.random.PRNGKey(0), inc, tf, a_raw, a_true, CFG._replace(target="x"))
    with pytest.raises(ValueError, match="hidden"):
        nets.fit(jax.random.PRNGKey(0), inc, tf, a_raw, a_true, CFG._replace(hidden=(8,)))
    with pytest.raises(ValueError, match="batch_size"):
        nets.fit(jax.random.PRNGKey(0), inc[:10], tf[:10], a_raw[:10], a_true[:10],
                 CFG._replace(batch_size=64))
    with pytest.raises(ValueError, match="not on a table node"):
        lookup_table.fit(inc, a_true, err, inc_nodes=[3.0, 75.0], az_nodes=[0.0, 180.0])
    with pytest.raises(ValueError, match="has no turntable point"):
        lookup_table.fit([3.0, 3.0], [0.0, 0.0], [0.1, 0.2], az_nodes=[0.0, 180.0])
