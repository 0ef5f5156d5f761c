"""How often each CGO seed improves on its parent and is selected, in the ICGO-RELM search of Fig. 9.

The searches are the study's own (:mod:`icgo.studies.icgo_relm`): its split, MSA, features and fitness kernel for
each repeat (``prepare``, ``search_kernel``; repeat k's key ``fold_in(PRNGKey(seed), k)``) and CGO itself, run step
by step through :func:`icgo.optim.cgo.advance`, which returns what happened to every seed of an iteration
(:class:`icgo.optim.cgo.SeedOutcome`). Only the bookkeeping is added: a run here ends at the best fitness of the
study's search with the same settings (tested), so the counts describe Fig. 9's runs themselves.

Per configuration and seed (1-3: eqs. 12-14; 4: the 4th seed, eq. 15 or its variant): the share of its trials that
improved on the parent, and the share the selection kept, over the whole run and over its last part; a trial is one
seed of one member in one iteration, pooled over members, iterations and repeats. The configurations counted for
``results/fig9_seeds.*`` (``python -m experiments.fig9_seeds``) are :data:`CONFIGS`, its report :func:`markdown`.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from icgo.models import relm as _relm
from icgo.models.search_fitness import search_fitness
from icgo.optim.cgo import CGO, CGOConfig, advance
from icgo.studies.icgo_relm.config import StudyConfig
from icgo.studies.icgo_relm.prepare import exclude_failed_repeats, filtered, prepare, reference_field
from icgo.studies.icgo_relm.search import search_aux


class SeedRates(NamedTuple):
    """Per-repeat, per-iteration shares of one configuration's runs.

    Attributes:
        improved: (R, T, K) share of the P members whose seed k beat its parent at iteration t.
        chosen: (R, T, K) share whose seed k the selection kept.
        best_f: (R,) final best fitness (the training RMSE the search minimises, deg).
    """

    improved: np.ndarray
    chosen: np.ndarray
    best_f: np.ndarray


def search_setup(frame: pd.DataFrame, meta: dict, cfg: StudyConfig, key):
    """The study's per-repeat search inputs: (keys (R, 2), fitness aux, bounds) exactly as
    :func:`icgo.studies.icgo_relm.search.search` builds them (failed-MSA repeats left out as the study does)."""
    rows, G, B, a_true, _ = filtered(frame, cfg)
    reference = reference_field(cfg, meta)
    prep, mem = prepare(rows, G, B, a_true, cfg, key, reference)
    prep, mem, cfg, _ = exclude_failed_repeats(prep, mem, cfg, reference)
    aux = search_aux(cfg, prep, cfg.execution(cells=prep.key.shape[0]).kernel)
    D = _relm.n_params(cfg.model.hidden)
    low, high = cfg.model.theta_bounds
    return prep.key, aux, (np.full(D, float(low)), np.full(D, float(high)))


def run_counted(keys, aux, bounds, pop_size: int, n_iter: int, config: CGOConfig,
                fitness=search_fitness) -> SeedRates:
    """CGO for every repeat (one jitted, vmapped ``lax.scan``), counting its seeds.

    Args:
        keys: (R, 2) repeat keys; aux: the fitness's per-repeat data (leading axis R); bounds: (lb, ub), (D,) each.
        pop_size, n_iter: the budget; config: the CGO config.
        fitness: ``fitness(pop, aux) -> (P,)`` (default: the RELM search fitness of the study).
    The keys are used as :func:`icgo.optim.run_batch` uses them (``split(key)`` into the initial and the iteration
    keys), so each run is the runner's run with that key.
    """
    lb, ub = (np.asarray(b, float) for b in bounds)

    def one(key, aux_r):
        k_init, k_run = jax.random.split(key)
        state = CGO.init(k_init, fitness, (lb, ub), pop_size, config, aux_r)

        def body(s, xs):
            t, k = xs
            s, out = advance(s, k, t, n_iter, fitness)
            return s, (out.improved.mean(axis=0), out.chosen.mean(axis=0))

        state, (imp, cho) = jax.lax.scan(body, state, (jnp.arange(n_iter), jax.random.split(k_run, n_iter)))
        return imp, cho, state.best_f

    imp, cho, best = _jitted(one)(keys, aux)
    return SeedRates(np.asarray(imp), np.asarray(cho), np.asarray(best))


def _jitted(one):
    return jax.jit(jax.vmap(one))


def rates_table(runs: dict[str, SeedRates], last: float = 0.5) -> pd.DataFrame:
    """One row per (configuration, seed): % of trials improved and chosen over the run and over its last ``last``
    fraction of iterations, pooled over members, iterations and repeats."""
    rows = []
    for name, r in runs.items():
        T = r.improved.shape[1]
        tail = slice(T - int(round(last * T)), T)
        for k in range(r.improved.shape[2]):
            rows.append({"configuration": name, "seed": k + 1, "repeats": r.improved.shape[0], "iterations": T,
                         "improved % (run)": 100 * float(r.improved[:, :, k].mean()),
                         f"improved % (last {tail.stop - tail.start} iterations)":
                             100 * float(r.improved[:, tail, k].mean()),
                         "chosen % (run)": 100 * float(r.chosen[:, :, k].mean()),
                         f"chosen % (last {tail.stop - tail.start} iterations)":
                             100 * float(r.chosen[:, tail, k].mean()),
                         "final training RMSE, mean (deg)": float(r.best_f.mean())})
    return pd.DataFrame(rows)


def study(frame: pd.DataFrame, meta: dict, configs: dict[str, CGOConfig], cfg: StudyConfig | None = None,
          key=None) -> dict[str, SeedRates]:
    """Every configuration's counted runs on the study's searches (``cfg``: default :class:`StudyConfig`; ``key``:
    ``PRNGKey(cfg.split.seed)``, as the study's)."""
    cfg = StudyConfig() if cfg is None else cfg
    key = jax.random.PRNGKey(cfg.split.seed) if key is None else key
    keys, aux, bounds = search_setup(frame, meta, cfg, key)
    return {name: run_counted(keys, aux, bounds, cfg.budget.pop_size, cfg.budget.iterations, c) for name,
                              c in configs.items()}


#: The configurations counted: name -> CGOConfig keywords (the paper variant's factory).
CONFIGS = {"default (4th seed: eq. 15 on a random subset)": {},
           "dims one (4th seed on one coordinate)": {"dims": "one"},
           "dims all (4th seed on every coordinate)": {"dims": "all"},
           "original_uniform True (4th seed a uniform random point)": {"original_uniform": True}}


def markdown(table, cfg, seconds: float, command: str) -> str:
    """``fig9_seeds.md``: protocol, stamp, the table, what a trial is."""
    from icgo.reporting.choices import LAMBDA
    from icgo.reporting.protocol import protocol_line, settings_line

    line = protocol_line(
        f"`{command}`", f"{cfg.split.n_repeats} repeats (Fig. 9's splits and keys), the same for every configuration",
        "random 7:3 of the 3-sigma-filtered rows, a new permutation per repeat; the search sees the training rows "
        "only (nothing is scored on test rows here)",
        f"data: lab_casing with noise seed 0; repeat k: split and search key fold_in(PRNGKey({cfg.split.seed}), k). "
        f"{LAMBDA.sentence()}",
        "none: counts of the search's own events (no method is compared with another by a test here; "
        "`fig9_ablation.md` tests the configurations)")
    paper = (cfg.budget.pop_size, cfg.budget.iterations) == (30, 100)
    stamp = settings_line(f"population {cfg.budget.pop_size} x {cfg.budget.iterations} iterations",
                          f"{cfg.split.n_repeats} repeats",
                          f"search dtype {cfg.precision}",
                          "The paper's protocol (population 30 x 100 iterations)." if paper else
                          "NOT the paper's protocol (population 30 x 100 iterations).")
    return "\n".join([
        "# Fig. 9's CGO-RELM searches: how often each seed improves on its parent and is selected", "", line, "",
        stamp, "", table.to_markdown(index=False, floatfmt=".3g"), "",
        "Seeds 1-3: eqs. 12-14; seed 4: the 4th seed (eq. 15 in the default). A trial is one seed of one member in one "
        f"iteration ({cfg.budget.pop_size} members x {cfg.budget.iterations} iterations x {cfg.split.n_repeats} "
        f"repeats per "
        "configuration); "
        "`improved`: its training RMSE is below its parent's; `chosen`: the greedy selection kept it (it replaced its "
        "parent). The runs are the study's searches: each ends at the final training RMSE of the study's run with "
        "the same settings (tests/test_cgo_seeds.py).",
        f"Wall time {seconds:.0f} s (one run on a shared machine: a rough figure).", ""])


def write_results(table: pd.DataFrame, text: str, stage: Path) -> None:
    """fig9_seeds.csv (:func:`rates_table`) and fig9_seeds.md (``text``, :func:`markdown`) into ``stage``."""
    table.to_csv(stage / "fig9_seeds.csv", index=False)
    (stage / "fig9_seeds.md").write_text(text)
