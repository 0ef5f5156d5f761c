"""Registry-wide study tests: every registered study gets the same checks (evosax/optax style).

For each study of :func:`icgo.studies.all_studies`: its tiny example runs, two
runs with the same key give identical records, its records are DataFrames
(the ICGO-RELM tables checked against :mod:`icgo.reporting.records`), its fitted models
save/load/apply bitwise, and its default config round-trips through a plain
mapping (the form a Hydra config takes).
"""

from __future__ import annotations

import dataclasses

import jax
import pandas as pd
import pytest

from icgo.core.settings import config_from_mapping, config_overrides, config_to_mapping
from icgo.artifacts.format import FittedModel
from icgo.artifacts.registry import load_model
from icgo.reporting import records as REC
from icgo.studies.registry import all_studies, get_study

NAMES = sorted(all_studies())


def test_the_registry_holds_every_study():
    assert {"icgo_relm", "misma", "gyro", "discrepancy"} <= set(NAMES)


@pytest.fixture(scope="module")
def runs():
    """Each study's example run twice with one key (cached per module)."""
    cache = {}

    def get(name):
        if name not in cache:
            study = get_study(name)
            data, cfg = study.example()
            key = jax.random.PRNGKey(5)
            cache[name] = (study, data, cfg, study.run(data, cfg, key), study.run(data, cfg, key))
        return cache[name]

    return get


@pytest.mark.parametrize("name", NAMES)
def test_default_config_is_valid_and_round_trips(name):
    study = get_study(name)
    cfg = study.config_cls()
    assert dataclasses.is_dataclass(cfg) and study.config_cls.__dataclass_params__.frozen
    assert config_from_mapping(study.config_cls, config_to_mapping(cfg)) == cfg
    with pytest.raises(ValueError, match="unknown setting"):
        config_from_mapping(study.config_cls, {**config_to_mapping(cfg), "no_such_setting": 1})
    assert config_overrides(cfg) == []


def test_config_overrides_name_each_setting_off_its_default_in_hydras_syntax():
    from icgo.studies.misma.config import MismaConfig

    cfg = MismaConfig()
    changed = dataclasses.replace(cfg, seed=cfg.seed + 1,
                                  real=dataclasses.replace(cfg.real, misma_repeats=cfg.real.misma_repeats + 2))
    assert config_overrides(changed) == [f"seed={cfg.seed + 1}", f"real.misma_repeats={cfg.real.misma_repeats + 2}"]
    from icgo.discrepancy import WorkflowConfig

    assert config_overrides(WorkflowConfig(candidates=("hard_iron", "mag_scale"), noise_from_data=False)) == [
        "candidates=[hard_iron,mag_scale]", "noise_from_data=false"]


@pytest.mark.parametrize("name", NAMES)
def test_example_runs_deterministically_with_records_and_models(name, runs, tmp_path):
    study, data, cfg, a, b = runs(name)
    assert study.example is not None
    ra, rb = study.records(a), study.records(b)
    assert ra and set(ra) == set(rb)
    for table, df in ra.items():
        assert isinstance(df, pd.DataFrame) and len(df) > 0, table
        assert all(isinstance(c, str) for c in df.columns), table
        if name == "icgo_relm" and table in REC.TABLES:
            missing = [c for c in REC.TABLES[table] if c not in df.columns]
            assert not missing, (table, missing)
        pd.testing.assert_frame_equal(df.drop(columns=[c for c in df.columns if c.endswith("_s")]),
                                      rb[table].drop(columns=[c for c in df.columns if c.endswith("_s")]),
                                      check_exact=True, obj=f"{name}.{table}")
    if not study.fits_models:
        assert a.models == {}
        return
    assert a.models, f"{name} fitted no model"
    for label, model in a.models.items():
        assert isinstance(model, FittedModel), label
        path = model.save(tmp_path / label)
        assert type(load_model(path)) is type(model)


def test_generalisation_qc_counts_are_the_survey_qc_of_the_tested_stations(runs):
    from icgo.physics.qc import survey_qc
    from icgo.studies.generalisation.study import _qc_stations
    from icgo.studies.icgo_relm.config import StudyConfig

    _, data, cfg, res, _ = runs("generalisation")
    qc = res.records["qc"]
    for cell in cfg.cells:
        got = qc[(qc.dataset == cell[0]) & (qc.protocol == cell[1])].set_index("stage")[["n", "g", "b", "dip", "any"]]
        assert list(got.index) == ["raw", "msa", "physics"]
        st = _qc_stations(data[cell], StudyConfig(split=dict(protocol=cell[1])))
        meta = data[cell].meta
        raw = survey_qc(st[["gx", "gy", "gz"]].to_numpy(), st[["bx", "by", "bz"]].to_numpy(),
                        meta["total_field_nT"], meta["dip_deg"]).counts
        assert got.loc["raw"].to_dict() == raw
        # fold protocols and transfer test every station once per repeat: the physics count sees them all
        assert got.loc["physics", "n"] == got.loc["msa", "n"] == raw["n"]


def test_a_sweepers_objective_is_the_studys_own_search_number_never_a_test_score(runs, tmp_path):
    """misma: MISMA's median best fitness averaged over the simulated variants, as its reported table has it; gyro:
    the networks' best validation loss averaged over variants and seeds, as the saved models carry it (read back
    from their files). The studies without one return None through the door."""
    import numpy as np

    from icgo.artifacts.network import GyroNetwork

    misma, _, _, res, _ = runs("misma")
    table = res.records["simulated"]
    assert misma.objective(res) == pytest.approx(np.mean(table.loc["MISMA_best_f_median"].astype(float)), rel=1e-12)
    gyro, _, _, res, _ = runs("gyro")
    saved = [load_model(m.save(tmp_path / k)) for k, m in res.models.items() if isinstance(m, GyroNetwork)]
    assert saved
    assert gyro.objective(res) == pytest.approx(np.mean(np.concatenate([s.best_val_loss for s in saved])), rel=1e-12)
    assert gyro.objective(res) not in set(res.records["methods"].filter(like="rmse").to_numpy().ravel())
    assert [n for n in NAMES if get_study(n).objective is not None] == ["gyro", "misma"]
