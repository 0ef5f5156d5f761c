"""The CPU benchmark of ``python -m experiments.bench``: the ICGO-RELM study against the machine's limit and
against mealpy.

``python -m experiments.bench`` (``make bench``) measures, in one run on the
machine it runs on (the CPU kernels here; ``--gpu-check`` measures the backend it finds,
:mod:`icgo.bench.backend`):

* ``fitness_evals_per_s``: batched RELM fitness throughput at the paper's
  scale (the study's own data, repeat 0: 407 training rows, 6 inputs,
  L = 30) for a batch of 120 (population 30 x 4 seeds) and 1200 (x 10
  repeats), after compilation, for the study's default search kernel
  (:func:`icgo.models.relm.train_fitness` with ``fitness_features`` = the feature dtype of
  ``StudyConfig().precision``); ``library_evals_per_s`` for the row-weighted float64 path
  ``icgo.models.relm.fitness``;
* ``fitness_by_features_evals_per_s``: that kernel with float64 features (``precision=float64``) and
  with float32 features (``precision=float32_features``: pre-activation, sigmoid and matrix-vector products in
  float32, Gram centred in float32, Cholesky and refinement residuals in float64) at the same
  batches, ``f32_features_speedup`` the ratio at batch 1200; ``max_rel_diff_vs_float64`` and
  ``max_rel_diff_f32_vs_float64`` their largest relative differences from ``icgo.models.relm.fitness``;
* ``roofline`` (``--skip-roofline``): :mod:`experiments.roofline` in a child process pinned to
  one core: each stage of the kernel against its own ceiling at its own shape, both feature dtypes;
* ``flop_fraction``: fast throughput x :func:`flops_per_eval` / the rate of a
  large dense float32 matrix product (the precision of the fast kernel's Gram
  product), measured in the same run;
* ``table3_kernel_s``: the full Table 3 study (5 strategies x 10 repeats,
  population 30, 100 iterations, 12,030 evaluations per run) through this
  file's own path (fast kernel, compile included), and ``compile_s``;
* ``table3_s`` (what a user runs, :func:`icgo.bench.front_door.front_door`):
  ``python -m experiments.run experiment=table3`` end to end in a fresh process
  with a warm compilation cache; ``table3_cold_s`` with an empty one; the same
  table as a five-job sweep on 1 and 2 launcher workers (``front_door``,
  ``sweep_workers_speedup``; the sweep's tables are checked bitwise against the
  one-job run); ``table3_1_device_s`` the one-job run with its search on one device
  (``devices=1``; the default shards it over one host device per core, :mod:`icgo.optim.sharded`)
  and ``study_devices_speedup`` the ratio; ``--skip-front-door``: ``table3_s`` is ``table3_kernel_s``;
  each single run's ``breakdown`` (:func:`icgo.bench.front_door.breakdown`: start, import, data, MSA,
  search, scoring, write, and the compile or cache-load part); ``like_for_like_s``
  (:func:`icgo.bench.front_door.like_for_like`): the front door run as mealpy's side is, 50 runs of
  CGO's ``mealpy`` variant in float64, and ``speedup_vs_mealpy_like_for_like``;
* ``alternating`` (``--alternate K``, :func:`interleaved_ratio`): mealpy's runs timed in K parts, each
  after a warm front-door run (Table 3 and like-for-like), and the ratios over the medians: both sides
  see the same stretch of a shared machine's load;
* ``cores`` (``--cores 1,2``, :func:`icgo.bench.front_door.core_curve`): Table 3's front door with the
  job's CPU affinity cut to that many cores (one host device per core), cold and warm, with the
  breakdown at each point;
* ``mealpy_table3_s`` and ``speedup_vs_mealpy`` (vs ``table3_s``): the same study with mealpy 3.x
  ``OriginalCGO`` on the same data and the same RELM fitness in numpy
  (:func:`numpy_fitness`), same population, iterations and runs; also in
  mealpy's own parallel mode on 2 processes (``mealpy_parallel_table3_s``,
  ``speedup_vs_mealpy_parallel``);
* ``peers``, ``pso_speedup_vs_evosax``: evosax's PSO and DE beside icgo's PSO on
  the same fast fitness at equal evaluations (:func:`icgo.bench.peers.peer_comparison`);
* ``numpy_evals_per_s``: :func:`numpy_fitness` in a plain loop;
* scaling rows: study wall time for 1, 10, 100 repeats (one strategy), and
  fitness time per batch of 120 for 582, 5,820 and 58,200 data rows.

``--quick`` runs a small version of everything (smoke use, minutes).

The fast kernel (see ``results/performance.md`` for the measurements behind
each step): only the training rows (gathered once per repeat, so shapes stay
fixed), the population processed in chunks that fit the cache (``lax.map``),
the Gram product of the *column-centred* hidden outputs in float32 with the
rank-one mean term added back in float64, a float64 Cholesky factor of that
matrix, and ``refine`` steps of iterative refinement with float64 residuals,
so the result is the float64 ridge solution of its hidden outputs; with float32
features (the default) those are rounded to float32, within 1e-6 relative of
``icgo.models.relm.fitness`` (both checked on the study's own data at every run:
``max_rel_diff_vs_float64``, ``max_rel_diff_f32_vs_float64``).
"""

from __future__ import annotations

import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from functools import partial
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import icgo  # noqa: F401  (enables float64)
from icgo.bench.front_door import core_curve, front_door, like_for_like, like_for_like_command, table3_command
from icgo.bench.kernels import (
    FEATURES,
    HIDDEN,
    LAM,
    N_INPUTS,
    StudyData,
    best_time,
    flops_per_eval,
    matmul_gflops,
    numpy_fitness,
    population,
    run_mealpy,
    slice_tree,
    study_data,
)
from icgo.bench.peers import peer_comparison
from icgo.bench.process import measure
from icgo.models import relm
from icgo.optim import STRATEGIES, run_batch
from icgo.optim.cgo import CGO
from icgo.studies.icgo_relm.config import StudyConfig
from icgo.studies.icgo_relm.result import score_all


def run_roofline(batch: int, chunk: int, refine: int, quick: bool) -> dict:
    """:mod:`experiments.roofline` in a child process (there one core and one XLA thread are set before
    JAX starts, which this process cannot do any more): its JSON object."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "roofline.json"
        cmd = [sys.executable, "-m", "experiments.roofline", "--batch", str(batch), "--chunk", str(chunk),
               "--refine", str(refine), "--out", str(path)] + (["--quick"] if quick else [])
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode:
            raise RuntimeError(f"experiments.roofline exited {proc.returncode}: {proc.stderr[-2000:]}")
        return json.loads(path.read_text())


# -------------------------------------------------------------------------- study
@partial(jax.jit, static_argnames=("strategies", "pop_size", "iterations", "chunk", "refine"))
def _study_core(keys, aux: relm.TrainRows, strategies, pop_size, iterations, chunk, refine):
    D = relm.n_params(HIDDEN)
    res = run_batch(CGO, _FAST[(chunk, refine)], (np.full(D, -1.0), np.full(D, 1.0)), keys, pop_size, iterations,
                    configs=CGO.axis_configs(None, strategies), aux=aux)
    return res.best_x, res.best_f, res.n_evals


_FAST: dict = {}


def _same_note(diff: float) -> str:
    """How a run's CGO metrics compare with the one-job default run's (:func:`icgo.bench.front_door.front_door`)."""
    return "bitwise the one-job run's metrics" if diff == 0 else f"metrics differ from the one-job run by up to {diff:.1g}"


def run_fast_study(sd: StudyData, strategies=STRATEGIES, pop_size=30, iterations=100, chunk=10, refine=2):
    """Table-3 study with the fast fitness: search, then refit and score as ``run_study`` does.

    Returns:
        dict: compile_s, run_s, total_s, evals per run, mean test RMSE per strategy.
    """
    _FAST.setdefault((chunk, refine), relm.make_train_fitness(LAM, HIDDEN, chunk, refine, feature_dtype=FEATURES))
    R = sd.compact.T.shape[0]
    keys = jnp.stack([jax.random.fold_in(jax.random.PRNGKey(0), i) for i in range(R)])
    t0 = time.perf_counter()
    args = (keys, sd.compact, tuple(strategies), pop_size, iterations, chunk, refine)
    compiled = _study_core.lower(*args).compile()

    def score(thetas):
        return score_all(thetas, sd.prep, sd.G, sd.B, sd.a_true, LAM, HIDDEN,
                         raw_features=StudyConfig().model.features == "raw")

    # the scoring's programs are compiled here (on placeholder weights), so run_s times the study's work only
    jax.block_until_ready(score(jnp.zeros((len(strategies), R, relm.n_params(HIDDEN)))))
    t1 = time.perf_counter()
    best_x, best_f, n_evals = compiled(keys, sd.compact)
    scored = score(best_x)
    jax.block_until_ready(scored)
    t2 = time.perf_counter()
    return {"compile_s": t1 - t0, "run_s": t2 - t1, "total_s": t2 - t0, "evals_per_run": int(np.asarray(n_evals).max()),
            "best_f": np.asarray(best_f), "test_rmse": np.asarray(scored.test.rmse).mean(axis=1)}


def interleaved_ratio(sd: StudyData, chunks: int, fd_work: Path, fd_extra, ll_work: Path | None, ll_runs: int,
                      ll_extra, iterations: int) -> dict:
    """The speed-up over mealpy measured in alternation, for a machine whose load changes while it runs.

    mealpy's Table 3 runs (all of them) are timed in ``chunks`` parts; before each part the warm front
    door runs once (Table 3, and the like-for-like job when ``ll_work`` is given), in the caches that
    :func:`icgo.bench.front_door.front_door` and :func:`icgo.bench.front_door.like_for_like` filled.
    The ratios are mealpy's total over the median of each front-door command: both sides then share
    the same stretch of the machine's load.

    Returns:
        dict: ``table3_s`` and ``like_for_like_s`` (lists, one per part), ``mealpy_table3_s``, ``speedup``,
        ``speedup_like_for_like`` (or None), ``loadavg`` per part.
    """
    n_all = len(STRATEGIES) * int(sd.compact.T.shape[0])
    sizes = [len(c) for c in np.array_split(np.arange(n_all), chunks)]
    fd_t, ll_t, load, mealpy_s, first = [], [], [], 0.0, 0
    for k, n in enumerate(sizes):
        load.append(list(os.getloadavg()))
        cmds = [("table3", table3_command(fd_work, f"warm_alt{k}", fd_extra), fd_t)]
        if ll_work is not None:
            cmds.append(("like-for-like", like_for_like_command(ll_work, f"warm_alt{k}", ll_runs, ll_extra), ll_t))
        for name, cmd, times in cmds:
            m = measure(cmd)
            if m["rc"] != 0:
                raise RuntimeError(f"alternating {name} run {k} failed (exit {m['rc']}): "
                                   f"{m['tail'].strip().splitlines()[-1:]}")
            times.append(m["wall_s"])
        mealpy_s += run_mealpy(sd, n, 30, iterations, first=first)["total_s"]
        first += n
        print(f"  alternating part {k + 1}/{chunks}: table3 {fd_t[-1]:.1f} s"
              + (f", like-for-like {ll_t[-1]:.1f} s" if ll_t else "") + f", mealpy so far {mealpy_s:.1f} s "
              f"({first} runs), load {load[-1][0]:.1f}", file=sys.stderr, flush=True)
    return {"table3_s": fd_t, "like_for_like_s": ll_t, "mealpy_table3_s": mealpy_s,
            "speedup": mealpy_s / float(np.median(fd_t)),
            "speedup_like_for_like": mealpy_s / float(np.median(ll_t)) if ll_t else None, "loadavg": load}


def cpu_benchmark(a, iters: int, n_rep: int, s_iters: int, s_reps: tuple, mealpy_runs: int, cores) -> tuple[dict, str]:
    """Every measurement of the module docstring (the options of ``python -m experiments.bench`` in ``a``).

    Args:
        a: the parsed arguments (``quick``, ``chunk``, ``refine``, the ``skip_*`` switches, ``alternate``).
        iters, n_rep: the Table 3 study's iterations and repeats. s_iters, s_reps: the scaling rows' iterations
            and repeat counts. mealpy_runs: mealpy runs to time (0: none). cores: the core curve's counts or None.
    Returns:
        (the JSON object, the Markdown table of the rows).
    """
    quick = a.quick
    rows = []
    out = {"device": f"{jax.devices()[0].platform}:{jax.devices()[0].device_kind}", "cpu_count": os.cpu_count(),
           "repeats": n_rep, "iterations": iters, "scaling_iterations": s_iters,
           "loadavg_start": list(os.getloadavg()), "quick": quick, "chunk": a.chunk, "refine": a.refine}

    def row(what, value, unit, note=""):
        rows.append((what, value, unit, note))
        print(f"  {what}: {value:.4g} {unit} {note}", file=sys.stderr, flush=True)

    sd = study_data(n_rep)
    d0, c0 = slice_tree(sd.fit, 0), slice_tree(sd.compact, 0)
    n = sd.n_train
    fl = flops_per_eval(n)
    out.update(n_rows=sd.n_rows, n_train=n, flops_per_eval=fl)

    # accuracy of the fast kernel against the float64 library fitness, study data, every repeat
    diffs = {"float64": [], "float32": []}
    for r in range(n_rep):
        pop = population(jax.random.PRNGKey(100 + r), 120)
        ref = relm.fitness(pop, slice_tree(sd.fit, r), LAM, HIDDEN)
        for fd, d in diffs.items():
            got = relm.train_fitness(pop, slice_tree(sd.compact, r), LAM, HIDDEN, a.chunk, a.refine, feature_dtype=fd)
            d.append(float(jnp.max(jnp.abs(got / ref - 1))))
    out["max_rel_diff_vs_float64"] = max(diffs["float64"])
    out["max_rel_diff_f32_vs_float64"] = max(diffs["float32"])
    row("fast fitness vs float64 library, max relative difference", max(diffs["float64"]), "",
        f"{n_rep} repeats x 120 thetas")
    row("fast fitness, float32 features, vs float64 library, max relative difference", max(diffs["float32"]), "",
        f"{n_rep} repeats x 120 thetas")

    # machine limit
    reps = 3 if quick else 5
    g32, g64 = matmul_gflops("float32", reps=reps), matmul_gflops("float64", reps=reps)
    out.update(matmul_gflops_f32=g32, matmul_gflops_f64=g64)
    row("dense 2048^2 matmul float32", g32, "GFLOP/s")
    row("dense 2048^2 matmul float64", g64, "GFLOP/s")

    # fitness throughput
    kernels = {fd: relm.make_train_fitness(LAM, HIDDEN, a.chunk, a.refine, feature_dtype=fd)
               for fd in ("float64", "float32")}
    lib = relm.make_fitness(LAM, HIDDEN)
    out["fitness_features"] = FEATURES
    out["fitness_evals_per_s"], out["library_evals_per_s"], out["flop_fraction_by_batch"] = {}, {}, {}
    out["fitness_by_features_evals_per_s"] = {fd: {} for fd in kernels}
    for P in (120, 1200):
        pop = population(jax.random.PRNGKey(P), P)
        for fd, k in kernels.items():
            out["fitness_by_features_evals_per_s"][fd][str(P)] = P / best_time(k, pop, c0, reps=reps)
            row(f"train-mode kernel, {fd} features, batch {P}", out["fitness_by_features_evals_per_s"][fd][str(P)],
                "evals/s", "(the study's default)" if fd == FEATURES else "")
        rate = out["fitness_evals_per_s"][str(P)] = out["fitness_by_features_evals_per_s"][FEATURES][str(P)]
        out["library_evals_per_s"][str(P)] = P / best_time(lib, pop, d0, reps=1 if (quick or P > 120) else 3)
        out["flop_fraction_by_batch"][str(P)] = rate * fl / (g32 * 1e9)
        row(f"library relm.fitness (float64), batch {P}", out["library_evals_per_s"][str(P)], "evals/s")
    by = out["fitness_by_features_evals_per_s"]
    out["flop_fraction"] = out["flop_fraction_by_batch"]["1200"]
    out["f32_features_speedup"] = by["float32"]["1200"] / by["float64"]["1200"]
    row("float32 / float64 features, batch 1200", out["f32_features_speedup"], "x")
    row("flop_fraction (batch 1200, vs float32 matmul)", out["flop_fraction"], "")

    # per-stage roofline, in its own process: one core, one XLA thread
    if not a.skip_roofline:
        rl = run_roofline(120 if quick else 1200, a.chunk, a.refine, quick)
        out["roofline"] = rl
        for fd in ("float64", "float32"):
            row(f"roofline, {fd} features: sum of stage ceilings / kernel time (one core, batch {rl['batch']})",
                rl[fd]["kernel_fraction"], "", f"{rl[fd]['kernel_evals_per_s']:,.0f} evals/s; furthest stage "
                + min(rl[fd]["stages"].items(), key=lambda kv: kv[1]["fraction"])[0])

    # numpy reference
    X0, T0 = np.asarray(c0.Xa)[:, :N_INPUTS], np.asarray(c0.T)
    pop = np.asarray(population(jax.random.PRNGKey(7), 120))
    t = time.perf_counter()
    for th in pop:
        numpy_fitness(th, X0, T0)
    out["numpy_evals_per_s"] = 120 / (time.perf_counter() - t)
    row("numpy loop fitness", out["numpy_evals_per_s"], "evals/s")

    # Table 3 study
    res = run_fast_study(sd, STRATEGIES, 30, iters, a.chunk, a.refine)
    out.update(table3_kernel_s=res["total_s"], compile_s=res["compile_s"], table3_run_s=res["run_s"],
               evals_per_run=res["evals_per_run"],
               table3_test_rmse={s: float(v) for s, v in zip(STRATEGIES, res["test_rmse"])},
               table3_best_fitness_mean=float(res["best_f"].mean()))
    row(f"Table 3 study, the benchmark's own path ({len(STRATEGIES)} x {n_rep} runs, pop 30, {iters} it), compile "
        f"included", res["total_s"], "s", f"compile {res['compile_s']:.1f} s, {res['evals_per_run']} evals/run")

    # what a user runs: the front door in fresh processes (table3_s = warm cache), as one job and as a sweep
    if not a.skip_front_door:
        fd_work, fd_extra = Path(tempfile.mkdtemp(prefix="icgo-frontdoor-")), [f"split.n_repeats={n_rep}",
                                                                               f"budget.iterations={iters}"]
        fd = front_door(fd_work, fd_extra)
        out["front_door"] = fd
        out["table3_s"], out["table3_cold_s"] = fd["warm"]["wall_s"], fd["cold"]["wall_s"]
        row("Table 3 through the front door, cold compilation cache", fd["cold"]["wall_s"], "s",
            f"python -m experiments.run experiment=table3, fresh process, peak {fd['cold']['peak_rss_gb']:.2f} GB")
        row("Table 3 through the front door, warm cache (table3_s)", fd["warm"]["wall_s"], "s",
            f"peak {fd['warm']['peak_rss_gb']:.2f} GB; devices=null (one host device per core)")
        if not a.skip_sweeps:
            out["sweep_workers_speedup"] = fd["sweep_1_worker"]["wall_s"] / fd["sweep_2_workers"]["wall_s"]
            out["table3_1_device_s"] = fd["warm_1_device"]["wall_s"]
            out["study_devices_speedup"] = out["table3_1_device_s"] / out["table3_s"]
            row("Table 3 through the front door, warm cache, devices=1", fd["warm_1_device"]["wall_s"], "s",
                _same_note(fd["max_abs_diff"]["warm_1_device"]))
            row("study speed-up, one host device per core / one device", out["study_devices_speedup"], "x")
            for k, w in (("sweep_1_worker", 1), ("sweep_2_workers", 2)):
                row(f"Table 3 as a 5-job sweep (one strategy each), {w} worker(s)", fd[k]["wall_s"], "s",
                    _same_note(fd["max_abs_diff"][k]))
            row("sweep speed-up, 2 workers / 1", out["sweep_workers_speedup"], "x")
        b = fd["warm"]["breakdown"]
        row("  where the warm run's time went: start / import / data / MSA / search / scoring / write", fd["warm"]["wall_s"],
            "s", f"{b['start']:.1f} / {b['import']:.1f} / {b['load_data']:.1f} / {b['msa']:.1f} / {b['search']:.1f} / "
                 f"{b['scoring']:.1f} / {b['write']:.1f}; compile or cache load {b['compile']:.1f}")
        if not a.skip_like_for_like:
            ll_work, ll_extra = Path(tempfile.mkdtemp(prefix="icgo-likeforlike-")), [f"budget.iterations={iters}"]
            ll = like_for_like(ll_work, len(STRATEGIES) * n_rep, ll_extra)
            out["like_for_like"] = ll
            out["like_for_like_s"] = ll["warm"]["wall_s"]
            row("like-for-like front door (CGO variant=mealpy, original seed, precision=float64, 50 runs), warm",
                ll["warm"]["wall_s"], "s", f"cold {ll['cold']['wall_s']:.1f} s")
    else:
        out["table3_s"] = res["total_s"]

    if cores:
        out["cores"] = core_curve(cores, extra=[f"split.n_repeats={n_rep}", f"budget.iterations={iters}"])
        for pt in out["cores"]:
            b = pt["warm"]["breakdown"]
            row(f"Table 3 front door on {pt['cores']} core(s) (affinity), warm", pt["warm"]["wall_s"], "s",
                f"cold {pt['cold']['wall_s']:.1f} s; start {b['start']:.1f} / import {b['import']:.1f} / data "
                f"{b['load_data']:.1f} / MSA {b['msa']:.1f} / search {b['search']:.1f} / scoring {b['scoring']:.1f} / "
                f"write {b['write']:.1f}; compile or cache load {b['compile']:.1f}")

    # mealpy
    alternate = a.alternate > 1 and not a.skip_front_door
    if mealpy_runs and alternate:  # every run timed, in parts between warm front-door runs
        alt = interleaved_ratio(sd, a.alternate, fd_work, fd_extra, None if a.skip_like_for_like else ll_work,
                                len(STRATEGIES) * n_rep, [] if a.skip_like_for_like else ll_extra, iters)
        out["alternating"] = alt
        out["mealpy_table3_s"], out["mealpy_runs_timed"], out["mealpy_extrapolated"] = (
            alt["mealpy_table3_s"], len(STRATEGIES) * n_rep, False)
        out["speedup_vs_mealpy"] = alt["speedup"]
        row(f"mealpy OriginalCGO + numpy fitness, same study, all runs timed in {a.alternate} parts",
            out["mealpy_table3_s"], "s", "each part after one warm front-door run of each command below")
        row("speedup vs mealpy (front door, warm: the median of the alternating runs)", alt["speedup"], "x",
            "Table 3 front door " + ", ".join(f"{t:.1f}" for t in alt["table3_s"]) + " s")
        if alt["speedup_like_for_like"] is not None:
            out["speedup_vs_mealpy_like_for_like"] = alt["speedup_like_for_like"]
            row("speedup vs mealpy, like for like (same CGO rules, float64 both sides; median)",
                alt["speedup_like_for_like"], "x", "like-for-like front door "
                + ", ".join(f"{t:.1f}" for t in alt["like_for_like_s"]) + " s")
    elif mealpy_runs:
        m = run_mealpy(sd, mealpy_runs, 30, iters)
        n_all = len(STRATEGIES) * n_rep
        out["mealpy_table3_s"] = m["per_run_s"] * n_all
        out["mealpy_runs_timed"] = mealpy_runs
        out["mealpy_extrapolated"] = mealpy_runs != n_all
        out["mealpy_evals_per_run"] = m["evals_per_run"]
        out["mealpy_best_fitness_mean"] = float(m["best_f"].mean())
        out["speedup_vs_mealpy"] = out["mealpy_table3_s"] / out["table3_s"]
        note = f"{mealpy_runs} of {n_all} runs timed, extrapolated" if out["mealpy_extrapolated"] else "all runs timed"
        row("mealpy OriginalCGO + numpy fitness, same study", out["mealpy_table3_s"], "s",
            f"{note}; {m['evals_per_run']} evals/run")
        row("speedup vs mealpy", out["speedup_vs_mealpy"], "x",
            "front door, warm cache" if not a.skip_front_door else "the benchmark's own path")
        if "like_for_like_s" in out:
            out["speedup_vs_mealpy_like_for_like"] = out["mealpy_table3_s"] / out["like_for_like_s"]
            row("speedup vs mealpy, like for like (same CGO rules, float64 both sides), warm",
                out["speedup_vs_mealpy_like_for_like"], "x")
    if mealpy_runs and not a.skip_front_door:
        out["speedup_vs_mealpy_cold"] = out["mealpy_table3_s"] / out["table3_cold_s"]
        row("speedup vs mealpy, front door with a cold cache", out["speedup_vs_mealpy_cold"], "x")
    if mealpy_runs and not a.skip_mealpy_parallel:
        n_all = len(STRATEGIES) * n_rep
        mp = run_mealpy(sd, mealpy_runs, 30, iters, mode="process", n_workers=2)
        out["mealpy_parallel_table3_s"] = mp["per_run_s"] * n_all
        out["speedup_vs_mealpy_parallel"] = out["mealpy_parallel_table3_s"] / out["table3_s"]
        row("mealpy OriginalCGO, its parallel mode (process, 2 workers), same study", out["mealpy_parallel_table3_s"],
            "s", f"{mealpy_runs} of {n_all} runs timed" + (", extrapolated" if mealpy_runs != n_all else ""))
        row("speedup vs mealpy's parallel mode", out["speedup_vs_mealpy_parallel"], "x")

    # a JAX peer on the same fitness: evosax PSO and DE vs icgo's PSO at equal evaluations
    if not a.skip_peers:
        peers = peer_comparison(sd.compact, LAM, HIDDEN, 30, iters, reps=2 if quick else 3)
        out["peers"] = peers
        by = {p["name"]: p for p in peers}
        out["pso_speedup_vs_evosax"] = by["evosax PSO"]["wall_s"] / by["icgo PSO"]["wall_s"]
        for p in peers:
            row(f"{p['name']}, {n_rep} searches x {p['evals']} evals, after compile", p["wall_s"], "s",
                f"best training RMSE mean {p['best_f_mean']:.4f} deg")
        row("icgo PSO speed vs evosax PSO (time ratio)", out["pso_speedup_vs_evosax"], "x")

    # scaling
    if not a.skip_scaling:
        out["scaling_repeats_s"] = {}
        for R in s_reps:
            sdr = study_data(R)
            res = run_fast_study(sdr, ("original",), 30, s_iters, a.chunk, a.refine)
            out["scaling_repeats_s"][str(R)] = res["run_s"]
            row(f"study, 1 strategy, {R} repeats, {s_iters} it (after compile)", res["run_s"], "s",
                f"compile {res['compile_s']:.1f} s")
        rs = out["scaling_repeats_s"]
        keys = list(rs)
        out["repeats_cost_ratio"] = rs[keys[-1]] / rs[keys[0]]
        row(f"{keys[-1]} repeats / 1 repeat", out["repeats_cost_ratio"], "x")
        out["scaling_rows_batch120_s"] = {}
        for tile in ((1, 2) if quick else (1, 10, 100)):
            sdt = study_data(1, tile=tile)
            P = 120
            pop = population(jax.random.PRNGKey(3), P)
            tt = best_time(kernels[FEATURES], pop, slice_tree(sdt.compact, 0), reps=2 if tile > 1 else reps)
            out["scaling_rows_batch120_s"][str(sdt.n_rows)] = tt
            row(f"fast fitness batch 120, {sdt.n_rows} data rows ({sdt.n_train} training)", tt, "s")

    out["loadavg_end"] = list(os.getloadavg())
    out["python"] = platform.python_version()
    out["jax"] = jax.__version__
    table = ["| measurement | value | unit | note |", "| --- | ---: | --- | --- |"]
    table += [f"| {w} | {v:.4g} | {u} | {nt} |" for w, v, u, nt in rows]
    return out, "\n".join(table)
