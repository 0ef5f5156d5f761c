"""Physical sanity of a magnetometer calibration: what the group-spread score cannot see.

A calibration can shrink the within-group spread of rolled shots by bending the
field out of shape: an unconstrained joint fit reaches 0.10 deg while the
dip varies by 7-15 deg across the shots of one device, and one held-out fit
collapses to a rank-1 matrix (every shot due south, score 0.000). A calibrated
magnetometer at one site must instead see **one field**: one dip and one |B| for
every shot, through a well-conditioned matrix. :func:`sanity` measures the three:

* ``dip_spread_deg``: max - min over all shots of the measured dip
  ``asin(G.B / (|G| |B|))`` of the calibrated sensors;
* ``b_spread_pct``: sample std of the calibrated |B| over all shots, % of its mean;
* ``cond``: 2-norm condition number of the magnetometer matrix ``R^-1`` (scale-free).

A calibration beyond any limit of :data:`LIMITS` is **degenerate**: it is reported
with the reason and never as a score or a win. The limits (``docs/calibrate.md``)
come from the industry survey-QC bands quoted in ENGINEERING-NOTES, loosened 4x for
consumer-grade sensors: dip +/- 0.25 deg is a 0.5 deg wide band -> 2 deg of spread;
|B| +/- 300 nT of a ~50,000 nT field is a 0.6 % half-width -> 2.4 % std; and a condition number of
2, i.e. axis gains differing by a factor 2 after calibration, far outside the
few-percent sensitivity tolerances of MEMS magnetometer datasheets. Sound fits of
the 9 bundled devices stay far inside all three (measured in docs/calibrate.md).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from icgo.physics.qc import measured_dip_deg

#: Limits of a physical calibration (see the module doc): dip spread deg, |B| std %, cond(R^-1).
LIMITS = {"dip_spread_deg": 2.0, "b_spread_pct": 2.4, "cond": 2.0}


class Sanity(NamedTuple):
    """Physical invariants of a calibrated recording (see the module doc).

    Attributes:
        dip_spread_deg: deg. b_spread_pct: %. cond: 1.
        degenerate: True if any limit of :data:`LIMITS` is exceeded (or a value is not finite).
        reasons: one short phrase per exceeded limit.
    """

    dip_spread_deg: float
    b_spread_pct: float
    cond: float
    degenerate: bool
    reasons: tuple

    def row(self) -> dict:
        """The values as table columns (``reasons`` joined by ``"; "``)."""
        return {"dip_spread_deg": self.dip_spread_deg, "b_spread_pct": self.b_spread_pct, "cond": self.cond,
                "degenerate": self.degenerate, "reasons": "; ".join(self.reasons)}


def limits_sentence(limits: dict = LIMITS) -> str:
    """What ``degenerate`` means in a results table, one sentence naming the limits."""
    return (f"`degenerate`: the fit fails the physical sanity check on all shots (dip spread > "
            f"{limits['dip_spread_deg']:g} deg, |B| std > {limits['b_spread_pct']:g} % of its mean, or cond(R^-1) > "
            f"{limits['cond']:g}; `icgo.models.cal_sanity`, docs/calibrate.md): no score, never in a mean or a win.")


def sanity(G_cal, B_cal, matrix, limits: dict = LIMITS) -> Sanity:
    """The invariants of calibrated shots and the magnetometer matrix that produced them.

    Args:
        G_cal: (N, 3) calibrated gravity (any scale). B_cal: (N, 3) calibrated field (any scale).
        matrix: (3, 3) the magnetometer correction matrix ``R^-1`` (any scale).
        limits: the limits (default :data:`LIMITS`).
    Returns:
        :class:`Sanity`.
    """
    G_cal = np.asarray(G_cal, np.float64)
    B_cal = np.asarray(B_cal, np.float64)
    dip = measured_dip_deg(G_cal, B_cal)
    bn = np.linalg.norm(B_cal, axis=1)
    sv = np.linalg.svd(np.asarray(matrix, np.float64), compute_uv=False)
    vals = {"dip_spread_deg": float(np.ptp(dip)), "b_spread_pct": float(100.0 * bn.std(ddof=1) / bn.mean()),
            "cond": float(sv[0] / sv[-1]) if sv[-1] > 0 else float("inf")}
    reasons = tuple(f"{k} {v:.3g} > {limits[k]:g}" if np.isfinite(v) else f"{k} not finite"
                    for k, v in vals.items() if not (np.isfinite(v) and v <= limits[k]))
    return Sanity(**vals, degenerate=bool(reasons), reasons=reasons)
