"""The prior-art lookup table the patent's network replaced (CN1888384, background section).

The azimuth error tabulated over (inclination, azimuth) at the turntable points, toolface ignored (its
values averaged over the toolface positions at each node, or taken at one fixed toolface): :func:`fit`.
A table is a :class:`LookupTable` pytree; :func:`predict` compensates by bilinear interpolation
(:func:`error_at`), periodic in azimuth and clamped in inclination. All angles in degrees.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from icgo.models.nets import check_angles
from icgo.physics.frames import wrap360


class LookupTable(NamedTuple):
    """Azimuth error tabulated over (inclination, azimuth) nodes.

    Attributes:
        inc_nodes: (Ni,) ascending inclinations, deg.
        az_nodes: (Na,) ascending azimuths in [0, 360), deg.
        error: (Ni, Na) azimuth error ``wrap180(A_true - A_raw)`` at the nodes, deg.
    """

    inc_nodes: jnp.ndarray
    az_nodes: jnp.ndarray
    error: jnp.ndarray


def _node_index(values, nodes, tol, label, periodic=False):
    d = values[:, None] - nodes[None, :]
    if periodic:
        d = (d + 180.0) % 360.0 - 180.0
    j = np.argmin(np.abs(d), axis=1)
    if np.any(np.abs(d[np.arange(len(values)), j]) > tol):
        k = int(np.argmax(np.abs(d[np.arange(len(values)), j]) > tol))
        raise ValueError(f"lookup table: {label} {values[k]:.6g} deg is not on a table node "
                         f"(tolerance {tol} deg)")
    return j


def fit(inclination_deg, azimuth_deg, error_deg, toolface_deg=None, at_toolface_deg=None, inc_nodes=None,
        az_nodes=None, tol=1e-6):
    """Build the prior-art error table from turntable points (toolface ignored).

    Each table node is the mean of the wrapped errors of the points at that
    (inclination, azimuth), i.e. averaged over the toolface positions, or, when
    ``at_toolface_deg`` is given, the error of the points at that one toolface
    (the patent background's table built with the toolface held fixed).

    Args:
        inclination_deg, azimuth_deg: (N,) nominal (turntable) angles, deg; they
            must sit on the nodes.
        error_deg: (N,) azimuth error ``wrap180(A_true - A_raw)``, deg.
        toolface_deg: (N,) nominal toolface, needed with ``at_toolface_deg``.
        at_toolface_deg: None (average over toolface) or one toolface, deg.
        inc_nodes, az_nodes: node angles; default the distinct input values.
        tol: how far (deg) a point may sit from its node.
    Returns:
        LookupTable.
    Raises:
        ValueError: a node without points, a point off the nodes, NaN input.
    """
    i, a, e = check_angles(("inclination_deg", "azimuth_deg", "error_deg"), (inclination_deg, azimuth_deg, error_deg),
                           who="lookup table")
    a = np.mod(a, 360.0)
    e = (e + 180.0) % 360.0 - 180.0
    if at_toolface_deg is not None:
        if toolface_deg is None:
            raise ValueError("lookup table: at_toolface_deg needs toolface_deg")
        (tf,) = check_angles(("toolface_deg",), (toolface_deg,), n=i.shape[0], who="lookup table")
        keep = np.abs((tf - at_toolface_deg + 180.0) % 360.0 - 180.0) <= tol
        if not keep.any():
            raise ValueError(f"lookup table: no point at toolface {at_toolface_deg} deg")
        i, a, e = i[keep], a[keep], e[keep]
    inc_nodes = np.unique(np.round(i, 9)) if inc_nodes is None else np.sort(np.asarray(
        inc_nodes, np.float64))
    az_nodes = np.unique(np.round(a, 9) % 360.0) if az_nodes is None else np.sort(np.mod(
        np.asarray(az_nodes, np.float64), 360.0))
    if len(inc_nodes) < 1 or len(az_nodes) < 2:
        raise ValueError("lookup table: the table needs at least 1 inclination and 2 azimuth nodes")
    ji = _node_index(i, inc_nodes, tol, "inclination")
    ja = _node_index(a, az_nodes, tol, "azimuth", periodic=True)
    flat = ji * len(az_nodes) + ja
    size = len(inc_nodes) * len(az_nodes)
    count = np.bincount(flat, minlength=size)
    if np.any(count == 0):
        k = int(np.argmax(count == 0))
        raise ValueError(f"lookup table: table node (I={inc_nodes[k // len(az_nodes)]:g}, "
                         f"A={az_nodes[k % len(az_nodes)]:g}) has no turntable point")
    err = (np.bincount(flat, weights=e, minlength=size) / count).reshape(
        len(inc_nodes), len(az_nodes))
    return LookupTable(jnp.asarray(inc_nodes), jnp.asarray(az_nodes), jnp.asarray(err))


@jax.jit
def error_at(table: LookupTable, inclination_deg, azimuth_deg):
    """Bilinear interpolation of the table's error (deg) at (I, A_raw).

    Periodic in azimuth (the last node interpolates towards the first + 360);
    inclinations outside the nodes take the edge value (no extrapolation).

    Args:
        table: LookupTable.
        inclination_deg, azimuth_deg: (...) measured angles, deg.
    Returns:
        (...) interpolated azimuth error, deg.
    """
    inc = jnp.asarray(inclination_deg)
    az = wrap360(jnp.asarray(azimuth_deg))
    ni = table.inc_nodes
    na = table.az_nodes
    # inclination: clamp, then linear between bracketing nodes
    ic = jnp.clip(inc, ni[0], ni[-1])
    k = jnp.clip(jnp.searchsorted(ni, ic, side="right") - 1, 0, max(ni.shape[0] - 2, 0))
    k1 = jnp.minimum(k + 1, ni.shape[0] - 1)
    span = ni[k1] - ni[k]
    wi = jnp.where(span > 0, (ic - ni[k]) / jnp.where(span > 0, span, 1.0), 0.0)
    # azimuth: periodic, nodes extended by the first node + 360
    ext = jnp.concatenate([na, na[:1] + 360.0])
    azs = jnp.where(az < na[0], az + 360.0, az)
    m = jnp.clip(jnp.searchsorted(ext, azs, side="right") - 1, 0, na.shape[0] - 1)
    wa = (azs - ext[m]) / (ext[m + 1] - ext[m])
    m1 = (m + 1) % na.shape[0]
    e = table.error
    lo = (1 - wa) * e[k, m] + wa * e[k, m1]
    hi = (1 - wa) * e[k1, m] + wa * e[k1, m1]
    return (1 - wi) * lo + wi * hi


def predict(table: LookupTable, angles):
    """Compensated azimuth (deg, [0, 360)): ``A_raw + table error at (I, A_raw)``, toolface ignored.

    Jit- and vmap-able; the study and the saved model call it as it is (the interpolation compiled,
    :func:`error_at`, the sum and wrap op by op).

    Args:
        table: :class:`LookupTable`.
        angles: (N, 3) measured inclination I, toolface T (unused) and computed azimuth A_raw, deg.
    Returns:
        (N,) compensated azimuth, deg.
    """
    a = angles[:, 2]
    return wrap360(a + error_at(table, angles[:, 0], a))
