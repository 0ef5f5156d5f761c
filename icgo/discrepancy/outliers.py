"""Robust outliers: stations whose residual no smooth model explains, named and kept out of the fits.

Before the search, the stations are fitted once with every linear-start candidate effect of the vocabulary
free (the most flexible model the search could reach, :func:`screen`); a station is an outlier when one of
its six residual components lies more than ``outlier_z`` robust standard deviations from that component's
median, the robust standard deviation being 1.4826 x the median absolute deviation (MAD; Hampel 1974,
Rousseeuw & Croux 1993). Outliers are listed in the result and the report and carry weight 0 in every fit,
held-out score and headline number of the search; a spike of 7,000 nT on one axis is hundreds of noise
sigma, and one such station would otherwise dominate the held-out chi2 of every model.
Residuals are measured - predicted (:mod:`icgo.discrepancy.model`).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from icgo.discrepancy.compare import COMPONENTS
from icgo.discrepancy.fit import lm_fit
from icgo.discrepancy.model import Prepared, physical_residuals, predict
from icgo.physics import effects as _fx

#: Median absolute deviation to the standard deviation of a normal distribution.
MAD_TO_SIGMA = 1.4826
#: LM steps of the screening fit (fixed).
SCREEN_ITER = 30


class Outlier(NamedTuple):
    """One outlying station.

    Attributes:
        station: its row (0-based, in the stations given). component: its largest outlying residual component
            (``gx`` ... ``bz``). residual: that residual (g or nT). z: its robust z (MADs x 1.4826 from the median).
    """

    station: int
    component: str
    residual: float
    z: float


def _screen_fit(theta0, free, w, data, layout):
    theta = lm_fit(theta0, free, w, data, layout, SCREEN_ITER)[0]
    return physical_residuals(predict(theta, data, layout), data)


_screen_fit_jit = jax.jit(_screen_fit, static_argnames=("layout",))


def screen(prep: Prepared, valid, names, outlier_z: float) -> tuple:
    """The robust outliers of the stations (see the module).

    Args:
        prep: the prepared stations. valid: (n,) bool, the stations that may be used.
        names: the candidate effects; those with a data-driven start (nonlinear, e.g. ``magnetic_body``)
            are left out of the screening fit. outlier_z: the threshold (robust z); ``inf``: no screen.
    Returns:
        (outlier (n,) bool, tuple of :class:`Outlier`, largest z first).
    """
    valid = np.asarray(valid, bool)
    n = valid.size
    if not np.isfinite(outlier_z) or valid.sum() < 8:
        return np.zeros(n, bool), ()
    layout = prep.layout
    free = prep.free_nuisance.astype(float)
    for e in names:
        if _fx.EFFECTS[e].start is None:
            free[layout.slice(e)] = 1.0
    free = np.where(prep.given, 0.0, free)
    r = np.asarray(_screen_fit_jit(jnp.asarray(prep.theta0), jnp.asarray(free), jnp.asarray(valid, float),
                                   prep.data, layout))
    rv = r[valid]
    med = np.median(rv, 0)
    s = MAD_TO_SIGMA * np.median(np.abs(rv - med), 0)
    z = np.abs(r - med) / np.where(s > 0, s, np.inf)
    z = np.where(valid[:, None], z, 0.0)
    out = np.any(z > outlier_z, 1)
    rows = []
    for i in np.flatnonzero(out):
        c = int(np.argmax(z[i]))
        rows.append(Outlier(int(i), COMPONENTS[c], float(r[i, c]), float(z[i, c])))
    return out, tuple(sorted(rows, key=lambda o: -o.z))
