"""How a batched search runs on the backend it finds: which fitness kernel, over how many devices, and why.

One program, one process per host: the search's batch (worlds x strategies x repeats, each member a whole
population run) is laid out over the devices JAX sees (:mod:`icgo.optim.sharded`). The plan is a pure function of
the backend's name (``jax.default_backend()``: ``cpu``, ``gpu``, ``cuda``, ``rocm``, ``tpu``, ``METAL``, ...), the
devices it has, the processes of the job, the ``devices`` setting and the number of members. Nothing here imports
JAX at module import, so the plan can be made, printed and tested before a backend starts; :func:`runtime_plan`
asks this process's JAX runtime.

* **CPU** (:data:`CPU_KERNEL`): the cache-chunked kernel (a chunk of thetas whose hidden outputs stay in cache,
  batch members one after another: :func:`icgo.models.relm.train_fitness`) sharded over the host devices, one per
  core the job may use (:func:`icgo.core.devices.use_host_devices`, set before the backend starts). A member's result
  does not depend on the members beside it, so any device count gives the one-device result bitwise.
* **Any accelerator** (:data:`ACCELERATOR_KERNEL`): the whole block of members on each device as batched matrix
  products, rows accumulated in bounded blocks (:mod:`icgo.models.relm_fused` for the paper's training fitness,
  :func:`icgo.models.relm_gram.gram_fitness` for the others), sharded over every accelerator of the job.
"""

from __future__ import annotations

from typing import NamedTuple

#: The CPU kernel's name: cache-sized chunks of thetas (``lax.map``), batch members one after another.
CPU_KERNEL = "cache_chunked"
#: The accelerator kernel's name: each device's whole block at once, rows accumulated in bounded blocks.
ACCELERATOR_KERNEL = "batched"


class ExecutionPlan(NamedTuple):
    """What a search runs as (recorded in run.json as ``execution``).

    Attributes:
        backend: the JAX backend's name, lower case (``cpu``, ``gpu``, ``tpu``, ``metal``, ...).
        kernel: :data:`CPU_KERNEL` or :data:`ACCELERATOR_KERNEL`.
        devices: devices the search's members are sharded over (1: one device).
        processes: JAX processes of the job (``jax.distributed``; 1 for one process).
        members: the search's batch members (independent runs), 0 without a search.
        why: one sentence saying why.
    """

    backend: str
    kernel: str
    devices: int
    processes: int
    members: int
    why: str


def is_accelerator(backend: str) -> bool:
    """True for every backend but the CPU (``gpu``, ``cuda``, ``rocm``, ``tpu``, ``METAL``, a plugin's name)."""
    return normalise_backend(backend) != "cpu"


def normalise_backend(backend: str) -> str:
    """The backend's name in lower case (``"METAL"`` -> ``"metal"``); a non-string or empty name is refused."""
    if not isinstance(backend, str) or not backend.strip():
        raise ValueError(f"execution plan: the backend must be a platform name such as 'cpu' or 'gpu', got {backend!r}")
    return backend.strip().lower()


def check_devices_setting(devices) -> None:
    """The ``devices`` setting: None (every device) or an integer >= 1; else one-line ValueError."""
    if devices is not None and (isinstance(devices, bool) or not isinstance(devices, int) or devices < 1):
        raise ValueError(f"execution plan: devices must be None (every device) or an integer >= 1, got {devices!r}")


def execution_plan(backend: str, available: int, members: int, devices: int | None = None, processes: int = 1,
                   cores: int | None = None) -> ExecutionPlan:
    """The kernel and the devices for a search of ``members`` independent runs on ``backend``.

    Args:
        backend: the JAX backend's name (``jax.default_backend()``).
        available: devices the backend has, over every process of the job (``len(jax.devices())``).
        members: the search's batch members (worlds x strategies x repeats); 0 or 1: one device.
        devices: the setting: None (every available device) or the most to use.
        processes: the job's JAX processes (``jax.process_count()``).
        cores: CPU cores the job may use (its affinity mask), named in the sentence on a CPU; None: not named.
    Returns:
        :class:`ExecutionPlan`; ``devices`` is the fewest that keep the largest block of members as small as
        with all of them (:func:`icgo.optim.sharded.balanced_devices`).
    """
    name = normalise_backend(backend)
    check_devices_setting(devices)
    available, members, processes = max(1, int(available)), max(0, int(members)), max(1, int(processes))
    usable = available if devices is None else min(devices, available)
    per = -(-max(members, 1) // usable)
    n = -(-max(members, 1) // per)
    where = "" if processes == 1 else f" across {processes} processes (jax.distributed)"
    if name == "cpu":
        kernel, what = CPU_KERNEL, "the cache-chunked kernel"
        have = (f"{available} host device(s)" + (f", one per core of the job's {cores}" if cores == available
                                                 else f" (the job may use {cores} core(s))" if cores else ""))
    else:
        kernel, what = ACCELERATOR_KERNEL, "batched matrix products in bounded row blocks"
        have = f"{available} {name} device(s)"
    if devices is not None and devices < available:
        have += f", devices={devices}"
    shards = (f"{members} member(s) in {n} shard(s) of at most {per}" if members else "no search")
    return ExecutionPlan(name, kernel, n, processes, members,
                         f"backend {name}: {what}; {have}{where}; {shards} (one sharded program)")


def runtime_plan(backend: str | None, members: int, devices: int | None, cores: int | None = None) -> ExecutionPlan:
    """:func:`execution_plan` for this process's JAX runtime (``backend`` None: the default backend; its device
    count over every process of the job; ``cores`` None: the cores this process may run on)."""
    import jax

    from icgo.core.devices import available_cores

    if backend is None:
        backend = jax.default_backend()
    try:
        available = len(jax.devices(backend))
    except RuntimeError:  # a backend named for a plan on another machine (tests, --help): plan for one device
        available = 1
    cores = len(available_cores()) if cores is None else cores
    return execution_plan(backend, available, members, devices, jax.process_count(), cores)
