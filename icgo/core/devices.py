"""The devices a job's programs run on: the CPU's cores as JAX host devices, and several processes through
``jax.distributed``.

A JAX process sees one CPU device unless told otherwise before its backend starts. One sharded program
(:mod:`icgo.optim.sharded`) then runs on one core's worth of that device. :func:`use_host_devices` sets the
CPU backend's device count to the cores the job may use (its affinity mask: a launcher that pinned a job to one
core gives one device), so the same program spreads a batch over every core, as it does over every GPU of a node.
:func:`start_distributed` joins the processes of a multi-node job (one process per node, started by SLURM or by
hand) into one JAX runtime whose devices are those of every process.

Nothing here imports JAX at module import: the entry points call these before anything starts JAX's backend.
"""

from __future__ import annotations

import dataclasses
import os
import sys
import warnings
from pathlib import Path

from icgo.core.errors import SettingError

#: The XLA flag that fixes the CPU backend's device count (read when the backend starts).
HOST_DEVICE_FLAG = "--xla_force_host_platform_device_count"
#: Environment variables of a hand-started multi-process job (``start_distributed`` without a cluster):
#: the coordinator's ``host:port``, the number of processes and this process's index.
ENV_COORDINATOR, ENV_PROCESSES, ENV_PROCESS_ID = "ICGO_COORDINATOR", "ICGO_NUM_PROCESSES", "ICGO_PROCESS_ID"


def available_cores() -> list[int]:
    """The CPU cores this process may run on (its affinity mask; all CPUs where there is none)."""
    try:
        return sorted(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return list(range(os.cpu_count() or 1))


def xla_flags(threads: int | None, inherited: str = "") -> str:
    """``XLA_FLAGS`` for a process on ``threads`` CPU threads (None: ``inherited`` unchanged)."""
    if threads is None:
        return inherited
    ours = (f"--xla_cpu_multi_thread_eigen={'false' if threads == 1 else 'true'} "
            f"intra_op_parallelism_threads={threads}")
    kept = " ".join(f for f in inherited.split()
                    if not f.startswith(("--xla_cpu_multi_thread_eigen", "intra_op_parallelism_threads")))
    return f"{kept} {ours}".strip()


def sweep_job_flags(threads: int | None, pinned: bool, host_devices: int, inherited: str = "") -> str:
    """``XLA_FLAGS`` of a sweep's job process, chosen so that its programs are the ones a plain run on this machine
    compiles (and the persistent compilation cache holds): JAX's cache key hashes ``XLA_FLAGS`` (the thread flags
    included) and the program's device count, but not :data:`HOST_DEVICE_FLAG`.

    ``host_devices``: the host-device count of a plain run here (the sweep's cores), kept for every job whatever
    its share of the cores (results are bitwise across host-device counts: ``tests/test_parallel.py``); one
    already fixed in ``inherited`` stays. ``pinned``: the process is bound to its cores by its affinity mask,
    which already sizes XLA's thread pool, so no thread flag is added; else :func:`xla_flags` with ``threads``.
    """
    flags = inherited if pinned else xla_flags(threads, inherited)
    if flagged_host_devices(flags) is None:
        flags = f"{flags} {HOST_DEVICE_FLAG}={int(host_devices)}".strip()
    return flags


def flagged_host_devices(flags: str | None = None) -> int | None:
    """The host-device count an ``XLA_FLAGS`` string fixes (``--xla_force_host_platform_device_count=N``), or None."""
    flags = os.environ.get("XLA_FLAGS", "") if flags is None else flags
    for f in flags.split():
        if f.startswith(HOST_DEVICE_FLAG + "="):
            try:
                return int(f.split("=", 1)[1])
            except ValueError:
                return None
    return None


def use_host_devices(n: int | None = None) -> int:
    """Give the CPU backend ``n`` host devices (default: one per core of :func:`available_cores`).

    Must run before JAX's backend starts (the first array, ``jax.devices()``): afterwards the count is fixed and
    this returns it unchanged. A count already fixed by ``XLA_FLAGS`` (:data:`HOST_DEVICE_FLAG`) or by
    ``jax_num_cpu_devices`` is kept. On a machine whose default backend is an accelerator the CPU devices are
    not used by the studies; setting them costs nothing.

    Returns:
        The CPU backend's device count the process will have (or has).
    """
    import jax

    want = len(available_cores()) if n is None else int(n)
    if want < 1:
        raise ValueError(f"host devices: need at least 1, got {n!r}")
    fixed = flagged_host_devices()
    if fixed is not None:
        return fixed
    current = int(jax.config.jax_num_cpu_devices)
    if current > 0 and n is None:  # set by the user (config or JAX_NUM_CPU_DEVICES): theirs
        return current
    try:
        jax.config.update("jax_num_cpu_devices", want)
    except RuntimeError:  # the backend already started: its count stays
        return len(jax.devices("cpu"))
    return want


def distributed_request(environ=None) -> dict | None:
    """The multi-process job this process belongs to, read from its environment, or None for a single process.

    A SLURM step of more than one task (``SLURM_NTASKS`` > 1 inside a job: the launcher's one process per node)
    is joined by JAX's own SLURM detection (``{"cluster": "slurm", ...}``); a hand-started job names its
    coordinator, size and rank in :data:`ENV_COORDINATOR`, :data:`ENV_PROCESSES`, :data:`ENV_PROCESS_ID`.

    Raises:
        ValueError: one line naming the variable that is malformed.
    """
    env = os.environ if environ is None else environ
    if env.get(ENV_COORDINATOR):
        try:
            n, rank = int(env.get(ENV_PROCESSES, "")), int(env.get(ENV_PROCESS_ID, ""))
        except ValueError:
            raise ValueError(f"{ENV_COORDINATOR} is set, so {ENV_PROCESSES} and {ENV_PROCESS_ID} must be integers, "
                             f"got {env.get(ENV_PROCESSES)!r} and {env.get(ENV_PROCESS_ID)!r}") from None
        if n < 1 or not 0 <= rank < n:
            raise ValueError(f"{ENV_PROCESSES}={n} and {ENV_PROCESS_ID}={rank}: need 0 <= process id < processes")
        return {"cluster": "env", "coordinator_address": env[ENV_COORDINATOR], "num_processes": n, "process_id": rank}
    try:
        tasks = int(env.get("SLURM_NTASKS") or env.get("SLURM_STEP_NUM_TASKS") or 1)
    except ValueError:
        return None
    if env.get("SLURM_JOB_ID") and env.get("SLURM_STEP_NODELIST") and tasks > 1:
        return {"cluster": "slurm", "num_processes": tasks, "process_id": int(env.get("SLURM_PROCID", 0))}
    return None


def start_distributed(request: dict | None = None) -> dict | None:
    """Join this process to its multi-process job (``jax.distributed.initialize``) before JAX's backend starts.

    ``request``: :func:`distributed_request`'s answer (default: read from the environment). A single process
    (None) does nothing. Returns the request acted on, or None.
    """
    request = distributed_request() if request is None else request
    if request is None:
        return None
    import jax  # (the module imports JAX only where a job starts it, see the module docstring)

    if jax.distributed.is_initialized():
        return request
    if request["cluster"] == "slurm":
        jax.distributed.initialize()  # JAX reads SLURM's variables (coordinator: the step's first node)
    else:
        jax.distributed.initialize(coordinator_address=request["coordinator_address"],
                                   num_processes=request["num_processes"], process_id=request["process_id"])
    return request


def start_devices() -> dict:
    """Before JAX's backend starts: join a multi-process job (:func:`start_distributed`, e.g. the SLURM launcher's one
    process per node), then give the CPU backend one host device per core the job may use
    (:func:`use_host_devices`). Returns ``{"distributed": request or None, "host_devices": n}``.

    Raises:
        SettingError: a malformed ``ICGO_*`` variable (one line).
    """
    try:
        request = start_distributed()
    except ValueError as e:
        raise SettingError(str(e)) from None
    return {"distributed": request, "host_devices": use_host_devices()}


def is_secondary_process() -> bool:
    """True in every process of a multi-process job but the first: they compute with it, it alone writes."""
    jax = sys.modules.get("jax")
    return jax is not None and jax.process_index() != 0


#: Size bound of the persistent compilation cache (bytes), least recently used entries evicted beyond it. Any bound
#: turns on JAX's file lock (``filelock``) around each cache read and write: without one, JAX writes an entry in
#: place, and a process reading it while another (a parallel sweep's job, the other test worker) writes it can be
#: handed a torn program.
CACHE_MAX_BYTES = 4 * 2**30
#: The doors' ``jax_cache_dir`` default (the persistent compilation cache): under the user's cache directory
#: (XDG_CACHE_HOME, else ~/.cache, else /tmp/.cache), an OmegaConf interpolation resolved when the door composes.
JAX_CACHE_DEFAULT = "${oc.env:XDG_CACHE_HOME,${oc.env:HOME,/tmp}/.cache}/icgo/jax"


@dataclasses.dataclass(frozen=True)
class CacheSetting:
    """The compilation cache setting of the doors whose study config does not hold it (calibrate, discrepancy, misma,
    gyro: their ConfigStore node takes this default, :mod:`experiments._schema`; the run door's is
    ``RunConfig.jax_cache_dir``).

    Attributes:
        jax_cache_dir: JAX's persistent compilation cache (repeated runs and sweep jobs reuse compiled programs);
            None: off. Default: under the user's cache directory (XDG_CACHE_HOME or ~/.cache).
    """

    jax_cache_dir: str | None = JAX_CACHE_DEFAULT


def enable_jax_cache(path: str | None, min_compile_secs: float = 0.0) -> None:
    """Turn on JAX's persistent compilation cache in ``path`` (None: leave it off), locked and bounded
    (:data:`CACHE_MAX_BYTES`), caching every program that took at least ``min_compile_secs`` to compile.

    Programs with host callbacks are never cached by JAX (the progress bar reports between compiled chunks,
    so the study's programs are cached with or without it). JAX's warnings about a cache entry it could not
    write or read are silenced (the run goes on; the entry is compiled again).

    Raises:
        SettingError: the directory cannot be created (one line naming ``jax_cache_dir``).
    """
    if not path:
        return
    import jax  # (the module imports JAX only where a job starts it, see the module docstring)

    p = Path(path).expanduser()
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as e:  # a read-only file system, a file in the way
        raise SettingError(f"jax_cache_dir {str(p)!r}: cannot create the cache directory ({e.strerror}); "
                           f"set jax_cache_dir=null to run without the cache") from None
    jax.config.update("jax_compilation_cache_dir", str(p))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", min_compile_secs)
    jax.config.update("jax_compilation_cache_max_size", CACHE_MAX_BYTES)
    # a cache entry that cannot be written (a full disk) or read (cut short by an interrupted run) only costs a
    # compilation: JAX warns and goes on, and the command's one error or interruption line stays the only one
    warnings.filterwarnings("ignore", message=r"Error (writing|reading) persistent compilation cache entry",
                            category=UserWarning)


def env_info() -> dict:
    """Host facts a run records: the process id and the CPU count."""
    return {"pid": os.getpid(), "cpu_count": os.cpu_count()}
