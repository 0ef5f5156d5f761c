"""Split-conformal azimuth intervals and their empirical coverage (host-side numpy).

The interval of a compensated azimuth is ``a +/- q``, ``q`` the conformal quantile
(:func:`conformal_quantile`) of absolute errors on calibration rows the model did
not fit. Two uses:

* the half-width a saved model carries (:func:`icgo.models.relm.out_of_bag_halfwidth`);
* the coverage measured under a protocol (:func:`member_coverage`): each member (one
  fitted model of :mod:`icgo.studies.splits`) gets its own ``q``, calibrated on rows of *its
  training set* predicted by the other members that held them out (the cross-fitted
  "CV+" reading of split conformal: the member's own test rows never calibrate its
  interval), and is scored on its test rows.
"""

from __future__ import annotations

import numpy as np

from icgo.physics.frames import angle_diff


def conformal_quantile(abs_err, level: float) -> float:
    """The split-conformal quantile: the ``ceil((n + 1) level)``-th smallest of n values (the largest if that exceeds n).

    Args:
        abs_err: (n,) absolute calibration errors (deg). level: nominal coverage in (0, 1).
    Returns:
        The half-width (deg); NaN for n = 0.
    """
    x = np.sort(np.asarray(abs_err, float).ravel())
    n = x.size
    if n == 0:
        return float("nan")
    return float(x[min(int(np.ceil((n + 1) * level)), n) - 1])


def member_coverage(a_comp, a_true, train, heldout, test, pool, level: float):
    """Per member: the conformal half-width from the other members, and its coverage on the member's test rows.

    Args:
        a_comp: (S, M, N) compensated azimuths (deg) of S methods and M members.
        a_true: (N,) reference azimuths (deg).
        train, heldout, test: (M, N) 0/1 masks of each member (:class:`icgo.studies.splits.Members`).
        pool: (M,) group id; a member is calibrated by the other members of its group only
            (a repeat's folds for fold protocols, all repeats otherwise).
        level: nominal coverage.
    Returns:
        (halfwidth (S, M) deg, coverage (S, M) fraction of test rows with |error| <= halfwidth,
        n_calibration (M,) rows used per member).
    """
    err = np.abs(np.asarray(angle_diff(np.asarray(a_comp, float), np.asarray(a_true, float)[None, None])))
    train, heldout, test = (np.asarray(x) > 0 for x in (train, heldout, test))
    pool = np.asarray(pool)
    S, M, _ = err.shape
    q = np.full((S, M), np.nan)
    cov = np.full((S, M), np.nan)
    n_cal = np.zeros(M, int)
    for m in range(M):
        others = (pool == pool[m]) & (np.arange(M) != m)
        cal = heldout[others] & train[m][None]                 # (M', N): rows m fitted, held out by m'
        n_cal[m] = int(cal.sum())
        for s in range(S):
            q[s, m] = conformal_quantile(err[s][others][cal], level)
            if test[m].any():
                cov[s, m] = float(np.mean(err[s, m, test[m]] <= q[s, m]))
    return q, cov, n_cal
