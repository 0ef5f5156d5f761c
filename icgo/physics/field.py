"""Reference geomagnetic field (offline WMM) and the earth-rate vector.

The field comes from the World Magnetic Model through ``pygeomag`` (offline,
coefficients shipped with the package; reproduces NOAA's published test values).
Everything here is host-side (numpy / float), called once per data set, not in
a jitted hot path.
"""

from __future__ import annotations

import datetime as _dt
from typing import NamedTuple

import numpy as np

from icgo.physics.frames import EARTH_RATE_DEG_H

#: WMM coefficient files shipped with pygeomag, by epoch.
WMM_MODELS = {"WMM2020": "wmm/WMM_2020.COF", "WMM2025": "wmm/WMM_2025.COF"}


class FieldReference(NamedTuple):
    """Reference geomagnetic field at a site.

    total_field_nT: |B| (nT). dip_deg: inclination of the field, positive down (deg).
    declination_deg: angle from true north to magnetic north, positive east (deg).
    """

    total_field_nT: float
    dip_deg: float
    declination_deg: float

    @property
    def horizontal_nT(self) -> float:
        return self.total_field_nT * float(np.cos(np.deg2rad(self.dip_deg)))

    @property
    def vertical_nT(self) -> float:
        return self.total_field_nT * float(np.sin(np.deg2rad(self.dip_deg)))


#: Years the bundled field models cover (WMM2020: 2020-2025, WMM2025: 2025-2030); outside them the
#: field is extrapolated (``reference_field`` still answers; the data reader gives a notice).
FIELD_MODEL_YEARS = (2020.0, 2030.0)


def decimal_year(date) -> float:
    """Decimal year from a float/int year, ``datetime.date``/``datetime`` or ISO string ``YYYY-MM-DD``."""
    if isinstance(date, (int, float, np.floating, np.integer)):
        return float(date)
    if isinstance(date, str):
        try:
            date = _dt.date.fromisoformat(date.strip()[:10])
        except ValueError:
            raise ValueError(f"date {date!r}: expected YYYY-MM-DD or a decimal year") from None
    if isinstance(date, _dt.datetime):
        date = date.date()
    if not isinstance(date, _dt.date):
        raise ValueError(f"date {date!r}: expected YYYY-MM-DD, a date or a decimal year")
    start = _dt.date(date.year, 1, 1)
    days = (_dt.date(date.year + 1, 1, 1) - start).days
    return date.year + (date - start).days / days


def reference_field(latitude, longitude, altitude_km=0.0, date=2025.0, model=None) -> FieldReference:
    """Geomagnetic field from the offline WMM at a site and date.

    Args:
        latitude: geodetic latitude, deg in [-90, 90].
        longitude: deg in [-180, 360].
        altitude_km: height above the WGS-84 ellipsoid, km.
        date: decimal year, ``datetime.date`` or ``YYYY-MM-DD``.
        model: ``"WMM2020"`` or ``"WMM2025"``; default picks the model whose
            5-year life span contains the date (WMM2025 outside both).
    Returns:
        FieldReference(total_field_nT, dip_deg, declination_deg).
    """
    from pygeomag import GeoMag

    lat, lon, alt = float(latitude), float(longitude), float(altitude_km)
    if not -90.0 <= lat <= 90.0:
        raise ValueError(f"latitude {lat}: must be in [-90, 90] deg")
    if not -180.0 <= lon <= 360.0:
        raise ValueError(f"longitude {lon}: must be in [-180, 360] deg")
    year = decimal_year(date)
    if model is None:
        model = "WMM2020" if 2020.0 <= year < 2025.0 else "WMM2025"
    if model not in WMM_MODELS:
        raise ValueError(f"field model {model!r}: choose one of {sorted(WMM_MODELS)}")
    gm = GeoMag(coefficients_file=WMM_MODELS[model])
    r = gm.calculate(glat=lat, glon=lon, alt=alt, time=year, allow_date_outside_lifespan=True)
    return FieldReference(float(r.f), float(r.i), float(r.d))


def earth_rate_vector_ned(latitude_deg, rate_deg_h=EARTH_RATE_DEG_H) -> np.ndarray:
    """Earth rotation vector in NED, deg/h: ``Omega (cos phi, 0, -sin phi)``, shape (3,)."""
    p = np.deg2rad(float(latitude_deg))
    return np.array([rate_deg_h * np.cos(p), 0.0, -rate_deg_h * np.sin(p)])


def field_from_metadata(meta: dict) -> FieldReference:
    """Reference field from data-contract metadata.

    Uses ``total_field_nT``/``dip_deg``/``declination_deg`` when given (declination
    defaults to 0), else ``latitude``/``longitude``/``altitude_km``/``date`` through
    the WMM. Raises ValueError naming the missing keys when neither is present.
    """
    if "total_field_nT" in meta and "dip_deg" in meta:
        return FieldReference(
            float(meta["total_field_nT"]), float(meta["dip_deg"]), float(meta.get("declination_deg", 0.0))
        )
    if "latitude" in meta and "longitude" in meta and "date" in meta:
        return reference_field(meta["latitude"], meta["longitude"], meta.get("altitude_km", 0.0), meta["date"])
    raise ValueError(
        "metadata: need total_field_nT and dip_deg, or latitude, longitude and date for the field model"
    )
