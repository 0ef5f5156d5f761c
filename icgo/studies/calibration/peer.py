"""The peer package, circuitpython-mag-cal (``mag_cal``), run side by side with :mod:`icgo.studies.calibration`.

:func:`peer_rows` fits the peer's three stages (``fit_ellipsoid``, ``fit_to_axis``, ``fit_non_linear``) on a
split's training shots and scores each with the peer's own ``accuracy`` on the scored rolls, with the same
physical sanity check as ours (:func:`icgo.models.cal_sanity.sanity`).

numpy >= 2.5 returns ``numpy.linalg.eig`` results as complex arrays even when every eigenvalue is real (measured:
numpy 2.5.5 gives ``complex128`` for a real symmetric 3 x 3 matrix; older numpy gave ``float64``). The peer's
ellipsoid fit (``mag_cal.sensor.Sensor.fit_ellipsoid``) takes ``eig`` of a symmetric matrix and then adds its
complex transform into a real array (``align_along_axis``: a ``UFuncOutputCastingError``). :func:`peer_rows`
therefore runs the peer inside :func:`peer_numpy`, whose ``numpy.linalg.eig`` returns what numpy < 2.5 returned:
the real parts when every imaginary part is exactly zero, the complex arrays otherwise. The peer's arithmetic is
unchanged.
"""

from __future__ import annotations

import contextlib
import types

import numpy as np

from icgo.io.mag_cal_bundled import MAG_CAL_DEVICE_TO_TOOL, UT_TO_NT
from icgo.models.cal_sanity import sanity
from icgo.physics.rolls import rolled_ids

#: The peer's stages (circuitpython-mag-cal), in table order.
PEER_METHODS = ("peer_ellipsoid", "peer_fit_to_axis", "peer_fit_non_linear")


def peer_available() -> bool:
    """Whether circuitpython-mag-cal (``mag_cal``) can be imported."""
    try:
        import mag_cal  # noqa: F401
    except ImportError:
        return False
    return True


def _real_eig(a):
    """``numpy.linalg.eig`` as numpy < 2.5 returned it: real arrays when every imaginary part is exactly 0."""
    w, v = np.linalg.eig(a)
    if np.iscomplexobj(w) and not np.any(np.imag(w)) and not np.any(np.imag(v)):
        return np.real(w), np.real(v)
    return w, v


@contextlib.contextmanager
def peer_numpy():
    """The peer's ``mag_cal.sensor`` module sees ``numpy`` with :func:`_real_eig` as ``linalg.eig`` (module doc)."""
    from mag_cal import sensor

    linalg = types.SimpleNamespace(**{k: getattr(np.linalg, k) for k in dir(np.linalg) if not k.startswith("_")})
    linalg.eig = _real_eig
    shim = types.SimpleNamespace(**{k: getattr(np, k) for k in dir(np) if not k.startswith("__")})
    shim.linalg = linalg
    old = sensor.np
    sensor.np = shim
    try:
        yield
    finally:
        sensor.np = old


def _device_frame(G, B):
    """Tool frame -> mag_cal device frame (inverse of icgo.io.recording's permutation); mag in uT."""
    perm = list(MAG_CAL_DEVICE_TO_TOOL)
    gd, md = np.empty_like(G), np.empty_like(B)
    gd[:, perm], md[:, perm] = G, B / UT_TO_NT
    return gd, md


def peer_rows(G, B, groups, train, score) -> list[dict]:
    """circuitpython-mag-cal's pipeline fitted on ``train``: per stage its score on ``score`` and its sanity.

    Args:
        G, B: (N, 3) raw shots, tool frame, g and nT. groups: (N,) group ids. train, score: (N,) bool.
    Returns:
        one dict per stage: ``method`` (:data:`PEER_METHODS`), ``score_deg`` and the sanity columns.
    """
    from mag_cal import Calibration

    gd, md = _device_frame(G, B)
    ids = rolled_ids(groups)
    fit_pairs = [(md[(groups == g) & train], gd[(groups == g) & train]) for g in ids if ((groups == g) & train).any()]
    score_pairs = [(md[(groups == g) & score], gd[(groups == g) & score]) for g in ids if ((groups == g) & score).any()]
    out = []
    with peer_numpy():
        c = Calibration()

        def stage(name):
            s = sanity(c.grav.apply(gd), c.mag.apply(md), c.mag.transform)
            out.append({"method": name, "score_deg": c.accuracy(score_pairs), **s.row()})

        c.fit_ellipsoid(md[train], gd[train])
        stage("peer_ellipsoid")
        c.fit_to_axis(fit_pairs)
        stage("peer_fit_to_axis")
        c.fit_non_linear(fit_pairs)
        stage("peer_fit_non_linear")
    return out
