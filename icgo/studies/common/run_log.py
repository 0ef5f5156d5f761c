"""Lines a long run writes for a log: durations and rates in a few characters, and a line written to the run's log
files (Hydra's job log) without its console handlers (the caller prints it on stderr itself)."""

from __future__ import annotations

import logging

log = logging.getLogger("icgo.studies.progress")


def clock(seconds: float) -> str:
    """``H:MM:SS`` of a duration in seconds."""
    s = int(round(max(0.0, seconds)))
    return f"{s // 3600}:{s % 3600 // 60:02d}:{s % 60:02d}"


def count(n: float) -> str:
    """A rate or a count in a few characters: ``950``, ``16.9k``, ``3.2M``."""
    for div, unit in ((1e6, "M"), (1e3, "k")):
        if abs(n) >= div:
            return f"{n / div:.3g}{unit}"
    return f"{n:.3g}"


def to_log_files(text: str, logger: logging.Logger | None = None) -> None:
    """Write ``text`` as an INFO record to the file handlers of ``logger`` (default the root logger: Hydra's job
    log), not to its console handlers (the caller prints it on stderr itself)."""
    logger = logging.getLogger() if logger is None else logger
    record = log.makeRecord(log.name, logging.INFO, __file__, 0, text, None, None)
    for h in logger.handlers:
        if isinstance(h, logging.FileHandler) and record.levelno >= h.level:
            h.handle(record)
