"""icgo.artifacts.calibration: the 12-parameter calibration artifact (apply, save/load round trip, errors)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

import icgo  # noqa: F401
from icgo.core.errors import ModelError
from icgo.models import calibration as cal
from icgo.artifacts.calibration import MagCalibration, mag_calibration
from icgo.models.calibration_params import CalibrationParams
from icgo.artifacts.registry import load_model
from icgo.physics.frames import angle_diff, sensors_from_attitude

R_TRUE = np.array([[1.04, 0.02, -0.01], [-0.02, 0.97, 0.03], [0.01, -0.02, 1.02]])
B_TRUE = np.array([1500.0, -900.0, 600.0])


def _survey(n=40, seed=0):
    rng = np.random.default_rng(seed)
    A, I, T = rng.uniform(0, 360, n), rng.uniform(10, 170, n), rng.uniform(0, 360, n)
    s = sensors_from_attitude(A, I, T, 50_000.0, 60.0)
    G, B = np.asarray(s.G), np.asarray(cal.distort(R_TRUE, B_TRUE, s.B))
    frame = pd.DataFrame({"station": np.arange(n), "gx": G[:, 0], "gy": G[:, 1], "gz": G[:, 2],
                          "bx": B[:, 0], "by": B[:, 1], "bz": B[:, 2]})
    return frame, G, B, A, I


def test_true_parameters_recover_field_attitude_and_dip():
    frame, G, B, A, I = _survey()
    x = np.asarray(cal.params_from_error_model(R_TRUE, B_TRUE))
    m = mag_calibration("twelve", x, G, B, {"note": "true parameters"})
    out = m.apply(frame)
    np.testing.assert_allclose(out["b_total_nT"], 50_000.0, rtol=1e-9)
    np.testing.assert_allclose(out["dip_compensated_deg"], 60.0, atol=1e-7)
    np.testing.assert_allclose(np.asarray(angle_diff(out["azimuth_compensated"].to_numpy(), A)), 0.0, atol=1e-7)
    np.testing.assert_allclose(out["inclination_compensated"], I, atol=1e-7)
    ident = mag_calibration("twelve", np.asarray(cal.identity_params()), G, B, {}).apply(frame)
    np.testing.assert_array_equal(ident[["bx_corrected", "by_corrected", "bz_corrected"]].to_numpy(), B)
    assert np.abs(ident["b_total_nT"] - 50_000.0).max() > 1000.0  # the raw readings are distorted


def test_field_only_frame_gives_no_attitude_and_scale_applies():
    frame, G, B, _, _ = _survey()
    x = np.asarray(cal.params_from_error_model(R_TRUE, B_TRUE)) / np.r_[np.full(9, 50_000.0), np.ones(3)]
    m = mag_calibration("ellipsoid", x, G, B, {}, field_scale_nT=50_000.0)  # a unit-sphere fit reported in nT
    out = m.apply(frame[["bx", "by", "bz"]])
    assert list(out.columns) == ["bx_corrected", "by_corrected", "bz_corrected", "b_total_nT"]
    np.testing.assert_allclose(out["b_total_nT"], 50_000.0, rtol=1e-9)


def test_alignment_rotates_both_sensors():
    frame, G, B, _, _ = _survey()
    x = np.asarray(cal.params_from_error_model(R_TRUE, B_TRUE))
    c, s = np.cos(0.3), np.sin(0.3)
    Q = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    plain = mag_calibration("misma", x, G, B, {})
    rot = mag_calibration("misma", x, G, B, {}, alignment=Q)
    assert rot.axis_aligned and not plain.axis_aligned
    Gp, Bp = plain.corrected(G, B)
    Gr, Br = rot.corrected(G, B)
    np.testing.assert_array_equal(Br, Bp @ Q.T)
    np.testing.assert_array_equal(Gr, Gp @ Q.T)
    # a rotation about z changes toolface only: inclination and azimuth stay
    a, b = plain.apply(frame), rot.apply(frame)
    np.testing.assert_allclose(np.asarray(angle_diff(a.azimuth_compensated.to_numpy(), b.azimuth_compensated.to_numpy())), 0, atol=1e-9)
    assert np.abs(np.asarray(angle_diff(a.toolface_compensated.to_numpy(), b.toolface_compensated.to_numpy()))).min() > 1.0


def test_save_load_apply_is_bitwise(tmp_path):
    frame, G, B, _, _ = _survey()
    new, _, _, _, _ = _survey(seed=5)
    x = np.asarray(cal.params_from_error_model(R_TRUE, B_TRUE)) + 1e-3
    xg = np.r_[np.eye(3).ravel() * 1.01, 0.01, -0.02, 0.005]
    Q = np.linalg.qr(np.random.default_rng(1).standard_normal((3, 3)))[0]
    models = [mag_calibration("misma", x, G, B, {"repeat": 2}),
              mag_calibration("twelve", x, G, B, {}, x_accel=xg, alignment=Q, field_scale_nT=123.4)]
    for i, m in enumerate(models):
        before = m.apply(new)
        path = m.save(tmp_path / f"cal{i}")
        back = load_model(path)
        assert isinstance(back, MagCalibration) and back.method == m.method and back.config == m.config
        pd.testing.assert_frame_equal(back.apply(new), before, check_exact=True)
        assert back.data_hash == m.data_hash and back.domain == m.domain
    assert load_model(tmp_path / "cal0").params.x_accel is None


def test_bad_models_are_refused_in_one_line():
    frame, G, B, _, _ = _survey()
    x = np.asarray(cal.identity_params())
    for kwargs, msg in [(dict(method="magic"), "method"), (dict(params=CalibrationParams(np.zeros(11))), "x_mag"),
                        (dict(field_scale_nT=0.0), "field_scale_nT"), (dict(axis_aligned=True), "axis_aligned")]:
        args = dict(config={}, data_hash="", domain={}, method="misma", axis_aligned=False, field_scale_nT=1.0,
                    params=CalibrationParams(x))
        with pytest.raises(ModelError, match=msg) as e:
            MagCalibration(**{**args, **kwargs})
        assert "\n" not in str(e.value)
    m = mag_calibration("misma", x, G, B, {})
    with pytest.raises(ModelError, match="bz"):
        m.apply(frame.drop(columns=["bz"]))
