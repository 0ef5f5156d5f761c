"""``icgo_local``: a sweep's jobs in spawned processes, one process per job, ``workers`` at a time.

Why not joblib (loky) or submitit_local: a loky worker killed by its PID
aborts the whole multirun with ``TerminatedWorkerError`` (the job in the other
worker is lost, later jobs never run), and submitit_local stops launching.
Here each job is its own ``spawn`` process (never forked: JAX is initialised
inside the job), so a dead process costs only its job: the launcher leaves the
``FAILED`` marker ("killed by signal SIGKILL ...") in the job's directory and
starts the next one. The end-of-sweep report
(:class:`hydra_plugins.icgo_launcher.report.FailureReport`) then lists every job.

Each job's XLA runs on ``xla_threads`` threads; with one thread the job's
process is also pinned to its worker slot's cores (the cores shared out among the
slots: 16 cores and 3 workers give slots of 6, 5 and 5), so workers side by side
do not oversubscribe them. Every job gives the CPU as many host devices as a plain
run on the sweep's cores would (``icgo.core.devices.sweep_job_flags``), so its programs
are those a plain run compiled: the jobs load them from the persistent compilation
cache a single run filled (results are bitwise across host-device counts).

Ctrl-C stops the sweep: the running jobs are terminated (their run
directories are staged, so each is complete or absent), the report lists what
ran, and the launcher exits with status 130. Re-running the sweep into its
directory resumes it (finished jobs are kept: :mod:`hydra_plugins.icgo_launcher.jobs`).
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import signal
import sys
from collections import deque
from multiprocessing.connection import wait
from pathlib import Path
from typing import Any, Sequence

import cloudpickle
from hydra.core.hydra_config import HydraConfig
from hydra.core.singleton import Singleton
from hydra.core.utils import JobReturn, JobStatus, configure_log, filter_overrides, run_job, setup_globals
from omegaconf import OmegaConf, open_dict

from hydra_plugins.icgo_launcher import report
from hydra_plugins.icgo_launcher.jobs import FAILED, previous_run, write_failure
from icgo.core.devices import sweep_job_flags
from icgo.core.settings import first_line, interrupts_raise

log = logging.getLogger(__name__)

EXIT_CONFIG = 2
EXIT_INTERRUPTED = 130


def resolve_workers(workers: Any, n_jobs: int, cpus: int) -> int:
    """Jobs at once: ``workers`` (a positive integer) or, for None, one per CPU; at most ``n_jobs``."""
    if workers is None:
        workers = cpus
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ValueError(f"hydra.launcher.workers must be a positive integer or null (one per CPU), got {workers!r}")
    return max(1, min(workers, n_jobs))


def _check_threads(threads: Any) -> None:
    if threads is not None and (isinstance(threads, bool) or not isinstance(threads, int) or threads < 1):
        raise ValueError(f"hydra.launcher.xla_threads must be a positive integer or null (XLA's default), "
                         f"got {threads!r}")


def slot_cores(cpus: Sequence[int], workers: int, slot: int) -> list[int]:
    """The cores of worker slot ``slot`` of ``workers``: ``cpus`` cut into that many contiguous blocks."""
    n, k = len(cpus), max(1, min(int(workers), len(cpus)))
    lo, hi = slot * n // k, (slot + 1) * n // k
    return list(cpus[lo:hi])


def _child(payload: bytes, conn, threads: int | None, cores: list[int] | None, host_devices: int) -> None:
    """Entry point of a job's process: run one Hydra job and send back its JobReturn."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the launcher decides what Ctrl-C stops
    pinned = False
    if cores:
        try:
            os.sched_setaffinity(0, set(cores))
            pinned = True
        except OSError:  # a container that forbids it: the thread flags hold instead
            pass
    # before JAX starts its backend: a plain run's device count and flags, so the job loads its compiled programs
    os.environ["XLA_FLAGS"] = sweep_job_flags(threads, pinned, host_devices, os.environ.get("XLA_FLAGS", ""))
    config, hydra_context, task_function, singleton_state = cloudpickle.loads(payload)
    from icgo.studies.icgo_relm.progress import ENV_LINES  # (no JAX: the module imports none)

    os.environ[ENV_LINES] = f"job {config.hydra.job.num}"  # jobs share the terminal: progress lines, not bars
    setup_globals()
    Singleton.set_state(singleton_state)
    HydraConfig.instance().set_config(config)
    ret = run_job(hydra_context=hydra_context, config=config, task_function=task_function,
                  job_dir_key="hydra.sweep.dir", job_subdir_key="hydra.sweep.subdir")
    try:
        conn.send_bytes(cloudpickle.dumps(ret))
    except Exception:  # an unpicklable return value: the job's directory holds its result
        conn.send_bytes(cloudpickle.dumps(None))
    conn.close()


def _job_config(launcher, overrides: Sequence[str], idx: int):
    config = launcher.hydra_context.config_loader.load_sweep_config(launcher.config, list(overrides))
    with open_dict(config):
        config.hydra.job.id = f"{config.hydra.job.name}_{idx}"
        config.hydra.job.num = idx
    job_dir = Path(str(OmegaConf.select(config, "hydra.sweep.dir"))) / str(OmegaConf.select(config,
                                                                                            "hydra.sweep.subdir"))
    return config, job_dir


def _signal_name(code: int) -> str:
    try:
        return signal.Signals(-code).name
    except ValueError:
        return f"signal {-code}"


def _mark_dead(job_dir: Path, exitcode: int) -> str:
    """FAILED marker for a job whose process ended without a result (unless it left a complete run)."""
    if previous_run(job_dir) is not None:
        return "ok"
    if exitcode < 0:
        msg = (f"killed by {_signal_name(exitcode)}: the job's process died; re-run the sweep into its "
               f"directory to redo it")
    else:
        if (job_dir / FAILED).is_file():
            return "failed"
        msg = f"the job's process exited with status {exitcode} without a result"
    write_failure(job_dir, msg)
    return "killed" if exitcode < 0 else "failed"


def _placeholder(config, overrides, job_dir: Path) -> JobReturn:
    """A completed JobReturn without a value, so the sweeper goes on (the report names the job's status)."""
    return JobReturn(overrides=list(overrides), cfg=config, hydra_cfg=None, working_dir=str(job_dir),
                     task_name=str(config.hydra.job.name), status=JobStatus.COMPLETED, _return_value=None)


def _settle(ret: JobReturn | None, config, overrides, job_dir: Path, exitcode: int) -> JobReturn:
    """The JobReturn the sweeper receives for a finished job process."""
    if ret is None or exitcode != 0:
        status = _mark_dead(job_dir, exitcode)
        log.error("job %s %s", config.hydra.job.num, status)
        return _placeholder(config, overrides, job_dir)
    if ret.status == JobStatus.FAILED:  # the task raised past its own handler: record it, go on
        write_failure(job_dir, f"{type(ret._return_value).__name__}: {first_line(ret._return_value)}")
        return _placeholder(config, overrides, job_dir)
    return ret


def launch(launcher, job_overrides: Sequence[Sequence[str]], initial_job_idx: int) -> Sequence[JobReturn]:
    """Run the jobs ``workers`` at a time, each in its own process; a dead process costs only its job."""
    setup_globals()
    configure_log(launcher.config.hydra.hydra_logging, launcher.config.hydra.verbose)
    cpus = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else list(range(os.cpu_count() or 1))
    try:
        workers = resolve_workers(launcher.workers, len(job_overrides), len(cpus))
        _check_threads(launcher.xla_threads)
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        raise SystemExit(EXIT_CONFIG) from None
    # every job's config composed before the first job starts: a value Hydra refuses stops the sweep whole
    configs = {idx: _job_config(launcher, overrides, idx) for idx, overrides in enumerate(job_overrides,
                                                                                         start=initial_job_idx)}
    sweep_dir = Path(str(launcher.config.hydra.sweep.dir))
    sweep_dir.mkdir(parents=True, exist_ok=True)
    pin = launcher.xla_threads == 1 and workers <= len(cpus)
    log.info("icgo_local: %d job(s), %d at a time, XLA threads per job %s, sweep dir %s", len(job_overrides),
             workers, launcher.xla_threads or "default", sweep_dir)

    state = Singleton.get_state()
    ctx = mp.get_context("spawn")
    queue = deque(enumerate(job_overrides, start=initial_job_idx))
    results: dict[int, JobReturn] = {}
    running: dict[int, dict] = {}  # job index -> its process, pipe, received result, config, dir, slot
    free_slots = deque(range(workers))
    with interrupts_raise():  # Ctrl-C stops the jobs and reports (icgo.core.settings.on_interrupt)
        try:
            while queue or running:
                while queue and free_slots:
                    idx, overrides = queue.popleft()
                    config, job_dir = configs.pop(idx)
                    log.info("\t#%d : %s", idx, " ".join(filter_overrides(overrides)))
                    slot = free_slots.popleft()
                    recv, send = ctx.Pipe(duplex=False)
                    payload = cloudpickle.dumps((config, launcher.hydra_context, launcher.task_function, state))
                    proc = ctx.Process(target=_child, args=(payload, send, launcher.xla_threads,
                                                            slot_cores(cpus, workers, slot) if pin else None,
                                                            len(cpus)))
                    proc.start()
                    send.close()
                    running[idx] = dict(proc=proc, recv=recv, ret=None, overrides=overrides, config=config,
                                        dir=job_dir, slot=slot)
                # The pipe is read as soon as it has data: a result larger than the pipe's buffer
                # would otherwise block the job's process from exiting.
                owner = {}
                for idx, job in running.items():
                    owner[job["proc"].sentinel] = idx
                    if not job["recv"].closed:
                        owner[job["recv"]] = idx
                for ready in wait(list(owner)):
                    job = running[owner[ready]]
                    if ready is job["recv"]:
                        try:
                            job["ret"] = cloudpickle.loads(job["recv"].recv_bytes())
                        except (EOFError, OSError):  # the process died before it sent its result
                            pass
                        job["recv"].close()
                for idx in [i for i, job in running.items() if job["recv"].closed and not job["proc"].is_alive()]:
                    job = running.pop(idx)
                    job["proc"].join()
                    results[idx] = _settle(job["ret"], job["config"], job["overrides"], job["dir"], job["proc"].exitcode)
                    free_slots.append(job["slot"])
        except KeyboardInterrupt:
            for job in running.values():
                job["proc"].terminate()
            for job in running.values():
                job["proc"].join(timeout=10)
                if job["proc"].is_alive():  # a job that does not stop on SIGTERM
                    job["proc"].kill()
                    job["proc"].join()
                _mark_dead(job["dir"], job["proc"].exitcode if job["proc"].exitcode is not None else -signal.SIGTERM)
            print("interrupted (Ctrl-C): the running jobs were stopped", file=sys.stderr)
            report.report(launcher.config, file=sys.stderr)
            raise SystemExit(EXIT_INTERRUPTED) from None
    return [results[i] for i in sorted(results)]
