"""Shifted and rotated benchmark functions in JAX (CEC 2017 shift/rotation data).

CGO and SMA contract toward the origin (ENGINEERING-NOTES), so optimizers are
only compared on shifted and rotated functions. Each function is evaluated as

    z = M (s (x - o)),   error(x) = g(z)   (>= 0, 0 at x = o)

with o the CEC 2017 shift vector and M the CEC 2017 rotation matrix of the
given slot (:data:`CEC2017_DATA`, vendored from ``opfunu``), s a per-function scale
and g the base function. The functions return the *error* f(x) - f*, i.e.
opfunu's value minus its bias. Search box [-100, 100]^D.

Slots and scales (opfunu numbering of ``cec2017.F{k}2017``):

========== ==== ============ =========================================
name       slot scale s      reference in opfunu
========== ==== ============ =========================================
sphere     1    1            ``operator.sphere_func`` on slot-1 data
ellipsoid  2    1            ``operator.elliptic_func`` on slot-2 data
rosenbrock 3    2.048/100    ``cec2017.F32017`` (g(z) = rosen(z + 1))
rastrigin  4    1            ``cec2017.F42017``
ackley     5    1            ``operator.ackley_func`` on slot-5 data
griewank   6    600/100      ``operator.griewank_func`` on slot-6 data
levy       8    5.12/100     ``cec2017.F82017`` (g(z) = levy(z + 1))
schwefel   9    1000/100     ``cec2017.F92017`` (modified Schwefel)
bent_cigar 1    1            ``cec2017.F12017``
zakharov   2    1            ``cec2017.F22017``
========== ==== ============ =========================================

The first eight are the study set (:data:`STUDY`). Data other than CEC 2017
(e.g. dimensions it does not ship) can be drawn with ``data="random"``: a
uniform shift in [-80, 80]^D and a Haar-random rotation from a seed.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

BOX = 100.0


def _sphere(z):
    return jnp.sum(z * z, axis=-1)


def _ellipsoid(z):
    D = z.shape[-1]
    w = 10.0 ** (6.0 * jnp.arange(D) / (D - 1))
    return jnp.sum(w * z * z, axis=-1)


def _rosenbrock(z):
    x = z + 1.0
    return jnp.sum(100.0 * (x[..., :-1] ** 2 - x[..., 1:]) ** 2 + (x[..., :-1] - 1.0) ** 2, axis=-1)


def _rastrigin(z):
    return jnp.sum(z * z - 10.0 * jnp.cos(2 * jnp.pi * z) + 10.0, axis=-1)


def _ackley(z):
    D = z.shape[-1]
    t1 = jnp.sum(z * z, axis=-1)
    t2 = jnp.sum(jnp.cos(2 * jnp.pi * z), axis=-1)
    return -20.0 * jnp.exp(-0.2 * jnp.sqrt(t1 / D)) - jnp.exp(t2 / D) + 20.0 + jnp.e


def _griewank(z):
    D = z.shape[-1]
    return jnp.sum(z * z, axis=-1) / 4000.0 - jnp.prod(jnp.cos(z / jnp.sqrt(jnp.arange(1, D + 1))), axis=-1) + 1.0


def _levy(z):
    w = 1.0 + z / 4.0  # x = z + 1, w = 1 + (x - 1)/4
    t1 = jnp.sin(jnp.pi * w[..., 0]) ** 2 + (w[..., -1] - 1) ** 2 * (1 + jnp.sin(2 * jnp.pi * w[..., -1]) ** 2)
    t2 = jnp.sum((w[..., :-1] - 1) ** 2 * (1 + 10 * jnp.sin(jnp.pi * w[..., :-1] + 1) ** 2), axis=-1)
    return t1 + t2


def _schwefel(z):
    """Modified Schwefel (CEC 2017 / 2021 C code, as in opfunu)."""
    D = z.shape[-1]
    z = z + 4.209687462275036e2
    fm = jnp.fmod(z, 500.0)
    fa = jnp.fmod(jnp.abs(z), 500.0)
    hi = (500.0 - fm) * jnp.sin(jnp.sqrt(jnp.abs(500.0 - fm))) - ((z - 500.0) / 100.0) ** 2 / D
    lo = (-500.0 + fa) * jnp.sin(jnp.sqrt(jnp.abs(500.0 - fa))) - ((z + 500.0) / 100.0) ** 2 / D
    mid = z * jnp.sin(jnp.sqrt(jnp.abs(z)))
    g = jnp.where(z > 500.0, hi, jnp.where(z < -500.0, lo, mid))
    return 4.189828872724338e2 * D - jnp.sum(g, axis=-1)


def _bent_cigar(z):
    return z[..., 0] ** 2 + 1e6 * jnp.sum(z[..., 1:] ** 2, axis=-1)


def _zakharov(z):
    s = jnp.sum(0.5 * z, axis=-1)
    return jnp.sum(z * z, axis=-1) + s**2 + s**4


# name -> (base function, CEC 2017 slot, scale)
SPECS: dict[str, tuple[Callable, int, float]] = {
    "sphere": (_sphere, 1, 1.0),
    "ellipsoid": (_ellipsoid, 2, 1.0),
    "rosenbrock": (_rosenbrock, 3, 2.048 / 100.0),
    "rastrigin": (_rastrigin, 4, 1.0),
    "ackley": (_ackley, 5, 1.0),
    "griewank": (_griewank, 6, 600.0 / 100.0),
    "levy": (_levy, 8, 5.12 / 100.0),
    "schwefel": (_schwefel, 9, 1000.0 / 100.0),
    "bent_cigar": (_bent_cigar, 1, 1.0),
    "zakharov": (_zakharov, 2, 1.0),
}
#: The eight functions of the optimizer study.
STUDY = ("sphere", "ellipsoid", "rastrigin", "ackley", "griewank", "rosenbrock", "schwefel", "levy")


class Benchmark(NamedTuple):
    """A shifted, rotated benchmark function.

    Attributes:
        name: function name.
        fn: batched error ``fn(x) -> (P,)`` for x of shape (P, D) (also (D,) -> ()).
        bounds: ``(lb, ub)``, each (D,) = [-100, 100]^D.
        x_opt: the optimum o, shape (D,); ``fn(x_opt) == 0`` up to rounding.
        shift: o, (D,); rotation: M, (D, D); scale: s.
    """

    name: str
    fn: Callable
    bounds: tuple
    x_opt: np.ndarray
    shift: np.ndarray
    rotation: np.ndarray
    scale: float


#: The CEC 2017 shift vectors and rotation matrices of slots 1-9 in 2, 10, 20, 30, 50 and 100 dimensions
#: (where the suite ships them), vendored from opfunu 1.0.4's ``cec_based/data_2017`` text files
#: (``shift_data_{slot}.txt``, ``M_{slot}_D{dim}.txt``; the CEC 2017 competition's data, Awad et al. 2016)
#: as arrays ``shift_{slot}`` and ``rotation_{slot}_D{dim}``; ``tests/test_benchmarks.py`` checks them
#: against opfunu's files where opfunu imports (it needs setuptools < 81 for ``pkg_resources``).
CEC2017_DATA = "cec2017.npz"


@lru_cache(maxsize=1)  # a data cache, not a function's identity: the vendored file is read once per process
def _cec2017_arrays() -> dict:
    from importlib import resources

    with resources.files("icgo").joinpath("data").joinpath(CEC2017_DATA).open("rb") as f, np.load(f) as z:
        return {k: z[k] for k in z.files}


def cec2017_data(slot: int, dim: int) -> tuple[np.ndarray, np.ndarray]:
    """Shift vector (D,) and rotation matrix (D, D) of a CEC 2017 slot."""
    arrays = _cec2017_arrays()
    key = f"rotation_{slot}_D{dim}"
    if key not in arrays:
        raise ValueError(f"CEC 2017 has no rotation data for slot {slot} in {dim} dimensions (use data='random')")
    return arrays[f"shift_{slot}"][:dim], arrays[key]


def random_data(dim: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Uniform shift in [-80, 80]^D and a Haar-random orthogonal matrix."""
    rng = np.random.default_rng(seed)
    q, r = np.linalg.qr(rng.standard_normal((dim, dim)))
    return rng.uniform(-80.0, 80.0, dim), q * np.sign(np.diag(r))


def make(name: str, dim: int, data: str = "cec2017", seed: int = 0) -> Benchmark:
    """Build a shifted/rotated benchmark.

    Args:
        name: one of :data:`SPECS`.
        dim: dimension D (CEC 2017 data: 2, 10, 20, 30, 50, 100 where shipped).
        data: ``cec2017`` (:data:`CEC2017_DATA`) or ``random``.
        seed: seed of the ``random`` data.

    Returns:
        :class:`Benchmark`.
    """
    if name not in SPECS:
        raise ValueError(f"unknown benchmark {name!r}; choose one of {sorted(SPECS)}")
    if not isinstance(dim, (int, np.integer)) or dim < 2:
        raise ValueError(f"benchmark dimension must be an integer >= 2, got {dim!r}")
    base, slot, scale = SPECS[name]
    if data == "cec2017":
        shift, rot = cec2017_data(slot, int(dim))
    elif data == "random":
        shift, rot = random_data(int(dim), seed)
    else:
        raise ValueError(f"unknown benchmark data {data!r}; choose 'cec2017' or 'random'")
    o, MT = jnp.asarray(shift), jnp.asarray(rot.T)

    def fn(x):
        z = (scale * (x - o)) @ MT
        return base(z)

    lb, ub = -BOX * np.ones(dim), BOX * np.ones(dim)
    return Benchmark(name, jax.jit(fn), (lb, ub), shift, shift, rot, scale)


class Suite(NamedTuple):
    """Several benchmarks of one dimension as data, for one compiled fitness.

    Attributes:
        shift: (F, D); rot_t: (F, D, D) transposed rotations; scale: (F,);
        index: (F,) int position in :data:`SPECS` order of each function.
    """

    shift: jax.Array
    rot_t: jax.Array
    scale: jax.Array
    index: jax.Array


_BASES = tuple(spec[0] for spec in SPECS.values())
_NAMES = tuple(SPECS)


def suite(names, dim: int, data: str = "cec2017", seed: int = 0) -> Suite:
    """Stack benchmarks into a :class:`Suite` (leading axis F = len(names))."""
    bs = [make(n, dim, data, seed) for n in names]
    return Suite(jnp.asarray(np.stack([b.shift for b in bs])), jnp.asarray(np.stack([b.rotation.T for b in bs])),
                 jnp.asarray([b.scale for b in bs]), jnp.asarray([_NAMES.index(n) for n in names], jnp.int32))


def suite_fitness(x, aux: Suite):
    """Error of the suite member ``aux`` (one slice of a :class:`Suite`) at x (P, D).

    The function is chosen by ``lax.switch`` on ``aux.index``, so all functions
    share one compiled program and can be vmapped as per-repeat ``aux`` data.
    """
    z = (aux.scale * (x - aux.shift)) @ aux.rot_t
    return jax.lax.switch(aux.index, _BASES, z)
