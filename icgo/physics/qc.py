"""Survey quality control against the reference field: the checks MWD engineers run on every survey.

Per station (row), three comparisons with the reference (:class:`icgo.io.schema.ReferenceField`):

* ``|G| - gravity_g`` within ``g_tol_g`` (default 0.0025 g: the common MWD
  gravity-total acceptance band of +/- 2.5 mg);
* ``|B| - total_field_nT`` within ``b_tol_nT`` (default 300 nT);
* ``dip - dip_deg`` within ``dip_tol_deg`` (default 0.25 deg),

with the measured dip ``asin(G . B / (|G| |B|))`` (positive down). The two field
bands are the industry survey-QC bands quoted in ENGINEERING-NOTES ("Industry
survey QC: |Btotal - Bref| <= 300 nT and |dip - dip_ref| <= 0.25 deg"); the
gravity band is the usual companion (+/- 2.5 mg); all three are settings
(:class:`QCBands`). Sources and choices: ``docs/qc.md``.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np
import pandas as pd

from icgo.core.settings import is_real, need


def measured_dip_deg(G, B):
    """Measured magnetic dip per shot, deg (positive down): ``asin(G . B / (|G| |B|))``.

    Args:
        G: (N, 3) gravity, g. B: (N, 3) field, nT.
    Returns:
        (N,) numpy array, deg.
    """
    G = np.asarray(G, float)
    B = np.asarray(B, float)
    s = np.sum(G * B, 1) / (np.linalg.norm(G, axis=1) * np.linalg.norm(B, axis=1))
    return np.degrees(np.arcsin(np.clip(s, -1.0, 1.0)))


@dataclasses.dataclass(frozen=True)
class QCBands:
    """Acceptance bands of the survey QC (half-widths).

    Attributes:
        g_tol_g: |G| band, g. b_tol_nT: |B| band, nT. dip_tol_deg: dip band, deg.
    """

    g_tol_g: float = 0.0025
    b_tol_nT: float = 300.0
    dip_tol_deg: float = 0.25

    def __post_init__(self):
        for name in ("g_tol_g", "b_tol_nT", "dip_tol_deg"):
            v = getattr(self, name)
            need(is_real(v) and v > 0, name, f"must be a number > 0, got {v!r}")


class QCResult(NamedTuple):
    """Per-row QC values and flags, and their counts.

    Attributes:
        table: DataFrame with ``g_total_g``, ``b_total_nT``, ``dip_deg`` and their
            differences from the reference (``dg_g``, ``db_nT``, ``ddip_deg``), the
            flags ``qc_g``, ``qc_b``, ``qc_dip`` (True = outside the band) and ``qc_pass``.
        counts: ``{"n": rows, "g": flagged, "b": ..., "dip": ..., "any": rows failing any}``.
    """

    table: pd.DataFrame
    counts: dict


def survey_qc(G, B, total_field_nT: float, dip_deg: float, gravity_g: float = 1.0,
              bands: QCBands = QCBands(), prefix: str = "") -> QCResult:
    """QC of every station against the reference field.

    Args:
        G: (N, 3) gravity, g. B: (N, 3) field, nT (raw or corrected).
        total_field_nT: reference total field, nT. dip_deg: reference dip, deg.
        gravity_g: reference gravity, g.
        bands: acceptance bands.
        prefix: prepended to every column name (e.g. ``"raw_"``, ``"corrected_"``).
    Returns:
        QCResult.
    """
    G = np.asarray(G, float)
    B = np.asarray(B, float)
    gn = np.linalg.norm(G, axis=1)
    bn = np.linalg.norm(B, axis=1)
    dip = measured_dip_deg(G, B)
    dg, db, dd = gn - gravity_g, bn - total_field_nT, dip - dip_deg
    fg, fb, fd = np.abs(dg) > bands.g_tol_g, np.abs(db) > bands.b_tol_nT, np.abs(dd) > bands.dip_tol_deg
    table = pd.DataFrame({"g_total_g": gn, "dg_g": dg, "b_total_nT": bn, "db_nT": db, "dip_deg": dip,
                          "ddip_deg": dd, "qc_g": fg, "qc_b": fb, "qc_dip": fd, "qc_pass": ~(fg | fb | fd)})
    counts = {"n": int(len(table)), "g": int(fg.sum()), "b": int(fb.sum()), "dip": int(fd.sum()),
              "any": int((fg | fb | fd).sum())}
    return QCResult(table.add_prefix(prefix), counts)


def qc_sentence(qc: dict, bands: QCBands = QCBands()) -> str:
    """One Markdown sentence of QC counts per stage, e.g. for a study summary.

    Args:
        qc: stage label (``"raw"``, ``"msa"``, ...) -> counts of :class:`QCResult`.
        bands: the bands the counts were taken with (named in the sentence).
    """
    head = (f"Survey QC against the reference field (|G| {1000 * bands.g_tol_g:g} mg, |B| {bands.b_tol_nT:g} nT, "
            f"dip {bands.dip_tol_deg:g} deg; docs/qc.md): ")
    return head + "; ".join(f"{k}: {c['any']} of {c['n']} stations flagged (|G| {c['g']}, |B| {c['b']}, "
                            f"dip {c['dip']})" for k, c in qc.items()) + "."


#: Default band of the gyro's total-rate check, deg/h (:func:`earth_rate_qc`).
EARTH_RATE_TOL_DEG_H = 0.5


def earth_rate_qc(W, tol_deg_h: float = EARTH_RATE_TOL_DEG_H, rate_deg_h: float | None = None) -> QCResult:
    """The gyro's survey check: measured total rotation rate against the earth rate, per station.

    A gyro survey's counterpart of the |B| check. The band (default 0.5 deg/h) is our choice, twice
    the largest gyro bias of the patent instrument (``icgo.datasets.gyro_turntable.PATENT_GYRO``); docs/qc.md.

    Args:
        W: (N, 3) measured rates, deg/h (tool frame). tol_deg_h: band half-width, deg/h.
        rate_deg_h: the earth rate, deg/h (default :data:`icgo.physics.frames.EARTH_RATE_DEG_H`).
    Returns:
        QCResult with columns ``w_total_deg_h``, ``dw_deg_h``, ``qc_rate``, ``qc_pass``;
        counts ``{"n", "rate", "any"}``.
    """
    from icgo.physics.frames import EARTH_RATE_DEG_H

    need(is_real(tol_deg_h) and tol_deg_h > 0, "tol_deg_h", f"must be a number > 0, got {tol_deg_h!r}")
    rate = float(EARTH_RATE_DEG_H if rate_deg_h is None else rate_deg_h)
    wn = np.linalg.norm(np.asarray(W, float), axis=1)
    flag = np.abs(wn - rate) > tol_deg_h
    table = pd.DataFrame({"w_total_deg_h": wn, "dw_deg_h": wn - rate, "qc_rate": flag, "qc_pass": ~flag})
    return QCResult(table, {"n": int(len(table)), "rate": int(flag.sum()), "any": int(flag.sum())})
