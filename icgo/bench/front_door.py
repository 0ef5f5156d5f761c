"""The benchmark of what a user runs, used by :mod:`icgo.bench.cpu` and :mod:`icgo.bench.backend`.

* :func:`front_door`: ``python -m experiments.run experiment=table3`` end to end in a
  fresh process, with an empty (cold) and then a filled (warm) compilation cache; and
  Table 3 as a five-job sweep (one strategy per job) through the default launcher on
  1 and on 2 launcher workers (jobs at once).
* :func:`breakdown`: where a front-door run's time went, from its run.json; every command runs through
  :func:`icgo.bench.process.measure` (wall time and peak memory of a child process);
* :func:`core_curve`: Table 3's front door with the job's affinity cut to 1, 2, ... cores;
* :func:`like_for_like`: the front door run as mealpy's side of the comparison is (CGO's ``mealpy``
  variant, the original seed, float64);
* :func:`calibrate_front_door`: ``python -m experiments.calibrate`` on one bundled device, cold then warm.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path

import pandas as pd

from icgo.bench.process import measure
from icgo.optim import STRATEGIES


#: The settings of every front-door run timed here: no figures, no progress lines and no MLflow run (tracking is
#: an optional extra that mealpy's side of the comparison has no counterpart of; its own cost is in the README).
UNTIMED_EXTRAS = ("figures=false", "progress=false", "tracking=false")


def table3_command(work: Path, name: str, extra=()) -> list[str]:
    """``python -m experiments.run experiment=table3`` into ``work/name`` with the cache ``work/cache``."""
    return [sys.executable, "-m", "experiments.run", "experiment=table3", *UNTIMED_EXTRAS,
            f"jax_cache_dir={work / 'cache'}", f"hydra.run.dir={work / name}", *extra]


def breakdown(run_dir: Path, wall_s: float) -> dict:
    """Where a front-door run's wall time went, from its run.json (``timings``, :mod:`icgo.studies.common.timing`).

    Keys (seconds): ``start`` (Python, Hydra and the interpreter's exit: the wall time outside the job),
    ``import`` (the study's modules, JAX with them), ``load_data``, ``msa`` (the split and the multi-station
    analysis), ``search``, ``scoring`` (refit, metrics, tables), ``write``; ``compile`` (of all of them: JAX
    tracing and compiling or loading programs from the persistent cache); ``execution``: the plan it ran.
    """
    run = json.loads((run_dir / "run.json").read_text())
    t = run["timings"]
    return {"start": wall_s - run["total_time_s"] - t["write_s"], "import": t["import_s"],
            "load_data": t["load_data_s"], "msa": t["prepare_s"], "search": t["search_s"],
            "scoring": t["score_s"] + t["tables_s"], "write": t["write_s"],
            "compile": sum(t[f"{s}_compile_s"] for s in ("prepare", "search", "score", "tables")),
            "execution": run["execution"]}


def core_curve(cores: list[int], workdir=None, extra=()) -> list[dict]:
    """Table 3 through the front door with the job's CPU affinity cut to the first ``k`` cores, for each k.

    Each point runs twice into its own compilation cache: ``cold`` (it compiles) and ``warm`` (it loads
    what the cold run compiled: the sharded search's program depends on the number of devices, so a cache
    filled at another point would not hold it). The job gives the CPU one host device per core it may use
    (:func:`icgo.core.devices.use_host_devices`), and the study shards its search over them.

    Returns:
        One dict per k: cores, cold and warm ``{wall_s, peak_rss_gb, breakdown}`` (:func:`breakdown`).
    """
    avail = sorted(os.sched_getaffinity(0))
    out = []
    for k in cores:
        if k > len(avail):
            raise ValueError(f"core_curve: {k} cores asked, this process may use {len(avail)}")
        work = Path(workdir or tempfile.mkdtemp(prefix="icgo-cores-")) / f"cores_{k}"
        point = {"cores": k}
        for name in ("cold", "warm"):
            m = measure(table3_command(work, name, extra), cpus=avail[:k])
            if m["rc"] != 0:
                raise RuntimeError(f"front door on {k} cores ({name}) failed (exit {m['rc']}): "
                                   f"{m['tail'].strip().splitlines()[-1:]}")
            point[name] = {"wall_s": m["wall_s"], "peak_rss_gb": m["peak_rss_gb"],
                           "breakdown": breakdown(work / name, m["wall_s"])}
            b = point[name]["breakdown"]
            print(f"  {k} core(s), {name}: {m['wall_s']:.1f} s = start {b['start']:.1f} + import {b['import']:.1f} + "
                  f"data {b['load_data']:.1f} + MSA {b['msa']:.1f} + search {b['search']:.1f} + scoring "
                  f"{b['scoring']:.1f} + write {b['write']:.1f} (compile or cache load {b['compile']:.1f})",
                  file=sys.stderr, flush=True)
        out.append(point)
    return out


def front_door(workdir=None, extra=(), sweeps: bool = True) -> dict:
    """Wall time and peak memory of Table 3 through ``python -m experiments.run``, each in a fresh process.

    Measured, in order, all with one compilation cache that starts empty:
    ``cold`` (the first run: compiles), ``warm`` (the same command again: the
    cache holds its programs; its search sharded over one host device per core, the
    default ``devices=null``), ``warm_1_device`` (``devices=1``: its search on one device),
    then the five-job sweep ``strategy=<one each>`` through the default launcher
    on ``hydra.launcher.workers=1`` and ``=2`` (jobs at once; each loads its programs from the cache).

    Args:
        workdir: where the run directories and the cache go (default: a temporary directory).
        extra: further overrides for every command (e.g. a smaller budget in a test).
        sweeps: False: only ``cold`` and ``warm``.
    Returns:
        {name: {"wall_s", "peak_rss_gb", "rc"}} for cold, warm, warm_1_device, sweep_1_worker, sweep_2_workers
        (the single runs with their :func:`breakdown`), and ``max_abs_diff``: per other run, the largest
        difference of its CGO metrics (test and train MAE, RMSE, R^2 as written) from ``warm``'s; 0 = bitwise.
    """
    work = Path(workdir or tempfile.mkdtemp(prefix="icgo-frontdoor-"))
    sweep = [sys.executable, "-m", "experiments.run", "-m", "experiment=table3",
             f"strategy={','.join(STRATEGIES)}", *UNTIMED_EXTRAS, f"jax_cache_dir={work / 'cache'}", *extra]
    cmds = {"cold": table3_command(work, "cold", extra), "warm": table3_command(work, "warm", extra),
            "warm_1_device": table3_command(work, "warm1", [*extra, "devices=1"]),
            "sweep_1_worker": sweep + ["hydra.launcher.workers=1", f"hydra.sweep.dir={work / 'sweep1'}"],
            "sweep_2_workers": sweep + ["hydra.launcher.workers=2", f"hydra.sweep.dir={work / 'sweep2'}"]}
    if not sweeps:
        cmds = {k: v for k, v in cmds.items() if k in ("cold", "warm")}
    out = {}
    for name, cmd in cmds.items():
        m = measure(cmd)
        if m["rc"] != 0:
            raise RuntimeError(f"front door {name} failed (exit {m['rc']}): {m['tail'].strip().splitlines()[-1:]}")
        out[name] = {k: m[k] for k in ("wall_s", "peak_rss_gb", "rc")}
        if name in ("cold", "warm", "warm_1_device"):
            out[name]["breakdown"] = breakdown(work / {"warm_1_device": "warm1"}.get(name, name), m["wall_s"])
        print(f"  front door {name}: {m['wall_s']:.1f} s, {m['peak_rss_gb']:.2f} GB", file=sys.stderr, flush=True)
    if sweeps:
        out["max_abs_diff"] = {name: _table_diff(work / "warm", work / d) for name, d in
                               (("warm_1_device", "warm1"), ("sweep_1_worker", "sweep1"),
                                ("sweep_2_workers", "sweep2"))}
    return out


def like_for_like_command(work: Path, name: str, runs: int = 50, extra=()) -> list[str]:
    """The like-for-like front-door command (:func:`like_for_like`) into ``work/name``, cache ``work/cache``."""
    return [sys.executable, "-m", "experiments.run", "strategy=original", f"split.n_repeats={runs}",
            "optimizer.params.variant=mealpy", "precision=float64", *UNTIMED_EXTRAS,
            f"jax_cache_dir={work / 'cache'}", f"hydra.run.dir={work / name}", *extra]


def like_for_like(workdir=None, runs: int = 50, extra=()) -> dict:
    """The front door run like mealpy's side of the comparison: ``runs`` searches (Table 3 has 50) of CGO's
    ``mealpy`` variant (mealpy's OriginalCGO rules) with the original 4th seed, in float64 (``precision=float64``,
    as mealpy's numpy fitness), cold then warm. Returns ``{cold, warm}`` as :func:`front_door`'s entries."""
    work = Path(workdir or tempfile.mkdtemp(prefix="icgo-likeforlike-"))
    out = {}
    for name in ("cold", "warm"):
        m = measure(like_for_like_command(work, name, runs, extra))
        if m["rc"] != 0:
            raise RuntimeError(f"like-for-like {name} failed (exit {m['rc']}): {m['tail'].strip().splitlines()[-1:]}")
        out[name] = {"wall_s": m["wall_s"], "peak_rss_gb": m["peak_rss_gb"], "breakdown": breakdown(work / name,
                                                                                                      m["wall_s"])}
        print(f"  like-for-like front door {name}: {m['wall_s']:.1f} s", file=sys.stderr, flush=True)
    return out


def calibrate_front_door(data: str = "icgo/data/mag_cal/ab.json", warm_runs: int = 3, workdir=None) -> dict:
    """Wall time of ``python -m experiments.calibrate data=<one 24-shot device>``, each run a fresh process.

    One compilation cache that starts empty: ``cold`` (the first run compiles and fills it), then
    ``warm_runs`` runs of the same command (the cache holds their programs; what is left is the imports,
    tracing and lowering, the fits, the peer package and the figure).

    Returns:
        {"cold": {"wall_s", "peak_rss_gb", "rc"}, "warm": [...], "warm_min_s", "warm_median_s", "data"}.
    """
    work = Path(workdir or tempfile.mkdtemp(prefix="icgo-calibrate-"))
    cmd = [sys.executable, "-m", "experiments.calibrate", f"data={data}", f"jax_cache_dir={work / 'cache'}"]
    runs = []
    for k in range(1 + warm_runs):
        m = measure(cmd + [f"hydra.run.dir={work / f'run{k}'}"])
        if m["rc"] != 0:
            raise RuntimeError(f"calibrate run {k} failed (exit {m['rc']}): {m['tail'].strip().splitlines()[-1:]}")
        runs.append({key: m[key] for key in ("wall_s", "peak_rss_gb", "rc")})
        print(f"  calibrate {'cold' if k == 0 else 'warm'}: {m['wall_s']:.1f} s", file=sys.stderr, flush=True)
    warm = [r["wall_s"] for r in runs[1:]]
    return {"data": data, "cold": runs[0], "warm": runs[1:], "warm_min_s": min(warm),
            "warm_median_s": float(sorted(warm)[len(warm) // 2])}


def _table_diff(single: Path, other: Path) -> float:
    """Largest absolute difference of the CGO methods' metrics between a run (or a sweep's jobs) and ``single``."""
    def cgo(d: Path):
        df = pd.concat([pd.read_csv(p) for p in sorted(d.glob("*/metrics.csv")) or [d / "metrics.csv"]])
        return df[df.method.str.startswith("cgo-")].set_index(["method", "repeat", "split"]).sort_index()

    ref, got = cgo(single), cgo(other)
    if not got.index.equals(ref.index):
        return float("inf")
    cols = ["mae", "rmse", "r2", "r2_error"]
    return float((got[cols] - ref[cols]).abs().to_numpy().max())
