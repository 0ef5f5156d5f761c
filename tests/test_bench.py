"""Building blocks of the benchmark (icgo/bench/) at tiny sizes (no timing is tested)."""

import numpy as np
import pytest
from conftest import relm_train_data as _data

from icgo.bench import kernels, process, rows
from icgo.bench.front_door import breakdown
from icgo.models import relm
from icgo.optim.registry import get


def test_flop_count_matches_hand_count():
    # n=10, L=2, d=6: 2ndL 240 + nL 20 + sigmoid 3nL 60 + Gram 2nL^2 80 + H^T T 40
    # + Cholesky L^3/3 -> 2 + solves 2L^2 8 + H beta 40 + residual 3n 30 + ridge L 2
    assert kernels.flops_per_eval(10, hidden=2, d=6) == 522
    # the Gram term dominates at the paper's scale
    assert 2 * 407 * 30**2 / kernels.flops_per_eval(407) > 0.7


def test_numpy_fitness_equals_jax_fitness():
    X, T, mask, pop, fit = _data()
    ref = np.asarray(relm.fitness(pop, fit, 1e-3, 5))
    idx = mask > 0
    got = np.array([kernels.numpy_fitness(np.asarray(th), X[idx], T[idx], 1e-3, 5) for th in pop])
    np.testing.assert_allclose(got, ref, rtol=1e-10, atol=0)


def test_large_recording_and_measure(tmp_path):
    """--rows building blocks: a tiled contract CSV that reads back, and a child's time and peak memory."""
    import os
    import sys

    from icgo.io import recording as io

    rec = rows.write_large_recording(tmp_path / "big.csv", 1500)
    back = io.read_recording(tmp_path / "big.csv")
    assert len(back.frame) == 1500 and back.frame["station"].is_unique and back.field is not None
    np.testing.assert_array_equal(back.frame["azimuth_deg"], rec.frame["azimuth_deg"])
    rows.write_large_recording(tmp_path / "md.csv", 20, md_step_m=0.5)
    with_md = io.read_recording(tmp_path / "md.csv")
    np.testing.assert_array_equal(with_md.frame["md"], 0.5 * np.arange(20))
    m = process.measure([sys.executable, "-c", "print('ok')"])
    assert m["rc"] == 0 and "ok" in m["tail"] and 0 < m["peak_rss_gb"] < 1 and m["wall_s"] > 0
    core = max(os.sched_getaffinity(0))  # --cores: the command runs on the cores it is given
    m = process.measure([sys.executable, "-c", "import os; print(sorted(os.sched_getaffinity(0)))"], cpus=[core])
    assert m["rc"] == 0 and m["tail"].strip() == f"[{core}]"


def test_evosax_peers_spend_the_same_evaluations_and_icgo_pso_is_run_batch():
    """peers.peer_comparison at tiny sizes: equal budgets, finite results, icgo's row equals run_batch."""
    import jax
    import jax.numpy as jnp

    from icgo.bench.peers import peer_comparison
    from icgo.optim import run_batch

    sd = kernels.study_data(2)
    res = peer_comparison(sd.compact, kernels.LAM, kernels.HIDDEN, pop_size=8, iterations=3, reps=1)
    assert [r["name"] for r in res] == ["icgo PSO", "evosax PSO", "evosax DE"]
    assert all(r["evals"] == 8 * 4 and np.isfinite(r["best_f_mean"]) and r["best_f_mean"] > 0 for r in res)
    D = relm.n_params(kernels.HIDDEN)
    ref = run_batch(get("pso"), relm.make_train_fitness(kernels.LAM, kernels.HIDDEN), (-jnp.ones(D), jnp.ones(D)),
                    jax.random.split(jax.random.PRNGKey(0), 2), 8, 3, aux=sd.compact).best_f
    assert res[0]["best_f_mean"] == float(np.mean(np.asarray(ref)))


def test_mealpy_in_its_parallel_mode_runs_the_same_search():
    sd = kernels.study_data(1)
    single = kernels.run_mealpy(sd, 1, pop_size=8, iterations=2)
    parallel = kernels.run_mealpy(sd, 1, pop_size=8, iterations=2, mode="process", n_workers=2)
    assert single["evals_per_run"] == parallel["evals_per_run"] > 8
    assert np.isfinite(parallel["best_f"]).all()


def test_breakdown_splits_a_front_door_run_from_its_record(tmp_path):
    import json

    t = {"import_s": 1.0, "load_data_s": 2.0, "prepare_s": 3.0, "search_s": 4.0, "score_s": 0.5, "tables_s": 0.25,
         "write_s": 0.75, "prepare_compile_s": 1.0, "search_compile_s": 0.0, "score_compile_s": 0.1,
         "tables_compile_s": 0.2}
    (tmp_path / "run.json").write_text(json.dumps({"timings": t, "total_time_s": 11.0, "execution": {"devices": 2}}))
    b = breakdown(tmp_path, wall_s=13.0)
    assert b["start"] == 13.0 - 11.0 - 0.75 and b["msa"] == 3.0 and b["scoring"] == 0.75 and b["write"] == 0.75
    assert b["compile"] == 1.0 + 0.0 + 0.1 + 0.2 and b["execution"]["devices"] == 2


def test_backend_check_skips_a_study_point_that_would_overrun_the_budget():
    from icgo.bench.backend import overrun

    assert overrun(None, 1000, 0.0) is None                                          # the first point always runs
    last = {"repeats": 10, "compile_s": 20.0, "run_s": 3.0}
    assert overrun(last, 100, 50.0) is None                                          # 20 + 30 s projected, 50 left
    assert overrun(last, 1000, 100.0) == "projected 320 s from 10 repeats does not fit in the 100 s left"
    assert overrun(last, 1000, -5.0) == "projected 320 s from 10 repeats does not fit in the 0 s left"


@pytest.mark.slow
def test_gpu_check_runs_on_a_cpu_and_says_the_gpu_is_absent(capsys):
    from icgo.bench.backend import backend_check, report

    res = backend_check(budget_s=300, mealpy_runs=1, front=False, batches=(12, 24, 48), repeats=(1, 2, 10**6),
                        curve=(1, 2), curve_size=(2, 2), worlds=(1, 10**6), strategies=("original",),
                        model={"hidden": 6}, budget={"pop_size": 5, "iterations": 2})
    assert not res["gpu_present"] and res["headline"].startswith("GPU absent") and "unmeasured" in res["headline"]
    assert res["plan"]["kernel"] == "cache_chunked"
    assert set(res["kernel_evals_per_s"]) == {"train_fitness", "fused_train_fitness"}
    assert list(res["kernel_evals_per_s"]["train_fitness"]) == ["12", "24", "48"]
    assert [p["devices"] for p in res["devices_curve"]["cpu"]] == [1, 2] and res["devices_curve"]["accelerator"] is None
    assert res["worlds"][0]["worlds"] == 1 and "projected" in res["worlds"][1]["skipped"]
    assert res["max_rel_diff_vs_float64"] < 5e-6 and 0 < res["flop_fraction"] < 1
    assert [p["repeats"] for p in res["study"]] == [1, 2, 10**6] and all("wall_s" in p for p in res["study"][:2])
    assert "projected" in res["study"][2]["skipped"]
    md = report(res)
    assert md.startswith("GPU absent") and "study, 2 repeats" in md


def test_rows_commands_are_checked():
    """--rows-commands names only commands rows_scaling runs; apply among them."""
    from icgo.bench import cli

    p = cli.parser("bench", "")
    errors = []
    assert cli.plan(p.parse_args(["--rows", "10", "--rows-commands", "apply"]), errors.append).sizes == [10]
    assert not errors
    with pytest.raises(SystemExit):
        cli.plan(p.parse_args(["--rows", "10", "--rows-commands", "apply,nonsense"]), p.error)
