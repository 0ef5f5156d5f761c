"""The site of a recording given as settings: ``site.lat= site.lon= site.date= [site.alt_km=]`` or ``site.dip= site.field=``.

:func:`site_reference` checks the settings the way :mod:`icgo.io.recording` checks a survey's metadata (ranges,
units, a date the field model covers) and returns the site's dip and total field: from the World Magnetic Model
(:func:`icgo.physics.field.reference_field`, pygeomag) for a place and date, or as given. A bad or incomplete
site is one :class:`~icgo.core.errors.SettingError` line naming the setting.
"""

from __future__ import annotations

import math
from typing import NamedTuple

from icgo.core.errors import SettingError

#: The keys of the ``site`` setting.
SITE_KEYS = ("lat", "lon", "date", "alt_km", "dip", "field")
#: Range of a plausible geomagnetic total field, nT (the data contract's, icgo.io.schema.B_MEDIAN_RANGE_NT
#: is for raw readings; the earth's own field is 22,000-67,000 nT).
SITE_FIELD_RANGE_NT = (10_000.0, 100_000.0)


class Site(NamedTuple):
    """A site's reference field. dip_deg: deg, positive down. field_nT: |B|, nT. origin: where it came from."""

    dip_deg: float
    field_nT: float
    origin: str


def _number(site: dict, key: str, lo: float, hi: float, unit: str, hint: str = "") -> float:
    v = site[key]
    try:
        x = float(v)
    except (TypeError, ValueError, OverflowError):
        raise SettingError(f"site.{key}", f"{v!r}: expected a number ({unit})") from None
    if isinstance(v, bool) or not math.isfinite(x) or not lo <= x <= hi:
        raise SettingError(f"site.{key}", f"{v!r}: expected a number in [{lo:g}, {hi:g}] {unit}{hint}")
    return x


def site_reference(site: dict | None) -> Site | None:
    """The site's reference field from the ``site`` settings, or None when none is given.

    Args:
        site: ``{"lat", "lon", "date", "alt_km", "dip", "field"}`` (None values: not given).
    Raises:
        SettingError: an unknown key, a partial site (a place without its date, a dip without the field, or
            both forms), a value out of range, a field that looks like uT or Gauss, a date the field model
            does not cover (2020-2030: give site.dip= and site.field= instead).
    """
    site = {k: v for k, v in (site or {}).items() if v is not None}
    unknown = sorted(set(site) - set(SITE_KEYS))
    if unknown:
        raise SettingError("site", f"unknown key(s) {unknown}; give site.lat= site.lon= site.date= [site.alt_km=], "
                                   "or site.dip= site.field=")
    if not site:
        return None
    place, given = [k for k in ("lat", "lon", "date", "alt_km") if k in site], [k for k in ("dip", "field") if k in site]
    if place and given:
        raise SettingError("site", "give either the place (site.lat, site.lon, site.date) or the field "
                                   "(site.dip, site.field), not both")
    if given:
        if len(given) == 1:
            other = "field" if given == ["dip"] else "dip"
            raise SettingError(f"site.{given[0]}", f"given without site.{other} (the site check needs both)")
        dip = _number(site, "dip", -90.0, 90.0, "deg")
        f = site["field"]
        hint = ""
        try:
            fx = float(f)
            if 10.0 <= fx <= 100.0:
                hint = " (looks like uT: multiply by 1000)"
            elif 0.1 <= fx <= 1.0:
                hint = " (looks like Gauss: multiply by 100000)"
        except (TypeError, ValueError, OverflowError):
            pass
        field = _number(site, "field", *SITE_FIELD_RANGE_NT, "nT", hint)
        return Site(dip, field, "given (site.dip, site.field)")
    ranges = {"lat": (-90.0, 90.0, "deg"), "lon": (-180.0, 360.0, "deg"), "alt_km": (-12.0, 1000.0, "km")}
    values = {k: _number(site, k, *r) for k, r in ranges.items() if k in site}  # what is given, checked first
    missing = [f"site.{k}" for k in ("lat", "lon", "date") if k not in site]
    if missing:
        raise SettingError("site", f"{', '.join(missing)} missing: the field model needs the latitude, longitude "
                                   "and date (or give site.dip= and site.field=)")
    from icgo.physics.field import FIELD_MODEL_YEARS, decimal_year, reference_field

    lat, lon, alt = values["lat"], values["lon"], values.get("alt_km", 0.0)
    try:
        year = decimal_year(site["date"] if isinstance(site["date"], str) else float(site["date"]))
    except (TypeError, ValueError):
        raise SettingError("site.date", f"{site['date']!r}: expected YYYY-MM-DD or a decimal year") from None
    if not FIELD_MODEL_YEARS[0] <= year < FIELD_MODEL_YEARS[1]:
        raise SettingError("site.date", f"{site['date']!r} lies outside the field model's years "
                                        f"({FIELD_MODEL_YEARS[0]:g}-{FIELD_MODEL_YEARS[1]:g}, WMM2020 and WMM2025); "
                                        "give site.dip= and site.field= instead")
    r = reference_field(lat, lon, alt, year)
    return Site(r.dip_deg, r.total_field_nT, f"WMM at {lat:g}, {lon:g}, {alt:g} km, {site['date']}")
