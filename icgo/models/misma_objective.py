"""MISMA's penalised fitness over a fixed data set (the paper's eqs. 5, 7, 8; terms in :mod:`icgo.models.calibration`,
the gyro term in :mod:`icgo.models.gyro_reference`)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from icgo.models import cal_objectives as obj
from icgo.models.calibration import CalData
from icgo.models.gyro_reference import gyro_term


class MismaObjective:
    """The penalised MISMA fitness over a fixed data set (eqs. 5, 7, 8).

    ``F(x) = J_dot(x) + mu_m J_mag(x) + mu_p sum_{s,axis} max(0, th - |rho_s|)^2 / n [+ mu_g J_gyro(x)]``

    where the Pearson sum runs over rotating segments with at least 3 samples
    and ``J_gyro`` (:func:`icgo.models.gyro_reference.gyro_term`) compares the corrected
    field with the gyro-derived reference M_omega when ``gyro`` is given.
    The equality constraint ``|B| = |M_omega|`` is a quadratic penalty
    (``mu_m = 1`` makes it as strong as the objective, both being squared
    relative quantities); the inequality constraint ``|rho| >= th`` is an
    exterior quadratic penalty with a large weight, i.e. practically hard.

    Instances are callables ``(P, 12) -> (P,)`` for :mod:`icgo.optim` (hashed
    by identity, so one instance compiles once) and carry :meth:`gmr`, the
    per-candidate GMR used by MISMA.

    Args:
        data: :class:`icgo.models.calibration.CalData`.
        pearson_threshold: ``th`` (paper: set from the correlation-strength table).
        pearson_mode: ``"axis"`` or ``"complex"`` (see :func:`icgo.models.cal_objectives.pearson_xy`).
        mu_magnitude: weight of the magnitude penalty (0 disables it).
        mu_pearson: weight of the Pearson penalty (0 disables it).
        n_segments: number of segment ids (static); default max(segment) + 1.
        gyro: ``(GyroReference, B)`` (the reference and the (M, 3) raw field at its samples, nT) or None.
        mu_gyro: weight of ``J_gyro`` (used only with ``gyro``).
    """

    def __init__(self, data: CalData, pearson_threshold=0.8, pearson_mode="axis",
                 mu_magnitude=1.0, mu_pearson=1.0, n_segments=None, gyro=None, mu_gyro=1.0):
        if pearson_mode not in ("axis", "complex"):
            raise ValueError(f"pearson_mode {pearson_mode!r}: choose 'axis' or 'complex'")
        if not 0.0 <= float(pearson_threshold) <= 1.0:
            raise ValueError(f"pearson_threshold must be in [0, 1], got {pearson_threshold}")
        if mu_magnitude < 0 or mu_pearson < 0 or mu_gyro < 0:
            raise ValueError("penalty weights mu_magnitude, mu_pearson and mu_gyro must be >= 0")
        self.gyro = None if gyro is None else (gyro[0], jnp.asarray(gyro[1]))
        self.mu_gyro = float(mu_gyro)
        self.data = data
        self.pearson_threshold = float(pearson_threshold)
        self.pearson_mode = pearson_mode
        self.mu_magnitude = float(mu_magnitude)
        self.mu_pearson = float(mu_pearson)
        self.n_segments = int(np.max(np.asarray(data.segment))) + 1 if n_segments is None else int(n_segments)

    # single candidate -------------------------------------------------------
    def terms(self, x, data=None):
        """The three terms ``(J_dot, J_mag, P_pearson)`` for one (12,) candidate (data: CalData or None = own)."""
        d = self.data if data is None else data
        j_dot = obj.dot_invariance(x, d.G, d.B, d.dot_weights)
        j_mag = obj.magnitude_consistency(x, d.B, d.ref_nT, d.weights)
        rho, n = obj.pearson_xy(x, d.G, d.B, d.segment, d.rotating, self.n_segments, self.pearson_mode)
        valid = (n >= 3.0)[:, None] * jnp.ones_like(rho)
        viol = jnp.maximum(0.0, self.pearson_threshold - jnp.abs(rho)) ** 2
        p = jnp.sum(viol * valid) / jnp.maximum(jnp.sum(valid), 1.0)
        return j_dot, j_mag, p

    def gyro_term(self, x):
        """``J_gyro`` of one (12,) candidate (0 without a gyro reference)."""
        if self.gyro is None:
            return jnp.zeros((), jnp.asarray(x).dtype)
        return gyro_term(x, self.gyro[1], self.gyro[0])

    def single(self, x, data=None):
        """Penalised fitness of one (12,) candidate; +inf when not finite."""
        j_dot, j_mag, p = self.terms(x, data)
        f = j_dot + self.mu_magnitude * j_mag + self.mu_pearson * p + self.mu_gyro * self.gyro_term(x)
        return jnp.where(jnp.isfinite(f), f, jnp.inf)

    def __call__(self, pop, aux=None):
        """Batched fitness ``(P, 12) -> (P,)``; ``aux`` (a CalData of the same shapes) replaces the data.

        Passing the data as ``aux`` lets one instance (one compiled program)
        serve many recordings of equal size.
        """
        return jax.vmap(lambda x: self.single(x, aux))(jnp.asarray(pop))

    def gmr(self, x, aux=None):
        """GMR (eq. 15) of one (12,) candidate."""
        d = self.data if aux is None else aux
        return obj.magnitude_ratio(x, d.B, d.ref_nT, d.weights)
