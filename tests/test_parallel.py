"""icgo.studies.workers: a study's search split over worker processes is bitwise the one-process search."""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest

import icgo  # noqa: F401  (float64)
from icgo.studies import icgo_relm as study
from icgo.studies import workers as parallel
from tests.test_study import sim_frame

TINY = study.StudyConfig(optimizer="cgo", strategies=("original", "wavelet"), n_repeats=3, hidden=10, pop_size=6,
                         iterations=3, seed=2)


def _same(a, b):
    """Two studies' searches and scores are bitwise equal."""
    for name in ("best_fitness", "evals"):
        np.testing.assert_array_equal(a.curves[name], b.curves[name])
    np.testing.assert_array_equal(a.model.theta, b.model.theta)
    np.testing.assert_array_equal(a.model.beta, b.model.beta)
    pd.testing.assert_frame_equal(a.metrics, b.metrics)
    pd.testing.assert_frame_equal(a.predictions, b.predictions)


def test_workers_give_the_one_process_study_bitwise():
    """Split by strategies (2 strategies x 3 repeats on 2 workers: blocks of 1 x 3) and by repeats (on 3 workers:
    blocks of 2 x 1): bitwise the one-process study; the workers' timings are recorded."""
    frame = sim_frame()
    assert study.search_grid(2, 3, 2) == (2, 1) and study.search_grid(2, 3, 3) == (1, 3)
    one = study.run_study(frame, dataclasses.replace(TINY, workers=1))
    timings, ticks = {}, []
    _same(one, study.run_study(frame, dataclasses.replace(TINY, workers=2), timings=timings,
                               progress=lambda d, t: ticks.append((d, t))))
    assert len(timings["workers"]) == 2 and timings["execution"]["workers"] == 2
    # the workers' progress reaches the parent, summed over their blocks (weighted by strategies x repeats)
    members = len(TINY.strategies) * TINY.n_repeats
    total = ticks[-1][1]
    assert ticks[-1] == (total, total) and all(t == total for _, t in ticks) and total % members == 0
    assert total // members in (TINY.iterations, TINY.iterations + 1)
    assert [d for d, _ in ticks] == sorted(d for d, _ in ticks)
    assert all(w["run_s"] > 0 and w["import_s"] > 0 for w in timings["workers"])
    _same(one, study.run_study(frame, dataclasses.replace(TINY, workers=3)))


@pytest.mark.parametrize("n_methods, n_repeats, n_workers, grid", [
    (5, 10, 1, (1, 1)), (5, 10, 2, (1, 2)), (5, 10, 4, (1, 4)), (5, 10, 10, (1, 10)), (5, 10, 16, (3, 5)),
    (5, 10, 64, (5, 10)), (1, 10, 16, (1, 10)), (5, 1, 16, (5, 1)), (2, 3, 2, (2, 1)), (2, 3, 3, (1, 3))])
def test_search_grid_keeps_the_largest_block_smallest(n_methods, n_repeats, n_workers, grid):
    a, b = study.search_grid(n_methods, n_repeats, n_workers)
    assert (a, b) == grid and a * b <= n_workers
    largest = -(-n_methods // a) * -(-n_repeats // b)
    # no other cut into at most n_workers blocks has a smaller largest block
    assert all(-(-n_methods // x) * -(-n_repeats // y) >= largest
               for x in range(1, n_methods + 1) for y in range(1, n_repeats + 1) if x * y <= n_workers)


def test_execution_only_splits_the_random_protocols_searches_on_a_cpu():
    from icgo.optim import STRATEGIES

    table3 = study.StudyConfig(strategies=STRATEGIES)  # 5 strategies x 10 repeats x 12 030 evaluations x ~400 rows
    assert study.search_work(table3, 407) == pytest.approx(5 * 10 * 30 * (1 + 4 * 100) * 407)
    assert table3.execution(581).workers == min(len(parallel.available_cores()), 10)
    assert table3.execution(581, "cpu", cores=16).workers == 15  # the 5 x 10 grid in 3 x 5 blocks
    assert table3.execution(581, "gpu", cores=16).workers == 1
    assert dataclasses.replace(table3, optimizer=None).execution(581, "cpu", 16).workers == 1
    assert dataclasses.replace(table3, n_repeats=1).execution(581, "cpu", 16).workers == 1
    assert study.StudyConfig(protocol="leave_azimuth_out").execution(581, "cpu", 16).workers == 1
    with pytest.raises(ValueError, match="workers"):
        study.StudyConfig(protocol="leave_azimuth_out", workers=2)
    with pytest.raises(ValueError, match="workers"):
        study.StudyConfig(workers=0)


def test_a_progress_wrapper_keeps_auto_in_one_process_and_refuses_explicit_workers():
    frame = sim_frame()
    calls = []

    def wrap(f):
        calls.append(1)
        return f

    with pytest.raises(ValueError, match="wrapper"):
        study.run_study(frame, dataclasses.replace(TINY, workers=2), wrap_fitness=wrap)
    res = study.run_study(frame, dataclasses.replace(TINY, n_repeats=1), wrap_fitness=wrap)
    assert calls and np.isfinite(res.curves["best_fitness"]).all()
