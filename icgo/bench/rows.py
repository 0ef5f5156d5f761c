"""The benchmark's ``--rows``: the commands a user runs on a large contract CSV, timed with their peak memory.

A recording of each size is written (:func:`write_large_recording`), then each command runs in its own process
(:func:`icgo.bench.process.measure`): the reader (``icgo.io.recording.read_recording``), the ICGO-RELM study
(``experiments.run dataset=csv``), the discrepancy workflow (``experiments.discrepancy data=FILE``) and streaming
apply (``experiments.apply``: a model fitted once by a ``budget=smoke`` study applied to a survey of that many rows
with measured depth, read in chunks: its peak memory is the chunk's, whatever the rows). The CSVs are written into
a temporary directory (or ``workdir``) and each is deleted once its commands ran.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

from icgo.bench.front_door import UNTIMED_EXTRAS
from icgo.bench.process import measure
from icgo.datasets import casing_stations as datasets
from icgo.io.recording import write_recording

#: Measurement noise added to each tiled copy of the lab_casing rows (1 sigma per axis): g and nT,
#: the discrepancy workflow's default noise (``icgo.discrepancy.NOISE``).
TILE_NOISE = (3e-4, 15.0)


def write_large_recording(path, n_rows: int, seed: int = 0, md_step_m: float | None = None):
    """A contract CSV (+ ``.meta.json``) of ``n_rows`` rows: lab_casing tiled, fresh noise on every copy.

    The simulated lab_casing survey (583 rows, ICGO 3.1) is repeated until it has
    ``n_rows`` rows; every copy gets independent white noise of :data:`TILE_NOISE`
    on G (g) and B (nT), the reference attitude is kept, ``station`` counts rows.

    Args:
        path: CSV path (its directory must exist). n_rows: rows (>= 1). seed: noise seed.
        md_step_m: with a value, a measured-depth column ``md`` (m) rising by it from row to row (a survey
            ``apply`` places by minimum curvature).
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
    if md_step_m is not None:
        frame["md"] = md_step_m * np.arange(n_rows)
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
    model = apply_model(work, timeout) if "apply" in commands else None
    for n in sizes:
        csv = work / f"rows_{n}.csv"
        if not csv.exists():
            write_large_recording(csv, n, md_step_m=APPLY_MD_STEP_M if "apply" in commands else None)
        cmds = {
            "reader": [py, "-c", f"import icgo.io.recording; icgo.io.recording.read_recording({str(csv)!r})"],
            "study": [py, "-m", "experiments.run", "dataset=csv", f"dataset.path={csv}", f"budget={budget}",
                      *UNTIMED_EXTRAS, "overwrite=true", f"hydra.run.dir={work / f'run_{n}'}"]
            + ([f"split.n_repeats={repeats}"] if repeats else []),
            "discrepancy": [py, "-m", "experiments.discrepancy", f"data={csv}",
                            f"hydra.run.dir={work / f'discrepancy_{n}'}"],
            "apply": [py, "-m", "experiments.apply", f"model={model}", f"data={csv}", f"out={work / f'apply_{n}'}",
                      "overwrite=true"],
        }
        for name in commands:
            m = measure(cmds[name], timeout)
            m.update(rows=n, command=name)
            out.append(m)
            status = "ok" if m["rc"] == 0 else f"exit {m['rc']}: {m['tail'].strip().splitlines()[-1:]}"
            print(f"  {name:12s} {n:>9d} rows  {m['wall_s']:8.1f} s  {m['peak_rss_gb']:6.2f} GB  {status}",
                  file=sys.stderr, flush=True)
        for f in (csv, csv.with_suffix(".meta.json")):  # a 16M-row survey is GBs: gone once measured
            f.unlink(missing_ok=True)
        shutil.rmtree(work / f"apply_{n}", ignore_errors=True)
    return out


#: Measured depth between consecutive rows of the ``apply`` command's survey (m): positions by minimum curvature
#: are part of what it streams.
APPLY_MD_STEP_M = 0.1


def apply_model(work: Path, timeout: float | None = None) -> Path:
    """The run directory of a ``budget=smoke`` ICGO-RELM study (2 repeats) on lab_casing, fitted in a child process
    once: the model the ``apply`` command applies."""
    run = work / "apply_model"
    if not (run / "run.json").exists():
        m = measure([sys.executable, "-m", "experiments.run", "budget=smoke", "split.n_repeats=2", "figures=false",
                     "progress=false", "overwrite=true", f"hydra.run.dir={run}"], timeout)
        if m["rc"] != 0:
            raise RuntimeError(f"fitting the apply model failed (exit {m['rc']}): {m['tail'][-500:]}")
    return run


def rows_report(res: list[dict], budget: str, repeats: int | None) -> tuple[str, dict]:
    """The Markdown table of :func:`rows_scaling`'s measurements and its JSON object."""
    table = ["| command | rows | wall s | peak RSS GB | exit |", "| --- | ---: | ---: | ---: | ---: |"]
    table += [f"| {m['command']} | {m['rows']:,} | {m['wall_s']:.1f} | {m['peak_rss_gb']:.2f} | {m['rc']} |"
              for m in res]
    line = json.dumps({"rows_scaling": [{k: v for k, v in m.items() if k != "tail"} for m in res],
                       "budget": budget, "repeats": repeats or 10,
                       "cpu_count": os.cpu_count(), "loadavg_end": list(os.getloadavg())})
    return "\n".join(table), json.loads(line)
