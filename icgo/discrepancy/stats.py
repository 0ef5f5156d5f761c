"""The one significance test of the discrepancy workflow: a paired z over stations."""

from __future__ import annotations

import math

import numpy as np


def paired_z(before, after) -> float:
    """Paired z of the per-station improvement ``before - after``.

    ``z = mean(d) / (std(d, ddof=1) / sqrt(n))`` with ``d = before - after``
    (the standard error floored at 1e-9); positive when ``after`` is smaller.
    Used for a candidate's improvement over the current model and for the
    evidence margin of the best candidate over another (held-out chi2 per
    station in both cases).

    Args:
        before, after: (n,) per-station values (e.g. held-out chi2), paired by station.
    Returns:
        z, dimensionless.
    """
    d = np.asarray(before) - np.asarray(after)
    return float(d.mean() / max(d.std(ddof=1) / math.sqrt(d.size), 1e-9))
