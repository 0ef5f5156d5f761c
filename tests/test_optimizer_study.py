"""icgo.studies.optimizers (the optimizer benchmark) and its entry point experiments.optimizers.

Also the building blocks of the mealpy side (moved here from tests/test_optim_study.py): the
independent numpy fitness, the equal-budget evaluation count and the +/=/- rule.
"""

from __future__ import annotations

import dataclasses
import inspect
import re
import sys

import jax
import numpy as np
import pandas as pd
import pytest
from scipy.stats import ranksums

import icgo  # noqa: F401  (float64)
from experiments import optimizers as entry
from icgo.core.errors import SettingError
from icgo.core.settings import config_from_mapping, config_to_mapping
from icgo.optim import OPTIMIZERS, get, run_batch
from icgo.optim import benchmarks as bm
from icgo.optim.cgo import CGO
from icgo.studies.optimizers import study
from icgo.studies.optimizers.study import OptimizerStudyConfig
from icgo.studies.registry import STUDIES

#: The method labels of results/optimizers.md (unchanged by the move into the library).
LABELS = ["cgo (paper, original)", "icgo (paper, three_stage)", "cgo (mealpy, original)",
          "icgo (mealpy, three_stage)", "cgo (matlab)", "pso", "ga", "sma"]


@pytest.fixture(scope="module")
def example_runs():
    """The registered example run with PRNGKey(0) twice, with jax.random.key(0), and with PRNGKey(1)."""
    data, cfg = study.example()
    return (data, cfg, study.run(data, cfg, jax.random.PRNGKey(0)), study.run(data, cfg, jax.random.PRNGKey(0)),
            study.run(data, cfg, jax.random.key(0)), study.run(data, cfg, jax.random.PRNGKey(1)))


# --------------------------------------------------------------------- registry and config
def test_registered():
    s = STUDIES["optimizers"]
    assert s is study.STUDY and s.config_cls is OptimizerStudyConfig and s.run is study.run
    assert s.fits_models is False  # a benchmark fits no model: result.models == {}


def test_defaults_are_the_former_cli_defaults_and_the_cli_takes_them_from_the_config():
    d = OptimizerStudyConfig()
    assert (d.functions, d.dims, d.runs, d.pop_size, d.budget, d.seed, d.jobs, d.alpha, d.peer, d.methods) == \
        (None, (10, 30), 30, 20, 3220, 0, 1, 0.05, True, None)
    args = entry.parser().parse_args([])
    assert config_from_mapping(OptimizerStudyConfig, {k: getattr(args, k) for k in entry.FIELDS}) == d
    assert set(entry.FIELDS) == {f.name for f in dataclasses.fields(OptimizerStudyConfig)}


def test_config_round_trips_and_refuses_unknown_keys():
    cfg = OptimizerStudyConfig(functions=("sphere", "levy"), dims=(2, 10), methods=("pso",))
    m = config_to_mapping(cfg)
    assert m["dims"] == [2, 10] and config_from_mapping(OptimizerStudyConfig, m) == cfg
    with pytest.raises(ValueError, match=r"unknown setting\(s\) \['runz'\]"):
        config_from_mapping(OptimizerStudyConfig, {"runz": 3})


@pytest.mark.parametrize("field, value, problem", [
    ("runs", 0, "integer >= 1"), ("runs", 2.5, "integer >= 1"), ("dims", (7,), "no CEC 2017 data"),
    ("dims", (), "non-empty"), ("dims", (10, 10), "distinct"), ("functions", ("sphere", "nope"), r"unknown \['nope'\]"),
    ("functions", ("sphere", "sphere"), "repeat"), ("pop_size", 3, ">= 4"),
    ("budget", 99, "one iteration of every algorithm"), ("seed", -1, ">= 0"), ("jobs", 0, ">= 1"),
    ("alpha", 1.5, r"\(0, 1\)"), ("alpha", True, r"\(0, 1\)"), ("peer", "yes", "true or false"),
    ("methods", ("pso", "adam"), r"unknown \['adam'\]"), ("methods", (), "non-empty")])
def test_config_errors_are_one_line_and_name_the_field(field, value, problem):
    with pytest.raises(SettingError) as e:
        OptimizerStudyConfig(**{field: value})
    assert e.value.field == field and "\n" not in str(e.value)
    assert str(e.value).startswith(f"{field} ") and re.search(problem, str(e.value))


def test_budget_bound_comes_from_the_registry():
    """One iteration of every algorithm: CGO spends 4P per iteration, the others P (registry ``evals``)."""
    per = max(get(a).evals(20, get(a).config_cls())[1] for a in study.PEERS)
    assert per == 80
    OptimizerStudyConfig(budget=20 + per)
    with pytest.raises(SettingError, match="budget"):
        OptimizerStudyConfig(budget=20 + per - 1)


def test_functions_must_belong_to_the_suite():
    cfg = OptimizerStudyConfig(functions=("zakharov",))
    assert study.study_functions(("sphere", "zakharov"), cfg) == ("zakharov",)
    assert study.study_functions(None, OptimizerStudyConfig()) == bm.STUDY
    with pytest.raises(SettingError, match=r"functions unknown \['zakharov'\]; choose from"):
        study.study_functions(None, cfg)
    with pytest.raises(ValueError, match="suite|data"):
        study.study_functions(("sphere", "nope"), OptimizerStudyConfig())


# --------------------------------------------------------------------- labels from the registry
def test_labels_come_from_the_registry_and_match_the_published_tables():
    ms = study.methods()
    assert [m.label for m in ms] == LABELS
    assert {m.algorithm for m in ms} <= set(OPTIMIZERS) and set(study.PEERS) <= set(OPTIMIZERS)
    for job in study.jobs():
        alg = get(job.algorithm)
        if job.configs is not None:  # side by side along the registry's axis
            assert alg.axis is not None and len(job.configs) == len(job.labels)
            values = [getattr(c, alg.axis) for c in job.configs]
            assert list(job.configs) == alg.axis_configs(job.configs[0], values)
        elif job.algorithm != CGO.name:
            assert list(job.labels) == alg.labels() and job.config is None
    assert [m.peer_label for m in ms] == ["mealpy OriginalCGO"] * 5 + ["mealpy OriginalPSO", "mealpy BaseGA",
                                                                       "mealpy OriginalSMA"]


def test_no_cgo_literal_outside_the_cgo_module():
    for mod in (study, entry):
        src = inspect.getsource(mod)
        assert not re.search(r"""["']cgo["']""", src), mod.__name__


# --------------------------------------------------------------------- the example
def test_example_runs_without_mealpy(monkeypatch):
    monkeypatch.setitem(sys.modules, "mealpy", None)  # `import mealpy` now raises ImportError
    data, cfg = study.example()
    assert not cfg.peer
    res = study.run(data, cfg, jax.random.PRNGKey(3))
    assert res.models == {} and set(res.records) == {"runs", "cells", "summary"}
    runs = res.records["runs"]
    labels = [m.label for m in study.methods(cfg)]
    assert list(dict.fromkeys(runs.algorithm)) == labels == list(cfg.methods)
    assert len(runs) == len(cfg.dims) * len(labels) * len(data) * cfg.runs
    assert np.all(np.isfinite(runs.error)) and np.all(runs.error >= 0)
    for label, g in runs.groupby("algorithm"):  # every run spends P + k per-iteration evaluations <= budget
        alg = get(next(m.algorithm for m in study.methods(cfg) if m.label == label))
        per = alg.evals(cfg.pop_size, alg.config_cls())[1]
        assert set(g.evals) == {cfg.pop_size + (cfg.budget - cfg.pop_size) // per * per}, label
    cells = res.records["cells"]
    assert cells.mealpy_median.isna().all() and cells.p_value.isna().all() and set(cells.result_holm) == {""}
    with pytest.raises(ValueError, match="mealpy") as e:
        study.run(data, dataclasses.replace(cfg, peer=True), jax.random.PRNGKey(3))
    assert "\n" not in str(e.value)


def test_deterministic_by_key_and_prngkey_equals_the_typed_key(example_runs):
    _, _, a, b, typed, other = example_runs
    for name in a.records:
        pd.testing.assert_frame_equal(a.records[name], b.records[name], check_exact=True)
        pd.testing.assert_frame_equal(a.records[name], typed.records[name], check_exact=True)
    assert not np.array_equal(a.records["runs"].error, other.records["runs"].error)


def test_keys_follow_the_documented_rule(example_runs):
    """Job j at dimension D draws split(fold_in(key, 1000 D + j), F runs); function i run r takes key i runs + r."""
    data, cfg, a, *_ = example_runs
    names = study.study_functions(data, cfg)
    j = [job.name for job in study.jobs()].index(get("pso").name)
    dim, F, R = cfg.dims[0], len(names), cfg.runs
    keys = jax.random.split(jax.random.fold_in(jax.random.key(0), 1000 * dim + j), F * R)
    aux = jax.tree_util.tree_map(lambda x: np.repeat(np.asarray(x), R, axis=0), bm.suite(names, dim))
    r = run_batch(get("pso"), bm.suite_fitness, (-100.0 * np.ones(dim), 100.0 * np.ones(dim)), keys, cfg.pop_size,
                  max_evals=cfg.budget, aux=aux)
    runs = a.records["runs"]
    got = runs[runs.algorithm == "pso"].error.to_numpy()
    np.testing.assert_array_equal(got, np.asarray(r.best_f))


# --------------------------------------------------------------------- decisions
def _holm(p):
    """Holm's step-down adjustment written out (independent of icgo.maths.stats.holm)."""
    p = np.asarray(p, float)
    m, out, running = len(p), np.empty(len(p)), 0.0
    for rank, i in enumerate(np.argsort(p, kind="stable")):
        running = max(running, min(1.0, (m - rank) * p[i]))
        out[i] = running
    return out


def _check_cells_against_scipy(runs, cells, alpha):
    for row in cells.itertuples():
        sel = (runs.dim == row.dim) & (runs.function == row.function)
        a = runs[sel & (runs.algorithm == row.ours)].sort_values("run").error.to_numpy()
        m = next(x for x in study.methods() if x.label == row.ours)
        b = runs[sel & (runs.algorithm == m.peer_runs_label)].sort_values("run").error.to_numpy()
        assert row.mealpy == m.peer_label
        np.testing.assert_allclose([row.ours_median, row.mealpy_median], [np.median(a), np.median(b)], rtol=1e-12)
        if np.allclose(a, b):
            assert (row.result, row.p_value) == ("=", 1.0)
            continue
        p = ranksums(a, b).pvalue
        assert row.p_value == p
        want = "=" if p >= alpha else ("+" if np.median(a) < np.median(b) else "-")
        assert row.result == want, row
    for label, g in cells.groupby("ours"):
        np.testing.assert_allclose(g.p_holm, _holm(g.p_value), rtol=1e-15)
        want = np.where(g.p_holm < alpha, g.result, "=")
        assert list(g.result_holm) == list(want)


def test_cell_decisions_equal_scipy_rank_sum_on_the_run_table():
    """A synthetic run table with a clear `+`, a clear `-`, a tie and identical samples."""
    rng = np.random.default_rng(0)
    R, rows = 12, []
    shifts = {"sphere": -5.0, "ackley": 5.0, "levy": 0.0, "griewank": None}  # ours minus peer; None: identical
    for dim in (2, 10):
        for name, d in shifts.items():
            b = rng.normal(10.0, 1.0, R)
            a = b.copy() if d is None else rng.normal(10.0 + d, 1.0, R)
            rows += [dict(dim=dim, algorithm="pso", function=name, run=r, error=v, evals=60) for r, v in enumerate(a)]
            rows += [dict(dim=dim, algorithm="mealpy pso", function=name, run=r, error=v, evals=60)
                     for r, v in enumerate(b)]
    runs = pd.DataFrame(rows)
    ms = study.methods(OptimizerStudyConfig(methods=("pso",)))
    for alpha in (0.05, 0.001):
        cells = study.cell_table(runs, (2, 10), tuple(shifts), alpha, ms)
        assert len(cells) == 8
        _check_cells_against_scipy(runs, cells, alpha)
        by = cells.set_index(["dim", "function"]).result
        assert by[(2, "sphere")] == "+" and by[(2, "ackley")] == "-" and by[(2, "griewank")] == "="
    summary = study.summary_table(cells, (2, 10), ms)
    for row in summary.itertuples(index=False):
        n = cells[cells.dim == row.dim].result.value_counts()
        assert (row[3], row[4], row[5]) == (n.get("+", 0), n.get("=", 0), n.get("-", 0))


def test_decide_rule():
    a = np.arange(30.0)
    assert study.decide(a, a) == ("=", 1.0)
    assert study.decide(a, a + 100)[0] == "+" and study.decide(a + 100, a)[0] == "-"
    s, p = study.decide(a, a + 0.5)
    assert s == "=" and p > 0.05
    assert study.decide(a, a + 0.5, alpha=0.99)[0] == "+"


# --------------------------------------------------------------------- the mealpy peer
@pytest.mark.parametrize("name", sorted(bm.SPECS))
def test_numpy_fitness_matches_jax_benchmark(name):
    pytest.importorskip("opfunu")
    rng = np.random.default_rng(0)
    x = rng.uniform(-100, 100, (5, 10))
    f_np = np.array([study.numpy_fn(name, 10)(xi) for xi in x])
    np.testing.assert_allclose(f_np, np.asarray(bm.make(name, 10).fn(x)), rtol=1e-9)


@pytest.mark.parametrize("algo, budget", [(CGO.name, 20 + 2 * 80), ("pso", 20 + 3 * 20)])
def test_mealpy_side_spends_the_budget(algo, budget):
    pytest.importorskip("mealpy")
    _, _, _, vals, evals = study.mealpy_runs("sphere", 10, algo, 2, 20, budget)
    assert vals.shape == (2,) and np.all(vals > 0)
    np.testing.assert_array_equal(evals, [budget, budget])


def test_a_tiny_study_with_the_peer_decides_like_scipy():
    """PSO vs mealpy OriginalPSO, D = 2, 6 runs: the cell table recomputed from the run table with scipy."""
    pytest.importorskip("mealpy")
    cfg = OptimizerStudyConfig(dims=(2,), runs=6, pop_size=10, budget=210, methods=("pso",))
    res = study.run(("sphere", "rastrigin"), cfg, jax.random.PRNGKey(0))
    runs, cells = res.records["runs"], res.records["cells"]
    assert list(dict.fromkeys(runs.algorithm)) == ["pso", "mealpy pso"]
    assert set(runs.evals) == {210} and set(cells.ours_evals) == set(cells.mealpy_evals) == {210}
    _check_cells_against_scipy(runs, cells, cfg.alpha)
    again = study.run(("sphere", "rastrigin"), cfg, jax.random.PRNGKey(0)).records["runs"]
    pd.testing.assert_frame_equal(runs, again, check_exact=True)  # mealpy is seeded too


@pytest.mark.slow
@pytest.mark.parametrize("name", ["ackley", "sphere", "rastrigin"])
def test_mealpy_variant_matches_mealpy_original_cgo(name):
    """Side by side: our `mealpy` CGO variant and mealpy's OriginalCGO are the same algorithm, so at an equal
    budget (D = 10, 20 runs, 3220 evaluations) their final errors must not differ significantly (rank-sum)."""
    from icgo.optim.cgo import CGOConfig

    runs, dim = 20, 10
    mp = study.mealpy_runs(name, dim, CGO.name, runs, 20, 3220)[3]
    s = bm.suite((name,), dim)
    aux = jax.tree_util.tree_map(lambda a: np.repeat(np.asarray(a), runs, axis=0), s)
    r = run_batch(CGO, bm.suite_fitness, (-100 * np.ones(dim), 100 * np.ones(dim)),
                  jax.random.split(jax.random.key(0), runs), 20, max_evals=3220,
                  config=CGOConfig.mealpy(), aux=aux)
    ours = np.asarray(r.best_f)
    assert int(np.max(r.n_evals)) == 3220
    assert ranksums(ours, mp).pvalue > 0.01, (np.median(ours), np.median(mp))


# --------------------------------------------------------------------- the entry point
@pytest.mark.parametrize("argv, message", [
    (["--functions", "sphere", "nope"], "--functions: unknown ['nope']"),
    (["--runs", "0"], "--runs: must be an integer >= 1, got 0"),
    (["--pop-size", "3"], "--pop-size: must be an integer >= 4"),
    (["--methods", "adam"], "--methods: unknown ['adam']")])
def test_bad_options_are_one_line_cli_errors(argv, message, capsys, tmp_path):
    with pytest.raises(SystemExit) as e:
        entry.main(argv + ["--out", str(tmp_path / "x")])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert message in err
    assert not (tmp_path / "x").exists()


def test_entry_point_writes_the_three_files(tmp_path, monkeypatch):
    """--no-peer run of the example's size: optimizers.md, the cell table and the run table (without evals)."""
    monkeypatch.setitem(sys.modules, "mealpy", None)
    data, cfg = study.example()
    argv = ["--functions", *data, "--dims", "2", "--runs", str(cfg.runs), "--pop-size", str(cfg.pop_size),
            "--budget", str(cfg.budget), "--no-peer", "--methods", *cfg.methods, "--out", str(tmp_path)]
    entry.main(argv)
    runs = pd.read_csv(tmp_path / "optimizers_runs.csv")
    assert list(runs.columns) == ["dim", "algorithm", "function", "run", "error"]
    res = study.run(None, dataclasses.replace(cfg, functions=data), jax.random.PRNGKey(0))
    np.testing.assert_array_equal(runs.error, res.records["runs"].error)
    cells = pd.read_csv(tmp_path / "optimizers_table.csv")
    assert list(cells.columns) == list(res.records["cells"].columns) and len(cells) == len(res.records["cells"])
    md = (tmp_path / "optimizers.md").read_text()
    assert md.startswith("# Optimizer study") and "mealpy was not run" in md and "## D = 2" in md
    assert f"Run settings: population {cfg.pop_size}, {cfg.budget} fitness evaluations per run, {cfg.runs} runs per " \
           "cell, float64" in md
