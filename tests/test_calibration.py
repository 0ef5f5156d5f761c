"""Tests for icgo.models.calibration: closed forms, the peer metric, bad input."""

import jax.numpy as jnp
import numpy as np
import pytest

import icgo  # noqa: F401
from icgo.models import cal_objectives, cal_pointing
from icgo.models import calibration as cal
from icgo.models.misma_objective import MismaObjective
from icgo.physics.frames import sensors_from_attitude


def _stations(n=60, seed=0, F=50_000.0, dip=60.0):
    rng = np.random.default_rng(seed)
    A, I, T = rng.uniform(0, 360, n), rng.uniform(5, 175, n), rng.uniform(0, 360, n)
    s = sensors_from_attitude(A, I, T, F, dip)
    return np.asarray(s.G), np.asarray(s.B), A


R_GEN = np.array([[1.05, 0.03, -0.02], [-0.04, 0.96, 0.05], [0.02, -0.03, 1.02]])
B_BIAS = np.array([800.0, -500.0, 300.0])


def test_pack_unpack_correct_inverts_distort():
    G, Bt, _ = _stations()
    x = cal.params_from_error_model(R_GEN, B_BIAS)
    r_inv, b = cal.unpack(cal.pack(*cal.unpack(x)))
    np.testing.assert_allclose(r_inv @ R_GEN, np.eye(3), atol=1e-14)
    np.testing.assert_allclose(np.asarray(cal.correct(x, cal.distort(R_GEN, B_BIAS, Bt))), Bt, atol=1e-9)


def test_objectives_zero_at_true_parameters():
    G, Bt, _ = _stations()
    Bm = np.asarray(cal.distort(R_GEN, B_BIAS, Bt))
    x = cal.params_from_error_model(R_GEN, B_BIAS)
    assert float(cal_objectives.dot_invariance(x, G, Bm)) < 1e-28
    assert float(cal_objectives.magnitude_consistency(x, Bm, 50_000.0)) < 1e-28
    assert float(cal_objectives.magnitude_ratio(x, Bm, 50_000.0)) == pytest.approx(1.0, abs=1e-14)
    # the normalised dot product is sin(dip) (closed form)
    np.testing.assert_allclose(np.asarray(cal.normalized_dot(G, Bt)), np.sin(np.deg2rad(60.0)), atol=1e-14)
    # and the raw readings are not consistent
    assert float(cal_objectives.dot_invariance(cal.identity_params(), G, Bm)) > 1e-6


def test_magnitude_ratio_closed_form():
    G, Bt, _ = _stations()
    x = cal.pack(1.1 * jnp.eye(3), jnp.zeros(3))  # corrected modulus = 1.1 F everywhere
    assert float(cal_objectives.magnitude_ratio(x, Bt, 50_000.0)) == pytest.approx(1 / 1.1, rel=1e-12)
    assert float(cal_objectives.magnitude_consistency(x, Bt, 50_000.0)) == pytest.approx(0.01, rel=1e-10)


def test_pearson_axis_and_complex_closed_form():
    # rotation about z at fixed I, A: per-axis correlation = cos(phase difference), complex = 1
    T = np.linspace(0, 720, 200, endpoint=False)
    A, I, dip = 100.0, 60.0, 50.0
    s = sensors_from_attitude(np.full_like(T, A), np.full_like(T, I), T, 50_000.0, dip)
    G, B = np.asarray(s.G), np.asarray(s.B)
    H, V = np.cos(np.deg2rad(dip)), np.sin(np.deg2rad(dip))
    a, i = np.deg2rad(A), np.deg2rad(I)
    u = np.array([H * np.cos(a) * np.cos(i) - V * np.sin(i), -H * np.sin(a)])
    expect = np.dot(u, [-1.0, 0.0]) / np.linalg.norm(u)
    x = cal.identity_params()
    seg, rot = np.zeros(len(T), np.int32), np.ones(len(T))
    rho, n = cal_objectives.pearson_xy(x, G, B, seg, rot, 1, "axis")
    np.testing.assert_allclose(np.asarray(rho)[0], [expect, expect], atol=1e-9)
    rho_c, _ = cal_objectives.pearson_xy(x, G, B, seg, rot, 1, "complex")
    assert float(rho_c[0, 0]) == pytest.approx(1.0, abs=1e-9)
    assert float(n[0]) == len(T)


def test_ellipsoid_fit_exact_for_symmetric_R():
    G, Bt, _ = _stations(80)
    Rs = 0.5 * (R_GEN + R_GEN.T)
    Bm = np.asarray(cal.distort(Rs, B_BIAS, Bt))
    x = cal.ellipsoid_fit(Bm, 50_000.0, G)
    np.testing.assert_allclose(x, np.asarray(cal.params_from_error_model(Rs, B_BIAS)), rtol=0, atol=1e-7)


def test_fit_twelve_recovers_general_R():
    G, Bt, _ = _stations(80)
    Bm = np.asarray(cal.distort(R_GEN, B_BIAS, Bt))
    x = cal.fit_twelve(G, Bm, 50_000.0)
    xt = np.asarray(cal.params_from_error_model(R_GEN, B_BIAS))
    np.testing.assert_allclose(x[:9], xt[:9], atol=1e-8)
    np.testing.assert_allclose(x[9:], xt[9:], atol=1e-4)


def test_fitness_is_inf_not_nan_for_degenerate_candidates():
    G, Bt, _ = _stations(20)
    obj = MismaObjective(cal.make_caldata(G, Bt, 50_000.0))
    pop = jnp.stack([jnp.zeros(12), cal.identity_params(), jnp.full(12, jnp.nan)])
    f = np.asarray(obj(pop))
    assert np.isinf(f[0]) and np.isinf(f[2]) and f[1] < 1e-20


def test_too_few_orientations_names_how_many_more():
    G, Bt, _ = _stations(5)
    G = np.repeat(G, 3, axis=0)
    Bt = np.repeat(Bt, 3, axis=0)
    with pytest.raises(ValueError, match=r"only 5 distinct orientations.*at least 12: record 7 more"):
        cal.fit_twelve(G, Bt, 50_000.0)
    with pytest.raises(ValueError, match=r"ellipsoid fit needs at least 9: record 4 more"):
        cal.ellipsoid_fit(Bt, 50_000.0, G)


def test_single_axis_rotation_is_rejected_by_ellipsoid_fit():
    T = np.linspace(0, 360, 40, endpoint=False)
    s = sensors_from_attitude(np.full_like(T, 30.0), np.full_like(T, 70.0), T, 50_000.0, 60.0)
    with pytest.raises(ValueError, match="rank-deficient"):
        cal.ellipsoid_fit(np.asarray(s.B) + 100.0, 50_000.0, np.asarray(s.G))


def test_make_caldata_bad_input():
    G, Bt, _ = _stations(10)
    with pytest.raises(ValueError, match="must both be"):
        cal.make_caldata(G[:, :2], Bt, 1.0)
    Bn = Bt.copy()
    Bn[3, 1] = np.nan
    with pytest.raises(ValueError, match="non-finite value at row 3"):
        cal.make_caldata(G, Bn, 1.0)
    with pytest.raises(ValueError, match="reference modulus"):
        cal.make_caldata(G, Bt, -1.0)


def test_group_spread_matches_peer_package_on_a_real_device():
    from mag_cal import Calibration

    from icgo.io.mag_cal_bundled import MAG_CAL_DEVICE_TO_TOOL, load_mag_cal_device

    rec = load_mag_cal_device("ab")
    G, B, groups = rec.G, rec.B, rec.frame["group"].to_numpy()
    Gc = np.asarray(cal.correct(cal.ellipsoid_fit_accel(G), G))
    Bc = np.asarray(cal.correct(cal.ellipsoid_fit(B, 1.0, G), B))
    ours, per = cal_pointing.group_spread_deg(Gc, Bc, groups)
    # the peer's own Calibration.accuracy on the same calibrated vectors (identity sensors)
    perm = list(MAG_CAL_DEVICE_TO_TOOL)
    gd, md = np.empty_like(Gc), np.empty_like(Bc)
    gd[:, perm], md[:, perm] = Gc, Bc
    c = Calibration()
    for sensor in (c.mag, c.grav):
        sensor.transform, sensor.centre = np.eye(3), np.zeros(3)
    peer = c.accuracy([(md[8:16], gd[8:16]), (md[16:24], gd[16:24])])
    assert sorted(per) == [8, 9]
    assert ours == pytest.approx(peer, rel=1e-10)
    assert ours > 0.5  # ellipsoid only: the pointing axis is not aligned yet


def test_align_to_axis_removes_a_known_mounting_rotation():
    # groups rolled about the tool axis, sensors mounted with a 3 deg tilt: alignment restores zero spread
    from icgo.physics.effects import rotation_from_vector

    T = np.linspace(0, 315, 8)
    rows = [sensors_from_attitude(np.full(8, a), np.full(8, i), T, 50_000.0, 60.0) for a, i in ((40, 30), (200, 70))]
    G = np.concatenate([np.asarray(r.G) for r in rows])
    B = np.concatenate([np.asarray(r.B) for r in rows])
    groups = np.repeat([8, 9], 8)
    M = np.asarray(rotation_from_vector(jnp.array([2.0, -2.0, 0.0])))
    Gm, Bm = G @ M.T, B @ M.T
    assert cal_pointing.group_spread_deg(Gm, Bm, groups)[0] > 1.0
    Q = cal_pointing.align_to_axis(Gm, Bm, groups)
    assert cal_pointing.group_spread_deg(Gm @ Q.T, Bm @ Q.T, groups)[0] < 1e-6


# ------------------------------------------- the least-squares fits (icgo.maths.lsq)
def _scipy_peer(fn, u0, args, x_scale):
    """The same residuals solved by scipy's trust-region reflective least squares (independent solver)."""
    import jax
    from scipy.optimize import least_squares

    f, j = jax.jit(fn), jax.jit(jax.jacfwd(fn))
    return least_squares(lambda u: np.asarray(f(u, args)), u0, jac=lambda u: np.asarray(j(u, args)), method="trf",
                         x_scale=x_scale, xtol=1e-14, ftol=1e-15, gtol=1e-15, max_nfev=2000)


def test_modulus_fit_closed_form_without_ridge():
    # noise-free, symmetric R: every corrected modulus equals |M|, the bias is exact, and R^-T R^-1 is the truth's
    G, Bt, _ = _stations(80)
    Rs = 0.5 * (R_GEN + R_GEN.T)
    Bm = np.asarray(cal.distort(Rs, B_BIAS, Bt))
    x = cal.modulus_fit(Bm, 50_000.0, ridge=0.0)
    np.testing.assert_allclose(np.linalg.norm(np.asarray(cal.correct(x, Bm)), axis=1), 50_000.0, rtol=1e-10)
    np.testing.assert_allclose(x[9:], B_BIAS, rtol=0, atol=1e-5)
    r_inv = x[:9].reshape(3, 3)
    t_inv = np.linalg.inv(Rs)
    np.testing.assert_allclose(r_inv.T @ r_inv, t_inv.T @ t_inv, rtol=0, atol=1e-10)


def test_fit_twelve_matches_scipy_peer_on_noisy_data():
    G, Bt, _ = _stations(80, seed=3)
    rng = np.random.default_rng(3)
    Bm = np.asarray(cal.distort(R_GEN, B_BIAS, Bt)) + rng.normal(0, 50.0, Bt.shape)
    Gn = G + rng.normal(0, 2e-3, G.shape)
    x0 = cal.ellipsoid_fit(Bm, 50_000.0, Gn)
    x = cal.fit_twelve(Gn, Bm, 50_000.0, x0=x0)
    scale = np.concatenate([np.full(9, np.abs(x0[:9]).max()), np.full(3, 50_000.0)])
    args = (jnp.asarray(scale), jnp.asarray(Gn), jnp.asarray(Bm), jnp.ones(len(Bm)), jnp.asarray(50_000.0),
            jnp.asarray(1.0))
    peer = _scipy_peer(cal._twelve_residuals, x0 / scale, args, "jac")
    np.testing.assert_allclose(x / scale, peer.x, rtol=0, atol=1e-7)
    cost = float(np.sum(np.asarray(cal._twelve_residuals(jnp.asarray(x / scale), args)) ** 2))
    assert cost == pytest.approx(float(np.sum(peer.fun**2)), rel=1e-10)


def _attitudes():
    """(A, I, T) deg: 24 spread shots, then two rolls of 8 (at I = 30 and 110 deg)."""
    rng = np.random.default_rng(7)
    A, I, T = rng.uniform(0, 360, 24), rng.uniform(10, 170, 24), rng.uniform(0, 360, 24)
    roll = np.linspace(0, 315, 8)
    A = np.concatenate([A, np.full(8, 40.0), np.full(8, 200.0)])
    I = np.concatenate([I, np.full(8, 30.0), np.full(8, 110.0)])
    return A, I, np.concatenate([T, roll, roll])


def test_joint_fit_finds_an_accelerometer_bias_when_free_and_keeps_its_start_when_held():
    # exact shots; the start is the truth with a 20 mg accelerometer bias error (the magnetometer exact):
    # a weak penalty removes the error, a strong one keeps the start, and the fit has converged
    from icgo.models import joint

    groups = np.concatenate([np.arange(24), np.full(8, 100), np.full(8, 101)])
    s = sensors_from_attitude(*_attitudes(), 1.0, 60.0)
    G, B = np.asarray(s.G), np.asarray(s.B)
    xg0 = np.r_[np.eye(3).ravel(), 0.02, -0.01, 0.0]
    xm0 = np.r_[np.eye(3).ravel(), 0.0, 0.0, 0.0]
    train = np.ones(len(G), bool)
    weak = joint.fit(G, B, groups, train, xg0, xm0, lambdas=(1e-8,), n_steps=60)
    np.testing.assert_allclose(weak.xg[9:], 0.0, atol=1e-6)
    np.testing.assert_allclose(weak.xm, xm0, atol=0)  # the staged fit: the magnetometer stays at its start
    assert weak.gap < 1e-6
    strong = joint.fit(G, B, groups, train, xg0, xm0, lambdas=(1e8,))
    np.testing.assert_allclose(strong.xg, xg0, atol=1e-6)
    both = joint.fit(G, B, groups, train, xg0, xm0, lambdas=(1e-8, 1e8), n_steps=60)
    assert both.lam == 1e-8 and both.cv[0] < both.cv[1]  # leave-one-group-out prefers the fit that removes it


def test_the_joint_fit_leaves_out_rolls_inside_the_training_shots_only():
    from icgo.models.joint import roll_folds

    groups = np.r_[np.arange(8), [8] * 8, [9] * 8]
    every = np.ones(24, bool)
    rolls, fit_w, held_w = roll_folds(groups, every)
    assert rolls.shape == (2, 24) and fit_w.shape == held_w.shape == (2, 24)
    assert held_w[0].astype(bool).tolist() == (groups == 8).tolist() and not (fit_w * held_w).any()
    # group 9 held out by the calibration's split: inside its training shots, roll 8's halves (never a shot of 9)
    train = groups != 9
    _, fit_w, held_w = roll_folds(groups, train)
    assert [np.flatnonzero(h).tolist() for h in held_w] == [[9, 11, 13, 15], [8, 10, 12, 14]]
    assert not fit_w[:, groups == 9].any() and not held_w[:, groups == 9].any()
    # half a roll left (4 shots): nothing to leave out, two empty folds (same shapes) and the strength held
    _, fit_w, held_w = roll_folds(groups, (groups != 9) & ~np.isin(np.arange(24), [9, 11, 13, 15]))
    assert held_w.sum() == 0 and fit_w.shape == (2, 24)
