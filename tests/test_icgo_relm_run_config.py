"""The typed config of the ICGO-RELM door (icgo.studies.icgo_relm.run_config): built node by node from the composed
mapping, unknown keys and bad values refused in one line naming the YAML key, and the one StudyConfig constructor."""

from __future__ import annotations

import dataclasses

import pytest
from omegaconf import OmegaConf

from icgo.core.errors import SettingError
from icgo.core.settings import config_from_mapping
from icgo.studies.icgo_relm import run_config as RC
from icgo.studies.icgo_relm.settings import TransferTarget
from tests.test_experiments_run import _compose


def _mapping(overrides=()):
    return OmegaConf.to_container(_compose(list(overrides)), resolve=True)


def test_each_dataset_option_builds_its_own_node():
    assert type(RC.RunConfig.from_mapping(_mapping()).dataset) is RC.SimulatedData
    wc = RC.RunConfig.from_mapping(_mapping(["dataset=well_conditions", "dataset.condition=3"])).dataset
    assert type(wc) is RC.WellConditionsData and wc.condition == 3 and wc.kwargs == {}
    csv = RC.RunConfig.from_mapping(_mapping(["dataset=csv", "dataset.path=/etc/hostname"])).dataset
    assert type(csv) is RC.CsvData and csv.require_meta is True and csv.kwargs is None and csv.condition is None
    m = _mapping()
    m["dataset"]["name"] = "bogus"
    with pytest.raises(SettingError, match=r"^dataset.name 'bogus' is no data set of icgo.datasets.registry.DATASETS "
                                           r"\(lab_casing, well_conditions, .*\) nor csv; a simulator of your own"):
        RC.RunConfig.from_mapping(m)
    m["dataset"]["name"] = 3
    with pytest.raises(SettingError, match=r"^dataset.name must be one of \['csv', 'well_conditions'\], got 3"):
        RC.RunConfig.from_mapping(m)


@pytest.mark.parametrize("where, key, value", [("split", "bogus", 1), ("dataset", "pth", "x"), ("", "bogus", 1),
                                               ("optimizer", "lable", "x"), ("schedule", "clok", "stage")])
def test_an_unknown_key_is_one_line_naming_its_path(where, key, value):
    m = _mapping()
    (m[where] if where else m)[key] = value
    path = f"{where}.{key}" if where else key
    with pytest.raises(SettingError) as e:
        RC.RunConfig.from_mapping(m)
    assert "\n" not in str(e.value) and f"unknown setting(s) ['{path}']" in str(e.value)


def test_the_transfer_target_is_a_node_and_only_with_its_protocol():
    run = RC.RunConfig.from_mapping(_mapping(["split=transfer"]))
    assert isinstance(run.split.target, TransferTarget) and run.split.target.path is None
    from icgo.studies.common.splits import TransferDraw

    assert TransferDraw(**run.split.target.draw()) == TransferDraw()
    m = _mapping(["split=transfer"])
    m["split"]["target"] = "bogus"
    with pytest.raises(SettingError, match=r"^split.target must be a group of settings"):
        RC.RunConfig.from_mapping(m)


def test_each_value_is_checked_once_where_it_enters_under_the_yaml_key():
    """A node checks its values when it is built (the door's config or a library StudyConfig alike), naming the key
    the user typed; what spans nodes (the strategies of the optimizer) is checked by the study config, under the
    door's key too."""
    with pytest.raises(SettingError, match=r"^split.n_repeats must be an integer >= 1, got 0"):
        RC.RunConfig.from_mapping(_mapping(["split.n_repeats=0"]))
    with pytest.raises(SettingError, match=r"^model.lam must be a number > 0 and at most 1000"):
        RC.RunConfig.from_mapping(_mapping(["model.lam=5000"]))
    run = RC.RunConfig.from_mapping(_mapping(["strategy.names=[original,original]"]))
    with pytest.raises(SettingError, match=r"^strategy.names must be a non-empty tuple of distinct names"):
        run.study_config()


def test_a_library_study_config_refuses_lam_above_the_bound():
    from icgo.studies.icgo_relm.config import StudyConfig

    with pytest.raises(SettingError, match=r"^model.lam must be a number > 0 and at most 1000"):
        StudyConfig(model=dict(lam=5e3))


@dataclasses.dataclass(frozen=True)
class Inner:
    a: int = 1


@dataclasses.dataclass(frozen=True)
class Outer:
    inner: Inner | None = None
    flag: bool = False


def test_config_from_mapping_builds_optional_nested_nodes_and_refuses_a_value_for_a_node():
    assert config_from_mapping(Outer, {"inner": {"a": 2}}).inner == Inner(2)
    assert config_from_mapping(Outer, {"inner": None}).inner is None
    with pytest.raises(SettingError, match=r"^inner must be a group of settings"):
        config_from_mapping(Outer, {"inner": 3})
    with pytest.raises(SettingError, match=r"unknown setting\(s\) \['inner.b'\]"):
        config_from_mapping(Outer, {"inner": {"b": 2}})
    with pytest.raises(SettingError, match=r"^flag must be true or false, got 'yes'"):
        config_from_mapping(Outer, {"flag": "yes"})
