"""Reference field: NOAA's published WMM test values and the metadata path."""

import numpy as np
import pytest

from icgo.physics import field

# NOAA WMM2020 test values (WMM2020testvalues.pdf): year, alt km, lat, lon, F nT, I deg, D deg.
# Published to 0.1 nT and 0.01 deg.
WMM2020_TEST_VALUES = [
    (2020.0, 0, 80, 0, 55000.1, 83.14, -1.28),
    (2020.0, 0, 0, 120, 41104.9, -15.42, 0.16),
    (2020.0, 0, -80, 240, 55120.6, -72.20, 69.36),
    (2020.0, 100, 80, 0, 52802.0, 83.19, -1.70),
    (2022.5, 0, 0, 120, 41130.5, -15.24, -0.06),
    (2022.5, 100, -80, 240, 52235.4, -72.27, 68.55),
]


@pytest.mark.parametrize("year,alt,lat,lon,f,inc,dec", WMM2020_TEST_VALUES)
def test_wmm2020_published_test_values(year, alt, lat, lon, f, inc, dec):
    ref = field.reference_field(lat, lon, alt, year, model="WMM2020")
    assert abs(ref.total_field_nT - f) <= 0.05 + 1e-9
    assert abs(ref.dip_deg - inc) <= 0.005 + 1e-9
    assert abs(ref.declination_deg - dec) <= 0.005 + 1e-9


def test_components_consistent():
    ref = field.reference_field(30.0, 114.0, 0.0, "2025-06-01")
    np.testing.assert_allclose(np.hypot(ref.horizontal_nT, ref.vertical_nT), ref.total_field_nT, rtol=1e-12)
    assert 40_000 < ref.total_field_nT < 60_000 and 30 < ref.dip_deg < 60


def test_decimal_year():
    assert field.decimal_year("2024-01-01") == 2024.0
    assert abs(field.decimal_year("2024-07-02") - (2024 + 183 / 366)) < 1e-12
    with pytest.raises(ValueError, match="date"):
        field.decimal_year("not a date")


def test_metadata_paths():
    direct = field.field_from_metadata({"total_field_nT": 50000, "dip_deg": 60})
    assert direct == field.FieldReference(50000.0, 60.0, 0.0)
    site = field.field_from_metadata({"latitude": 80, "longitude": 0, "altitude_km": 0, "date": 2020.0})
    assert abs(site.total_field_nT - 55000.1) < 0.1
    with pytest.raises(ValueError, match="total_field_nT"):
        field.field_from_metadata({"dip_deg": 60})


def test_bad_site():
    with pytest.raises(ValueError, match="latitude"):
        field.reference_field(95, 0)
    with pytest.raises(ValueError, match="field model"):
        field.reference_field(0, 0, model="IGRF99")


def test_earth_rate_vector():
    v = field.earth_rate_vector_ned(90.0)
    np.testing.assert_allclose(v, [0, 0, -15.041067], atol=1e-5)
