"""Progress a log can hold: lines off a terminal (done/total, rate, ETA) on stderr and in the run's log, the
search's estimated time from its plan, the worlds too few for their test, and a worlds run's figure."""

from __future__ import annotations

import itertools
import logging
import re
import time

import numpy as np
import pytest

from icgo.studies.icgo_relm import progress as P
from icgo.studies.icgo_relm import progress as E


class _Clock:
    """A fake ``time.perf_counter``: each call returns the next value."""

    def __init__(self, values):
        self.values = iter(values)

    def __call__(self):
        return next(self.values)


def test_progress_modes(monkeypatch):
    monkeypatch.delenv(P.ENV_LINES, raising=False)
    monkeypatch.setattr("sys.stderr.isatty", lambda: False)
    assert P.progress_mode("auto") == ("lines", P.EVERY_S)
    assert P.progress_mode("auto", accelerator=True) is None
    assert P.progress_mode(False) is None and P.progress_mode(True) == ("lines", P.EVERY_S)
    assert P.progress_mode(5) == ("lines", 5.0)
    monkeypatch.setattr("sys.stderr.isatty", lambda: True)
    assert P.progress_mode("auto") == ("bar", P.EVERY_S)
    monkeypatch.setenv(P.ENV_LINES, "job 3")  # a sweep's job on a shared terminal
    assert P.progress_mode("auto") == ("lines", P.EVERY_S)
    for bad in ("sometimes", 0, -1.0):
        with pytest.raises(ValueError, match="progress must be"):
            P.progress_mode(bad)


def test_lines_every_n_seconds_with_rate_and_eta_on_stderr_and_in_the_log(monkeypatch, capsys, tmp_path):
    """Chunks end at t = 10 (compiled), 11, 12, ..., 19 s; lines every 3 s: the first chunk, then a line once 3 s
    have passed, and the last; rate (9 - 1) it / (19 - 11) s = 1 it/s after the first chunk; ETA (10 - done) s."""
    monkeypatch.delenv(P.ENV_LINES, raising=False)
    log_file = tmp_path / "run.log"
    handler = logging.FileHandler(log_file)
    logging.getLogger().addHandler(handler)
    rates = []
    try:
        # perf_counter calls: the start, then one per chunk
        monkeypatch.setattr(P.time, "perf_counter", _Clock([0.0] + [10.0 + k for k in range(10)]))
        lines = P.ProgressLines("study", every_s=3, evals_per_iteration=104.0, on_rate=rates.append)
        for k in range(10):
            lines(k + 1, 10)
        lines.close()
    finally:
        logging.getLogger().removeHandler(handler)
        handler.close()
    err = capsys.readouterr().err.strip().splitlines()
    assert err[0] == "study: compiling or loading the search program; progress every 3 s"
    assert err[1] == "study: 1/10 it (10 %), program ready after 0:00:10, elapsed 0:00:10"
    assert err[2] == "study: 4/10 it (40 %), 1 it/s, 104 evals/s, elapsed 0:00:13, ETA 0:00:06"
    assert err[3] == "study: 7/10 it (70 %), 1 it/s, 104 evals/s, elapsed 0:00:16, ETA 0:00:03"
    assert err[4] == "study: 10/10 it (100 %), 1 it/s, 104 evals/s, elapsed 0:00:19, ETA 0:00:00"
    assert len(err) == 5
    logged = log_file.read_text()
    for line in err:
        assert line in logged
    assert rates == [pytest.approx(104.0)]  # 1 it/s x 104 evaluations per iteration


def test_a_sweep_jobs_lines_name_the_job(monkeypatch, capsys):
    monkeypatch.setenv(P.ENV_LINES, "job 2")
    P.ProgressLines("study", every_s=60).close()
    assert capsys.readouterr().err.startswith("job 2: study: compiling")


def test_clock_and_count():
    from icgo.studies.common.run_log import clock, count

    assert clock(0) == "0:00:00" and clock(3725.4) == "1:02:05"
    assert count(950) == "950" and count(16_900) == "16.9k" and count(3_200_000) == "3.2M"


def test_the_plan_counts_the_evaluations_the_search_spends():
    """planned_evaluations against the optimizers' own count over a real (tiny) search: CGO's 4 per seed per
    iteration, PSO's one per particle."""
    from icgo.studies.icgo_relm.study import run_study
    from icgo.studies.icgo_relm.config import StudyConfig
    from icgo.datasets import casing_stations

    frame = casing_stations.lab_casing(0, toolface_step_deg=45.0).frame
    for opt, strategies in (("cgo", ("chaos", "wavelet")), ("pso", ("original",))):
        cfg = StudyConfig(split=dict(n_repeats=2), model=dict(hidden=8), budget=dict(pop_size=6, iterations=3),
                          optimizer=opt, strategies=strategies)
        res = run_study(frame, cfg)
        total, per_it = E.planned_evaluations(cfg, len(cfg.method_names()) * 2)
        n_evals = np.asarray(res.n_evals).sum()
        assert total == n_evals, (opt, total, n_evals)
        assert per_it == len(cfg.method_names()) * 2 * (4 * 6 if opt == "cgo" else 6)


def test_an_estimate_is_the_evaluations_over_the_rate_measured_before(tmp_path):
    from icgo.core.execution import ExecutionPlan
    from icgo.studies.icgo_relm.config import StudyConfig

    cfg = StudyConfig(split=dict(n_repeats=10), budget=dict(pop_size=30, iterations=100), optimizer="cgo",
                      strategies=("chaos",))
    plan = ExecutionPlan("cpu", "cache_chunked", 2, 1, 10, "why")
    cache = tmp_path / "icgo" / "jax"
    first = E.estimate(cfg, plan, 10, 1000, str(cache))
    assert first.evaluations == 10 * (30 + 4 * 30 * 100) and first.seconds is None
    assert "no rate measured here yet" in E.sentence(first)
    first.record(12_000.0)  # measured on 700 training rows
    assert (tmp_path / "icgo" / E.RATES_FILE).is_file()
    same = E.estimate(cfg, plan, 10, 1000, str(cache))
    assert same.rate == pytest.approx(12_000.0) and same.seconds == pytest.approx(first.evaluations / 12_000.0)
    twice = E.estimate(cfg, plan, 10, 2000, str(cache))  # twice the rows: half the rate
    assert twice.rate == pytest.approx(6_000.0)
    assert re.search(r"about 0:00:10 of search", E.sentence(same))  # 120,300 / 12k = 10.0 s
    other = E.estimate(cfg, plan._replace(devices=1), 10, 1000, str(cache))
    assert other.rate is None  # another kind of search has no rate yet
    assert E.estimate(cfg, plan, 10, 1000, None).store is None


def test_smallest_p_against_the_exact_wilcoxon():
    """All differences of one sign: scipy's exact two-sided p is 2 / 2**n; Holm multiplies the smallest by m."""
    from scipy import stats

    from icgo.studies.icgo_relm.worlds.stats import smallest_p, worlds_needed

    for n in range(2, 12):
        d = np.arange(1, n + 1, dtype=float)
        assert stats.wilcoxon(d, method="exact").pvalue == pytest.approx(smallest_p(n))
    assert smallest_p(3, 4) == 1.0 and smallest_p(8, 4) == pytest.approx(4 * 2 / 256)
    assert worlds_needed(1) == 6 and worlds_needed(4) == 8  # 2/32 = 0.0625 >= 0.05; 4 * 2/128 = 0.0625; 4 * 2/256
    for m, n in itertools.product(range(1, 6), range(2, 12)):
        assert (smallest_p(n, m) < 0.05) == (n >= worlds_needed(m))


def test_the_power_note_names_the_worlds_needed():
    from icgo.studies.icgo_relm.worlds.stats import power_note

    note = power_note(3, 5)
    assert "3 worlds are too few" in note and "Holm over 4 test(s), is 1" in note and "8 worlds" in note
    assert power_note(8, 5) is None and power_note(1, 5) is None and power_note(30, 2) is None
    assert power_note(5, 2) is not None and power_note(6, 2) is None


def test_the_worlds_figure_is_written_in_the_pooled_order(tmp_path, monkeypatch):
    import pandas as pd

    from icgo.studies.icgo_relm.worlds import figure as worlds_figure
    from icgo.studies.icgo_relm.names import method_name
    from icgo.studies.icgo_relm.worlds.stats import order

    per = pd.DataFrame({"world": [0, 0, 1, 1, 2, 2], "method": ["a", "b"] * 3, "n": 2,
                        "mae": [0.3, 0.1, 0.4, 0.2, 0.2, 0.25], "rmse": 0.0, "r2_error": 0.0})
    assert order(per, ["a", "b"]) == ["b", "a"]  # pooled means 0.183 < 0.3
    drawn = {}
    real = worlds_figure.save_figure

    def spy(fig, path, title):
        ax = fig.axes[0]
        drawn["ticks"] = [t.get_text() for t in ax.get_xticklabels()]
        drawn["lines"] = len(ax.lines)
        real(fig, path, title)

    monkeypatch.setattr(worlds_figure, "save_figure", spy)
    worlds_figure.plot_worlds(per, ["a", "b"], tmp_path / "worlds.png", "t")
    assert (tmp_path / "worlds.png").stat().st_size > 1000
    assert drawn["ticks"] == [method_name("b"), method_name("a")]  # the pooled order, left to right
    assert drawn["lines"] >= 3  # one line per world (and the pooled mean)


def test_a_line_between_chunks_when_a_chunk_outlasts_the_interval(monkeypatch, capsys):
    """Lines every 0.2 s, chunks that take longer: the clock thread writes the compiling line, then the count
    extrapolated at the measured rate (marked ~, never past the total); nothing after close()."""
    monkeypatch.delenv(P.ENV_LINES, raising=False)
    lines = P.ProgressLines("study", every_s=0.2)
    time.sleep(0.5)
    assert "study: compiling or loading the search program, elapsed 0:00:00" in capsys.readouterr().err
    lines(10, 100)
    time.sleep(0.01)
    lines(20, 100)  # 10 it in ~0.01 s: the extrapolated count reaches the total long before the next line
    time.sleep(0.5)
    between = [s for s in capsys.readouterr().err.splitlines() if "~" in s]
    assert between and between[-1].startswith("study: ~100/100 it (~100 %), ") and "ETA ~0:00:00" in between[-1]
    lines.close()
    time.sleep(0.5)
    assert capsys.readouterr().err == ""
