"""Small models of every kind, built from their parts (no fit), for the hostile-file tests.

Each is a valid model whose arrays have the real shapes of its kind; ``apply`` works on the
matching survey of :func:`survey`. Used by tests/test_hostile.py and tests/test_fuzz_io.py.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from icgo.discrepancy.inversion import PhysicsParams
from icgo.models import gyro_relm, lookup_table, nets
from icgo.models import msa as _msa
from icgo.models import relm as _relm
from icgo.models.calibration_params import CalibrationParams
from icgo.models.compensation import RELMParams
from icgo.artifacts.calibration import MagCalibration
from icgo.artifacts.discrepancy import PhysicsModel
from icgo.artifacts.format import sensor_domain
from icgo.artifacts.network import GyroNetwork, GyroRELM, LookupTableModel
from icgo.artifacts.relm import MSAModel, RELMCompensation


def survey(n: int = 24, seed: int = 0) -> pd.DataFrame:
    """A contract survey: G near 1 g, B near 50,000 nT with dip ~60 deg, the reference attitude, and the gyro
    tool's own attitude columns."""
    from icgo.physics.frames import azimuth_from_gv, inclination_from_g, toolface_from_g

    rng = np.random.default_rng(seed)
    inc = rng.uniform(10, 80, n)
    az = rng.uniform(0, 360, n)
    tf = rng.uniform(-180, 180, n)
    from icgo.physics.frames import sensors_from_attitude

    sens = sensors_from_attitude(az, inc, tf, 50_000.0, 60.0)
    G, B = np.asarray(sens[0]), np.asarray(sens[1])
    return pd.DataFrame({"station": np.arange(n), "gx": G[:, 0], "gy": G[:, 1], "gz": G[:, 2], "bx": B[:, 0],
                         "by": B[:, 1], "bz": B[:, 2], "azimuth_deg": np.asarray(azimuth_from_gv(G, B)),
                         "inclination_deg": np.asarray(inclination_from_g(G)),
                         "inclination_raw_deg": np.asarray(inclination_from_g(G)),
                         "toolface_raw_deg": np.asarray(toolface_from_g(G)),
                         "azimuth_raw_deg": np.asarray(azimuth_from_gv(G, B))})


def models(seed: int = 0) -> dict:
    """KIND -> a small valid model of that kind."""
    rng = np.random.default_rng(seed)
    s = survey()
    G, B = s[["gx", "gy", "gz"]].to_numpy(), s[["bx", "by", "bz"]].to_numpy()
    base = dict(config={"made_by": "tests/hostile_models.py"}, data_hash="0" * 16, domain=sensor_domain(G, B))
    R, S, L = 2, 1, 4
    X = np.hstack([G, B])
    relm = RELMCompensation(**base, methods=["relm"], selected="relm", repeat_ids=[0, 1], hidden=L, lam=1e-3,
                            features="raw",
                            params=RELMParams(msa_bias=rng.normal(0, 50, (R, 3)), msa_scale=np.zeros((R, 3)),
                                              x_mean=np.tile(X.mean(0), (R, 1)), x_std=np.tile(X.std(0) + 1e-9, (R, 1)),
                                              theta=rng.uniform(-1, 1, (S, R, _relm.n_params(L))),
                                              beta=rng.normal(0, 0.1, (S, R, L)), hidden=L, raw_features=True),
                            train_rmse=np.full((S, R), 0.2), interval_halfwidth=np.array([0.5]))
    msa = MSAModel(**base, params=_msa.MSAParams(bias=rng.normal(0, 50, (R, 3)), scale=np.zeros((R, 3))),
                   repeat_ids=[0, 1])
    cal = MagCalibration(**base, method="twelve", axis_aligned=False, field_scale_nT=1.0,
                         params=CalibrationParams(np.r_[np.eye(3).ravel(), rng.normal(0, 100, 3)]))
    cfg = nets.NetConfig()
    n_in, (m1, m2), E = nets.n_inputs(cfg.encoding), cfg.hidden, 5
    tdom = {"inclination_raw_deg": [0.0, 90.0], "n_points": 100}
    tbase = dict(config={}, data_hash="1" * 16, domain=tdom)
    net = GyroNetwork(**tbase, variant="net_error", net_config={**cfg._asdict(), "hidden": list(cfg.hidden)},
                      params=nets.NetParams(w1=rng.normal(0, 0.3, (S, m1, n_in)), b1=np.zeros((S, m1)),
                                            w2=rng.normal(0, 0.3, (S, m2, m1)), b2=np.zeros((S, m2)),
                                            v=rng.normal(0, 0.3, (S, m2)), y_scale=np.ones(S),
                                            encoding=cfg.encoding, target=cfg.target),
                      best_epoch=np.ones(S, np.int64), best_val_loss=np.ones(S), train_loss=np.ones((S, E)),
                      val_loss=np.ones((S, E)), stopped_epoch=np.full(S, E, np.int64))
    grelm = GyroRELM(**tbase, method="relm", encoding="scaled", hidden=L, lam=1e-3,
                     params=gyro_relm.GyroRELMParams(theta=rng.uniform(-1, 1, (S, (n_in + 1) * L)),
                                                     beta=rng.normal(0, 0.1, (S, L)), mean=np.zeros((S, n_in)),
                                                     std=np.ones((S, n_in)), encoding="scaled"),
                     train_fitness=np.ones(S))
    table = LookupTableModel(**tbase, toolface="mean", params=lookup_table.LookupTable(
        inc_nodes=np.array([0.0, 45.0, 90.0]), az_nodes=np.array([0.0, 120.0, 240.0]),
        error=rng.normal(0, 0.1, (3, 3))))
    phys = PhysicsModel(**base, effects=["hard_iron"], sigma_b_nT=50.0, sigma_g=0.001, n_iter=5,
                        params=PhysicsParams({"hard_iron": rng.normal(0, 50, 3)}, np.array([50_000.0, 60.0, 0.0]),
                                             50.0, 0.001, 5))
    return {m.KIND: m for m in (relm, msa, cal, net, grelm, table, phys)}
