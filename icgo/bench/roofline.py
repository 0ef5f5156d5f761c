"""Per-stage roofline of the fast RELM fitness (:func:`icgo.models.relm.train_fitness`) on this CPU.

What ``python -m experiments.roofline`` measures (:func:`run`); that door pins itself to one core with one XLA
thread (:func:`icgo.core.devices.xla_flags`, as the launcher's jobs, set before JAX is imported), and
:mod:`icgo.bench.cpu` runs it in a child process for the same reason.

Shape: the Table 3 study's repeat 0 (:func:`icgo.bench.kernels.study_data`): n = 407 training
rows, d1 = 7 augmented inputs (6 standardised sensors and a column of ones for the bias),
L = 30 hidden units, chunks of C = 10 thetas, ``refine`` = 2, a batch of P = 1200 thetas.

Stages (the kernel's own functions, ``icgo.models.relm.train_rmse_chunk``), each jitted alone at the
kernel's chunk shape: a ``lax.fori_loop`` of max(ceil(P / C), 100) iterations (enough to amortise
the call's fixed cost) runs the stage on one real chunk's inputs (computed from the study's data
by the stages before it), the first input nudged in place by a runtime 0.0 each iteration (behind
an optimisation barrier) so XLA can neither hoist the stage out of the loop nor fold it, and the
stage's output written to a chunk-sized buffer, as the kernel keeps a chunk in cache. Time per
evaluation = best wall time (``block_until_ready``, after warm-up) / (iterations x C). Counts
per evaluation (s: bytes of a feature value, 8 or 4; thetas are float64; compulsory bytes: the
stage's inputs read once and outputs written once, a chunk-shared input divided by C):

================  ================================  ================================================
stage             flops                             compulsory bytes
================  ================================  ================================================
pre-activation    2 n d1 L                          8 d1 L (theta) + s n L (Z) + s n d1 / C (Xa)
sigmoid           4 n L (exp counted as 1)          2 s n L (read Z, write H)
centring + Gram   2 n L^2 + 4 n L + 2 L^2           s n L (H) + 8 n / C (T) + 8 (L^2 + L) (A, H^T T)
(and H^T T)       (Gram as a general product,
                  means, centring, H^T T, n m m^T)
Cholesky + solve  L^3 / 3 + 2 L^2 + L               16 (L^2 + L) (A, H^T T in; factor, beta out)
refinement        refine (4 n L + n + 2 L^2 + 3 L)  refine (s n L + 8 n / C + 8 (L^2 + 2 L))
                  (H beta, T - H beta, H^T r,       (one pass over H per step; T; factor, beta)
                  solve, lam beta, update)
final RMSE        2 n L + 3 n + 2                   s n L + 8 n / C + 8 L
================  ================================  ================================================

Ceiling of a stage (the roofline bound at its own shape): ``max(flops / F, bytes / B)`` with

* F the flop rate, measured here the same way (the same loop, one chunk-sized operand
  nudged), of a dense 2-D GEMM with the stage's own contraction dimension:
  pre-activation: (n x d1) @ (d1 x C L) in the feature dtype, the stage's flops as one product;
  centring + Gram: (L x n) @ (n x C L) in the Gram's dtype (float32), the flops of the chunk's
  C Grams as one product; Cholesky + solve: C batched (L x L) @ (L x L) float64 products, the
  factor's own inner dimension; sigmoid, refinement and final RMSE (elementwise work and
  matrix-vector products, memory-bound): the (L x n) @ (n x C L) GEMM in the feature dtype;
* B the streaming bandwidth of ``x a + b`` (read and write) on a (C, n, L) array in the
  feature dtype (float64 for the Cholesky stage), the chunk's hidden outputs: the size at which
  the kernel's stages move their data (cache, not DRAM: the chunks are sized to stay in cache).
  For context, ``numpy_copy_<dtype>`` is ``np.copyto`` of the same array: the cache's own rate,
  which XLA's elementwise loops (about 3e9 elements/s in either dtype here) do not approach.

Fraction of a stage = ceiling / measured time. Whole kernel: ``kernel_fraction`` = sum of the
stage ceilings / the measured time of ``train_fitness`` itself at batch P (``stage_sum_us`` is
the sum of the measured stage times, a check that the stages account for the kernel). Both
``feature_dtype`` options are measured.
"""

from __future__ import annotations

import os
import time

import jax
import jax.numpy as jnp
import numpy as np

from icgo.bench.kernels import HIDDEN, LAM, best_time, population, slice_tree, study_data
from icgo.models import relm

#: Fewest loop iterations of a timed stage or ceiling (a call costs ~20 us before its first iteration).
MIN_ITERATIONS = 100
STAGES = ("pre-activation", "sigmoid", "centring + Gram", "Cholesky + solve", "refinement", "final RMSE")
FEATURE_DTYPES = ("float64", "float32")
GRAM_DTYPE = "float32"


def stage_counts(n: int, d1: int, hidden: int, chunk: int, refine: int, feature_bytes: int) -> dict:
    """Flops and compulsory bytes per evaluation of each stage (the module docstring's table).

    Args:
        n: training rows. d1: augmented inputs (with the bias column). hidden: L. chunk: C.
        refine: refinement steps. feature_bytes: bytes of a hidden output (8 float64, 4 float32).
    Returns:
        {stage: (flops, bytes)}.
    """
    L, s, C = hidden, feature_bytes, chunk
    return {
        "pre-activation": (2 * n * d1 * L, 8 * d1 * L + s * n * L + s * n * d1 / C),
        "sigmoid": (4 * n * L, 2 * s * n * L),
        "centring + Gram": (2 * n * L**2 + 4 * n * L + 2 * L**2, s * n * L + 8 * n / C + 8 * (L**2 + L)),
        "Cholesky + solve": (L**3 / 3 + 2 * L**2 + L, 16 * (L**2 + L)),
        "refinement": (refine * (4 * n * L + n + 2 * L**2 + 3 * L),
                       refine * (s * n * L + 8 * n / C + 8 * (L**2 + 2 * L))),
        "final RMSE": (2 * n * L + 3 * n + 2, s * n * L + 8 * n / C + 8 * L),
    }


def loop_time(stage, inputs, iterations: int, reps: int) -> float:
    """Best wall time (s) of ``iterations`` runs of ``stage(*inputs)`` in one jitted ``lax.fori_loop``.

    Each iteration first adds a runtime 0.0 to one element of ``inputs[0]`` (in place), so the
    stage depends on the loop and is computed every time; its output goes to a loop buffer.
    """
    out0 = jax.tree_util.tree_map(lambda a: jnp.zeros(a.shape, a.dtype), jax.eval_shape(stage, *inputs))

    @jax.jit
    def run(x, rest, eps):
        def body(_, carry):
            x, _out = carry
            x = jax.lax.optimization_barrier(x.at[(0,) * x.ndim].add(eps.astype(x.dtype)))
            return x, stage(x, *rest)

        return jax.lax.fori_loop(0, iterations, body, (x, out0))[1]

    return best_time(run, inputs[0], tuple(inputs[1:]), jnp.zeros((), jnp.float64), reps=reps)


def _uniform(shape, dtype, seed: int = 0):
    return jax.random.uniform(jax.random.PRNGKey(seed), shape, jnp.dtype(dtype))


def gemm_rate(m: int, k: int, n: int, dtype, iterations: int, reps: int, batch: int | None = None) -> float:
    """GFLOP/s of an (m x k) @ (k x n) product in ``dtype`` (``batch`` of them at once), timed by :func:`loop_time`."""
    lead = () if batch is None else (batch,)
    a, b = _uniform(lead + (m, k), dtype, 1), _uniform(lead + (k, n), dtype, 2)
    t = loop_time(jnp.matmul, (a, b), iterations, reps)
    return 2 * m * k * n * (batch or 1) * iterations / t / 1e9


def stream_rate(shape, dtype, iterations: int, reps: int) -> float:
    """GB/s of ``x a + b`` (read x, write the result) on an array of ``shape`` in ``dtype`` (:func:`loop_time`)."""
    x = _uniform(shape, dtype)
    one, zero = jnp.ones((), x.dtype), jnp.zeros((), x.dtype)
    t = loop_time(lambda x, a, b: x * a + b, (x, one, zero), iterations, reps)
    return 2 * x.size * x.dtype.itemsize * iterations / t / 1e9


def numpy_copy_rate(shape, dtype, reps: int = 200) -> float:
    """GB/s of ``np.copyto`` (read and write) of an array of ``shape``: the cache's own streaming rate."""
    x = np.ones(shape, dtype)
    out = np.empty_like(x)
    best = float("inf")
    for _ in range(reps):
        t = time.perf_counter()
        np.copyto(out, x)
        best = min(best, time.perf_counter() - t)
    return 2 * x.nbytes / best / 1e9


def ceilings(n: int, d1: int, hidden: int, chunk: int, iterations: int, reps: int) -> dict:
    """The measured rates the stage ceilings use: GEMM proxies (GFLOP/s) and streaming bandwidth (GB/s).

    Keys: ``gemm_d1_<dtype>`` (n x d1) @ (d1 x C L); ``gemm_n_<dtype>`` (L x n) @ (n x C L);
    ``gemm_L_float64`` C x (L x L) @ (L x L); ``stream_<dtype>`` on (C, n, L); and, for context only
    (not a ceiling: not measured the same way), ``numpy_copy_<dtype>`` of the same array.
    """
    L, C = hidden, chunk
    out = {"gemm_L_float64": gemm_rate(L, L, L, "float64", iterations, reps, batch=C)}
    for dt in FEATURE_DTYPES:
        out[f"gemm_d1_{dt}"] = gemm_rate(n, d1, C * L, dt, iterations, reps)
        out[f"gemm_n_{dt}"] = gemm_rate(L, n, C * L, dt, iterations, reps)
        out[f"stream_{dt}"] = stream_rate((C, n, L), dt, iterations, reps)
        out[f"numpy_copy_{dt}"] = numpy_copy_rate((C, n, L), dt)
    return out


def stage_ceilings(counts: dict, rates: dict, feature_dtype: str) -> dict:
    """{stage: (ceiling time per evaluation (s), bound "compute" or "memory")}: max(flops / F, bytes / B)."""
    fd = feature_dtype
    proxy = {"pre-activation": (f"gemm_d1_{fd}", f"stream_{fd}"), "sigmoid": (f"gemm_n_{fd}", f"stream_{fd}"),
             "centring + Gram": (f"gemm_n_{GRAM_DTYPE}", f"stream_{fd}"),
             "Cholesky + solve": ("gemm_L_float64", "stream_float64"),
             "refinement": (f"gemm_n_{fd}", f"stream_{fd}"), "final RMSE": (f"gemm_n_{fd}", f"stream_{fd}")}
    out = {}
    for stage, (flops, nbytes) in counts.items():
        f_key, b_key = proxy[stage]
        tc, tm = flops / (rates[f_key] * 1e9), nbytes / (rates[b_key] * 1e9)
        out[stage] = (max(tc, tm), "compute" if tc >= tm else "memory")
    return out


def stage_times(rows: relm.TrainRows, pop, hidden: int, lam: float, chunk: int, refine: int, feature_dtype: str,
                iterations: int, reps: int) -> dict:
    """{stage: measured time per chunk (s)} of each stage at the kernel's chunk shape (unweighted rows).

    The inputs of every stage are those of the kernel on the chunk ``pop[:chunk]``.
    """
    dt, gd = pop.dtype, jnp.dtype(GRAM_DTYPE)
    lam = jnp.asarray(lam, dt)
    Xa, T = rows.Xa, rows.T
    d1 = Xa.shape[1]
    p0 = pop[:chunk]
    Z = relm.pre_activation(Xa, relm.input_weights(p0, d1, hidden, feature_dtype))
    H = jax.nn.sigmoid(Z)
    A, HtT, n = relm.normal_equations(H, T, None, dt, gd)
    C = relm.cholesky(A, lam)
    beta0 = relm.cho_solve(C, HtT)

    def refinement(H):
        beta = beta0
        for _ in range(refine):
            beta = relm.refine_step(H, T, None, beta, C, lam)
        return beta

    beta = refinement(H)

    stages = {
        "pre-activation": (lambda p: relm.pre_activation(Xa, relm.input_weights(p, d1, hidden, feature_dtype)), p0),
        "sigmoid": (jax.nn.sigmoid, Z),
        "centring + Gram": (lambda H: relm.normal_equations(H, T, None, dt, gd)[:2], H),
        "Cholesky + solve": (lambda A: relm.cho_solve(relm.cholesky(A, lam), HtT), A),
        "refinement": (refinement, H),
        "final RMSE": (lambda H: relm.rmse(H, T, None, n, beta), H),
    }
    return {name: loop_time(f, (x,), iterations, reps) / iterations for name, (f, x) in stages.items()}


def measure(rows: relm.TrainRows, hidden: int = HIDDEN, lam: float = LAM, batch: int = 1200, chunk: int = 10,
            refine: int = 2, reps: int = 7) -> dict:
    """The per-stage roofline of :func:`icgo.models.relm.train_fitness` on ``rows`` (one repeat, unweighted).

    Args:
        rows: TrainRows (n, d1) of one repeat. hidden: L. lam: ridge lambda. batch: thetas P of the
            kernel's call. chunk: C. refine: refinement steps. reps: timing rounds.
    Returns:
        dict: shape, ``rates`` (GFLOP/s, GB/s), and per feature dtype ``stages`` ({stage: time_us,
        flops, bytes, gflops, gbs, ceiling_us, bound, fraction} per evaluation), ``stage_sum_us``,
        ``kernel_us``, ``kernel_evals_per_s``, ``ceiling_sum_us``, ``kernel_fraction``; and
        ``f32_speedup`` (float32 / float64 features, evaluations per second).
    """
    n, d1 = rows.Xa.shape
    chunk = min(chunk, batch)  # the kernel's own rule: a chunk of at least the batch is the batch
    iterations = max(-(-batch // chunk), MIN_ITERATIONS)
    pop = population(jax.random.PRNGKey(batch), batch, hidden)
    rates = ceilings(n, d1, hidden, chunk, iterations, reps)
    out = {"batch": batch, "chunk": chunk, "n": n, "d1": d1, "hidden": hidden, "refine": refine,
           "gram_dtype": GRAM_DTYPE, "rates": rates}
    for fd in FEATURE_DTYPES:
        counts = stage_counts(n, d1, hidden, chunk, refine, jnp.dtype(fd).itemsize)
        ceil = stage_ceilings(counts, rates, fd)
        times = stage_times(rows, pop, hidden, lam, chunk, refine, fd, iterations, reps)
        kernel = relm.make_train_fitness(lam, hidden, chunk, refine, feature_dtype=fd)
        t_kernel = best_time(kernel, pop, rows, reps=reps) / batch
        stages = {}
        for s in STAGES:
            t, (flops, nbytes), (tc, bound) = times[s] / chunk, counts[s], ceil[s]
            stages[s] = {"time_us": t * 1e6, "flops": flops, "bytes": nbytes, "gflops": flops / t / 1e9,
                         "gbs": nbytes / t / 1e9, "ceiling_us": tc * 1e6, "bound": bound, "fraction": tc / t}
        ceiling_sum = sum(ceil[s][0] for s in STAGES)
        out[fd] = {"stages": stages, "stage_sum_us": sum(v["time_us"] for v in stages.values()),
                   "kernel_us": t_kernel * 1e6, "kernel_evals_per_s": 1 / t_kernel,
                   "ceiling_sum_us": ceiling_sum * 1e6, "kernel_fraction": ceiling_sum / t_kernel}
    out["f32_speedup"] = out["float32"]["kernel_evals_per_s"] / out["float64"]["kernel_evals_per_s"]
    return out


def table(res: dict) -> str:
    """Markdown table of :func:`measure`'s result: one row per (feature dtype, stage), then the kernel."""
    lines = ["| features | stage | us/eval | GFLOP/s | GB/s | ceiling us | bound | fraction |",
             "| --- | --- | ---: | ---: | ---: | ---: | --- | ---: |"]
    for fd in FEATURE_DTYPES:
        r = res[fd]
        for s, v in r["stages"].items():
            lines.append(f"| {fd} | {s} | {v['time_us']:.3f} | {v['gflops']:.2f} | {v['gbs']:.2f} | "
                         f"{v['ceiling_us']:.3f} | {v['bound']} | {v['fraction']:.3f} |")
        lines.append(f"| {fd} | **kernel** ({r['kernel_evals_per_s']:,.0f} evals/s; stages sum "
                     f"{r['stage_sum_us']:.2f} us) | {r['kernel_us']:.3f} | | | {r['ceiling_sum_us']:.3f} | | "
                     f"**{r['kernel_fraction']:.3f}** |")
    return "\n".join(lines)


def run(batch: int, chunk: int, refine: int, reps: int, quick: bool) -> dict:
    """:func:`measure` on the Table 3 study's repeat 0 (:func:`icgo.bench.kernels.study_data`), with the machine's
    state around it (load averages, XLA flags, the cores this process may use): the object the door prints."""
    res = {"loadavg_start": list(os.getloadavg())}
    res.update(measure(slice_tree(study_data(1).compact, 0), HIDDEN, LAM, batch, chunk, refine, reps))
    res.update(quick=quick, reps=reps, xla_flags=os.environ.get("XLA_FLAGS", ""),
               cpus=sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
               loadavg_end=list(os.getloadavg()), jax=jax.__version__)
    return res
