"""A study's search split over worker processes, one per core (CPU only).

XLA's intra-op threads add nothing at the fitness's shapes (measured: one process on both
cores 15,400 evals/s at 1.67 CPU-seconds per second, one pinned core 16,100), while two
pinned processes side by side each keep their full rate. So the ICGO-RELM search's batch
(strategies x repeats) is split into blocks: worker ``k`` of ``n`` runs one block in its own
spawned process, pinned to one core with XLA on one thread, and sends back its hidden weights,
curves and evaluation counts; the parent puts them in place and scores them as before. A
member's search depends only on its own key, strategy and data, and the CPU kernel runs batch
members one after another (:func:`icgo.methods.relm.train_fitness`), so the result is bitwise
that of one process (tested). How many workers, and never more than one on an accelerator:
:func:`icgo.core.execution.execution_plan`.

The workers start before the parent prepares the data (:class:`Workers`), so their start-up
(Python, JAX and the study's modules) overlaps the parent's; they receive the prepared arrays of
their block, not the survey, and do not repeat the multi-station analysis.

This module knows nothing of a particular study: :class:`Workers` runs a module-level function
of the study on each block's payload (``icgo.studies.icgo_relm.search_block``).

Only the random protocol is split: fold protocols pad every member's training rows to the
batch's largest count, so a member's padded shape would depend on its block.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import pickle
import time
from multiprocessing.connection import wait

import numpy as np


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


#: The pipe to the parent inside a worker process (None in the parent): :func:`progress_sink` writes to it.
_PARENT = None


def progress_sink():
    """Inside a worker: a ``progress(done, total)`` that reports to the parent's :meth:`Workers.run`; else None."""
    if _PARENT is None:
        return None
    conn = _PARENT
    return lambda done, total: conn.send(("progress", (int(done), int(total)), None))


def _worker(conn, core: int | None, cache_dir: str | None, job: bytes) -> None:
    """A worker's process: one XLA thread on one core; import the job (and JAX), say ready, wait for the
    payload, run ``job(*payload)`` (its progress reports go to the parent: :func:`progress_sink`), send the
    arrays back with the worker's own timings."""
    global _PARENT
    _PARENT = conn
    t0 = time.perf_counter()
    os.environ["XLA_FLAGS"] = xla_flags(1, os.environ.get("XLA_FLAGS", ""))  # before JAX starts its backend
    if core is not None:
        try:
            os.sched_setaffinity(0, {core})
        except OSError:  # a container that forbids it: the thread flags still hold
            pass
    try:
        import jax

        from icgo.studies.timing import compile_seconds

        if cache_dir:
            jax.config.update("jax_compilation_cache_dir", cache_dir)
        fn = pickle.loads(job)  # imports the job's module
        jax.devices()  # start the backend now, not on the payload's clock
        times = {"import_s": time.perf_counter() - t0}
        conn.send(("ready", None, times))
        t1 = time.perf_counter()
        payload = conn.recv()
        t2, c2 = time.perf_counter(), compile_seconds()
        out = tuple(np.asarray(x) for x in fn(*pickle.loads(payload)))
        times.update(wait_s=t2 - t1, run_s=time.perf_counter() - t2, compile_s=compile_seconds() - c2)
        conn.send(("ok", out, times))
    except BaseException as e:  # noqa: BLE001 (the parent reports it in one line)
        conn.send(("error", f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}", None))
    finally:
        conn.close()


class Workers:
    """``n`` spawned worker processes, each pinned to one core with XLA on one thread, started at once so that
    their start (Python, JAX, the job's module: about a second each) overlaps the parent's own work.

    ``with Workers(job, n) as w: results = w.run(payloads, labels)``; leaving the block ends any worker
    still running. ``job`` is a module-level function (pickled by reference) returning a tuple of arrays.
    """

    def __init__(self, job, n: int):
        import jax

        cores = available_cores()
        cache_dir = jax.config.jax_compilation_cache_dir
        ctx = mp.get_context("spawn")
        blob = pickle.dumps(job)
        self.t0 = time.perf_counter()
        self.procs = []
        for k in range(n):
            parent, child = ctx.Pipe()
            p = ctx.Process(target=_worker, args=(child, cores[k % len(cores)] if len(cores) > 1 else None, cache_dir,
                                                  blob), daemon=True)
            p.start()
            child.close()
            self.procs.append((p, parent))

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _recv(self, k: int, label: str, expect: str):
        p, conn = self.procs[k]
        try:
            status, value, times = conn.recv()
        except EOFError:  # it died before answering (killed, out of memory)
            p.join()
            raise RuntimeError(f"study worker {k} ({label}) died with exit code {p.exitcode} before "
                               f"returning its search") from None
        if status not in ((expect,) if isinstance(expect, str) else expect):
            raise RuntimeError(f"study worker {k} ({label}): {value}")
        return value, times

    def run(self, payloads: list[tuple], labels: list[str], progress=None,
            weights=None) -> tuple[list[tuple], list[dict]]:
        """``job(*payload)`` in worker k for payload k (at most one payload per worker).

        ``progress``: optional ``progress(done, total)``: the workers' reports (:func:`progress_sink`) summed,
        each weighted by ``weights`` (e.g. its number of members), as they arrive.

        Returns:
            (the jobs' tuples of numpy arrays in payload order, one dict of timings per worker: ``ready_s``
            from the start to ready (parent's clock), ``import_s`` its own start, ``run_s`` the job,
            ``compile_s`` the job's compile or cache-load part, ``wait_s`` ready to payload).
        Raises:
            RuntimeError: one line naming the worker that failed or died and why.
        """
        if len(payloads) > len(self.procs):
            raise ValueError(f"{len(payloads)} payloads for {len(self.procs)} workers")
        timings = []
        for k, label in enumerate(labels):
            _, times = self._recv(k, label, "ready")
            timings.append({"ready_s": time.perf_counter() - self.t0, **times})
            self.procs[k][1].send(pickle.dumps(payloads[k]))
        results = [None] * len(labels)
        weights = [1] * len(labels) if weights is None else list(weights)
        done = [(0, 0)] * len(labels)
        waiting = {self.procs[k][1]: k for k in range(len(labels))}
        while waiting:
            for conn in wait(list(waiting)):
                k = waiting[conn]
                value, times = self._recv(k, labels[k], ("ok", "progress"))
                if times is None:  # a progress report
                    done[k] = value
                    if progress is not None and all(t for _, t in done):
                        progress(sum(d * w for (d, _), w in zip(done, weights)),
                                 sum(t * w for (_, t), w in zip(done, weights)))
                    continue
                self.procs[k][0].join()
                results[k] = value
                timings[k].update(times)
                del waiting[conn]
        return results, timings

    def close(self) -> None:
        for p, conn in self.procs:
            if p.is_alive():
                p.terminate()
            conn.close()
