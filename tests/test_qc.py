"""Survey QC (icgo.physics.qc) against a hand computation, and its bands' validation."""

from __future__ import annotations

import numpy as np
import pytest

from icgo.core.errors import SettingError
from icgo.physics.frames import field_vector_ned, sensors_from_attitude
from icgo.physics.qc import QCBands, survey_qc


def test_flags_match_a_hand_computation():
    # three stations at a true attitude, then one with |B| off by 400 nT, one with G off by 3 mg
    A, I, T = np.array([30.0, 60.0, 90.0]), np.array([20.0, 45.0, 80.0]), np.array([0.0, 90.0, 200.0])
    G, B = (np.asarray(x) for x in sensors_from_attitude(A, I, T, 50_000.0, 60.0)[:2])
    B = B.copy()
    G = G.copy()
    B[1] *= (50_400.0 / 50_000.0)
    G[2] *= 1.003
    res = survey_qc(G, B, 50_000.0, 60.0, 1.0)
    t = res.table
    np.testing.assert_allclose(t.b_total_nT, [50_000.0, 50_400.0, 50_000.0], rtol=1e-12)
    np.testing.assert_allclose(t.dip_deg, 60.0, atol=1e-9)  # scaling a vector keeps the dip
    assert list(t.qc_b) == [False, True, False] and list(t.qc_g) == [False, False, True]
    assert list(t.qc_dip) == [False, False, False] and list(t.qc_pass) == [True, False, False]
    assert res.counts == {"n": 3, "g": 1, "b": 1, "dip": 0, "any": 2}
    assert survey_qc(G, B, 50_000.0, 60.0, prefix="raw_").table.columns[0] == "raw_g_total_g"


def test_dip_flag_and_band_settings():
    G, B = (np.asarray(x) for x in sensors_from_attitude(np.array([10.0]), np.array([30.0]), np.array([0.0]),
                                                          50_000.0, 60.3)[:2])
    assert survey_qc(G, B, 50_000.0, 60.0).counts["dip"] == 1            # 0.3 deg > 0.25
    assert survey_qc(G, B, 50_000.0, 60.0, bands=QCBands(dip_tol_deg=0.5)).counts["dip"] == 0
    assert np.allclose(field_vector_ned(50_000.0, 60.0)[2], 50_000.0 * np.sin(np.radians(60.0)))
    with pytest.raises(SettingError, match="b_tol_nT must be a number > 0"):
        QCBands(b_tol_nT=0.0)


def test_earth_rate_check_and_the_summary_sentence():
    from icgo.physics.frames import EARTH_RATE_DEG_H
    from icgo.physics.qc import earth_rate_qc, qc_sentence

    rate = float(EARTH_RATE_DEG_H)
    np.testing.assert_allclose(rate, 15.041, atol=1e-3)  # 7.2921150e-5 rad/s in deg/h
    W = np.array([[rate, 0.0, 0.0], [0.0, rate + 0.4, 0.0], [0.0, 0.0, rate - 0.6]])
    res = earth_rate_qc(W)
    np.testing.assert_allclose(res.table.dw_deg_h, [0.0, 0.4, -0.6], atol=1e-12)
    assert res.counts == {"n": 3, "rate": 1, "any": 1}
    assert earth_rate_qc(W, tol_deg_h=0.3).counts["rate"] == 2
    with pytest.raises(SettingError, match="tol_deg_h must be a number > 0"):
        earth_rate_qc(W, tol_deg_h=-1.0)
    s = qc_sentence({"raw": {"n": 5, "g": 0, "b": 2, "dip": 1, "any": 3}}, QCBands(b_tol_nT=200.0))
    assert "|B| 200 nT" in s and "raw: 3 of 5 stations flagged (|G| 0, |B| 2, dip 1)" in s
