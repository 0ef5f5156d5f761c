"""One job of a sweep as the launcher reads and marks its directory: the record of a finished run, the failure
marker a failed job leaves, and the identity of a job's configuration (the hash that lets a re-run sweep resume).

A sweep re-run into its directory keeps a finished job only when it ran this job's configuration (the
hash of its resolved config, :func:`config_hash`); one of another configuration is refused and left as
it was (the one study main, :func:`experiments._study_main.resume`). A job that fails leaves :data:`FAILED`
(one line: the error) and, for an unexpected error, ``error.txt`` (the traceback); the end-of-sweep report
(:mod:`hydra_plugins.icgo_launcher.report`) reads them, and the launcher leaves the marker of a job whose
process died.

Nothing here imports JAX (the launcher imports this module when Hydra starts).
"""

from __future__ import annotations

import hashlib
import json
import traceback
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

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


def _records():
    """:mod:`icgo.reporting.records`, imported when a run directory is read (it imports pandas, which a
    command's start and Hydra's plugin scan need not pay for)."""
    from icgo.reporting import records

    return records
