"""The command line of ``python -m experiments.bench``: its options (:func:`parser`), their checks and the mode
they pick (:func:`plan`), and that mode run (:func:`run`).

Modes: ``calibrate`` (``--calibrate``: :func:`icgo.bench.front_door.calibrate_front_door`), ``gpu_check``
(``--gpu-check``: :mod:`icgo.bench.backend`), ``rows`` (``--rows``: :mod:`icgo.bench.rows`) and, without a mode
option, ``cpu`` (:mod:`icgo.bench.cpu`). Every check of the options is made before anything is measured.
"""

from __future__ import annotations

import os
import re
from typing import NamedTuple

from icgo.core.settings import ArgumentParser

#: The modes whose result is printed only (a summary, then the JSON line), never written to results/.
PRINTED_ONLY = ("calibrate", "rows")
#: The commands ``--rows`` can measure (:func:`icgo.bench.rows.rows_scaling`).
ROWS_COMMANDS = ("reader", "study", "discrepancy", "apply")


def parser(prog: str, description: str) -> ArgumentParser:
    """Every option of the benchmark (one-line usage errors, :class:`icgo.core.settings.ArgumentParser`)."""
    p = ArgumentParser(prog=prog, description=description)
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
                        "reader, the study, the discrepancy workflow and streaming apply (--rows-commands) on "
                        "contract CSVs of that many rows (each deleted once measured)")
    p.add_argument("--rows-budget", default="smoke", help="--rows: the study's conf/budget option (default smoke)")
    p.add_argument("--rows-repeats", type=int, default=None, help="--rows: the study's split.n_repeats (default 10)")
    p.add_argument("--rows-commands", default="reader,study,discrepancy",
                   help="--rows: which commands to run, of reader, study, discrepancy, apply (e.g. --rows 1e6,4e6,16e6 "
                        "--rows-commands apply: streaming apply's peak memory)")
    p.add_argument("--rows-dir", default=None, help="--rows: directory for the CSVs and run directories")
    p.add_argument("--gpu-check", action="store_true",
                   help="only the backend check of icgo.bench.backend (kernels at batch 120 / 1,200 / 60,000, "
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
    return p


class Plan(NamedTuple):
    """What one benchmark command runs: its ``mode`` (see the module docstring), the parsed options ``a``, and the
    sizes the checks derived (``None`` where the mode has none)."""

    mode: str
    a: object
    cores: list | None = None
    sizes: list | None = None
    iters: int | None = None
    n_rep: int | None = None
    s_iters: int | None = None
    s_reps: tuple | None = None
    mealpy_runs: int | None = None


def plan(a, error) -> Plan:
    """The mode and sizes of parsed options ``a``; a bad option calls ``error(message)`` (the parser's: one line,
    exit 2). The checks run in the order the modes are picked, so a mode never sees another mode's options."""
    if a.out is not None and not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}", a.out):
        error(f"--out {a.out!r}: a tag of letters, digits, '.', '_', '-' (the files are results/bench_<tag>.*)")
    if a.calibrate:
        return Plan("calibrate", a)
    if a.gpu_check:
        return Plan("gpu_check", a)
    cores = None
    if a.cores:
        try:
            cores = [int(x) for x in a.cores.split(",")]
        except ValueError:
            error(f"--cores must be a comma list of integers, got {a.cores!r}")
        if min(cores) < 1 or max(cores) > len(os.sched_getaffinity(0)):
            error(f"--cores must be between 1 and the {len(os.sched_getaffinity(0))} cores this process may use")
    if a.rows:
        sizes = [int(float(x)) for x in a.rows.split(",")]
        if min(sizes) < 1:
            error("--rows sizes must be >= 1")
        unknown = set(a.rows_commands.split(",")) - set(ROWS_COMMANDS)
        if unknown:
            error(f"--rows-commands: unknown {sorted(unknown)}; choose from {', '.join(ROWS_COMMANDS)}")
        return Plan("rows", a, cores, sizes)
    if a.chunk < 1 or a.refine < 0:
        error("--chunk must be >= 1 and --refine >= 0")
    quick = a.quick
    iters = a.iterations or (10 if quick else 100)
    n_rep = a.repeats or (2 if quick else 10)
    s_iters = a.scaling_iterations or iters
    s_reps = tuple(int(x) for x in a.scaling_repeats.split(",")) if a.scaling_repeats else ((1, 2, 4) if quick else (1, 10, 100))
    if min(iters, n_rep, s_iters, *s_reps) < 1:
        error("--repeats, --iterations and the scaling sizes must be >= 1")
    from icgo.optim import STRATEGIES

    mealpy_runs = a.mealpy_runs if a.mealpy_runs is not None else (2 if quick else len(STRATEGIES) * n_rep)
    if mealpy_runs < 0:
        error("--mealpy-runs must be >= 0")
    return Plan("cpu", a, cores, None, iters, n_rep, s_iters, s_reps, mealpy_runs)


def run(pl: Plan) -> tuple[dict, str]:
    """The measurements of ``pl``'s mode: (the JSON object, the text printed before it: a Markdown table, or for
    ``calibrate`` one summary line)."""
    a = pl.a
    if pl.mode == "calibrate":
        from icgo.bench.front_door import calibrate_front_door

        res = calibrate_front_door(warm_runs=a.calibrate_runs)
        res.update(cpu_count=os.cpu_count(), loadavg_end=list(os.getloadavg()))
        return res, (f"calibrate {res['data']}: cold {res['cold']['wall_s']:.1f} s, warm {res['warm_min_s']:.1f} s "
                     f"(min of {len(res['warm'])}), median {res['warm_median_s']:.1f} s")
    if pl.mode == "gpu_check":
        from icgo.bench.backend import backend_check, report

        res = backend_check(mealpy_runs=5 if a.mealpy_runs is None else a.mealpy_runs)
        return res, report(res)
    if pl.mode == "rows":
        from icgo.bench.rows import rows_report, rows_scaling

        table, res = rows_report(rows_scaling(pl.sizes, a.rows_budget, a.rows_repeats, a.rows_dir,
                                              tuple(a.rows_commands.split(","))), a.rows_budget, a.rows_repeats)
        return res, table
    from icgo.bench.cpu import cpu_benchmark

    out, table = cpu_benchmark(a, pl.iters, pl.n_rep, pl.s_iters, pl.s_reps, pl.mealpy_runs, pl.cores)
    return out, table
