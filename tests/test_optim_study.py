"""Building blocks of experiments/optimizers.py: the independent numpy fitness given to mealpy,
the equal-budget evaluation count on the mealpy side, and the +/=/- rule."""

import numpy as np
import pytest

import icgo  # noqa: F401  (float64)
from experiments.optimizers import _numpy_fn, _sign, mealpy_runs
from icgo import benchmarks as bm


@pytest.mark.parametrize("name", bm.STUDY)
def test_numpy_fitness_matches_jax_benchmark(name):
    rng = np.random.default_rng(0)
    x = rng.uniform(-100, 100, (5, 10))
    f_np = np.array([_numpy_fn(name, 10)(xi) for xi in x])
    np.testing.assert_allclose(f_np, np.asarray(bm.make(name, 10).fn(x)), rtol=1e-9)


@pytest.mark.parametrize("algo, budget", [("cgo", 20 + 2 * 80), ("pso", 20 + 3 * 20)])
def test_mealpy_side_spends_the_budget(algo, budget):
    _, _, _, vals, evals = mealpy_runs("sphere", 10, algo, 2, 20, budget)
    assert vals.shape == (2,) and np.all(vals > 0)
    np.testing.assert_array_equal(evals, [budget, budget])


def test_sign_rule():
    a = np.arange(30.0)
    assert _sign(a, a) == ("=", 1.0)
    assert _sign(a, a + 100)[0] == "+" and _sign(a + 100, a)[0] == "-"
    s, p = _sign(a, a + 0.5)
    assert s == "=" and p > 0.05


@pytest.mark.slow
@pytest.mark.parametrize("name", ["ackley", "sphere", "rastrigin"])
def test_mealpy_variant_matches_mealpy_original_cgo(name):
    """Side by side: our `mealpy` CGO variant and mealpy's OriginalCGO are the same algorithm, so at an equal
    budget (D = 10, 20 runs, 3220 evaluations) their final errors must not differ significantly (rank-sum)."""
    import jax
    from scipy.stats import ranksums

    from icgo.optim import run_batch
    from icgo.optim.cgo import CGOConfig

    runs, dim = 20, 10
    mp = mealpy_runs(name, dim, "cgo", runs, 20, 3220)[3]
    s = bm.suite((name,), dim)
    aux = jax.tree_util.tree_map(lambda a: np.repeat(np.asarray(a), runs, axis=0), s)
    r = run_batch("cgo", bm.suite_fitness, (-100 * np.ones(dim), 100 * np.ones(dim)),
                  jax.random.split(jax.random.key(0), runs), 20, max_evals=3220,
                  config=CGOConfig.mealpy(), aux=aux)
    ours = np.asarray(r.best_f)
    assert int(np.max(r.n_evals)) == 3220
    assert ranksums(ours, mp).pvalue > 0.01, (np.median(ours), np.median(mp))


def test_unknown_function_is_a_one_line_cli_error(capsys, tmp_path):
    from experiments.optimizers import main

    with pytest.raises(SystemExit) as e:
        main(["--functions", "sphere", "nope", "--out", str(tmp_path / "x")])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "--functions: unknown ['nope']" in err
    assert not (tmp_path / "x").exists()
