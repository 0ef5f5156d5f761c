"""Multi-station analysis: recovery of injected biases, eq. (7) by hand, observability errors."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import icgo  # noqa: F401  (float64)
from icgo.models import msa
from icgo.physics import effects, frames

F, DIP, NOISE = 50_000.0, 60.0, 15.0
BIAS = np.array([300.0, -200.0, 500.0])


def stations(azimuths=(30, 60, 120, 150, 210, 240, 300, 330), tf_step=15, inc=90.0, fx=None, seed=0, noise=NOISE):
    A, T = np.meshgrid(np.asarray(azimuths, float), np.arange(0, 360, tf_step, dtype=float), indexing="ij")
    A, T = A.ravel(), T.ravel()
    I = np.full_like(A, inc)
    s = frames.sensors_from_attitude(A, I, T, F, DIP)
    G, B = effects.apply_effects(fx or {"hard_iron": BIAS}, s.G, s.B, frames.tool_to_earth(A, I, T))
    rng = np.random.default_rng(seed)
    return np.asarray(G), np.asarray(B) + rng.normal(0, noise, (A.size, 3)), A, T


def test_recovers_hard_iron_within_noise_floor_and_reduces_azimuth_error():
    G, B, A, _ = stations()
    r = msa.multi_station_analysis(G, B)
    # Noise floor: the linearised standard error, itself ~ noise / sqrt(N).
    assert np.all(np.asarray(r.std_error) < 2 * NOISE / np.sqrt(len(A)))
    assert np.all(np.abs(np.asarray(r.bias) - BIAS) < 3 * np.asarray(r.std_error))
    raw = np.abs(np.asarray(frames.angle_diff(frames.azimuth_from_gv(G, B), A)))
    cor = np.abs(np.asarray(frames.angle_diff(msa.corrected_azimuth(G, B, r), A)))
    assert cor.max() < 0.15 * raw.max() and cor.mean() < 0.1 * raw.mean()
    assert 1.0 <= float(r.condition) < 10.0


def test_cost_matches_eq7_by_hand():
    G, B, _, _ = stations()
    r = msa.multi_station_analysis(G, B)
    Bc = B - np.asarray(r.bias)
    g = G / np.linalg.norm(G, axis=1, keepdims=True)
    bv = np.sum(Bc * g, 1)                                   # eq. (5)
    bh = np.sqrt(np.sum(Bc * Bc, 1) - bv**2)                 # eq. (6)
    V = (np.sum((bh - bh.mean()) ** 2) + np.sum((bv - bv.mean()) ** 2)) / (len(bv) - 1)  # eqs. (3), (4), (7)
    assert float(r.cost) == pytest.approx(V, rel=1e-10)
    assert np.allclose(r.reference, [bh.mean(), bv.mean()], rtol=1e-12)
    # A nearby point has a larger V (it is a minimum).
    Bc2 = B - (np.asarray(r.bias) + [5.0, 0.0, 0.0])
    bv2 = np.sum(Bc2 * g, 1)
    bh2 = np.sqrt(np.sum(Bc2 * Bc2, 1) - bv2**2)
    assert (np.sum((bh2 - bh2.mean()) ** 2) + np.sum((bv2 - bv2.mean()) ** 2)) / (len(bv) - 1) > V


def test_weights_mask_equals_row_subset_and_vmaps():
    G, B, _, _ = stations()
    rng = np.random.default_rng(1)
    masks = (rng.random((3, len(G))) < 0.7).astype(float)
    batched = jax.vmap(lambda w: msa.msa_solve(G, B, w))(jnp.asarray(masks))
    for k in range(3):
        sub = msa.multi_station_analysis(G[masks[k] > 0], B[masks[k] > 0])
        np.testing.assert_allclose(batched.bias[k], sub.bias, atol=1e-6)
        np.testing.assert_allclose(batched.cost[k], sub.cost, rtol=1e-8)


def test_single_direction_axial_bias_unobservable_without_reference():
    G, B, _, _ = stations(azimuths=(60,), tf_step=5)
    with pytest.raises(ValueError, match="eps_z"):
        msa.multi_station_analysis(G, B)
    # Noise-free data: exactly dependent column, also caught.
    G0, B0, _, _ = stations(azimuths=(60,), tf_step=5, noise=0.0)
    with pytest.raises(ValueError, match="cannot determine"):
        msa.multi_station_analysis(G0, B0)
    # A known reference field makes it observable.
    r = msa.multi_station_analysis(G, B, reference=msa.reference_from_field(F, DIP))
    assert np.all(np.abs(np.asarray(r.bias) - BIAS) < 3 * np.asarray(r.std_error) + 1e-9)


def test_biases_and_scale_factors_with_reference():
    s = np.array([0.01, -0.008, 0.005])
    G, B, _, _ = stations(fx={"hard_iron": BIAS, "mag_scale": s}, inc=60.0)
    G2, B2, _, _ = stations(fx={"hard_iron": BIAS, "mag_scale": s}, inc=120.0, seed=3)
    G, B = np.vstack([G, G2]), np.vstack([B, B2])
    r = msa.multi_station_analysis(G, B, reference=msa.reference_from_field(F, DIP), model="biases_scales")
    est = np.asarray(r.params)
    assert np.all(np.abs(est - np.concatenate([BIAS, s])) < 3 * np.asarray(r.std_error))
    with pytest.raises(ValueError, match="reference"):
        msa.multi_station_analysis(G, B, model="biases_scales")


def test_soft_iron_is_not_a_bias_and_leaves_a_residual():
    # The bias model removes the bias only; a soft-iron matrix leaves a residual.
    G, B, A, T = stations(fx={"hard_iron": BIAS, "mag_cross_coupling": np.array([0.01, -0.006, 0.004])}, noise=0.0)
    r = msa.multi_station_analysis(G, B)
    res = np.asarray(frames.angle_diff(msa.corrected_azimuth(G, B, r), A))
    assert np.sqrt(np.mean(res**2)) > 0.05  # soft iron is not a bias: a residual survives


def test_bad_inputs():
    G, B, _, _ = stations()
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        msa.multi_station_analysis(G[:, :2], B)
    Bn = B.copy()
    Bn[3, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        msa.multi_station_analysis(G, Bn)
    with pytest.raises(ValueError, match="msa model"):
        msa.multi_station_analysis(G, B, model="full")
    with pytest.raises(ValueError, match="weights"):
        msa.multi_station_analysis(G, B, weights=np.ones(5))
    with pytest.raises(ValueError, match="stations cannot determine|weighted stations"):
        msa.multi_station_analysis(G[:3], B[:3])


def _eq7_residuals_numpy(bias, G, B):
    """Independent numpy form of eqs. (2)-(7) with station means: r (2N,), sum r^2 = V (nT^2)."""
    Bc = B - bias
    g = G / np.linalg.norm(G, axis=1, keepdims=True)
    bv = np.sum(Bc * g, 1)
    bh = np.sqrt(np.sum(Bc * Bc, 1) - bv**2)
    return np.concatenate([bh - bh.mean(), bv - bv.mean()]) / np.sqrt(len(bv) - 1)


def test_noise_free_bias_recovered_exactly_and_converged():
    # closed form: with hard iron only and no noise, the minimum of eq. (7) is the injected bias with V = 0
    G, B, _, _ = stations(noise=0.0)
    r = msa.multi_station_analysis(G, B)
    np.testing.assert_allclose(np.asarray(r.bias), BIAS, rtol=0, atol=1e-6)
    assert float(r.cost) < 1e-12 and bool(r.converged) and 1 <= int(r.n_steps) <= 100
    rk = msa.multi_station_analysis(G, B, reference=msa.reference_from_field(F, DIP))
    np.testing.assert_allclose(np.asarray(rk.bias), BIAS, rtol=0, atol=1e-6)


def test_noisy_fit_matches_scipy_least_squares_peer():
    from scipy.optimize import least_squares as scipy_lsq

    G, B, _, _ = stations(seed=4)
    r = msa.multi_station_analysis(G, B)
    peer = scipy_lsq(_eq7_residuals_numpy, np.zeros(3), args=(G, B), method="lm", xtol=1e-15, ftol=1e-15,
                     gtol=1e-15, x_scale=np.full(3, F))
    # both at the float64 floor of eq. (7) (~1e-5 nT here); V agrees to rounding
    np.testing.assert_allclose(np.asarray(r.bias), peer.x, rtol=0, atol=1e-4)
    assert float(r.cost) == pytest.approx(float(np.sum(peer.fun**2)), rel=1e-12)


def test_step_budget_too_small_is_reported():
    G, B, _, _ = stations()
    r = msa.msa_solve(G, B, np.ones(len(G)), max_steps=2)
    assert not bool(r.converged) and int(r.n_steps) == 2
    with pytest.raises(ValueError, match="did not converge"):
        msa.check_observability(r)


def test_msa_failures_gives_each_member_its_verdict():
    # members: every station; only the 30 deg azimuth (one tool axis: eps_z undetermined); every station again
    G, B, A, _ = stations()
    one_axis = (A == 30.0).astype(float)
    W = jnp.asarray(np.stack([np.ones(len(A)), one_axis, np.ones(len(A))]))
    r = jax.lax.map(lambda w: msa.msa_solve(jnp.asarray(G), jnp.asarray(B), w, None, model="biases", max_steps=100), W)
    verdicts = msa.msa_failures(r)
    assert verdicts[0] is None and verdicts[2] is None
    assert "cannot determine ['eps_z']" in verdicts[1]
    with pytest.raises(ValueError, match=r"multi-station analysis \(repeat 1\): the stations cannot determine"):
        msa.check_observability(r)
    # a budget too small for every member: each is named, and a non-finite solution says so
    r1 = jax.lax.map(lambda w: msa.msa_solve(jnp.asarray(G), jnp.asarray(B), w, None, model="biases", max_steps=1),
                     W[jnp.array([0, 2])])
    assert all(v.startswith("Levenberg-Marquardt did not converge in 1 steps") for v in msa.msa_failures(r1))
    bad = r._replace(cost=r.cost.at[2].set(jnp.nan))
    assert msa.msa_failures(bad)[2].startswith("the solution is not finite")
