"""A fitted sensor calibration as a params pytree and its one forward pass, :func:`predict`.

:class:`CalibrationParams` holds what any calibration of :mod:`icgo.models.calibration` (and the joint and
residual fits built on it) produces. Its leaves are the arrays, named as in a saved model file; a part the
calibration lacks is None, so the pytree's structure says which parts it has (and ``jit`` compiles one
program per structure):

* ``x_mag`` (12,) ``[R^-1 row-major, b]``: the magnetometer, eq. (4) ``B_c = R^-1 (B - b)``;
* ``x_accel`` (12,) ``[S row-major, c (g)]`` or None: the accelerometer, ``G_c = S (G - c)`` (None: gravity
  as read);
* ``alignment`` (3, 3) rotation ``Q`` or None: one rotation of both sensors onto the tool axis
  (:func:`icgo.models.cal_pointing.align_to_axis`), ``v @ Q.T``;
* ``nl_hidden`` (4, L) and ``nl_out`` (L, 3), or both None: the non-linear residual of the field
  (:mod:`icgo.models.mag_relm`), ``b + phi([u, 1] A) W``, after the alignment;
* ``nl_activation`` (static): the residual's hidden activation (:data:`icgo.models.mag_relm.ACTIVATIONS`),
  None without a residual.

:func:`predict` evaluates them in that order on ``x = [G | B]`` (N, 6) and returns ``[G_c | B_c]`` (N, 6), in
the units of the fit (``B_c`` in nT for a fit to ``|M_omega|`` in nT, on the unit sphere for a fit to it).
"""

from __future__ import annotations

import dataclasses
from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from icgo.models import mag_relm
from icgo.models.calibration import correct

#: The leaves of a :class:`CalibrationParams` in pytree order; each is also its array's name in a saved file.
LEAVES = ("x_mag", "x_accel", "alignment", "nl_hidden", "nl_out")
#: The leaves a calibration may lack (None).
OPTIONAL_LEAVES = LEAVES[1:]


@partial(jax.tree_util.register_dataclass, data_fields=LEAVES, meta_fields=("nl_activation",))
@dataclasses.dataclass(frozen=True)
class CalibrationParams:
    """A calibration's arrays (absent parts None) and the residual's activation (static); see the module doc.

    Attributes:
        x_mag: (12,) ``[R^-1, b]``, b in raw field units (nT). x_accel: (12,) ``[S, c]`` (g) or None.
        alignment: (3, 3) or None. nl_hidden: (4, L) or None. nl_out: (L, 3) or None.
        nl_activation: one of :data:`icgo.models.mag_relm.ACTIVATIONS` with a residual, else None.
    """

    x_mag: jnp.ndarray
    x_accel: jnp.ndarray | None = None
    alignment: jnp.ndarray | None = None
    nl_hidden: jnp.ndarray | None = None
    nl_out: jnp.ndarray | None = None
    nl_activation: str | None = None

    def parts(self) -> dict[str, bool]:
        """Which optional parts the calibration has: ``{"x_accel": True, "alignment": False, ...}``."""
        return {name: getattr(self, name) is not None for name in OPTIONAL_LEAVES}


def _namespace(params: CalibrationParams, x):
    """numpy when every array is a host (numpy) array, else jax.numpy (jax arrays, tracers under jit/vmap)."""
    traced = any(isinstance(a, jax.Array) for a in jax.tree_util.tree_leaves((params, x)))
    return jnp if traced else np


def predict(params: CalibrationParams, x):
    """Corrected gravity and field of a calibration: ``[G | B]`` -> ``[G_c | B_c]``.

    In order: eq. (4) ``B_c = R^-1 (B - b)`` and ``G_c = S (G - c)`` (gravity as read without ``x_accel``);
    the rotation ``v @ Q.T`` of both; the field's non-linear residual ``b + phi([u, 1] A) W``
    (:func:`icgo.models.mag_relm.features`). Which steps run is decided by the params' structure at trace
    time, so the function is jit- and vmap-able (vmap over a leading axis of ``x`` or of the params).

    Host arrays (numpy params and ``x``) are evaluated on the host, float64: eq. (4) by
    :func:`icgo.models.calibration.correct`, the rest with numpy; this is the arithmetic every saved
    calibration has been applied with, to the bit. jax arrays and tracers (``jit``, ``vmap``, ``grad``) are
    evaluated with jax.numpy in their own dtype; the two agree to a few float64 ulps (the ``exp`` and norm of
    numpy and of XLA differ in the last bit).

    Args:
        params: :class:`CalibrationParams`.
        x: (N, 6) ``[G (g) | B (raw field units, nT)]``; a field-only survey may pass any G (zeros): ``B_c``
            does not depend on it.
    Returns:
        (N, 6) ``[G_c (g) | B_c (fit units)]``, numpy for host inputs, a jax array otherwise.
    """
    xp = _namespace(params, x)
    if xp is np:
        x = np.asarray(x, np.float64)
        params = jax.tree_util.tree_map(lambda a: np.asarray(a, np.float64), params)
    G, B = x[:, :3], x[:, 3:]
    Bc = xp.asarray(correct(params.x_mag, B))
    Gc = G if params.x_accel is None else xp.asarray(correct(params.x_accel, G))
    if params.alignment is not None:
        Q = params.alignment
        Bc, Gc = Bc @ Q.T, Gc @ Q.T
    if params.nl_hidden is not None:
        Bc = Bc + mag_relm.features(Bc, params.nl_hidden, params.nl_activation, xp) @ params.nl_out
    return xp.concatenate([Gc, Bc], axis=1)
