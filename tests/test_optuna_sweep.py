"""Optuna sweeps of the ICGO-RELM door (hydra/sweeper=optuna, Hydra's own hydra-optuna-sweeper): the door returns
its objective (the search's fitness at its end, never the test split), so Optuna minimises it over a space."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from icgo.studies.common.tracking_tables import objective

ROOT = Path(__file__).resolve().parents[1]


def test_the_objective_is_the_mean_final_search_fitness(tmp_path):
    """Mean over (world, method, repeat, fold) of the best fitness at the last iteration, whatever the row order."""
    rows = []
    finals = []
    for w in (100, 101):
        for m in ("cgo-chaos", "pso"):
            for r in range(3):
                curve = np.sort(np.random.default_rng(w + r).uniform(0.1, 1.0, 5))[::-1]
                finals.append(curve[-1])
                rows += [{"world": w, "method": m, "repeat": r, "fold": 0, "iteration": i + 1, "best_fitness": f}
                         for i, f in enumerate(curve)]
    df = pd.DataFrame(rows).sample(frac=1.0, random_state=0)  # shuffled: the last iteration, not the last row
    df.to_csv(tmp_path / "convergence.csv", index=False)
    assert objective(tmp_path) == pytest.approx(np.mean(finals))
    assert objective(tmp_path / "absent") is None


@pytest.mark.slow
@pytest.mark.skipif(importlib.util.find_spec("hydra_plugins.hydra_optuna_sweeper") is None,
                    reason="hydra-optuna-sweeper is not installed (pip install 'icgo[optuna]')")
def test_an_optuna_sweep_over_hidden_units_and_ridge(tmp_path):
    """Two trials of a tiny space (debug=smoke, validation fitness): Optuna's best value is the smallest objective of
    the jobs (recomputed from each job's convergence.csv), its best parameters that job's config."""
    sweep = tmp_path / "sweep"
    cmd = [sys.executable, "-m", "experiments.run", "-m", "debug=smoke", "fitness=validation",
           "hydra/sweeper=optuna", "hydra.sweeper.n_trials=2", "hydra.sweeper.n_jobs=1",
           "hydra.sweeper.sampler.seed=0", "model.hidden=int(interval(8,40))",
           "model.lam=tag(log,interval(1e-5,1e-1))", f"hydra.sweep.dir={sweep}",
           f"jax_cache_dir={ROOT / '.jax_cache' / 'xdg' / 'icgo' / 'jax'}"]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    result = yaml.safe_load((sweep / "optimization_results.yaml").read_text())
    jobs = sorted(p for p in sweep.iterdir() if p.is_dir() and (p / "run.json").is_file())
    assert len(jobs) == 2
    values = {j: objective(j) for j in jobs}
    best = min(values, key=values.get)
    assert result["best_value"] == pytest.approx(values[best], rel=1e-9)
    cfg = yaml.safe_load((best / "config.yaml").read_text())
    assert result["best_params"]["model.hidden"] == cfg["model"]["hidden"]
    assert result["best_params"]["model.lam"] == pytest.approx(cfg["model"]["lam"])
    assert 8 <= cfg["model"]["hidden"] <= 40 and cfg["fitness"]["mode"] == "validation"


@pytest.mark.slow
@pytest.mark.skipif(importlib.util.find_spec("hydra_plugins.hydra_optuna_sweeper") is None,
                    reason="hydra-optuna-sweeper is not installed (pip install 'icgo[optuna]')")
def test_an_optuna_sweep_on_the_gyro_door(tmp_path):
    """Two trials over the networks' learning rate on a tiny plan: the gyro door returns its objective (the networks'
    best validation loss, icgo.studies.gyro.study.objective), and Optuna's best value is the smaller of the two
    recomputed from each job's saved networks."""
    from icgo.artifacts.network import GyroNetwork
    from icgo.artifacts.registry import load_model

    sweep = tmp_path / "sweep"
    cmd = [sys.executable, "-m", "experiments.gyro", "-m", "hydra/sweeper=optuna", "hydra.sweeper.n_trials=2",
           "hydra.sweeper.n_jobs=1", "hydra.sweeper.sampler.seed=0", "net.learning_rate=tag(log,interval(1e-3,1e-1))",
           "n_seeds=2", "data.inclinations_deg=[10,40]", "data.azimuth_step_deg=90", "data.toolface_step_deg=90",
           "data.n_random=50", "net.epochs=10", "net.patience=10", "net.batch_size=8", "relm.enabled=false",
           "sweep.enabled=false", f"out_dir={tmp_path / 'tables'}", f"hydra.sweep.dir={sweep}"]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    result = yaml.safe_load((sweep / "optimization_results.yaml").read_text())
    values = []
    for job in sorted(p for p in sweep.iterdir() if (p / "models").is_dir()):
        nets = [load_model(f) for f in sorted((job / "models").iterdir())]
        losses = [n.best_val_loss for n in nets if isinstance(n, GyroNetwork)]
        values.append(float(np.mean(np.concatenate(losses))))
    assert len(values) == 2
    assert result["best_value"] == pytest.approx(min(values), rel=1e-9)
