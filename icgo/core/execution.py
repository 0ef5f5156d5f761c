"""How a batched search runs on the backend it finds: which fitness kernel, how many processes, and why.

One set of defaults for every machine: the plan is a pure function of the JAX backend's name
(``jax.default_backend()``: ``cpu``, ``gpu``, ``cuda``, ``rocm``, ``tpu``, ``METAL``, ...), the
cores the job may use, the ``workers`` setting and the size of the search. Nothing here imports
JAX, so the plan can be made, printed and tested before a backend starts.

* **CPU** (:data:`CPU_KERNEL`): the cache-chunked kernel (a chunk of thetas whose hidden outputs
  stay in cache, batch members one after another: :func:`icgo.methods.relm.train_fitness`) and one
  worker process per core the job may use, each on one XLA thread (measured: XLA's intra-op
  threads add nothing at the fitness's shapes, two pinned processes keep their full rate each).
* **Any accelerator** (:data:`ACCELERATOR_KERNEL`): the whole strategies x repeats x population
  batch as batched matrix products, rows accumulated in blocks of bounded size
  (:func:`icgo.methods.relm.gram_fitness`), inside the one jitted ``lax.scan`` over iterations (no
  host round trip in the loop), and exactly one process: several processes opening one
  accelerator fail (measured on a GPU: ``cuSolver internal error`` in each one's first program)
  or share it with nothing gained.
"""

from __future__ import annotations

from typing import NamedTuple

#: The CPU kernel's name: cache-sized chunks of thetas (``lax.map``), batch members one after another.
CPU_KERNEL = "cache_chunked"
#: The accelerator kernel's name: the whole batch at once, rows accumulated in bounded blocks.
ACCELERATOR_KERNEL = "batched"
#: Estimated search work (fitness evaluations x training rows x methods x repeats) below which
#: ``workers=None`` (auto) stays in one process on a CPU: starting a worker (importing JAX,
#: loading its program) costs a few seconds, about 1e8 row-evaluations on one core here.
AUTO_MIN_WORK = 1e8


class ExecutionPlan(NamedTuple):
    """What a search runs as (recorded in run.json as ``execution``).

    Attributes:
        backend: the JAX backend's name, lower case (``cpu``, ``gpu``, ``tpu``, ``metal``, ...).
        kernel: :data:`CPU_KERNEL` or :data:`ACCELERATOR_KERNEL`.
        workers: processes the search runs in (1 on an accelerator, always).
        why: one sentence saying why.
    """

    backend: str
    kernel: str
    workers: int
    why: str


def is_accelerator(backend: str) -> bool:
    """True for every backend but the CPU (``gpu``, ``cuda``, ``rocm``, ``tpu``, ``METAL``, a plugin's name)."""
    return normalise_backend(backend) != "cpu"


def normalise_backend(backend: str) -> str:
    """The backend's name in lower case (``"METAL"`` -> ``"metal"``); a non-string or empty name is refused."""
    if not isinstance(backend, str) or not backend.strip():
        raise ValueError(f"execution plan: the backend must be a platform name such as 'cpu' or 'gpu', got {backend!r}")
    return backend.strip().lower()


def execution_plan(backend: str, cores: int, workers: int | None = None, blocks: int = 1,
                   work: float = 0.0) -> ExecutionPlan:
    """The kernel and the number of processes for a search on ``backend``.

    Args:
        backend: the JAX backend's name (``jax.default_backend()``).
        cores: CPU cores the job may use (its affinity mask: a launcher that pinned a job to one core
            gives 1, so a sweep's jobs are never split again).
        workers: the setting: None (auto) or an integer >= 1.
        blocks: the most processes the search can be split into (its independent blocks).
        work: the search's row-evaluations (fitness evaluations x training rows x methods x repeats).
    Returns:
        :class:`ExecutionPlan`.
    """
    name = normalise_backend(backend)
    if workers is not None and (isinstance(workers, bool) or int(workers) != workers or workers < 1):
        raise ValueError(f"execution plan: workers must be None or an integer >= 1, got {workers!r}")
    blocks, cores = max(1, int(blocks)), max(1, int(cores))
    if name != "cpu":
        asked = "" if workers in (None, 1) else f"; workers={workers} would open it from {workers} processes"
        return ExecutionPlan(name, ACCELERATOR_KERNEL, 1,
                             f"backend {name} is an accelerator: the whole batch as batched matrix products in one "
                             f"process{asked}")
    if workers is not None:
        n = min(int(workers), blocks)
        why = f"workers={workers}" + (f", capped at the search's {blocks} block(s)" if n < workers else "")
    elif work < AUTO_MIN_WORK:
        n, why = 1, f"a small search ({work:.2g} row-evaluations < {AUTO_MIN_WORK:.0e}) does not pay for a process"
    else:
        n = min(cores, blocks)
        why = f"one process per available core ({cores})" + (f", capped at the search's {blocks} block(s)"
                                                             if n < cores else "")
    return ExecutionPlan(name, CPU_KERNEL, n, f"backend cpu: the cache-chunked kernel; {n} process(es): {why}")
