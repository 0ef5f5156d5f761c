"""The benchmark's ``--rows``: the commands a user runs on a large contract CSV, timed with their peak memory.

A recording of each size is written (:func:`write_large_recording`), then each command runs in its own process
(:func:`icgo.bench.process.measure`): the reader (``icgo.io.recording.read_recording``), the ICGO-RELM study
(``experiments.run dataset=csv``) and the discrepancy workflow (``experiments.discrepancy data=FILE``).
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from icgo.bench.process import measure
from icgo.datasets import casing_stations as datasets
from icgo.io.recording import write_recording

#: Measurement noise added to each tiled copy of the lab_casing rows (1 sigma per axis): g and nT,
#: the discrepancy workflow's default noise (``icgo.discrepancy.NOISE``).
TILE_NOISE = (3e-4, 15.0)


def write_large_recording(path, n_rows: int, seed: int = 0):
    """A contract CSV (+ ``.meta.json``) of ``n_rows`` rows: lab_casing tiled, fresh noise on every copy.

    The simulated lab_casing survey (583 rows, ICGO 3.1) is repeated until it has
    ``n_rows`` rows; every copy gets independent white noise of :data:`TILE_NOISE`
    on G (g) and B (nT), the reference attitude is kept, ``station`` counts rows.

    Args:
        path: CSV path (its directory must exist). n_rows: rows (>= 1). seed: noise seed.
    Returns:
        The written :class:`icgo.io.recording.Recording`.
    """
    ds = datasets.lab_casing(0)
    base = ds.frame
    idx = np.arange(n_rows) % len(base)
    frame = base.iloc[idx].reset_index(drop=True)
    rng = np.random.default_rng(seed)
    for cols, sigma in zip((["gx", "gy", "gz"], ["bx", "by", "bz"]), TILE_NOISE):
        frame[cols] = frame[cols].to_numpy() + sigma * rng.standard_normal((n_rows, 3))
    frame["station"] = np.arange(n_rows)
    meta = {k: v for k, v in ds.meta.items() if k in ("name", "total_field_nT", "dip_deg", "declination_deg",
                                                      "gravity_g")}
    meta["name"] = f"lab_casing tiled to {n_rows} rows"
    return write_recording(path, frame, meta)


def rows_scaling(sizes, budget: str = "smoke", repeats: int | None = None, workdir=None,
                 commands=("reader", "study", "discrepancy"), timeout: float | None = None) -> list[dict]:
    """Wall time and peak memory of the user-facing commands on contract CSVs of ``sizes`` rows.

    Args:
        sizes: row counts. budget: ``conf/budget`` option of the study. repeats: the study's
            ``split.n_repeats`` (None: the config's 10). workdir: where the CSVs and run directories
            go (default a temporary directory). commands: which of reader, study, discrepancy.
        timeout: seconds per command (None: no limit).
    Returns:
        One dict per (rows, command): rows, command, wall_s, peak_rss_gb, rc (None: timed out).
    """
    work = Path(workdir or tempfile.mkdtemp(prefix="icgo-rows-"))
    work.mkdir(parents=True, exist_ok=True)
    py = sys.executable
    out = []
    for n in sizes:
        csv = work / f"rows_{n}.csv"
        if not csv.exists():
            write_large_recording(csv, n)
        cmds = {
            "reader": [py, "-c", f"import icgo.io.recording; icgo.io.recording.read_recording({str(csv)!r})"],
            "study": [py, "-m", "experiments.run", "dataset=csv", f"dataset.path={csv}", f"budget={budget}",
                      "figures=false", "progress=false", "overwrite=true", f"hydra.run.dir={work / f'run_{n}'}"]
            + ([f"split.n_repeats={repeats}"] if repeats else []),
            "discrepancy": [py, "-m", "experiments.discrepancy", f"data={csv}",
                            f"hydra.run.dir={work / f'discrepancy_{n}'}"],
        }
        for name in commands:
            m = measure(cmds[name], timeout)
            m.update(rows=n, command=name)
            out.append(m)
            status = "ok" if m["rc"] == 0 else f"exit {m['rc']}: {m['tail'].strip().splitlines()[-1:]}"
            print(f"  {name:12s} {n:>9d} rows  {m['wall_s']:8.1f} s  {m['peak_rss_gb']:6.2f} GB  {status}",
                  file=sys.stderr, flush=True)
    return out


def rows_report(res: list[dict], budget: str, repeats: int | None) -> tuple[str, dict]:
    """The Markdown table of :func:`rows_scaling`'s measurements and its JSON object."""
    table = ["| command | rows | wall s | peak RSS GB | exit |", "| --- | ---: | ---: | ---: | ---: |"]
    table += [f"| {m['command']} | {m['rows']:,} | {m['wall_s']:.1f} | {m['peak_rss_gb']:.2f} | {m['rc']} |"
              for m in res]
    line = json.dumps({"rows_scaling": [{k: v for k, v in m.items() if k != "tail"} for m in res],
                       "budget": budget, "repeats": repeats or 10,
                       "cpu_count": os.cpu_count(), "loadavg_end": list(os.getloadavg())})
    return "\n".join(table), json.loads(line)
