"""Kernel A/B: settings of the search's CPU kernel (:func:`icgo.models.relm.train_fitness`) timed side by side in
one process, for a machine whose load changes while it runs.

What ``python -m experiments.roofline --ab SPEC [SPEC ...]`` measures (:func:`run`); that door pins itself to one
core with one XLA thread. Shape: the call a Table 3 search makes on one device, ``members`` batch members (strategies
x repeats of the study's data, vmapped) of ``batch`` thetas each (CGO's 4 seeds x population 30), the study's
n = 407 training rows, L = 30, float32 features (the study's default precision). Each SPEC is a comma list of
``train_fitness`` settings (``chunk=5,refine=1``; ``base`` for the defaults). The variants run in turns, ``rounds``
times; each call is timed by **process CPU time** (what the process itself spent, which other processes' load on
the machine does not inflate as it does wall time), best taken. Per variant: evaluations per CPU second, the ratio to
the first SPEC, whether its fitness is bitwise the first's, and its largest relative difference from the float64
library fitness (:func:`icgo.models.relm.fitness`; the search kernel's contract is 5e-6).
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

from icgo.bench.kernels import FEATURES, HIDDEN, LAM, population, study_data
from icgo.models import relm

#: The settings a SPEC may name (:func:`icgo.models.relm.train_fitness`'s static arguments).
SETTINGS = {"chunk": int, "refine": int, "gram_dtype": str, "feature_dtype": str, "row_block": int}


def parse_spec(spec: str) -> dict:
    """``"chunk=5,refine=1"`` -> ``{"chunk": 5, "refine": 1}``; ``"base"`` -> ``{}``.

    Raises:
        ValueError: one line naming the setting that is not one of :data:`SETTINGS` or not a value of its type.
    """
    if spec.strip() == "base":
        return {}
    out = {}
    for part in spec.split(","):
        key, eq, value = part.partition("=")
        key = key.strip()
        if not eq or key not in SETTINGS:
            raise ValueError(f"--ab {spec!r}: {part!r} is not name=value with a name of {', '.join(SETTINGS)}")
        try:
            out[key] = SETTINGS[key](value.strip())
        except ValueError:
            raise ValueError(f"--ab {spec!r}: {key}={value!r} is not a {SETTINGS[key].__name__}") from None
    return out


def run(specs: list[str], members: int = 25, batch: int = 120, rounds: int = 10) -> dict:
    """Time the kernel under each SPEC in turns (module doc).

    Returns:
        dict: ``shape`` and, per SPEC, ``evals_per_cpu_s``, ``ratio`` (to the first), ``bitwise`` (to the first),
        ``max_rel_vs_float64``, ``cpu_ms`` (best call).
    """
    settings = [parse_spec(s) for s in specs]
    sd = study_data(10)
    rows = jax.tree_util.tree_map(lambda x: jnp.resize(x, (members,) + x.shape[1:]), sd.compact)
    pop = jnp.stack([population(jax.random.PRNGKey(i), batch) for i in range(members)])
    lam = jnp.full(members, LAM)
    fits = [jax.jit(jax.vmap(lambda p, r, lm, kw=kw: relm.train_fitness(
        p, r, lm, HIDDEN, **{"feature_dtype": FEATURES, **kw}))).lower(pop, rows, lam).compile() for kw in settings]
    n = rows.T.shape[1]
    ones = jnp.ones((1, n))
    ref = np.asarray(jax.jit(jax.vmap(lambda p, r, lm: relm.fitness(
        p, relm.FitData(r.Xa[:, :relm.N_INPUTS], r.T, ones, ones), lm, HIDDEN)))(pop, rows, lam))
    outs = [np.asarray(f(pop, rows, lam)) for f in fits]
    best = [float("inf")] * len(fits)
    for _ in range(rounds):
        for i, f in enumerate(fits):
            t = time.process_time()
            jax.block_until_ready(f(pop, rows, lam))
            best[i] = min(best[i], time.process_time() - t)
    evals = members * batch
    return {"shape": {"members": members, "batch": batch, "rows": int(n), "hidden": HIDDEN, "features": FEATURES,
                      "rounds": rounds},
            "variants": [{"spec": s, "cpu_ms": 1e3 * b, "evals_per_cpu_s": evals / b, "ratio": best[0] / b,
                          "bitwise": bool(np.array_equal(o, outs[0])),
                          "max_rel_vs_float64": float(np.max(np.abs(o / ref - 1.0)))}
                         for s, b, o in zip(specs, best, outs)]}


def table(res: dict) -> str:
    """Markdown table of :func:`run`'s result."""
    lines = ["| variant | CPU ms / call | evals / CPU s | ratio to first | bitwise first | max rel. vs float64 |",
             "| --- | ---: | ---: | ---: | --- | ---: |"]
    lines += [f"| `{v['spec']}` | {v['cpu_ms']:.1f} | {v['evals_per_cpu_s']:,.0f} | {v['ratio']:.3f} | "
              f"{'yes' if v['bitwise'] else 'no'} | {v['max_rel_vs_float64']:.2g} |" for v in res["variants"]]
    return "\n".join(lines)
