"""Benchmark of the ICGO-RELM study against the machine's limit and against mealpy: ``python -m experiments.bench``.

* without a mode option: the CPU benchmark (:mod:`experiments.bench_cpu`, whose docstring lists every measurement):
  kernels, roofline, the Table 3 study through its own path and the front door, mealpy, the JAX peers, scaling;
* ``--gpu-check``: the per-backend check in minutes (:mod:`experiments.bench_backend`);
* ``--rows 1e3,1e4,1e5,1e6``: the reader, the study and the discrepancy workflow on contract CSVs of that many
  rows, wall time and peak memory (:mod:`experiments.bench_rows`);
* ``--calibrate``: ``python -m experiments.calibrate`` on one bundled device, cold then warm.

It prints a Markdown table and, as its last line, one JSON object; ``--out NAME`` also writes
``results/bench_<NAME>.{md,json}``. ``--quick`` runs a small version of everything (smoke use, minutes).
"""

from __future__ import annotations

import json
import os
import re

from icgo.io.files import RESULTS_DIR, results_output


def main(argv=None) -> dict:
    from icgo.core.settings import ArgumentParser

    p = ArgumentParser(prog="python -m experiments.bench", description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="small sizes everywhere (smoke use)")
    p.add_argument("--mealpy-runs", type=int, default=None,
                   help="mealpy runs to time (default: all 50, quick: 2); fewer are extrapolated and marked")
    p.add_argument("--chunk", type=int, default=10, help="fast kernel: thetas per lax.map step")
    p.add_argument("--refine", type=int, default=2, help="fast kernel: iterative-refinement steps")
    p.add_argument("--repeats", type=int, default=None, help="repeats of the Table 3 study (default 10, quick 2)")
    p.add_argument("--iterations", type=int, default=None, help="optimizer iterations (default 100, quick 10)")
    p.add_argument("--scaling-repeats", default=None, help="comma list of repeat counts (default 1,10,100)")
    p.add_argument("--scaling-iterations", type=int, default=None, help="iterations of the scaling rows (default --iterations)")
    p.add_argument("--skip-scaling", action="store_true", help="skip the scaling rows")
    p.add_argument("--skip-front-door", action="store_true",
                   help="skip the front-door runs (then table3_s is the benchmark's own path)")
    p.add_argument("--skip-peers", action="store_true", help="skip the evosax comparison")
    p.add_argument("--skip-roofline", action="store_true", help="skip the per-stage roofline (experiments.roofline)")
    p.add_argument("--out", default=None, help="also write the JSON and the table to results/bench_<out>.{json,md}")
    p.add_argument("--calibrate", action="store_true",
                   help="only time python -m experiments.calibrate on one bundled 24-shot device, cold then warm")
    p.add_argument("--calibrate-runs", type=int, default=3, help="--calibrate: warm runs after the cold one")
    p.add_argument("--rows", default=None,
                   help="comma list of row counts (e.g. 1e3,1e4,1e5,1e6): only measure time and peak memory of the "
                        "reader, the study and the discrepancy workflow on contract CSVs of that many rows")
    p.add_argument("--rows-budget", default="smoke", help="--rows: the study's conf/budget option (default smoke)")
    p.add_argument("--rows-repeats", type=int, default=None, help="--rows: the study's split.n_repeats (default 10)")
    p.add_argument("--rows-commands", default="reader,study,discrepancy", help="--rows: which commands to run")
    p.add_argument("--rows-dir", default=None, help="--rows: directory for the CSVs and run directories")
    p.add_argument("--gpu-check", action="store_true",
                   help="only the backend check of experiments.bench_backend (kernels at batch 120 / 1,200 / 60,000, "
                        "flop_fraction, Table 3's front door cold and warm, the study at 1 / 10 / 100 / 1,000 repeats, "
                        "mealpy) in under 8 minutes; on a machine without a GPU it says so and measures what it finds")
    p.add_argument("--cores", default=None,
                   help="comma list of core counts (e.g. 1,2): Table 3's front door with its CPU affinity cut to that "
                        "many cores, cold and warm, and where the time went at each (the 'cores' section)")
    p.add_argument("--alternate", type=int, default=1,
                   help="time mealpy's Table 3 runs in this many parts, each after a warm front-door run (Table 3 "
                        "and like-for-like), for the ratios on a machine whose load changes (default 1: one block)")
    p.add_argument("--skip-mealpy-parallel", action="store_true", help="skip mealpy's own parallel mode")
    p.add_argument("--skip-sweeps", action="store_true",
                   help="front door: only the cold and warm runs (no devices=1 run, no five-job sweeps)")
    p.add_argument("--skip-like-for-like", action="store_true",
                   help="skip the like-for-like front door (mealpy's CGO variant in float64, 50 runs)")
    a = p.parse_args(argv)
    if a.out is not None and not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}", a.out):
        p.error(f"--out {a.out!r}: a tag of letters, digits, '.', '_', '-' (the files are results/bench_<tag>.*)")
    if a.calibrate:
        from experiments.bench_user import calibrate_front_door

        res = calibrate_front_door(warm_runs=a.calibrate_runs)
        res.update(cpu_count=os.cpu_count(), loadavg_end=list(os.getloadavg()))
        print(f"calibrate {res['data']}: cold {res['cold']['wall_s']:.1f} s, warm {res['warm_min_s']:.1f} s (min of "
              f"{len(res['warm'])}), median {res['warm_median_s']:.1f} s")
        print(json.dumps(res))
        return res
    if a.gpu_check:
        from experiments.bench_backend import backend_check, report

        res = backend_check(mealpy_runs=5 if a.mealpy_runs is None else a.mealpy_runs)
        return _publish(res, report(res), a.out)
    cores = None
    if a.cores:
        try:
            cores = [int(x) for x in a.cores.split(",")]
        except ValueError:
            p.error(f"--cores must be a comma list of integers, got {a.cores!r}")
        if min(cores) < 1 or max(cores) > len(os.sched_getaffinity(0)):
            p.error(f"--cores must be between 1 and the {len(os.sched_getaffinity(0))} cores this process may use")
    if a.rows:
        from experiments.bench_rows import rows_report, rows_scaling

        sizes = [int(float(x)) for x in a.rows.split(",")]
        if min(sizes) < 1:
            p.error("--rows sizes must be >= 1")
        table, res = rows_report(rows_scaling(sizes, a.rows_budget, a.rows_repeats, a.rows_dir,
                                              tuple(a.rows_commands.split(","))), a.rows_budget, a.rows_repeats)
        print(table)
        print(json.dumps(res))
        return res
    from experiments.bench_cpu import cpu_benchmark
    from experiments.bench_kernels import STRATEGIES

    if a.chunk < 1 or a.refine < 0:
        p.error("--chunk must be >= 1 and --refine >= 0")
    quick = a.quick
    iters = a.iterations or (10 if quick else 100)
    n_rep = a.repeats or (2 if quick else 10)
    s_iters = a.scaling_iterations or iters
    s_reps = tuple(int(x) for x in a.scaling_repeats.split(",")) if a.scaling_repeats else ((1, 2, 4) if quick else (1, 10, 100))
    if min(iters, n_rep, s_iters, *s_reps) < 1:
        p.error("--repeats, --iterations and the scaling sizes must be >= 1")
    mealpy_runs = a.mealpy_runs if a.mealpy_runs is not None else (2 if quick else len(STRATEGIES) * n_rep)
    if mealpy_runs < 0:
        p.error("--mealpy-runs must be >= 0")
    out, table = cpu_benchmark(a, iters, n_rep, s_iters, s_reps, mealpy_runs, cores)
    return _publish(out, table, a.out)


def _publish(out: dict, md: str, name: str | None) -> dict:
    """Print the Markdown and, last, the JSON line; with ``name`` also write results/bench_<name>.{md,json}
    (both files or neither)."""
    line = json.dumps(out, default=float)
    if name:  # both files or neither, into the shared results folder
        with results_output(RESULTS_DIR, writer="experiments.bench").staged() as stage:
            (stage / f"bench_{name}.md").write_text(md + "\n")
            (stage / f"bench_{name}.json").write_text(line + "\n")
    print(md)
    print(line)
    return out


if __name__ == "__main__":
    from icgo.core.settings import run_cli

    raise SystemExit(run_cli(lambda: (main(), 0)[1]))
