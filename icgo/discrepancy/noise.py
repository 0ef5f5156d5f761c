"""The sensor noise model of the discrepancy workflow: ONE set of noise constants.

Every default noise value in the workflow (:class:`~icgo.discrepancy.config.WorkflowConfig`,
:func:`~icgo.discrepancy.stations.simulate`, ``conf/discrepancy.yaml``, the report) comes from
:data:`NOISE`; nothing restates 15 nT or 3e-4 g by hand.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp


class Noise(NamedTuple):
    """White sensor noise, 1 sigma per axis.

    Attributes:
        sigma_b_nT: magnetometer noise, nT.
        sigma_g: accelerometer noise, g.
    """

    sigma_b_nT: float
    sigma_g: float


#: Default sensor noise (ENGINEERING-NOTES "Discrepancy fitting": ~15 nT, ~3e-4 g).
NOISE = Noise(sigma_b_nT=15.0, sigma_g=3e-4)


def effective_sigma(G, B, noise: Noise = NOISE) -> jnp.ndarray:
    """Per-station 1-sigma of the (G, B) residual components.

    The model takes toolface from the measured G, so accelerometer noise turns
    the predicted cross-axial field: sigma_T = sigma_g / |G_xy| (rad), which adds
    (B_y sigma_T)^2 to bx's variance and (B_x sigma_T)^2 to by's.

    Args:
        G: (n, 3) measured gravity, g. B: (n, 3) measured field, nT.
        noise: the sensor noise.
    Returns:
        (n, 6) sigmas: gx, gy, gz in g, then bx, by, bz in nT.
    """
    G, B = jnp.asarray(G), jnp.asarray(B)
    sigma_b, sigma_g = noise
    gxy2 = jnp.maximum(G[:, 0] ** 2 + G[:, 1] ** 2, 1e-12)
    st2 = sigma_g**2 / gxy2
    sb = jnp.stack([jnp.sqrt(sigma_b**2 + B[:, 1] ** 2 * st2), jnp.sqrt(sigma_b**2 + B[:, 0] ** 2 * st2),
                    jnp.full(G.shape[0], sigma_b, G.dtype)], 1)
    return jnp.concatenate([jnp.full((G.shape[0], 3), sigma_g, G.dtype), sb], 1)


def noise_floor(n_valid: int, n_groups: int = 0) -> float:
    """Expected chi2 per residual component when only noise is left.

    Each station's toolface is taken from its measured G, which absorbs one of
    its six residual components (5/6); in group mode each group's two direction
    nuisances absorb two more per group.

    Args:
        n_valid: number of stations used. n_groups: number of groups (0 with a
            reference attitude).
    Returns:
        chi2 per residual (dimensionless), at least 0.1.
    """
    return max((5.0 * n_valid - 2.0 * n_groups) / (6.0 * n_valid), 0.1)
