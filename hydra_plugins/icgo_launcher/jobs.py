"""One job of a run or a sweep: its directory's record of a finished run, the failure marker a failed job
leaves, and the identity of a job's configuration (the hash that lets a re-run sweep resume).

A sweep re-run into its directory keeps a finished job only when it ran this job's configuration (the
hash of its resolved config, :func:`config_hash`); one of another configuration is refused and left as
it was (:func:`resume`). A job that fails leaves :data:`FAILED` (one line: the error) and, for
an unexpected error, ``error.txt`` (the traceback); the end-of-sweep report
(:mod:`hydra_plugins.icgo_launcher.report`) reads them. :func:`run_guarded` runs a front door's job with these
rules (check, compute, write: each failure one line, or a marker in a sweep).

Nothing here imports JAX (the launcher imports this module when Hydra starts).
"""

from __future__ import annotations

import hashlib
import json
import logging
import sys
import time
import traceback
from pathlib import Path
from typing import Protocol

from omegaconf import DictConfig, OmegaConf

from icgo.core.settings import first_line

log = logging.getLogger(__name__)

#: Marker a failed multirun job leaves in its directory (one line: the error); the same name as
#: :data:`icgo.reporting.records.FAILED_FILE` (tested), written here without importing the records module.
FAILED = "FAILED"


#: Files a failed attempt leaves in a run directory (replaced by the next run; they do not make the directory used).
FAILURE_FILES = ("error.txt", FAILED)


#: Settings that change how a run is executed, not what it computes: left out of :func:`config_hash`.
RUNTIME_KEYS = ("overwrite", "progress", "jax_cache_dir", "devices", "tracking")


def config_hash(container: dict) -> str:
    """SHA-256 (hex) of a resolved config (a plain mapping, ``hydra`` node excluded) without :data:`RUNTIME_KEYS`:
    the identity of what a run computes. A sweep re-run into its directory keeps a finished job only when the
    hashes agree."""
    core = {k: v for k, v in container.items() if k not in RUNTIME_KEYS and k != "hydra"}
    return hashlib.sha256(json.dumps(core, sort_keys=True, default=str).encode()).hexdigest()


def cfg_hash(cfg: DictConfig) -> str:
    """:func:`config_hash` of a composed config."""
    return config_hash(OmegaConf.to_container(cfg, resolve=True))


def stored_config(outdir: Path) -> dict | None:
    """The resolved config a finished run recorded (its ``config.yaml``), or None if unreadable."""
    try:
        c = OmegaConf.to_container(OmegaConf.load(outdir / _records().CONFIG_FILE), resolve=False)
    except Exception:  # noqa: BLE001  (absent, not YAML: the run cannot be matched, so it is not kept)
        return None
    return c if isinstance(c, dict) else None


def stored_hash(outdir: Path, run: dict) -> str | None:
    """The config hash of a finished run: the one its run.json records, else that of its ``config.yaml``."""
    h = run.get("config_sha256")
    if isinstance(h, str):
        return h
    c = stored_config(outdir)
    return None if c is None else config_hash(c)


def config_difference(a: dict, b: dict, limit: int = 4) -> str:
    """``key: a-value vs b-value`` for the first keys (dotted) where two configs differ (runtime keys ignored)."""
    def flat(d, prefix=""):
        out = {}
        for k, v in d.items():
            if not prefix and k in RUNTIME_KEYS:
                continue
            if isinstance(v, dict):
                out.update(flat(v, f"{prefix}{k}."))
            else:
                out[f"{prefix}{k}"] = v
        return out

    fa, fb = flat(a), flat(b)
    keys = sorted(k for k in set(fa) | set(fb) if fa.get(k, "<absent>") != fb.get(k, "<absent>"))
    shown = [f"{k}: {fa.get(k, '<absent>')!r} there, {fb.get(k, '<absent>')!r} here" for k in keys[:limit]]
    return "; ".join(shown) + (f"; and {len(keys) - limit} more" if len(keys) > limit else "")


def previous_run(outdir: Path) -> dict | None:
    """The run record of a complete previous run in ``outdir``, or None (no run, or an unreadable record)."""
    records = _records()
    if not (outdir / records.RUN_FILE).is_file():
        return None
    try:
        return records.read_run(outdir)
    except records.RecordError:
        return None


def write_failure(outdir: Path, message: str, tb: str | None = None) -> None:
    """Leave the FAILED marker (one line) and, for unexpected errors, the traceback."""
    outdir.mkdir(parents=True, exist_ok=True)
    (outdir / FAILED).write_text(message.strip().splitlines()[0] + "\n")
    if tb:
        (outdir / "error.txt").write_text(tb)


def format_traceback(e: BaseException) -> str:
    """The traceback of an exception, as Python prints it."""
    return "".join(traceback.format_exception(type(e), e, e.__traceback__))


class Job(Protocol):
    """A front door's job as :func:`run_guarded` runs it (``typed``: the typed config; ``computed``: what
    ``compute`` returns; ``t0``: ``time.perf_counter()`` at the job's start)."""

    def check(self, cfg: DictConfig, outdir: Path):
        """The typed config, every setting and the run directory checked (ValueError: one line)."""

    def compute(self, typed, t0: float):
        """Load and run (ValueError: one line; anything else is a bug)."""

    def write(self, outdir: Path, cfg: DictConfig, typed, computed) -> dict:
        """Write the run directory all at once; returns the run record."""

    def report(self, typed, computed, run: dict, outdir: Path, t0: float) -> None:
        """Print the summary."""


def resume(cfg: DictConfig, outdir: Path, multirun: bool) -> tuple[bool, dict | None]:
    """(done, the job's result) for a run directory that already holds a finished run, unless ``overwrite=true``.

    In a sweep, re-running into its directory resumes it: a finished job is kept (done, its record) only when it
    ran this job's configuration (:func:`cfg_hash`); one of another configuration is refused and left as it was
    (done, None). Outside a sweep a complete run is refused: one line, exit status 2. Else (False, None).
    """
    previous = previous_run(outdir)
    if previous is None or cfg.get("overwrite") is True:
        return False, None
    if not multirun:
        print(f"error: {outdir} already holds a complete run; choose another hydra.run.dir or pass overwrite=true "
              f"(the old run is then replaced whole)", file=sys.stderr)
        raise SystemExit(2)
    there = stored_hash(outdir, previous)
    if there is not None and there == cfg_hash(cfg):
        log.info("kept the finished job in %s (overwrite=true reruns it)", outdir)
        (outdir / FAILED).unlink(missing_ok=True)
        return True, previous
    old = stored_config(outdir)
    diff = config_difference(old, OmegaConf.to_container(cfg, resolve=True)) if old else \
        "it records no readable config"
    log.error("refused: %s holds a finished run of another configuration (%s); it is left as it was "
              "(overwrite=true redoes the job, or choose another hydra.sweep.dir)", outdir, diff)
    return True, None


def run_guarded(cfg: DictConfig, outdir: Path, multirun: bool, job: Job) -> dict | None:
    """Run one job of a run or a sweep into ``outdir``: :func:`resume`, then ``job.check``, ``job.compute`` (every
    process of a multi-process job), ``job.write`` (the first process only) and ``job.report``.

    Outside a sweep a user's error (ValueError) is one line and exit status 2 or 1
    (:func:`icgo.core.settings.error_status`); in a sweep it leaves :data:`FAILED` (and the traceback of an error
    met while computing, any exception there) and the job returns None, so the other jobs go on.
    Returns the run record, or None for a failed or refused job (or a secondary process).
    """
    t0 = time.perf_counter()
    done, kept = resume(cfg, outdir, multirun)
    if done:
        return kept
    try:
        typed = job.check(cfg, outdir)
    except ValueError as e:
        return _failed(e, outdir, multirun)
    try:
        computed = job.compute(typed, t0)
    except ValueError as e:  # SettingError, DataError (icgo.core.errors), study/optimizer checks: one line each
        return _failed(e, outdir, multirun, format_traceback(e))
    except Exception as e:
        if not multirun:
            raise
        write_failure(outdir, f"{type(e).__name__}: {first_line(e)}", format_traceback(e))
        log.error("job failed: %s: %s", type(e).__name__, first_line(e))
        return None
    from icgo.core.devices import is_secondary_process

    if is_secondary_process():  # a multi-process job: the first process writes the run directory
        return None
    try:
        run = job.write(outdir, cfg, typed, computed)
    except ValueError as e:  # OutputError (a full disk, a read-only directory): the previous run is intact
        return _failed(e, outdir, multirun)
    job.report(typed, computed, run, outdir, t0)
    from hydra_plugins.icgo_launcher.tracking_hooks import track_job

    track_job(OmegaConf.to_container(cfg, resolve=True), outdir)  # MLflow, where installed and not turned off
    return run


def _failed(e: ValueError, outdir: Path, multirun: bool, tb: str | None = None) -> None:
    """A job's user error: in a sweep the FAILED marker (+ ``tb``) and None; else its one line and the exit."""
    if not multirun:
        from icgo.core.settings import error_status

        raise SystemExit(error_status(e) or 2)
    write_failure(outdir, first_line(e), tb)
    log.error("job failed: %s", first_line(e))
    return None


def _records():
    """:mod:`icgo.reporting.records`, imported when a run directory is read (it imports pandas, which a
    command's start and Hydra's plugin scan need not pay for)."""
    from icgo.reporting import records

    return records
