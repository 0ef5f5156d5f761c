"""The site of a calibration (icgo.models.cal_site, icgo.io.site): its mean dip and |B| against WMM or values given."""

from __future__ import annotations

import numpy as np
import pytest

from icgo.core.errors import SettingError
from icgo.io.site import site_reference
from icgo.models.cal_site import SITE_DIP_TOL_DEG, SITE_FIELD_TOL_PCT, site_check, site_values
from icgo.physics.frames import sensors_from_attitude


def _shots(n=40, F=49_000.0, dip=66.0, seed=0):
    r = np.random.default_rng(seed)
    A, I, T = r.uniform(0, 360, n), r.uniform(5, 175, n), r.uniform(0, 360, n)
    G, B = (np.asarray(x) for x in sensors_from_attitude(A, I, T, F, dip)[:2])
    return G, B


def test_site_values_are_the_field_the_shots_see_in_the_sensors_scale():
    G, B = _shots()
    # a unit-sphere calibration: R^-1 = I / F, so the sensor's own scale gives F back
    v = site_values(G, B / 49_000.0, np.eye(3) / 49_000.0)
    assert v.dip_deg == pytest.approx(66.0, abs=1e-9) and v.dip_std_deg < 1e-9
    assert v.field_nT == pytest.approx(49_000.0, rel=1e-12) and v.field_std_nT < 1e-6
    ok = site_check(v, 66.0, 49_000.0)
    assert not ok.flagged and ok.reason == "" and ok.dip_off_deg == pytest.approx(0.0, abs=1e-9)


def test_inconsistent_axes_are_flagged_against_the_site():
    G, B = _shots()
    # the accelerometer's z axis turned over (a mounting string wrong for one sensor): one dip, not the site's
    bad = site_values(G * [1, 1, -1], B / 49_000.0, np.eye(3) / 49_000.0)
    c = site_check(bad, 66.0, 49_000.0)
    assert c.flagged and abs(c.dip_off_deg) > SITE_DIP_TOL_DEG and c.reason.endswith("inconsistent axes or mounting")
    # |B| off by a factor (a unit error, or another site): flagged; within the tolerance: not
    far = site_check(site_values(G, B / 49_000.0, np.eye(3) / 30_000.0), 66.0, 49_000.0)
    assert far.flagged and "mean |B|" in far.reason and abs(far.field_off_pct) > SITE_FIELD_TOL_PCT
    near = site_check(site_values(G, B / 49_000.0, np.eye(3) / 52_000.0), 66.0, 49_000.0)
    assert not near.flagged


def test_site_settings_from_wmm_or_given_and_one_line_refusals():
    from pygeomag import GeoMag

    s = site_reference({"lat": 51.5, "lon": -0.1, "date": "2024-06-01"})
    from icgo.physics.field import decimal_year

    ref = GeoMag(coefficients_file="wmm/WMM_2020.COF").calculate(glat=51.5, glon=-0.1, alt=0.0,
                                                                 time=decimal_year("2024-06-01"))
    assert s.dip_deg == pytest.approx(ref.i, abs=1e-9) and s.field_nT == pytest.approx(ref.f, rel=1e-12)
    assert site_reference({"dip": 66.0, "field": 49_000}) == (66.0, 49_000.0, "given (site.dip, site.field)")
    assert site_reference(None) is None and site_reference({"lat": None}) is None
    for site, match in (({"lat": 100, "lon": 0, "date": 2024}, "site.lat 100"),
                        ({"lat": 51}, "site.lon, site.date missing"),
                        ({"dip": 60}, "site.dip given without site.field"),
                        ({"dip": 60, "field": 49}, "looks like uT"),
                        ({"dip": 60, "lat": 1}, "not both"),
                        ({"lat": 1, "lon": 2, "date": "1990-01-01"}, "outside the field model's years"),
                        ({"lat": 1, "lon": 2, "date": "yesterday"}, "site.date 'yesterday'"),
                        ({"bogus": 1}, "unknown key")):
        with pytest.raises(SettingError, match=match) as e:
            site_reference(site)
        assert "\n" not in str(e.value)
