"""Frame conventions: round trips, closed forms, the papers' own formulas."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import icgo  # noqa: F401  (enables float64)
from icgo.physics import frames as F


def _random_attitudes(n, seed=0, inc=(0.0, 180.0)):
    rng = np.random.default_rng(seed)
    return rng.uniform(0, 360, n), rng.uniform(*inc, n), rng.uniform(0, 360, n)


def test_wrap180_interval_and_values():
    x = jnp.array([-540.0, -180.0, -179.5, 0.0, 179.5, 180.0, 181.0, 540.0, 719.0])
    w = np.asarray(F.wrap180(x))
    np.testing.assert_allclose(w, [180.0, 180.0, -179.5, 0.0, 179.5, 180.0, -179.0, 180.0, -1.0])
    assert np.all(w > -180.0) and np.all(w <= 180.0)
    np.testing.assert_allclose(np.asarray(F.angle_diff(1.0, 359.0)), 2.0)
    np.testing.assert_allclose(np.asarray(F.wrap360(jnp.array([-1.0, 360.0, 725.0]))), [359.0, 0.0, 5.0])


def test_rotation_matches_scipy_euler():
    from scipy.spatial.transform import Rotation

    a, i, t = _random_attitudes(50, seed=1)
    c = np.asarray(F.tool_to_earth(a, i, t))
    ref = Rotation.from_euler("ZYZ", np.stack([a, i, t], -1), degrees=True).as_matrix()
    np.testing.assert_allclose(c, ref, atol=1e-13)
    np.testing.assert_allclose(np.linalg.det(c), 1.0, atol=1e-13)


def test_vertical_tool_reads_plus_one_g():
    s = F.sensors_from_attitude(123.0, 0.0, 45.0)
    np.testing.assert_allclose(np.asarray(s.G), [0.0, 0.0, 1.0], atol=1e-15)


def test_round_trip_10000_attitudes_float64():
    a, i, t = _random_attitudes(10_000, seed=2, inc=(F.NEAR_VERTICAL_DEG, 180.0 - F.NEAR_VERTICAL_DEG))
    s = F.sensors_from_attitude(a, i, t, total_field_nT=48_000.0, dip_deg=57.0)
    att = jax.jit(F.attitude_from_sensors)(s.G, s.B)
    assert np.max(np.abs(np.asarray(F.angle_diff(att.azimuth, a)))) < 1e-9
    assert np.max(np.abs(np.asarray(att.inclination) - i)) < 1e-9
    assert np.max(np.abs(np.asarray(F.angle_diff(att.toolface, t)))) < 1e-9
    assert not np.any(np.asarray(att.near_vertical))


def test_round_trip_float32_within_a_millidegree():
    a, i, t = _random_attitudes(2000, seed=3, inc=(5.0, 175.0))
    s = F.sensors_from_attitude(a, i, t)
    att = F.attitude_from_sensors(s.G.astype(jnp.float32), s.B.astype(jnp.float32))
    assert att.azimuth.dtype == jnp.float32
    assert np.max(np.abs(np.asarray(F.angle_diff(att.azimuth, a)))) < 5e-3


def test_near_vertical_is_finite_and_flagged():
    a, _, t = _random_attitudes(500, seed=4)
    i = np.concatenate([np.random.default_rng(5).uniform(0.0, 0.49, 250), 180.0 - np.random.default_rng(6).uniform(0.0, 0.49, 250)])
    i[0] = 0.0
    i[-1] = 180.0
    s = F.sensors_from_attitude(a, i, t)
    att = F.attitude_from_sensors(s.G, s.B)
    for v in att[:3]:
        assert np.all(np.isfinite(np.asarray(v)))
    assert np.all(np.asarray(att.near_vertical))
    # exactly vertical: G has no cross-axial part at all
    att0 = F.attitude_from_sensors(jnp.array([0.0, 0.0, 1.0]), jnp.array([2e4, 0.0, 4e4]))
    assert np.isfinite(float(att0.azimuth)) and bool(att0.near_vertical)


def test_vmap_and_jit_agree():
    a, i, t = _random_attitudes(64, seed=7, inc=(1, 179))
    s = F.sensors_from_attitude(a, i, t)
    direct = F.attitude_from_sensors(s.G, s.B)
    mapped = jax.jit(jax.vmap(F.attitude_from_sensors))(s.G, s.B)
    np.testing.assert_allclose(np.asarray(direct.azimuth), np.asarray(mapped.azimuth), atol=1e-12)


def test_azimuth_independent_of_toolface_zero():
    """Rolling the tool about its axis changes T but not A or I."""
    s1 = F.sensors_from_attitude(77.0, 40.0, 0.0)
    s2 = F.sensors_from_attitude(77.0, 40.0, 133.0)
    a1, a2 = F.attitude_from_sensors(s1.G, s1.B), F.attitude_from_sensors(s2.G, s2.B)
    np.testing.assert_allclose(float(a1.azimuth), float(a2.azimuth), atol=1e-10)
    np.testing.assert_allclose(float(a1.inclination), float(a2.inclination), atol=1e-10)


def test_icgo_eq1_agrees_with_standard_formulas():
    a, i, t = _random_attitudes(2000, seed=8, inc=(1.0, 179.0))
    s = F.sensors_from_attitude(a, i, t)
    gp, bp = F.paper_frame_from_tool(s.G, s.B)
    ap, ip, tp = F.attitude_icgo_eq1(gp, bp)
    assert np.max(np.abs(np.asarray(F.angle_diff(ap, a)))) < 1e-9
    assert np.max(np.abs(np.asarray(ip) - i)) < 1e-9
    assert np.max(np.abs(np.asarray(F.angle_diff(tp, t)))) < 1e-9  # no toolface offset


def test_icgo_eq1_literal_differs_in_our_frame():
    """Fed our frame directly, eq. (1) does not give our azimuth: the mapping is needed."""
    a, i, t = _random_attitudes(200, seed=9, inc=(10.0, 170.0))
    s = F.sensors_from_attitude(a, i, t)
    ap, ip, _ = F.attitude_icgo_eq1(s.G, s.B)
    np.testing.assert_allclose(np.asarray(ip), i, atol=1e-9)
    assert np.max(np.abs(np.asarray(F.angle_diff(ap, a)))) > 10.0


def test_gyro_compass_3axis_round_trip():
    a, i, t = _random_attitudes(1000, seed=10, inc=(2.0, 178.0))
    s = F.sensors_from_attitude(a, i, t, latitude_deg=40.0)
    np.testing.assert_allclose(np.linalg.norm(np.asarray(s.W), axis=-1), F.EARTH_RATE_DEG_H, rtol=1e-12)
    az = F.gyro_compass_azimuth(s.G, s.W)
    assert np.max(np.abs(np.asarray(F.angle_diff(az, a)))) < 1e-8


def test_earth_rate_value():
    np.testing.assert_allclose(F.EARTH_RATE_DEG_H, 15.041067, rtol=1e-6)


def test_patent_equations_round_trip():
    rng = np.random.default_rng(11)
    a, i, t = rng.uniform(0, 360, 500), rng.uniform(1.0, 75.0, 500), rng.uniform(0, 360, 500)
    w, acc = F.patent_sensors(a, i, t, 39.9)
    np.testing.assert_allclose(np.linalg.norm(np.asarray(w), axis=-1), F.EARTH_RATE_DEG_H, rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(np.asarray(acc), axis=-1), 1.0, rtol=1e-12)
    ap, ip, tp = F.patent_attitude(w[:, 0], w[:, 1], acc[:, 0], acc[:, 1], 39.9)
    assert np.max(np.abs(np.asarray(F.angle_diff(ap, a)))) < 1e-8
    np.testing.assert_allclose(np.asarray(ip), i, atol=1e-8)
    assert np.max(np.abs(np.asarray(F.angle_diff(tp, t)))) < 1e-8


def test_patent_accelerometers_are_minus_our_gravity_xy():
    """Patent eq. (4) a_x, a_y = -(G_x, G_y) of our frame for the same (I, T)."""
    rng = np.random.default_rng(12)
    a, i, t = rng.uniform(0, 360, 100), rng.uniform(0, 90, 100), rng.uniform(0, 360, 100)
    _, acc = F.patent_sensors(a, i, t, 30.0)
    s = F.sensors_from_attitude(a, i, t)
    np.testing.assert_allclose(np.asarray(acc[:, :2]), -np.asarray(s.G[:, :2]), atol=1e-13)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_dtype_is_kept(dtype):
    g = jnp.array([0.1, 0.2, 0.9], dtype)
    b = jnp.array([1e4, 2e3, 4e4], dtype)
    att = F.attitude_from_sensors(g, b)
    assert att.azimuth.dtype == dtype and att.inclination.dtype == dtype
