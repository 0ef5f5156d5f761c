"""A study's search split over worker processes, one per core.

XLA's intra-op threads add nothing at the fitness's shapes (measured: one process on both
cores 15,400 evals/s at 1.67 CPU-seconds per second, one pinned core 16,100), while two
pinned processes side by side each keep their full rate. So the ICGO-RELM search's batch
(strategies x repeats) is split by repeats: worker ``k`` of ``n`` runs a contiguous block of
the repeat ids in its own spawned process, pinned to one core with XLA on one thread, and
sends back its hidden weights, curves and evaluation counts; the parent concatenates them in
repeat order and scores them as before. A repeat's search depends only on its own key and
data, and the batched kernels run batch members one after another
(:func:`icgo.methods.relm.train_fitness`), so the result is bitwise that of one process (tested).

This module knows nothing of a particular study: :func:`run_in_workers` runs a module-level
function of the study on each block's payload (``icgo.studies.icgo_relm.search_block``).

Only the random protocol is split: fold protocols pad every member's training rows to the
batch's largest count, so a member's padded shape would depend on its block.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import pickle
from multiprocessing.connection import wait
from typing import Any

import numpy as np

#: Estimated search work (fitness evaluations x training rows x methods x repeats) below
#: which ``workers=None`` (auto) stays in one process: starting a worker (importing JAX,
#: loading or compiling its program) costs a few seconds, about 1e8 row-evaluations here.
AUTO_MIN_WORK = 1e8


def xla_flags(threads: int | None, inherited: str = "") -> str:
    """``XLA_FLAGS`` for a process on ``threads`` CPU threads (None: ``inherited`` unchanged)."""
    if threads is None:
        return inherited
    ours = (f"--xla_cpu_multi_thread_eigen={'false' if threads == 1 else 'true'} "
            f"intra_op_parallelism_threads={threads}")
    kept = " ".join(f for f in inherited.split()
                    if not f.startswith(("--xla_cpu_multi_thread_eigen", "intra_op_parallelism_threads")))
    return f"{kept} {ours}".strip()


def available_cores() -> list[int]:
    """The CPU cores this process may run on (its affinity mask; all CPUs where there is none)."""
    try:
        return sorted(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return list(range(os.cpu_count() or 1))


def plan_workers(workers: int | None, n_repeats: int, work: float, cores: int | None = None) -> int:
    """Worker processes for a search: ``workers`` (>= 1) or, for None, one per available core
    when ``work`` (row-evaluations) reaches :data:`AUTO_MIN_WORK`; never more than the repeats.

    A job that a launcher pinned to one core (``icgo_local``, SLURM with one CPU) sees one
    available core, so a sweep's jobs are never split again.
    """
    cores = len(available_cores()) if cores is None else cores
    n = (cores if work >= AUTO_MIN_WORK else 1) if workers is None else int(workers)
    return max(1, min(n, n_repeats))


#: The pipe to the parent inside a worker process (None in the parent): :func:`progress_sink` writes to it.
_PARENT = None


def progress_sink():
    """Inside a worker: a ``progress(done, total)`` that reports to the parent's :func:`run_in_workers`; else None."""
    if _PARENT is None:
        return None
    conn = _PARENT
    return lambda done, total: conn.send(("progress", (int(done), int(total))))


def _worker(conn, core: int | None, cache_dir: str | None, job, payload: bytes) -> None:
    """A worker's process: one XLA thread on one core, ``job(*payload)``, send the arrays back."""
    global _PARENT
    _PARENT = conn
    os.environ["XLA_FLAGS"] = xla_flags(1, os.environ.get("XLA_FLAGS", ""))  # before JAX starts its backend
    if core is not None:
        try:
            os.sched_setaffinity(0, {core})
        except OSError:  # a container that forbids it: the thread flags still hold
            pass
    try:
        import jax

        if cache_dir:
            jax.config.update("jax_compilation_cache_dir", cache_dir)
        out = job(*pickle.loads(payload))
        conn.send(("ok", tuple(np.asarray(x) for x in out)))
    except BaseException as e:  # noqa: BLE001 (the parent reports it in one line)
        conn.send(("error", f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"))
    finally:
        conn.close()


def run_in_workers(job, payloads: list[tuple], labels: list[str], progress=None, weights=None) -> list[tuple]:
    """``job(*payload)`` for each payload, each in its own spawned process pinned to one core.

    Args:
        job: a module-level function (pickled by reference) returning a tuple of arrays.
        payloads: one tuple of arguments per worker (pickled).
        labels: one per worker, naming it in errors (e.g. ``"repeats 0-4"``).
        progress: optional ``progress(done, total)``: the workers' reports (:func:`progress_sink`) summed,
            each weighted by ``weights`` (e.g. its number of repeats), as they arrive.
    Returns:
        The jobs' tuples of numpy arrays, in payload order.
    Raises:
        RuntimeError: one line naming the worker that failed or died and why.
    """
    import jax

    cores = available_cores()
    cache_dir = jax.config.jax_compilation_cache_dir
    ctx = mp.get_context("spawn")
    procs = []
    for k, payload in enumerate(payloads):
        parent, child = ctx.Pipe(duplex=False)
        p = ctx.Process(target=_worker, args=(child, cores[k % len(cores)] if len(cores) > 1 else None,
                                              cache_dir, job, pickle.dumps(payload)), daemon=True)
        p.start()
        child.close()
        procs.append((p, parent, labels[k]))
    results: list[Any] = [None] * len(procs)
    weights = [1] * len(procs) if weights is None else list(weights)
    done = [(0, 0)] * len(procs)
    waiting = {conn: k for k, (_, conn, _) in enumerate(procs)}
    try:
        while waiting:
            for conn in wait(list(waiting)):
                k = waiting[conn]
                p, _, label = procs[k]
                try:
                    status, value = conn.recv()
                except EOFError:  # it died before answering (killed, out of memory)
                    p.join()
                    raise RuntimeError(f"study worker {k} ({label}) died with exit code {p.exitcode} before "
                                       f"returning its search") from None
                if status == "progress":
                    done[k] = value
                    if progress is not None and all(t for _, t in done):
                        progress(sum(d * w for (d, _), w in zip(done, weights)),
                                 sum(t * w for (_, t), w in zip(done, weights)))
                    continue
                p.join()
                if status != "ok":
                    raise RuntimeError(f"study worker {k} ({label}): {value}")
                results[k] = value
                del waiting[conn]
    finally:
        for p, conn, _ in procs:
            if p.is_alive():
                p.terminate()
            conn.close()
    return results
