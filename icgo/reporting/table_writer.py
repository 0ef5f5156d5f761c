"""What every ``results/`` table builder shares: the list of what the builder now running lacks, the mean +/- std
of a column, and the writer of ``<name>.csv`` + ``<name>.md`` (title, stamp, protocol line, table, notes).

A builder returns True when it wrote its output; when it cannot, :func:`have` and :func:`skip` note why in
:data:`LACKING`, which the caller (:func:`icgo.studies.icgo_relm.results.build.build`) sets per builder and lists in
``tables_missing.txt``.
"""

from __future__ import annotations

import contextvars
from pathlib import Path

import numpy as np
import pandas as pd

from icgo.reporting import stamp

#: What the builder now running lacks (set per builder by :func:`icgo.studies.icgo_relm.results.build.build`,
#: filled by :func:`have` and :func:`skip`).
LACKING: contextvars.ContextVar[list] = contextvars.ContextVar("lacking")


def skip(reason: str) -> bool:
    """Note why the builder now running writes nothing (named in ``tables_missing.txt``); returns False."""
    LACKING.get([]).append(f"skipped: {reason}")
    return False


def n_repeats(m: pd.DataFrame) -> int:
    """The distinct repeats of a table (0 when it is empty)."""
    return int(m["repeat"].nunique()) if len(m) else 0


def one_draw(m: pd.DataFrame) -> str:
    """The data draw a table's numbers rest on, in words (every repeat re-splits and re-searches the same draw)."""
    draws = sorted({(str(d), int(s)) for d, s in zip(m["dataset"], m["seed"])}) if len(m) else []
    return ("one simulated draw (" + ", ".join(f"{d} noise seed {s}" for d, s in draws) + f"; its {n_repeats(m)} "
            "repeats re-split and re-search that draw, so the claim is not yet made over independent draws)")


def have(df: pd.DataFrame, methods) -> bool:
    """True if ``df`` has rows of every method; else the missing ones are noted for the builder's message."""
    missing = list(methods) if df.empty else [m for m in methods if m not in set(df["method"])]
    if missing:
        LACKING.get([]).extend(m for m in missing if m not in LACKING.get([]))
    return not missing


def mean_and_std(x) -> tuple[float, float]:
    """(mean, sample std) of a column; the std is NaN for a single value."""
    x = np.asarray(x, float)
    return float(x.mean()), float(x.std(ddof=1)) if x.size > 1 else float("nan")


def plus_minus(m, s=None, d=4) -> str:
    """``"m +/- s"`` with ``d`` decimals, or ``"m"`` alone when ``s`` is None or not finite."""
    return f"{m:.{d}f}" if s is None or not np.isfinite(s) else f"{m:.{d}f} +/- {s:.{d}f}"


def write_table(df: pd.DataFrame, out: Path, name: str, title: str, notes=(), protocol: str = "") -> None:
    """``<name>.csv`` and ``<name>.md``: title, stamp, protocol line, the table, the notes."""
    df.to_csv(out / f"{name}.csv", index=False)
    line = stamp.note()
    text = [f"# {title}", "", *([line, ""] if line else []), *([protocol, ""] if protocol else []),
            df.to_markdown(index=False), ""]
    text += [n for n in notes]
    (out / f"{name}.md").write_text("\n".join(text).rstrip() + "\n")
