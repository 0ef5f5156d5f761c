"""The benchmark on the backend it finds, in minutes: ``python -m experiments.bench --gpu-check``.

Made to run on a lent GPU machine in under 8 minutes and to print everything a backend's row of
``results/performance.md`` needs, with the device named. On a machine without a GPU it runs the same
measurements on what it finds and says first that the GPU is absent: its numbers are that device's,
and the GPU's stay unmeasured (never estimated).

Measured, in order (:func:`backend_check`):

1. the device, the backend and the study's execution plan for Table 3 (:meth:`icgo.studies.icgo_relm.config.StudyConfig.execution`);
2. the plan's search kernel (``float32_features``; on an accelerator the fused kernel,
   :mod:`icgo.models.relm_fused`) at batch 120, 1,200 and 60,000 (evaluations per second, after compilation,
   best of a few calls), the other kernels beside it at 120 and 1,200 (the CPU's cache-chunked kernel, and on an
   accelerator the unfused batched-Gram kernel), and the plan kernel's largest relative difference from the
   float64 library fitness (120 thetas);
3. a 2048^2 matrix product in float32 (the backend's default precision) and float64, and ``flop_fraction``:
   kernel evals/s at batch 1,200 x :func:`icgo.bench.kernels.flops_per_eval` / the float32 rate;
4. Table 3 through the front door (``python -m experiments.run experiment=table3``) in fresh processes,
   cold (empty compilation cache) and warm, with each run's time breakdown;
5. the Table 3 study (5 strategies, 12,030 evaluations a run) in this process at 1, 10, 100 and 1,000
   repeats (``run_study``: time with and without compilation, per stage); a point whose time, projected
   from the one before (its compile time, and its run time linear in repeats), would not fit in what is
   left of the budget is skipped and says so;
6. mealpy's OriginalCGO on the numpy fitness, ``--mealpy-runs`` of the 50 Table 3 runs timed and scaled
   to 50 (marked), and the ratio to the warm front door;
7. the devices curve (:func:`devices_curve`): Table 3's search (5 strategies x 10 repeats, ``CURVE_ITERATIONS``
   iterations) as one program sharded over 1, 2, 4, 8 and 16 CPU host devices in one child process
   (``JAX_PLATFORMS=cpu``, 16 host devices; on a 16-core GPU machine: its CPU), and on every device of the backend
   when that is not the CPU;
8. the study over 1, 10 and 100 worlds (:func:`worlds_scaling`: Table 3's study on that many independent
   lab_casing worlds, every search in one sharded program), projected and skipped as the study points are.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time

import jax
import jax.numpy as jnp
import numpy as np

from icgo.bench.front_door import front_door
from icgo.bench.kernels import (
    HIDDEN,
    LAM,
    best_time,
    flops_per_eval,
    matmul_gflops,
    population,
    run_mealpy,
    slice_tree,
    study_data,
)
from icgo.core.devices import HOST_DEVICE_FLAG, available_cores
from icgo.core.execution import ACCELERATOR_KERNEL, CPU_KERNEL
from icgo.datasets import casing_stations as datasets
from icgo.models import relm, search_fitness
from icgo.optim import STRATEGIES
from icgo.studies.icgo_relm import study
from icgo.studies.icgo_relm.worlds import study as worlds_study
from icgo.studies.icgo_relm.config import StudyConfig
from icgo.studies.icgo_relm.search import SearchKernel, search, search_kernel

#: Wall seconds the check aims to stay under (the lent machine's 8 minutes, less a margin).
BUDGET_S = 420.0
BATCHES = (120, 1200, 60_000)
STUDY_REPEATS = (1, 10, 100, 1000)
#: Host-device counts of the devices curve, and the iterations of its search (Table 3's 100 cut, so five points
#: fit the check's budget on a 2-core machine as on a 16-core one).
CURVE_DEVICES, CURVE_ITERATIONS = (1, 2, 4, 8, 16), 20
WORLDS = (1, 10, 100)


def device_line() -> dict:
    """The device this process computes on, the backend's name, and whether a GPU is there."""
    d = jax.devices()[0]
    gpu = any(x.platform in ("gpu", "cuda", "rocm") for x in jax.devices())
    return {"backend": jax.default_backend(), "device": f"{d.platform}:{d.device_kind}", "n_devices": len(jax.devices()),
            "gpu_present": gpu, "cpu_count": os.cpu_count(), "jax": jax.__version__}


def kernel_rates(sd, plan_kernel: str, batches=BATCHES, reps: int = 3) -> dict:
    """Evaluations per second of the study's search kernels at each batch (repeat 0's training rows).

    Returns:
        {kernel: {batch: evals/s}} for the plan's kernel at every batch and the other one at the batches
        up to 1,200; and ``max_rel_diff``: the plan kernel against :func:`icgo.models.relm.fitness` (float64).
    """
    rows, fit = slice_tree(sd.compact, 0), slice_tree(sd.fit, 0)
    out = {}
    plan_sk = search_kernel("float32_features", "train", plan_kernel)
    others = [search_kernel("float32_features", "train", CPU_KERNEL if plan_kernel == ACCELERATOR_KERNEL
                            else ACCELERATOR_KERNEL)]
    if plan_kernel == ACCELERATOR_KERNEL:  # the unfused batched-Gram kernel beside the fused one
        others.append(SearchKernel("gram_train_fitness", True, "float32", "float64"))
    f = jax.jit(search_fitness.search_fitness)
    for sk in (plan_sk, *others):
        aux = sk.aux(rows, jnp.asarray(LAM), HIDDEN)
        out[sk.name] = {}
        for P in batches if sk is plan_sk else [b for b in batches if b <= 1200]:
            pop = population(jax.random.PRNGKey(P), P)
            out[sk.name][P] = P / best_time(f, pop, aux, reps=reps if P <= 1200 else 1)
            print(f"  {sk.name}, batch {P:,}: {out[sk.name][P]:,.0f} evals/s", file=sys.stderr, flush=True)
    pop = population(jax.random.PRNGKey(7), 120)
    aux = plan_sk.aux(rows, jnp.asarray(LAM), HIDDEN)
    out["max_rel_diff"] = float(jnp.max(jnp.abs(search_fitness.search_fitness(pop, aux) / relm.fitness(pop, fit, LAM, HIDDEN)
                                                - 1)))
    return out


def overrun(last: dict | None, repeats: int, left_s: float) -> str | None:
    """Why a study point of ``repeats`` repeats is skipped, or None: its time projected from the last point
    run (``{"repeats", "compile_s", "run_s"}``: the same compile time, the run time linear in repeats; None
    for the first point, always run) exceeds ``left_s``."""
    if last is None:
        return None
    projected = last["compile_s"] + last["run_s"] * repeats / last["repeats"]
    if projected <= left_s:
        return None
    return (f"projected {projected:.0f} s from {last['repeats']} repeats does not fit in the "
            f"{max(left_s, 0.0):.0f} s left")


def study_scaling(repeats=STUDY_REPEATS, deadline: float = float("inf"), **config) -> list[dict]:
    """Table 3's study (lab_casing, 5 strategies, pop 30, 100 iterations) in this process at each repeat count.

    A point is skipped (``skipped``: why) when the previous point's time x the ratio of repeats would end
    past ``deadline`` (``time.perf_counter()``); a failing point records its one-line error and the rest go on.
    ``config``: other :class:`icgo.studies.icgo_relm.config.StudyConfig` settings (smaller ones in a test).
    """
    frame = datasets.lab_casing(0).frame
    out, last = [], None
    for R in repeats:
        cfg = StudyConfig(**{"strategies": STRATEGIES, **config}).replace(split={"n_repeats": R})
        why = overrun(last, R, deadline - time.perf_counter())
        if why:
            out.append({"repeats": R, "skipped": why})
            print(f"  study, {R} repeats: {why}", file=sys.stderr, flush=True)
            continue
        timings: dict = {}
        t = time.perf_counter()
        try:
            study.run_study(frame, cfg, timings=timings)
        except Exception as e:  # noqa: BLE001 (recorded, the other points go on)
            out.append({"repeats": R, "error": f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"})
            print(f"  study, {R} repeats: {out[-1]['error']}", file=sys.stderr, flush=True)
            continue
        wall = time.perf_counter() - t
        compile_s = sum(timings[f"{s}_compile_s"] for s in ("prepare", "search", "score", "tables"))
        last = {"repeats": R, "wall_s": wall, "compile_s": compile_s, "run_s": wall - compile_s,
                **{k: timings[k] for k in ("prepare_s", "search_s", "search_compile_s", "score_s", "tables_s")},
                "devices": timings["execution"]["devices"], "kernel": timings["execution"]["kernel"]}
        out.append(last)
        print(f"  study, {R} repeats x 5 strategies: {wall:.1f} s ({compile_s:.1f} s compiling), search "
              f"{timings['search_s']:.1f} s", file=sys.stderr, flush=True)
    return out


def search_rate(n_devices: int, repeats: int = 10, iterations: int = CURVE_ITERATIONS, reps: int = 2) -> dict:
    """Table 3's search (5 strategies x ``repeats`` members, population 30) as one program sharded over the first
    ``n_devices`` devices of the default backend, in this process: compile (the first call), then the best of
    ``reps`` calls; returns ``{"devices", "members", "compile_s", "run_s", "evals_per_s"}``."""
    cfg = StudyConfig(split=dict(n_repeats=repeats), budget=dict(iterations=iterations), strategies=STRATEGIES)
    st = study.stage(datasets.lab_casing(0).frame, cfg, None, jax.random.PRNGKey(0))
    kernel = CPU_KERNEL if jax.default_backend() == "cpu" else ACCELERATOR_KERNEL
    devices = jax.devices()[:n_devices]
    t = time.perf_counter()
    out = jax.block_until_ready(search(st.cfg, st.prep, kernel=kernel, devices=devices))
    compile_s = time.perf_counter() - t
    best = float("inf")
    for _ in range(reps):
        t = time.perf_counter()
        out = jax.block_until_ready(search(st.cfg, st.prep, kernel=kernel, devices=devices))
        best = min(best, time.perf_counter() - t)
    evals = float(np.asarray(out[2])[..., -1].sum())
    return {"devices": n_devices, "members": int(np.asarray(out[2]).shape[0] * np.asarray(out[2]).shape[1]),
            "compile_s": compile_s - best, "run_s": best, "evals_per_s": evals / best}


def _curve_child(counts: str, out_path: str, repeats: int, iterations: int) -> None:
    """The devices curve's child process (host devices set by its ``XLA_FLAGS``): one :func:`search_rate` per
    count, written as JSON to ``out_path``."""
    res = []
    for n in (int(x) for x in counts.split(",")):
        res.append(search_rate(n, repeats, iterations))
        print(f"  {n} host device(s): {res[-1]['run_s']:.2f} s, {res[-1]['evals_per_s']:,.0f} evals/s", file=sys.stderr,
              flush=True)
        with open(out_path, "w") as f:
            json.dump(res, f)


def devices_curve(counts=CURVE_DEVICES, timeout_s: float = 300.0, repeats: int = 10,
                  iterations: int = CURVE_ITERATIONS) -> dict:
    """Table 3's search sharded over 1, 2, 4, ... CPU host devices, in one child process that has
    ``max(counts)`` of them (``JAX_PLATFORMS=cpu``, ``--xla_force_host_platform_device_count``), each point
    :func:`search_rate`; on an accelerator also over 1 .. all of its devices in this process. Points past the
    child's ``timeout_s`` are missing (the ones done are kept). Returns ``{"cpu": [...], "cpu_cores": n,
    "accelerator": [...] or None}``."""

    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "curve.json")
        flags = " ".join(f for f in os.environ.get("XLA_FLAGS", "").split() if not f.startswith(HOST_DEVICE_FLAG))
        env = {**os.environ, "JAX_PLATFORMS": "cpu", "XLA_FLAGS": f"{flags} {HOST_DEVICE_FLAG}={max(counts)}".strip()}
        code = (f"from icgo.bench.backend import _curve_child; "
                f"_curve_child({','.join(map(str, counts))!r}, {path!r}, {repeats}, {iterations})")
        try:
            subprocess.run([sys.executable, "-c", code], env=env, timeout=timeout_s, check=False)
        except subprocess.TimeoutExpired:
            print(f"  devices curve: stopped after {timeout_s:.0f} s", file=sys.stderr, flush=True)
        cpu = json.load(open(path)) if os.path.exists(path) else []
    acc = None
    if jax.default_backend() != "cpu":
        n_all = len(jax.devices())
        acc = [search_rate(n, repeats, iterations) for n in sorted({1, *(c for c in counts if c < n_all), n_all})]
    return {"cpu": cpu, "cpu_cores": len(available_cores()), "accelerator": acc}


def worlds_scaling(worlds=WORLDS, deadline: float = float("inf"), **config) -> list[dict]:
    """Table 3's study on 1, 10, 100 independent worlds (lab_casing data seeds from 100), every world's search in
    one sharded program (:func:`icgo.studies.icgo_relm.worlds.study.run_worlds`); a point is skipped when its time projected from
    the last one (compile as measured, the rest linear in worlds) would end past ``deadline``."""
    out, last = [], None
    for n in worlds:
        why = overrun(None if last is None else {"repeats": last["worlds"], "compile_s": last["compile_s"],
                                                 "run_s": last["run_s"]}, n, deadline - time.perf_counter())
        if why:
            out.append({"worlds": n, "skipped": why.replace("repeats", "worlds")})
            print(f"  {n} worlds: {out[-1]['skipped']}", file=sys.stderr, flush=True)
            continue
        cfg = StudyConfig(**{"strategies": STRATEGIES, **config})
        t = time.perf_counter()
        members = worlds_study.simulate("lab_casing", worlds_study.world_seeds(worlds_study.FIRST_REPORTED_SEED, n))
        timings: dict = {}
        worlds_study.run_worlds(members, cfg, timings=timings)
        wall = time.perf_counter() - t
        compile_s = sum(timings[f"{s}_compile_s"] for s in ("prepare", "search", "score", "tables"))
        last = {"worlds": n, "wall_s": wall, "compile_s": compile_s, "run_s": wall - compile_s,
                "search_s": timings["search_s"], "devices": timings["execution"]["devices"],
                "members": timings["execution"]["members"]}
        out.append(last)
        print(f"  {n} worlds x 5 strategies x {cfg.split.n_repeats} repeats: {wall:.1f} s "
              f"({compile_s:.1f} s compiling), "
              f"search {timings['search_s']:.1f} s", file=sys.stderr, flush=True)
    return out


def backend_check(budget_s: float = BUDGET_S, mealpy_runs: int = 5, front: bool = True, batches=BATCHES,
                  repeats=STUDY_REPEATS, curve=CURVE_DEVICES, worlds=WORLDS, curve_size=(10, CURVE_ITERATIONS),
                  **config) -> dict:
    """Every measurement of the module docstring on this process's backend; returns them (JSON-able).

    ``front``: False leaves the front door out; ``batches``, ``repeats``, ``curve`` (host-device counts; empty:
    no curve), ``curve_size`` (its repeats and iterations), ``worlds``, ``config``: smaller sizes (a test).
    """
    t0 = time.perf_counter()
    deadline = t0 + budget_s
    out = device_line()
    head = (f"device: {out['device']} (backend {out['backend']}, {out['n_devices']} device(s), jax {out['jax']})"
            if out["gpu_present"] else
            f"GPU absent: this check ran on {out['device']} (backend {out['backend']}); every number below is that "
            f"device's, and the GPU numbers are unmeasured")
    print(head, file=sys.stderr, flush=True)
    out["headline"] = head
    sd = study_data(10)
    plan = StudyConfig(strategies=STRATEGIES).execution()
    out["plan"] = plan._asdict()
    print(f"  plan for Table 3: {plan.why}", file=sys.stderr, flush=True)
    rates = kernel_rates(sd, plan.kernel, batches)
    out["kernel_evals_per_s"] = {k: {str(b): v for b, v in r.items()} for k, r in rates.items() if k != "max_rel_diff"}
    out["max_rel_diff_vs_float64"] = rates["max_rel_diff"]
    out["matmul_gflops_f32"], out["matmul_gflops_f64"] = matmul_gflops("float32"), matmul_gflops("float64")
    plan_name = search_kernel("float32_features", "train", plan.kernel).name
    out["plan_fitness"] = plan_name
    out["flop_fraction"] = (rates[plan_name][max(b for b in batches if b <= 1200)] * flops_per_eval(sd.n_train, HIDDEN)
                            / (out["matmul_gflops_f32"] * 1e9))
    print(f"  matmul float32 {out['matmul_gflops_f32']:,.0f} GFLOP/s, float64 {out['matmul_gflops_f64']:,.0f}; "
          f"flop_fraction {out['flop_fraction']:.3g}", file=sys.stderr, flush=True)
    if front:
        fd = front_door(sweeps=False)
        out["front_door"] = fd
        out["table3_cold_s"], out["table3_s"] = fd["cold"]["wall_s"], fd["warm"]["wall_s"]
    if mealpy_runs:
        m = run_mealpy(sd, mealpy_runs)
        out["mealpy_table3_s"] = m["per_run_s"] * len(STRATEGIES) * 10
        out["mealpy_runs_timed"] = mealpy_runs
        if front:
            out["speedup_vs_mealpy"] = out["mealpy_table3_s"] / out["table3_s"]
        print(f"  mealpy OriginalCGO: {mealpy_runs} of 50 runs timed, Table 3 scaled to {out['mealpy_table3_s']:.1f} s",
              file=sys.stderr, flush=True)
    out["study"] = study_scaling(repeats, deadline, **config)
    out["curve_size"] = list(curve_size)
    if curve:
        out["devices_curve"] = devices_curve(curve, max(60.0, min(300.0, deadline - time.perf_counter())), *curve_size)
    out["worlds"] = worlds_scaling(worlds, deadline, **config)
    out["check_s"] = time.perf_counter() - t0
    return out


def report(res: dict) -> str:
    """Markdown of :func:`backend_check`'s result."""
    lines = [res["headline"], "", f"Plan for Table 3: {res['plan']['why']}", "",
             "| measurement | value |", "| --- | ---: |"]
    for kernel, by in res["kernel_evals_per_s"].items():
        for b, v in by.items():
            lines.append(f"| {kernel} kernel, batch {int(b):,} | {v:,.0f} evals/s |")
    lines.append(f"| plan kernel vs float64 library, max relative difference | {res['max_rel_diff_vs_float64']:.2g} |")
    lines.append(f"| 2048^2 matmul float32 / float64 | {res['matmul_gflops_f32']:,.0f} / "
                 f"{res['matmul_gflops_f64']:,.0f} GFLOP/s |")
    lines.append(f"| flop_fraction (batch 1,200, vs float32 matmul) | {res['flop_fraction']:.3g} |")
    if "front_door" in res:
        for name in ("cold", "warm"):
            b = res["front_door"][name]["breakdown"]
            lines.append(f"| Table 3 front door, {name} | {res['front_door'][name]['wall_s']:.1f} s (search "
                         f"{b['search']:.1f}, MSA {b['msa']:.1f}, compile or cache load {b['compile']:.1f}) |")
    if "mealpy_table3_s" in res:
        lines.append(f"| mealpy OriginalCGO, Table 3 ({res['mealpy_runs_timed']} of 50 runs timed, scaled) | "
                     f"{res['mealpy_table3_s']:.1f} s |")
    if "speedup_vs_mealpy" in res:
        lines.append(f"| speed-up vs mealpy (front door, warm) | {res['speedup_vs_mealpy']:.2f}x |")
    for p in res["study"]:
        what = (p.get("skipped") or p.get("error") or
                f"{p['wall_s']:.1f} s ({p['compile_s']:.1f} s compiling; search {p['search_s']:.1f} s)")
        lines.append(f"| study, {p['repeats']:,} repeats x 5 strategies | {what} |")
    curve = res.get("devices_curve") or {}
    for p in curve.get("cpu", []):
        lines.append(f"| Table 3's search ({p['members']} members, {res['curve_size'][1]} iterations) on "
                     f"{p['devices']} CPU "
                     f"host device(s) of {curve['cpu_cores']} core(s) | {p['run_s']:.2f} s, {p['evals_per_s']:,.0f} "
                     f"evals/s |")
    for p in curve.get("accelerator") or []:
        lines.append(f"| Table 3's search on {p['devices']} {res['backend']} device(s) | {p['run_s']:.2f} s, "
                     f"{p['evals_per_s']:,.0f} evals/s |")
    for p in res.get("worlds", []):
        what = (p.get("skipped") or f"{p['wall_s']:.1f} s ({p['compile_s']:.1f} s compiling; search "
                                     f"{p['search_s']:.1f} s, {p['members']} members on {p['devices']} device(s))")
        lines.append(f"| Table 3's study over {p['worlds']} world(s) | {what} |")
    lines.append(f"| the whole check | {res['check_s']:.0f} s |")
    return "\n".join(lines)
