"""docs/extending.md as written: a researcher's own strategy, optimizer and data set from a folder outside the
repository (their modules, their config folder on ``hydra.searchpath``, ``_target_``), with nothing in icgo edited.

The page's ``file=`` blocks are written into a fresh temporary folder; its ``python run`` blocks and ``bash run``
commands run there as written (``python`` is this interpreter, icgo found through ``PYTHONPATH`` as an installed
package would be). The fast tests compose each command's config and build the study from it (every registration
and check, no search), and run the notebook blocks; the slow test runs the commands themselves.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra

from experiments._preflight import CONF_DIR, check_overrides, check_plain_overrides
from icgo.core.errors import SettingError

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "extending.md"
BLOCK = re.compile(r"^```(\w+)[ \t]*([^\n]*)\n(.*?)^```", re.S | re.M)


def _blocks():
    """(language, info, text) of every fenced block of the page, in order."""
    return [(m.group(1), m.group(2).strip(), m.group(3)) for m in BLOCK.finditer(PAGE.read_text())]


def _files():
    return {info.split("=", 1)[1]: text for _, info, text in _blocks() if info.startswith("file=")}


def _commands():
    return [text.replace("\\\n", " ").strip() for lang, info, text in _blocks() if lang == "bash" and info == "run"]


def _snippets():
    return [text for lang, info, text in _blocks() if lang == "python" and info == "run"]


@pytest.fixture
def folder(tmp_path):
    """The page's folder ``my_research/``, written from its blocks."""
    home = tmp_path / "my_research"
    for name, text in _files().items():
        (home / name).parent.mkdir(parents=True, exist_ok=True)
        (home / name).write_text(text)
    yield home
    for name in _files():
        if name.endswith(".py") and "/" not in name:
            sys.modules.pop(name[:-3], None)  # the next test's folder is another one


def _env(home: Path) -> dict:
    path = os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    return {**os.environ, "PYTHONPATH": path, "PWD": str(home),
            "PATH": os.pathsep.join([str(Path(sys.executable).parent), os.environ["PATH"]])}


def _overrides(command: str, home: Path) -> list[str]:
    """The overrides of a page command, as bash hands them to the door."""
    words = shlex.split(command.replace("$PWD", str(home)))
    assert words[:3] == ["python", "-m", "experiments.run"], command
    return words[3:]


def test_the_page_has_one_of_each_kind():
    files = _files()
    assert {"my_strategies.py", "my_optimizers.py", "my_datasets.py", "conf/strategy/cauchy.yaml",
            "conf/optimizer/de.yaml", "conf/dataset/bench.yaml"} <= set(files)
    assert len(_commands()) == 3 and len(_snippets()) == 2
    assert any("worlds=2" in c and "strategy=cauchy" in c for c in _commands())  # beside the built-ins, over worlds


@pytest.fixture
def registries():
    """The registries as shipped, restored in place after the test (a registration here is this test's only)."""
    from icgo.datasets import registry as datasets
    from icgo.optim import mutation
    from icgo.optim import registry as optimizers

    kept = [(r, dict(r)) for r in (mutation.MUTATIONS, optimizers.OPTIMIZERS, datasets.DATASETS)]
    yield mutation, optimizers, datasets
    for r, before in kept:
        r.clear()
        r.update(before)


def _run_config(overrides):
    from omegaconf import OmegaConf

    from icgo.studies.icgo_relm.run_config import RunConfig

    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
            cfg = compose(config_name="config", overrides=overrides)
    finally:
        GlobalHydra.instance().clear()
    return RunConfig.from_mapping(OmegaConf.to_container(cfg, resolve=True))


def test_each_command_composes_registers_and_builds_its_study(folder, registries, monkeypatch):
    mutation, optimizers, datasets = registries
    monkeypatch.syspath_prepend(str(folder))
    want = [{"cgo-original", "cgo-chaos", "cgo-gaussian", "cgo-wavelet", "cgo-three_stage", "cgo-cauchy"}, {"de"},
            {"cgo-three_stage", "cgo-cauchy"}]
    for command, methods in zip(_commands(), want):
        overrides = _overrides(command, folder)
        assert check_overrides(overrides) is None  # the door's group check finds the options of the user's folder
        assert check_plain_overrides(overrides, "config") is None  # and composes with them to check plain keys
        run = _run_config(overrides)
        study = run.study_config()
        assert set(study.method_names()) == methods, command
    import my_datasets
    import my_optimizers
    import my_strategies

    assert mutation.MUTATIONS["cauchy"].label == "Cauchy" and mutation.MUTATIONS["cauchy"].operator.func is \
        my_strategies.cauchy and mutation.MUTATIONS["cauchy"].operator.keywords == {"gamma": 0.1}
    assert tuple(mutation.MUTATIONS)[:5] == mutation.STRATEGIES  # the built-ins keep their indices
    assert optimizers.OPTIMIZERS["de"] is my_optimizers.DE and datasets.DATASETS["bench"] is my_datasets.bench
    from icgo.studies.icgo_relm.names import method_name

    assert method_name("cgo-cauchy") == "ICGO-RELM (Cauchy)" and method_name("de") == "DE-RELM"
    typo = check_plain_overrides([*_overrides(_commands()[0], folder), "strategy.nams=[x]"], "config")
    assert typo.startswith("unknown setting 'strategy.nams' in override")
    # without the user's folder the door refuses the option in one line (exit 2 there)
    assert "unknown strategy 'cauchy'" in check_overrides([o for o in _overrides(_commands()[0], folder)
                                                           if not o.startswith("hydra.searchpath")])


def test_the_users_data_set_is_the_contract_with_the_attitude_it_claims(folder, monkeypatch):
    """The page's simulator without its injected errors: the azimuth docs/design.md's formula computes from its G and
    B is the planned azimuth within the accelerometer noise, and |B| the total field (float64)."""
    import numpy as np

    from icgo.physics.frames import attitude_from_sensors, angle_diff

    monkeypatch.syspath_prepend(str(folder))
    import my_datasets

    d = my_datasets.bench(0, hard_iron_nT=(0.0, 0.0, 0.0), soft_iron=0.0, mag_noise_nT=0.0)
    f = d.frame
    assert len(f) == 8 * 72 and d.meta["total_field_nT"] == 54_940.0
    att = attitude_from_sensors(f[["gx", "gy", "gz"]].to_numpy(), f[["bx", "by", "bz"]].to_numpy())
    assert np.abs(np.asarray(angle_diff(att.azimuth, f.azimuth_deg.to_numpy()))).max() < 0.2  # 5e-4 g noise only
    np.testing.assert_allclose(np.linalg.norm(f[["bx", "by", "bz"]].to_numpy(), axis=1), 54_940.0, rtol=1e-5)


def test_the_pages_notebook_blocks_run_as_written(folder, registries, monkeypatch):
    """Each ``python run`` block, in this process (its compiled programs cached as the suite's) from the user's
    folder; the blocks assert their own results (closed-form optimum 0 of the shifted sphere)."""
    monkeypatch.syspath_prepend(str(folder))
    monkeypatch.chdir(folder)
    for code in _snippets():
        exec(compile(code, str(PAGE), "exec"), {"__name__": "__page__"})


def test_a_bad_target_is_one_line_naming_the_setting(folder, registries, monkeypatch):
    monkeypatch.syspath_prepend(str(folder))
    base = _overrides(_commands()[1], folder)
    with pytest.raises(SettingError, match=r"^optimizer\._target_ 'my_optimizers\.NoSuch': my_optimizers has no "
                                           r"'NoSuch'$"):
        _run_config([*base, "optimizer._target_=my_optimizers.NoSuch"])
    with pytest.raises(SettingError, match=r"^optimizer\.name 'dee' must be the name of the algorithm"):
        _run_config([*base, "optimizer.name=dee"])
    first = _overrides(_commands()[0], folder)
    with pytest.raises(SettingError, match=r"^strategy\.define\.cauchy\._target_ 'nowhere\.cauchy': cannot import "
                                           r"module 'nowhere'"):
        _run_config([*first, "strategy.define.cauchy._target_=nowhere.cauchy"])
    with pytest.raises(SettingError, match=r"^strategy\.define\.chaos .*already registered with another operator"):
        _run_config([*first, "+strategy.define.chaos._target_=my_strategies.cauchy"])


@pytest.mark.slow
def test_the_pages_commands_run_as_written(folder):
    """Each command of the page, by bash in the user's folder: exit 0 and the user's method in the run's record."""
    want = ["cgo-cauchy", "de", "cgo-cauchy"]
    for command, method in zip(_commands(), want):
        before = set(folder.glob("outputs/**/run.json"))
        out = subprocess.run(["bash", "-c", command], cwd=folder, env=_env(folder), capture_output=True, text=True,
                             timeout=600)
        assert out.returncode == 0, out.stderr[-3000:]
        (run_json,) = set(folder.glob("outputs/**/run.json")) - before
        assert method in json.loads(run_json.read_text())["methods"], command
        assert method in (run_json.parent / "metrics.csv").read_text()
    assert "worlds" in json.loads(sorted(folder.glob("outputs/**/run.json"))[0].read_text())
