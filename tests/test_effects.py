"""Each effect, injected alone into clean stations, changes exactly what its physics says."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from icgo.physics import effects as E
from icgo.physics import frames as F


@pytest.fixture(scope="module")
def stations():
    rng = np.random.default_rng(0)
    n = 200
    a, i, t = rng.uniform(0, 360, n), rng.uniform(5, 175, n), rng.uniform(0, 360, n)
    s = F.sensors_from_attitude(a, i, t, total_field_nT=50_000.0, dip_deg=60.0)
    return dict(a=a, i=i, t=t, G=s.G, B=s.B, C=F.tool_to_earth(a, i, t))


def _apply(name, p, st):
    return E.apply_effects({name: jnp.asarray(p, jnp.float64)}, st["G"], st["B"], st["C"])


def test_vocabulary_is_complete():
    assert set(E.EFFECTS) == {
        "hard_iron", "external_field", "mag_scale", "mag_cross_coupling",
        "mag_misalignment", "accel_bias", "accel_scale", "magnetic_body",
    }
    for e in E.EFFECTS.values():
        assert e.n_params == (9 if e.name == "magnetic_body" else 3) and e.description
        assert e.typical_each().shape == (e.n_params,) and np.all(e.typical_each() > 0)
    assert E.names_for_rig(None) == tuple(n for n in E.ORDER if n != "magnetic_body")


def test_hard_iron_constant_in_tool_frame(stations):
    p = np.array([300.0, -200.0, 700.0])
    G, B = _apply("hard_iron", p, stations)
    np.testing.assert_allclose(np.asarray(B - stations["B"]), np.broadcast_to(p, B.shape), atol=1e-9)
    np.testing.assert_array_equal(np.asarray(G), np.asarray(stations["G"]))


def test_external_field_constant_in_earth_frame(stations):
    p = np.array([150.0, -80.0, 40.0])
    G, B = _apply("external_field", p, stations)
    d_earth = np.asarray(F.tool_to_earth_vector(B - stations["B"], stations["a"], stations["i"], stations["t"]))
    np.testing.assert_allclose(d_earth, np.broadcast_to(p, d_earth.shape), atol=1e-9)
    d_tool = np.asarray(B - stations["B"])
    assert np.std(d_tool, axis=0).max() > 50.0  # not constant in the tool frame
    np.testing.assert_array_equal(np.asarray(G), np.asarray(stations["G"]))


def test_external_field_is_a_different_reference_field(stations):
    """Adding an earth-fixed field equals simulating with the summed field vector."""
    p = np.array([150.0, -80.0, 40.0])
    _, B = _apply("external_field", p, stations)
    total = np.asarray(F.field_vector_ned(50_000.0, 60.0)) + p
    ref = F.earth_to_tool_vector(total, stations["a"], stations["i"], stations["t"])
    np.testing.assert_allclose(np.asarray(B), np.asarray(ref), atol=1e-9)


def test_mag_scale_is_diagonal(stations):
    p = np.array([0.01, -0.02, 0.005])
    _, B = _apply("mag_scale", p, stations)
    np.testing.assert_allclose(np.asarray(B), np.asarray(stations["B"]) * (1 + p), rtol=1e-14)


def test_mag_cross_coupling_symmetric_offdiagonal(stations):
    p = np.array([0.01, -0.02, 0.005])
    _, B = _apply("mag_cross_coupling", p, stations)
    m = np.array([[1, p[0], p[1]], [p[0], 1, p[2]], [p[1], p[2], 1]])
    np.testing.assert_allclose(np.asarray(B), np.asarray(stations["B"]) @ m.T, rtol=1e-12)


def test_mag_misalignment_keeps_norm_and_first_order(stations):
    p = np.array([0.3, -0.5, 0.2])  # deg
    _, B = _apply("mag_misalignment", p, stations)
    np.testing.assert_allclose(np.linalg.norm(B, axis=-1), np.linalg.norm(stations["B"], axis=-1), rtol=1e-13)
    w = np.deg2rad(p)
    first = np.asarray(stations["B"]) + np.cross(w, np.asarray(stations["B"]))
    np.testing.assert_allclose(np.asarray(B), first, atol=50_000 * np.sum(w**2))
    # the dot product with G changes (it is what the dip-check sees)
    assert np.max(np.abs(np.sum(np.asarray(B - stations["B"]) * np.asarray(stations["G"]), -1))) > 10.0


def test_rotation_from_vector_matches_scipy():
    from scipy.spatial.transform import Rotation

    w = np.array([10.0, -20.0, 5.0])
    np.testing.assert_allclose(np.asarray(E.rotation_from_vector(w)),
                               Rotation.from_rotvec(w, degrees=True).as_matrix(), atol=1e-14)
    np.testing.assert_allclose(np.asarray(E.rotation_from_vector(np.zeros(3))), np.eye(3))


def test_accel_effects(stations):
    b = np.array([1e-3, -2e-3, 5e-4])
    G, B = _apply("accel_bias", b, stations)
    np.testing.assert_allclose(np.asarray(G - stations["G"]), np.broadcast_to(b, G.shape), atol=1e-15)
    np.testing.assert_array_equal(np.asarray(B), np.asarray(stations["B"]))
    s = np.array([1e-3, -2e-3, 5e-4])
    G, _ = _apply("accel_scale", s, stations)
    np.testing.assert_allclose(np.asarray(G), np.asarray(stations["G"]) * (1 + s), rtol=1e-14)


def test_composition_is_twelve_parameter_model(stations):
    params = {
        "hard_iron": jnp.array([100.0, -50.0, 300.0]),
        "mag_misalignment": jnp.array([0.2, 0.1, -0.3]),
        "mag_scale": jnp.array([0.01, -0.01, 0.02]),
        "mag_cross_coupling": jnp.array([0.003, -0.002, 0.001]),
    }
    _, B = E.apply_effects(params, stations["G"], stations["B"], stations["C"])
    r = np.asarray(E.twelve_parameter_matrix(params))
    np.testing.assert_allclose(np.asarray(B), np.asarray(stations["B"]) @ r.T + np.asarray(params["hard_iron"]), rtol=1e-12)
    # dict order does not matter
    rev = dict(reversed(list(params.items())))
    _, B2 = E.apply_effects(rev, stations["G"], stations["B"], stations["C"])
    np.testing.assert_array_equal(np.asarray(B), np.asarray(B2))


def test_differentiable_and_jittable(stations):
    def loss(p):
        _, B = E.apply_effects({"mag_misalignment": p, "hard_iron": p * 100.0}, stations["G"], stations["B"], stations["C"])
        return jnp.sum(B**2)

    g0 = jax.jit(jax.grad(loss))(jnp.zeros(3))
    assert np.all(np.isfinite(np.asarray(g0)))
    eps = 1e-6
    num = [(loss(jnp.eye(3)[k] * eps) - loss(-jnp.eye(3)[k] * eps)) / (2 * eps) for k in range(3)]
    np.testing.assert_allclose(np.asarray(g0), np.asarray(num), rtol=1e-5)


def test_unknown_and_malformed():
    g = jnp.zeros((1, 3))
    with pytest.raises(ValueError, match="unknown effect"):
        E.apply_effects({"soft_iron": jnp.zeros(3)}, g, g, jnp.eye(3)[None])
    with pytest.raises(ValueError, match="expected 3 parameters"):
        E.apply_effects({"hard_iron": jnp.zeros(2)}, g, g, jnp.eye(3)[None])


def test_register_new_effect():
    e = E.Effect("temp_bias_test", 1, "bias growing with row index", "nT", 10.0, lambda p, G, B, C: (G, B + p[0]))
    try:
        E.register(e, order_after="hard_iron")
        assert E.ORDER.index("temp_bias_test") == E.ORDER.index("hard_iron") + 1
        with pytest.raises(ValueError, match="already registered"):
            E.register(e)
    finally:
        E.EFFECTS.pop("temp_bias_test", None)
        if "temp_bias_test" in E.ORDER:
            E.ORDER.remove("temp_bias_test")
