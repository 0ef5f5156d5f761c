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


def test_two_workers_give_the_one_process_study_bitwise():
    """... and their progress reaches the parent, summed over the workers' repeats."""
    frame = sim_frame()
    one = study.run_study(frame, dataclasses.replace(TINY, workers=1))
    ticks = []
    two = study.run_study(frame, dataclasses.replace(TINY, workers=2), progress=lambda d, t: ticks.append((d, t)))
    total = TINY.iterations * TINY.n_repeats
    assert ticks and ticks[-1] == (total, total) and all(t == total for _, t in ticks)
    assert [d for d, _ in ticks] == sorted(d for d, _ in ticks)
    for name in ("best_fitness", "evals"):
        np.testing.assert_array_equal(one.curves[name], two.curves[name])
    pd.testing.assert_frame_equal(one.metrics, two.metrics)
    pd.testing.assert_frame_equal(one.predictions, two.predictions)
    np.testing.assert_array_equal(one.model.theta, two.model.theta)
    np.testing.assert_array_equal(one.model.beta, two.model.beta)


def test_plan_workers_auto_explicit_and_caps():
    big, small = parallel.AUTO_MIN_WORK, parallel.AUTO_MIN_WORK / 10
    assert parallel.plan_workers(None, 10, big, cores=2) == 2
    assert parallel.plan_workers(None, 10, small, cores=2) == 1   # not worth starting processes
    assert parallel.plan_workers(None, 10, big, cores=1) == 1     # a job pinned to one core stays one
    assert parallel.plan_workers(4, 3, small, cores=2) == 3       # never more than the repeats
    assert parallel.plan_workers(1, 10, big, cores=2) == 1


def test_search_workers_only_for_the_random_protocols_searches():
    from icgo.optim import STRATEGIES

    table3 = study.StudyConfig(strategies=STRATEGIES)  # 5 strategies x 10 repeats x 12 030 evaluations x ~400 rows
    assert study.search_work(table3, 407) == pytest.approx(5 * 10 * 30 * (1 + 4 * 100) * 407)
    assert table3.search_workers(581) == min(len(parallel.available_cores()), 10)
    assert dataclasses.replace(table3, optimizer=None).search_workers(581) == 1
    assert dataclasses.replace(table3, n_repeats=1).search_workers(581) == 1
    assert study.StudyConfig(protocol="leave_azimuth_out").search_workers(581) == 1
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
