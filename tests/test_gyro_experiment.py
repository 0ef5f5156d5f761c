"""End-to-end checks of experiments.gyro (tiny settings) and its config errors."""

import numpy as np
import pandas as pd
import pytest
from hydra import compose, initialize_config_dir

from experiments import gyro

CONF = str(gyro.ROOT / "conf")


def _cfg(tmp_path, *overrides):
    with initialize_config_dir(config_dir=CONF, version_base="1.3"):
        return compose("gyro", [f"out_dir={tmp_path}", "jax_cache=null", *overrides])


def test_config_errors_are_one_line(tmp_path):
    for ov, msg in [(["n_seeds=0"], "n_seeds"),
                    (["net.target=true_azimuth"], "target"),
                    (["+variants.bad={optimiser: sgd}"], "unknown key"),
                    (["sweep.variant=nope"], "sweep.variant"),
                    (["table.toolface=median"], "table.toolface"),
                    (["relm.fitness=test"], "relm.fitness")]:
        with pytest.raises(gyro.ConfigError, match=msg) as e:
            gyro.check_config(_cfg(tmp_path, *ov))
        assert "\n" not in str(e.value)


def test_table_is_exact_at_the_nodes_for_toolface_free_errors(tmp_path):
    # Same turntable points as train and test: the table reproduces the toolface-mean error
    cfg = _cfg(tmp_path)
    train, _ = gyro.load_sets(cfg, 30.0, 90.0)
    err = gyro.azimuth_errors(train["azimuth_raw_deg"], train["azimuth_deg"])
    # Query at the nominal node angles: compensated = raw + mean-over-toolface error of the node
    f = train.assign(inclination_raw_deg=train["inclination_deg"], azimuth_raw_deg=train["azimuth_deg"])
    pred = gyro.table_predict(cfg, train, {"t": f})["t"]
    node_mean = pd.Series(err).groupby([train["inclination_deg"], train["azimuth_deg"]]).transform("mean")
    np.testing.assert_allclose(gyro.azimuth_errors(train["azimuth_deg"], pred), node_mean, atol=1e-9)


def test_run_end_to_end_tiny(tmp_path):
    cfg = _cfg(tmp_path, "n_seeds=2", "net.epochs=40", "net.patience=40", "data.n_random=200",
               "~variants", "+variants={net_error: {}, net_azimuth: {target: azimuth}}",
               "relm.enabled=false", "sweep.enabled=false")
    summary = gyro.run(cfg)
    for name in ("gyro_methods.csv", "gyro_methods.md", "gyro_seam.csv", "gyro_seam.png",
                 "gyro_toolface.png", "gyro_run.json"):
        assert (tmp_path / name).is_file(), name
    m = pd.read_csv(tmp_path / "gyro_methods.csv")
    assert set(m["method"]) == {"raw", "table", "net_error", "net_azimuth"}
    assert (m.loc[m.method == "net_error", "n_seeds"] == 2).all()
    # raw RMSE recomputed independently from the data set (numpy, no icgo angle helpers)
    _, tests = gyro.load_sets(cfg)
    for k, f in tests.items():
        d = np.mod(f["azimuth_raw_deg"] - f["azimuth_deg"] + 180.0, 360.0) - 180.0
        got = m.loc[(m.method == "raw") & (m.test == k), "rmse_mean"].item()
        np.testing.assert_allclose(got, np.sqrt(np.mean(d ** 2)), rtol=1e-12)
    assert summary["n_train"] == 1440 and len(summary["best_epoch"]["net_error"]) == 2
