"""The position-dependent effect ``magnetic_body``: its dipole field against magpylib (a peer library), its
turntable geometry, the rig it needs, and the workflow on data in which a body is hidden: a magpylib cuboid
magnet (a body of another kind than the effect's point dipole) and the project's pole-pair casing (lab_casing),
with the controls (no body; a body seen from the pivot, no lever arm)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from icgo import discrepancy as D
from icgo.core.errors import DataError
from icgo.discrepancy.stations import rig_from_meta
from icgo.physics import effects as fx
from icgo.physics.dipole import body_start, dipole_field, sensor_positions
from icgo.physics.frames import sensors_from_attitude, tool_to_earth, toolface_from_g

jax.config.update("jax_enable_x64", True)
magpy = pytest.importorskip("magpylib")

LEVER = (0.02, 0.0, 0.15)
#: A 6 cm NdFeB-like cube, magnetized 1.4e5 A/m (about 30 A m^2), 1 m from the pivot.
CUBE = dict(position=(0.3, 0.9, 0.2), size=0.06, magnetization=(1.0e5, -0.9e5, 0.3e5))


def _cuboid_field(points):
    cube = magpy.magnet.Cuboid(dimension=(CUBE["size"],) * 3, polarization=tuple(
        4e-7 * np.pi * np.asarray(CUBE["magnetization"])), position=CUBE["position"])
    return np.asarray(cube.getB(np.asarray(points))) * 1e9  # T -> nT


def test_dipole_field_matches_magpylib_dipole():
    rng = np.random.default_rng(0)
    pts = rng.normal(size=(50, 3))
    pos, m = np.array([0.1, -0.2, 0.3]), np.array([12.0, -5.0, 7.0])
    ref = np.asarray(magpy.misc.Dipole(moment=m, position=pos).getB(pts)) * 1e9
    # magpylib uses the CODATA mu0 (1 + 5.5e-10 of 4 pi 1e-7), icgo the exact 4 pi 1e-7
    np.testing.assert_allclose(np.asarray(dipole_field(jnp.asarray(pts), pos, m)), ref, rtol=1e-9)
    # finite (0) at the dipole itself, with finite derivatives
    assert np.all(np.asarray(dipole_field(jnp.asarray(pos), pos, m)) == 0.0)
    g = jax.jacfwd(lambda p: dipole_field(jnp.asarray(pos), p, m))(jnp.asarray(pos))
    assert np.all(np.isfinite(np.asarray(g)))


def test_far_cube_is_a_dipole():
    """The cube's own field (magpylib, closed form) is a point dipole of moment M V far from it (to 0.1 %)."""
    pts = np.array([[0.0, 0.0, 0.0], [0.1, -0.1, 0.05]])
    m = np.asarray(CUBE["magnetization"]) * CUBE["size"] ** 3
    np.testing.assert_allclose(np.asarray(dipole_field(jnp.asarray(pts), np.asarray(CUBE["position"]), m)),
                               _cuboid_field(pts), rtol=2e-3, atol=2.0)


def test_magnetic_body_apply_geometry():
    """B_tool = C^T dipole(C l - p); with no lever arm it is an earth-fixed constant, external_field exactly."""
    A, I, T = np.array([10.0, 200.0, 95.0]), np.array([90.0, 45.0, 120.0]), np.array([0.0, 33.0, 271.0])
    C = tool_to_earth(A, I, T)
    p = np.array([20.0, -8.0, 3.0, 0.4, 0.9, -0.1, *LEVER])
    _, B = fx.EFFECTS["magnetic_body"].apply(jnp.asarray(p), jnp.zeros((3, 3)), jnp.zeros((3, 3)), C)
    r = np.asarray(C) @ np.asarray(LEVER)
    want = np.einsum("nji,nj->ni", np.asarray(C), np.asarray(dipole_field(jnp.asarray(r), p[3:6], p[:3])))
    np.testing.assert_allclose(np.asarray(B), want, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(sensor_positions(C, jnp.asarray(LEVER))), r, rtol=1e-12)
    p0 = p.copy()
    p0[6:] = 0.0
    _, B0 = fx.EFFECTS["magnetic_body"].apply(jnp.asarray(p0), jnp.zeros((3, 3)), jnp.zeros((3, 3)), C)
    e = np.asarray(dipole_field(jnp.zeros(3), p[3:6], p[:3]))
    _, Be = fx.EFFECTS["external_field"].apply(jnp.asarray(e), jnp.zeros((3, 3)), jnp.zeros((3, 3)), C)
    np.testing.assert_allclose(np.asarray(B0), np.asarray(Be), rtol=1e-12, atol=1e-9)


def test_rig_gates_the_effect():
    assert "magnetic_body" in fx.ORDER and "magnetic_body" not in fx.names_for_rig(None)
    assert "magnetic_body" in fx.names_for_rig("turntable")
    assert rig_from_meta({}) == (None, None)
    assert rig_from_meta({"rig": "turntable", "sensor_lever_m": [0.01, 0, 0.2]}) == ("turntable", (0.01, 0.0, 0.2))
    for bad in ({"rig": "carousel"}, {"rig": "turntable", "sensor_lever_m": [1, 2]},
                {"sensor_lever_m": [0.0, 0.0, 0.1]}):
        with pytest.raises(DataError, match="rig|sensor_lever_m") as e:
            rig_from_meta(bad, "x.meta.json")
        assert "\n" not in str(e.value) and "x.meta.json" in str(e.value)
    st = _stations(None, lever=LEVER)._replace(rig=None, lever_m=None)
    with pytest.raises(ValueError, match="rig"):
        D.run_workflow(st, D.WorkflowConfig(candidates=("hard_iron", "magnetic_body")))


def _stations(body, lever=LEVER, hard_iron=(400.0, -300.0, 250.0), seed=0):
    """A turntable plan (8 azimuths x 18 toolfaces at inclination 90 and 60 deg) with a hidden hard_iron and
    a body (``"cube"``: the magpylib cube; None: none), 15 nT / 0.3 mg noise."""
    A, T = np.meshgrid(np.arange(8) * 45.0 + 10.0, np.arange(18) * 20.0)
    A = np.concatenate([A.ravel(), A.ravel()])
    T = np.concatenate([T.ravel(), T.ravel() + 10.0])
    I = np.repeat([90.0, 60.0], A.size // 2)
    field = (50_000.0, 60.0, 0.0)
    s = sensors_from_attitude(A, I, T, *field)
    C = np.asarray(tool_to_earth(A, I, T))
    B = np.asarray(s.B) + np.asarray(hard_iron)
    if body == "cube":
        B = B + np.einsum("nji,nj->ni", C, _cuboid_field(C @ np.asarray(lever)))
    k1, k2 = jax.random.split(jax.random.PRNGKey(seed))
    G = np.asarray(s.G) + D.NOISE.sigma_g * np.asarray(jax.random.normal(k1, (A.size, 3)))
    B = B + D.NOISE.sigma_b_nT * np.asarray(jax.random.normal(k2, (A.size, 3)))
    return D.Stations(G, B, A, I, field=field, rig="turntable", lever_m=tuple(lever))


CONFIG = D.WorkflowConfig(candidates=("hard_iron", "external_field", "magnetic_body"), max_effects=3, k_folds=4)


def test_body_start_recovers_a_dipole():
    st = _stations("cube", hard_iron=(0.0, 0.0, 0.0))
    T = np.asarray(toolface_from_g(st.G))
    C = np.asarray(tool_to_earth(st.azimuth, st.inclination, T))
    s = sensors_from_attitude(st.azimuth, st.inclination, T, *st.field)
    start = body_start(st.B - np.asarray(s.B), C, np.ones(st.n), np.r_[[np.nan] * 6, LEVER])
    # the grid's best position lies near the cube (grid spacing ~ 0.3 m at 1 m)
    assert np.linalg.norm(start[3:6] - np.asarray(CUBE["position"])) < 0.5
    np.testing.assert_array_equal(start[6:], LEVER)


@pytest.mark.slow
def test_workflow_names_a_hidden_cube():
    res = D.run_workflow(_stations("cube"), CONFIG)
    assert "magnetic_body" in res.named and "hard_iron" in res.named, D.verdict(res)
    assert res.kind == "explained", D.verdict(res)
    assert res.heldout < 2.0 * res.noise_floor
    assert res.gaps[-1].mag_rms_nT < 0.1 * res.gaps[0].mag_rms_nT


@pytest.mark.slow
def test_control_no_body():
    res = D.run_workflow(_stations(None), CONFIG)
    assert "magnetic_body" not in res.model and res.named == ["hard_iron"], D.verdict(res)
    assert res.kind == "explained"


@pytest.mark.slow
def test_control_body_seen_from_the_pivot():
    """No lever arm: the body's field is constant at the sensor, external_field's; the workflow says so."""
    res = D.run_workflow(_stations("cube", lever=(0.0, 0.0, 0.0)), CONFIG)
    v = D.verdict(res)
    assert res.kind == "not_separable", v
    step = next(s for s in res.steps if not s.separable)
    assert {step.name, *step.equivalent} >= {"external_field", "magnetic_body"}, v
    assert "not separable" in v and "magnetic_body" in v and "external_field" in v


@pytest.mark.slow
def test_lab_casing_names_the_casing():
    """The goal on the project's pole-pair casing (lab_casing, every row its 3-sigma filter keeps): the workflow
    names magnetic_body, the magnetometer remainder falls below 2x noise, and the two spiked rows (7,000 and
    -9,000 nT on one axis) are named as robust outliers and left out."""
    from icgo.datasets.casing_stations import lab_casing
    from icgo.io import recording

    ds = lab_casing(0)
    st = D.stations_from_recording(recording.validate(ds.frame, ds.meta, source="lab_casing"))
    assert st.rig == "turntable" and st.lever_m == (0.015, 0.0, 0.15)
    res = D.run_workflow(st)
    assert "magnetic_body" in res.named, D.verdict(res)
    assert res.pattern.b_rms_nT < 2.0 * res.config.sigma_b_nT, D.verdict(res)
    spiked = {o.station for o in res.outliers}
    assert len(spiked) == 2 and {o.component for o in res.outliers} <= {"bx", "by", "bz"}
    assert all(abs(o.residual) > 5000.0 for o in res.outliers)
