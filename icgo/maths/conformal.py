"""Split-conformal azimuth intervals and their empirical coverage (host-side numpy).

The interval of a compensated azimuth is ``a +/- q``, ``q`` the conformal quantile
(:func:`conformal_quantile`) of absolute errors on calibration rows the model did
not fit. Two uses:

* the half-width a saved model carries (:func:`icgo.artifacts.relm.out_of_bag_halfwidth`);
* the coverage measured under a protocol (:func:`member_coverage`): each member (one
  fitted model of :mod:`icgo.studies.common.splits`) gets its own ``q``, calibrated on rows of *its
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


#: Members whose running counts (members x calibration values, int32) one step of :func:`member_coverage` holds.
COVERAGE_CHUNK = 64


def member_coverage(a_comp, a_true, train, heldout, test, pool, level: float):
    """Per member: the conformal half-width from the other members, and its coverage on the member's test rows.

    Member m's calibration values are the errors, on the rows m trained on, of the other members of its group that
    held those rows out. Computed without gathering them per member: per method and group, every held-out error is
    sorted once; member m's k-th smallest calibration value is where the running count of the sorted values whose
    row m trained on reaches k (k of :func:`conformal_quantile`), found for :data:`COVERAGE_CHUNK` members at a
    time. Equal to :func:`conformal_quantile` of each member's gathered values (tested).

    Args:
        a_comp: (S, M, N) compensated azimuths (deg) of S methods and M members.
        a_true: (N,) reference azimuths (deg).
        train, heldout, test: (M, N) 0/1 masks of each member (:class:`icgo.studies.common.splits.Members`).
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
    n_cal = np.zeros(M, int)
    for g in np.unique(pool):
        idx = np.flatnonzero(pool == g)
        tr = train[idx]                                                           # (Mg, N)
        # member m's own held-out rows never meet its training rows; remove them anyway (the definition)
        n_cal[idx] = tr.astype(int) @ heldout[idx].sum(0) - (tr & heldout[idx]).sum(1)
        ho_m, ho_n = np.nonzero(heldout[idx])                                     # every held-out (member, row)
        for s in range(S):
            vals = err[s, idx][ho_m, ho_n]
            order = np.argsort(vals, kind="stable")
            vals, rows, owner = vals[order], ho_n[order], ho_m[order]
            for a in range(0, len(idx), COVERAGE_CHUNK):
                members = np.arange(a, min(a + COVERAGE_CHUNK, len(idx)))
                hit = tr[members][:, rows] & (owner[None, :] != members[:, None])  # (chunk, H): m's values
                counts = np.cumsum(hit, axis=1, dtype=np.int32)
                n = n_cal[idx[members]]
                k = np.minimum(np.ceil((n + 1) * level).astype(int), n)
                pos = np.argmax(counts >= np.maximum(k, 1)[:, None], axis=1)
                q[s, idx[members]] = np.where(n > 0, vals[pos] if len(vals) else np.nan, np.nan)
    with np.errstate(invalid="ignore"):
        cov = np.where(test.any(1)[None], ((err <= q[..., None]) & test[None]).sum(-1) / np.maximum(test.sum(1), 1),
                       np.nan)
    return q, cov, n_cal
