"""icgo: JAX framework for inclinometer / MWD azimuth error compensation.

Importing the package enables JAX float64 (``jax_enable_x64``): the RELM ridge
solve and the least-squares fits need it (see ENGINEERING-NOTES: float32 ridge
solves fail on ill-conditioned sigmoid features). float32 paths are still
available by passing float32 arrays explicitly.
"""

import jax

jax.config.update("jax_enable_x64", True)

__version__ = "0.1.0"
