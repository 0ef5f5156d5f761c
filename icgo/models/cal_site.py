"""The site a calibration was made at: the mean dip and field strength its calibrated shots see, against the site's.

A calibration that is physically sound (:mod:`icgo.models.cal_sanity`: one dip and one |B| over the shots)
can still be wrong about *which* field: a magnetometer and an accelerometer whose axes are inconsistent (a
mounting string wrong for one sensor, a sensor turned on its board) are calibrated to one dip that is not the
site's (a peer calibration of such a recording gave a dip of 0-10 deg where the site's is 60-70). Only the site
tells: :func:`site_values` measures the mean dip and |B| (and their spread over the shots) of one calibration,
and :func:`site_check` compares them with the site's reference field (WMM via :mod:`icgo.physics.field`, or
values given). A calibration off by more than :data:`SITE_DIP_TOL_DEG` or :data:`SITE_FIELD_TOL_PCT` is
**inconsistent with the site**: inconsistent axes or mounting, never recommended.

|B| here is the calibrated field in the sensor's own scale: the unit-sphere field times the fitted ellipsoid's
mean radius (``|det R^-1|^(-1/3)``, raw nT per fit unit), so the sensor's mean gain, as its maker calibrated it,
is kept (a fit to the unit sphere alone would say nothing about the strength).

The tolerances come from the sources, not from any recording (no bundled device has a known site):

* dip, 10 deg: WMM's dip uncertainty is about 0.2 deg (its error model), crustal anomalies and the steel of a
  building move the dip by up to a few degrees indoors, and a sound calibration's dip varies by at most
  2 deg over the shots (:data:`icgo.models.cal_sanity.LIMITS`); an axis error moves it by tens of degrees;
* |B|, 20 %: WMM's |B| uncertainty is about 150 nT (0.3 %), a consumer magnetometer's sensitivity tolerance
  is a few to 10 % part to part, and indoor steel adds up to about 10 %; a unit error is a factor of 10 or more.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from icgo.physics.qc import measured_dip_deg

#: Largest |mean dip - site dip| of a calibration consistent with the site, deg (module doc).
SITE_DIP_TOL_DEG = 10.0
#: Largest |mean |B| - site |B|| of a calibration consistent with the site, % of the site's (module doc).
SITE_FIELD_TOL_PCT = 20.0


class SiteValues(NamedTuple):
    """What one calibration's shots say about the site.

    Attributes:
        dip_deg, dip_std_deg: mean and sample std of the calibrated dip over the shots, deg.
        field_nT, field_std_nT: mean and sample std of the calibrated |B| in the sensor's scale, nT.
    """

    dip_deg: float
    dip_std_deg: float
    field_nT: float
    field_std_nT: float


class SiteCheck(NamedTuple):
    """A calibration's site values against the site's reference field.

    Attributes:
        dip_off_deg: mean dip minus the site's, deg. field_off_pct: mean |B| minus the site's, % of the site's.
        flagged: beyond :data:`SITE_DIP_TOL_DEG` or :data:`SITE_FIELD_TOL_PCT`. reason: one phrase, or "".
    """

    dip_off_deg: float
    field_off_pct: float
    flagged: bool
    reason: str


def site_values(G_cal, B_cal, matrix) -> SiteValues:
    """Mean dip and |B| (with their spreads) of calibrated shots.

    Args:
        G_cal: (N, 3) calibrated gravity (any scale). B_cal: (N, 3) calibrated field, fit units.
        matrix: (3, 3) the magnetometer matrix ``R^-1`` (raw nT -> fit units); its mean gain
            ``|det|^(1/3)`` gives the fit units back in raw nT.
    """
    G_cal = np.asarray(G_cal, np.float64)
    B_cal = np.asarray(B_cal, np.float64)
    dip = measured_dip_deg(G_cal, B_cal)
    radius = abs(float(np.linalg.det(np.asarray(matrix, np.float64)))) ** (-1.0 / 3.0)
    bn = np.linalg.norm(B_cal, axis=1) * radius
    sd = (lambda v: float(np.std(v, ddof=1)) if v.size > 1 else 0.0)
    return SiteValues(float(np.mean(dip)), sd(dip), float(np.mean(bn)), sd(bn))


def site_check(values: SiteValues, dip_deg: float, field_nT: float) -> SiteCheck:
    """``values`` against the site's dip (deg) and |B| (nT); flagged beyond the tolerances (module doc)."""
    dip_off = values.dip_deg - float(dip_deg)
    field_off = 100.0 * (values.field_nT - float(field_nT)) / float(field_nT)
    reasons = []
    if not abs(dip_off) <= SITE_DIP_TOL_DEG:
        reasons.append(f"mean dip {values.dip_deg:.1f} deg vs the site's {float(dip_deg):.1f} (off by more than "
                       f"{SITE_DIP_TOL_DEG:g})")
    if not abs(field_off) <= SITE_FIELD_TOL_PCT:
        reasons.append(f"mean |B| {values.field_nT:.0f} nT vs the site's {float(field_nT):.0f} ({field_off:+.0f} %, "
                       f"more than {SITE_FIELD_TOL_PCT:g} %)")
    reason = ("; ".join(reasons) + ": inconsistent axes or mounting") if reasons else ""
    return SiteCheck(dip_off, field_off, bool(reasons), reason)
