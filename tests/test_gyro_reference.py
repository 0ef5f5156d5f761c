"""The gyro-derived reference M_omega (icgo.physics.strapdown, icgo.models.gyro_reference) and MISMA's comparison rows (issue 17)."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

import icgo  # noqa: F401  (float64)
from icgo.core.errors import SettingError
from icgo.datasets import drill_string
from icgo.datasets import instruments as ins
from icgo.models import calibration as cal
from icgo.models.gyro_reference import fit_to_reference, gyro_reference, gyro_term, reference_at
from icgo.physics import frames as F
from icgo.physics.strapdown import gyro_rates_from_attitude, relative_rotations, rot_exp, rot_log
from icgo.studies.misma import compare
from icgo.studies.misma.config import GyroConfig, MismaSearchConfig
from icgo.studies.misma.simulated import PARAM_NAMES, grade_dataset, identifiability

STRAIGHT = {"inclination_start_deg": 88.0, "inclination_end_deg": 86.5, "azimuth_start_deg": 120.0,
            "azimuth_end_deg": 124.0}


def _perfect(**kw):
    """rotating_drill with a perfect, noise-free gyro and noise-free accelerometer and magnetometer."""
    return drill_string.rotating_drill(0, duration_s=1200.0, gyro=ins.GyroErrors(), gyro_noise_deg_h=0.0,
                                   accel_noise_g=0.0, mag_noise_nT=0.0, **kw)


def _reference(ds, window_s=10.0, bias="none"):
    fr, meta = ds.frame, ds.meta
    return gyro_reference(fr[["gx", "gy", "gz"]].to_numpy(), fr[["wx", "wy", "wz"]].to_numpy(), fr["time_s"].to_numpy(),
                          fr["static"].to_numpy().astype(bool), meta["latitude"], meta["total_field_nT"],
                          meta["dip_deg"], window_s, bias)


def _true_field(ds):
    fr, meta = ds.frame, ds.meta
    return np.asarray(F.earth_to_tool_vector(F.field_vector_ned(meta["total_field_nT"], meta["dip_deg"]),
                                             fr["azimuth_deg"].to_numpy(), fr["inclination_deg"].to_numpy(),
                                             fr["toolface_deg"].to_numpy()))


def test_rot_log_takes_the_nominal_branch_beyond_180_deg():
    phi = np.array([0.0, 0.0, np.deg2rad(220.0)])
    R = rot_exp(phi)
    np.testing.assert_allclose(rot_log(R, phi), phi, atol=1e-12)  # scipy's principal value would be -140 deg
    np.testing.assert_allclose(rot_exp(rot_log(R, -phi)), R, atol=1e-12)


def test_gyro_rates_integrate_back_to_the_attitude_history():
    rng = np.random.default_rng(1)
    n, dt, lat = 40, 1.0, 35.0
    A, I = 60 + np.cumsum(rng.uniform(0, 0.3, n)), 30 + np.cumsum(rng.uniform(0, 0.3, n))
    rate = rng.uniform(150, 220, n)
    T = np.mod(np.cumsum(rate) * dt, 360.0)
    W = gyro_rates_from_attitude(A, I, T, dt, lat, rate)
    np.testing.assert_allclose(W[1:, 2] / 3600.0, rate[1:], atol=0.5)  # ~ the string's rate about z (deg/s)
    Q = relative_rotations(W, dt, 10, 0, n - 1)
    C = np.asarray(F.tool_to_earth(A, I, T))
    from icgo.physics.strapdown import earth_rotation

    # C^i_b(k) = C^i_b(a) Q_k with C^i_b = exp([w_ie x] t) C^n_b
    E = earth_rotation(lat, np.arange(n) * dt)
    lhs = np.einsum("kij,kjl->kil", E, C)
    rhs = np.einsum("ij,kjl->kil", E[10] @ C[10], Q)
    np.testing.assert_allclose(lhs, rhs, atol=1e-11)


def test_perfect_gyro_reproduces_the_true_field_direction_history():
    """Issue 17 "must show": perfect gyro, no noise -> M_omega equals the simulator's field to numerical precision."""
    ds = _perfect()
    ref = _reference(ds)
    true = _true_field(ds)[ref.index]
    psi, m = reference_at(jnp.asarray(true), ref)
    assert np.max(np.abs(np.asarray(m) - true)) < 1e-6  # nT, of a 52 650 nT field
    # the heading the gyro cannot see comes out as the true azimuth at each anchor
    fr = ds.frame
    from icgo.models.gyro_reference import stop_runs

    anchors = [(a + b) // 2 for a, b in stop_runs(fr["static"].to_numpy())]
    np.testing.assert_allclose(np.asarray(F.angle_diff(np.degrees(np.asarray(psi)), fr["azimuth_deg"].to_numpy()[anchors])),
                               0.0, atol=1e-7)
    B = fr[["bx", "by", "bz"]].to_numpy()[ref.index]
    x_true = np.asarray(cal.params_from_error_model(np.asarray(ds.truth["R"]), np.asarray(ds.truth["b_nT"])))
    assert float(gyro_term(jnp.asarray(x_true), jnp.asarray(B), ref)) < 1e-20
    assert float(gyro_term(jnp.asarray(cal.identity_params()), jnp.asarray(B), ref)) > 1e-3


def test_gyro_bias_estimated_at_the_stops():
    gyro = ins.GyroErrors(bias_deg_h=(180.0, -144.0, 216.0))
    ds = drill_string.rotating_drill(0, duration_s=1200.0, gyro=gyro, gyro_noise_deg_h=0.0, accel_noise_g=0.0,
                                 mag_noise_nT=0.0)
    ref = _reference(ds, bias="stop")
    # what remains is the horizontal earth rate the stop cannot separate (<= 15.04 cos(lat) deg/h)
    err = np.linalg.norm(ref.bias_deg_h - np.asarray(gyro.bias_deg_h), axis=1)
    assert np.all(err <= F.EARTH_RATE_DEG_H * np.cos(np.radians(ds.meta["latitude"])) + 1e-9)
    true = _true_field(ds)[ref.index]
    _, m = reference_at(jnp.asarray(true), ref)
    ang = np.degrees(np.arccos(np.clip(np.sum(np.asarray(m) * true, 1) / np.linalg.norm(true, axis=1) ** 2, -1, 1)))
    assert ang.max() < 0.2  # vs 216 deg/h x 45 s = 2.7 deg uncorrected
    ref_none = _reference(ds, bias="none")
    _, m0 = reference_at(jnp.asarray(_true_field(ds)[ref_none.index]), ref_none)
    assert np.max(np.linalg.norm(np.asarray(m0) - _true_field(ds)[ref_none.index], axis=1)) > 10 * np.max(
        np.linalg.norm(np.asarray(m) - true, axis=1))


def test_gyro_reference_fit_recovers_the_12_parameters_on_the_curving_hole():
    ds = _perfect()
    ref = _reference(ds)
    B = ds.frame[["bx", "by", "bz"]].to_numpy()
    x_true = np.asarray(cal.params_from_error_model(np.asarray(ds.truth["R"]), np.asarray(ds.truth["b_nT"])))
    x = fit_to_reference(B[ref.index], ref, cal.modulus_fit(B, ds.meta["total_field_nT"]))
    err = np.abs(x - x_true)
    assert err[:9].max() < 1e-3 and err[9:].max() < 5.0  # (1) and nT; the study's tolerance is 0.01 / 200 nT


def test_near_straight_hole_stays_unidentifiable_with_a_perfect_gyro():
    """The measured statement of issue 17: the gyro term does not separate the tool-axis scale from its bias.

    In a straight hole the heading at each stop is free (the gyro cannot see it),
    so the field on the tool axis is unknown and ``r33 B_z - b_z`` is one number.
    """
    ds = _perfect(**STRAIGHT)
    ref = _reference(ds)
    fr = ds.frame
    G, B = fr[["gx", "gy", "gz"]].to_numpy(), fr[["bx", "by", "bz"]].to_numpy()
    x_true = np.asarray(cal.params_from_error_model(np.asarray(ds.truth["R"]), np.asarray(ds.truth["b_nT"])))
    ref_nT = ds.meta["total_field_nT"]
    sv_mag, _ = identifiability(G, B, ref_nT, x_true)
    sv_gyro, v = identifiability(G, B, ref_nT, x_true, (ref, B[ref.index]))
    assert sv_gyro[-1] < 1e-2 and sv_mag[-1] < 1e-2
    top2 = {PARAM_NAMES[i] for i in np.argsort(-np.abs(v))[:2]}
    assert top2 == {"Rinv_33", "b_z_nT"}
    # the curving hole, by contrast, is well conditioned with the gyro term
    dc = _perfect()
    rc = _reference(dc)
    Gc, Bc = dc.frame[["gx", "gy", "gz"]].to_numpy(), dc.frame[["bx", "by", "bz"]].to_numpy()
    sv_c, _ = identifiability(Gc, Bc, ref_nT, x_true, (rc, Bc[rc.index]))
    assert sv_c[-1] > 20 * sv_gyro[-1]


def test_gyro_reference_bad_input_one_line():
    ds = _perfect()
    fr = ds.frame
    args = (fr[["gx", "gy", "gz"]].to_numpy(), fr[["wx", "wy", "wz"]].to_numpy(), fr["time_s"].to_numpy())
    with pytest.raises(ValueError, match="no static samples"):
        gyro_reference(*args, np.zeros(len(fr), bool), 35.0, 52650.0, 53.8)
    t = fr["time_s"].to_numpy().copy()
    t[5] += 0.5
    with pytest.raises(ValueError, match="uniform steps"):
        gyro_reference(args[0], args[1], t, fr["static"].to_numpy().astype(bool), 35.0, 52650.0, 53.8)
    with pytest.raises(ValueError, match="bias mode"):
        gyro_reference(*args, fr["static"].to_numpy().astype(bool), 35.0, 52650.0, 53.8, bias="kalman")


@pytest.mark.parametrize("section, value, needle", [
    ("gyro", {"term": "scalar"}, "simulated.gyro.term must be one of vector, off"),
    ("gyro", {"bias": "kalman"}, "simulated.gyro.bias must be one of stop, none"),
    ("gyro", {"sweep": [1.0, -1.0]}, "simulated.gyro.sweep must be a list of numbers >= 0"),
    ("gyro", {"window_s": -1.0}, "simulated.gyro.window_s must be a number >= 0"),
    ("misma", {"bounds": "wide"}, "simulated.misma.bounds must be one of around_u, paper"),
])
def test_gyro_and_bounds_settings_fail_in_one_line(section, value, needle):
    cls = {"gyro": GyroConfig, "misma": MismaSearchConfig}[section]
    with pytest.raises(SettingError, match=needle.replace(".", r"\.")):
        cls(**value)


def test_paper_box_unit_coordinates_and_rows():
    from icgo.optim.misma import paper_bounds

    lb, ub = paper_bounds()
    np.testing.assert_array_equal(lb, np.r_[np.full(9, -68.0), np.full(3, -68_000.0)])
    np.testing.assert_array_equal(ub, np.r_[np.full(9, 128.0), np.full(3, 128_000.0)])
    seen = []
    f = compare.UnitBoxFitness(lambda pop, aux=None: seen.append(np.asarray(pop)) or jnp.sum(pop, 1), lb, ub)
    f(jnp.asarray([np.zeros(12), np.ones(12)]))
    np.testing.assert_allclose(seen[0], np.vstack([lb, ub]))
    # each contrast changes one thing between its two rows, and the headline follows the settings
    for name, a, b in compare.contrasts(True):
        assert sum(x != y for x, y in zip(a, b)) <= 2, name  # gyro term + its box move together
    assert compare.headline_misma(True, "paper") == compare.Row("MISMA", "paper", "unit", "mag+gyro")
    assert compare.headline_misma(False, "around_u") == compare.Row("MISMA", "U", "unit", "mag")
    assert all(r.objective == "mag" for r in compare.rows(False))


def test_gyro_grade_factor_scales_every_error():
    g = drill_string.MISMA_GYRO
    assert g.scaled(1.0) == ins.GyroErrors(*[tuple(map(float, v)) if not isinstance(v[0], tuple) else
                                             tuple(tuple(map(float, r)) for r in v) for v in g])
    z = g.scaled(0.0)
    assert all(np.all(np.asarray(v) == 0) for v in z)
    ds = grade_dataset(drill_string.rotating_drill(0, duration_s=600.0), {"duration_s": 600.0}, 0.0)
    assert ds.truth["gyro_noise_deg_h"] == 0.0 and np.all(np.asarray(ds.truth["gyro"]["bias_deg_h"]) == 0)
    # the magnetometer data do not depend on the gyro grade
    np.testing.assert_array_equal(ds.frame[["bx", "by", "bz"]].to_numpy(),
                                  drill_string.rotating_drill(0, duration_s=600.0).frame[["bx", "by", "bz"]].to_numpy())
