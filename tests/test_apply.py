"""experiments.apply / icgo.survey.apply: a saved model corrects a new survey; QC, metrics, one-line errors."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra

from experiments import _entry as C
from experiments.apply import run_apply
from icgo.core.errors import ModelError
from icgo.datasets import protocols as datasets
from icgo.io.recording import read_recording, write_recording
from icgo.models.format import SCHEMA_VERSION
from icgo.physics.qc import QCBands
from icgo.studies import icgo_relm

ROOT = Path(__file__).resolve().parent.parent
META_KEYS = ("total_field_nT", "dip_deg", "declination_deg", "gravity_g", "name")


def _cfg(overrides):
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(C.CONF_DIR / "apply"), version_base="1.3"):
        return compose(config_name="apply", overrides=list(overrides))


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    """A small fitted ICGO-RELM model saved to disk, and a new lab_casing draw written as a survey."""
    tmp = tmp_path_factory.mktemp("apply")
    res = icgo_relm.run_study(datasets.lab_casing(0, toolface_step_deg=30.0).frame,
                              icgo_relm.StudyConfig(optimizer="pso", n_repeats=2, hidden=8, pop_size=6, iterations=3))
    model = res.model.save(tmp / "relm_compensation")
    new = datasets.lab_casing(5, toolface_step_deg=30.0)
    survey = tmp / "survey.csv"
    write_recording(survey, new.frame, {k: v for k, v in new.meta.items() if k in META_KEYS})
    return tmp, res.model, model, survey


def test_apply_writes_the_corrected_survey_with_metrics_and_qc(setup):
    tmp, model, path, survey = setup
    meta = run_apply(_cfg([f"model={path}", f"data={survey}"]), tmp / "out")
    table = pd.read_csv(tmp / "out" / "survey_corrected.csv")
    on_disk = json.loads((tmp / "out" / "survey_corrected.meta.json").read_text())
    assert on_disk["metrics"] == meta["metrics"] and on_disk["model_kind"] == "relm_compensation"
    rec = read_recording(survey)
    expect = model.apply(rec.frame)
    np.testing.assert_array_equal(table.azimuth_compensated, expect.azimuth_compensated)  # written repr-exact
    err = ((expect.azimuth_compensated - rec.frame.azimuth_deg + 180.0) % 360.0 - 180.0).to_numpy()
    assert meta["metrics"]["compensated"]["mae"] == pytest.approx(np.abs(err).mean(), rel=1e-12)
    assert meta["metrics"]["compensated"]["rmse"] == pytest.approx(np.sqrt(np.mean(err**2)), rel=1e-12)
    # QC counts from an independent numpy computation against the survey's reference field
    G, B = rec.G, rec.B
    f = rec.field
    bad_b = np.abs(np.linalg.norm(B, axis=1) - f.total_field_nT) > 300.0
    dip = np.degrees(np.arcsin(np.sum(G * B, 1) / (np.linalg.norm(G, axis=1) * np.linalg.norm(B, axis=1))))
    bad_dip = np.abs(dip - f.dip_deg) > 0.25
    assert meta["qc"]["raw"]["b"] == int(bad_b.sum()) and meta["qc"]["raw"]["dip"] == int(bad_dip.sum())
    assert meta["qc"]["corrected"]["n"] == len(table) and "raw_qc_pass" in table and "corrected_qc_pass" in table


def test_without_reference_azimuth_it_reports_qc_only(setup):
    tmp, _, path, survey = setup
    rec = read_recording(survey)
    bare = tmp / "bare.csv"
    write_recording(bare, rec.frame.drop(columns=["azimuth_deg", "inclination_deg"]), rec.meta,
                    require_reference=False)
    meta = run_apply(_cfg([f"model={path}", f"data={bare}"]), tmp / "out_bare")
    assert meta["metrics"] is None and meta["qc"]["raw"]["n"] == len(rec.frame)
    assert any("no reference azimuth" in n for n in meta["notices"])


def test_apply_config_defaults_are_the_library_defaults():
    cfg = _cfg(["model=x", "data=y"])
    assert QCBands(**cfg.qc) == QCBands()
    assert {f.name for f in dataclasses.fields(QCBands)} == set(cfg.qc)


def test_bad_model_files_are_one_line_errors(setup, tmp_path):
    _, _, path, survey = setup
    (tmp_path / "x.json").write_text('{"a": 1}')
    with pytest.raises(ModelError, match="not a model file"):
        run_apply(_cfg([f"model={tmp_path / 'x.json'}", f"data={survey}"]), tmp_path / "o1")
    head = json.loads(Path(path).read_text())
    head["schema_version"] = SCHEMA_VERSION + 1
    newer = tmp_path / "newer.json"
    newer.write_text(json.dumps(head))
    (tmp_path / head["arrays"]).write_bytes((Path(path).parent / head["arrays"]).read_bytes())
    with pytest.raises(ModelError, match="newer than this icgo"):
        run_apply(_cfg([f"model={newer}", f"data={survey}"]), tmp_path / "o2")
    assert not (tmp_path / "o1").exists() and not (tmp_path / "o2").exists()
    with pytest.raises(ValueError, match="unknown setting"):
        run_apply(_cfg([f"model={path}", f"data={survey}", "+bogus=1"]), tmp_path / "o3")


def test_cli_survey_lacking_sensor_columns_is_one_line(setup, tmp_path):
    """A survey without bz: one line on stderr, exit 1 (bad data), nothing written (run in a fresh process)."""
    _, _, path, survey = setup
    frame = pd.read_csv(survey).drop(columns=["bz"])
    bad = tmp_path / "nobz.csv"
    frame.to_csv(bad, index=False)
    p = subprocess.run([sys.executable, "-m", "experiments.apply", f"model={path}", f"data={bad}",
                        f"out={tmp_path / 'o'}"], capture_output=True, text=True, timeout=300,
                       env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"}, cwd=tmp_path)
    lines = [x for x in p.stderr.strip().splitlines() if "xla_bridge" not in x and "libtpu" not in x]
    assert p.returncode == 1 and len(lines) == 1 and lines[0].startswith("error: ") and "bz" in lines[0], p.stderr
    assert not (tmp_path / "o").exists()


def test_every_kinds_output_is_a_known_output_column():
    """A survey holding any column a correction writes is refused as input (never mixed): the list must hold every
    kind's output and the QC columns."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import hostile_models

    from icgo.physics.qc import survey_qc
    from icgo.survey.apply import OUTPUT_COLUMNS, QC_COLUMNS

    survey = hostile_models.survey()
    for model in hostile_models.models().values():
        assert set(model.apply(survey).columns) - {"station", "azimuth_raw_deg"} <= OUTPUT_COLUMNS, model.KIND
    G = survey[["gx", "gy", "gz"]].to_numpy()
    B = survey[["bx", "by", "bz"]].to_numpy()
    assert tuple(survey_qc(G, B, 50_000.0, 60.0).table.columns) == QC_COLUMNS


def test_a_corrected_survey_is_refused_never_mixed(setup, tmp_path):
    _, _, path, survey = setup
    run_apply(_cfg([f"model={path}", f"data={survey}"]), tmp_path / "first")
    corrected = tmp_path / "first" / "survey_corrected.csv"
    with pytest.raises(ValueError, match="output columns of a correction"):
        run_apply(_cfg([f"model={path}", f"data={corrected}", "require_meta=false"]), tmp_path / "second")
    assert not (tmp_path / "second").exists()


def test_a_used_output_directory_is_refused_then_replaced_whole(setup, tmp_path):
    _, _, path, survey = setup
    out = tmp_path / "out"
    run_apply(_cfg([f"model={path}", f"data={survey}"]), out)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    with pytest.raises(ValueError, match="already holds files"):
        run_apply(_cfg([f"model={path}", f"data={survey}"]), out)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    (out / "stale.txt").write_text("old")
    run_apply(_cfg([f"model={path}", f"data={survey}", "overwrite=true"]), out)
    assert not (out / "stale.txt").exists()


@pytest.mark.parametrize("value", ["maybe", "'false'", "0", "null"])
def test_require_meta_takes_only_true_or_false(setup, tmp_path, value):
    _, _, path, survey = setup
    with pytest.raises(ValueError, match="require_meta=.*must be true or false"):
        run_apply(_cfg([f"model={path}", f"data={survey}", f"require_meta={value}"]), tmp_path / "o")


def test_another_devices_calibration_is_said_in_a_notice():
    """Device ab's ellipsoid calibration: its own shots give one earth field (no notice); device jd's do not."""
    from icgo.io.recording import load_mag_cal_device
    from icgo.methods.calibration import ellipsoid_fit
    from icgo.models.calibration import mag_calibration
    from icgo.survey.apply import correct_survey

    ab = load_mag_cal_device("ab")
    scale = float(np.median(np.linalg.norm(ab.B, axis=1)))
    model = mag_calibration("ellipsoid", ellipsoid_fit(ab.B / scale, 1.0), ab.G, ab.B / scale, {},
                            field_scale_nT=scale)
    model = dataclasses.replace(model, x_mag=np.r_[model.x_mag[:9], model.x_mag[9:] * scale], field_scale_nT=1.0)
    own = correct_survey(model, ab.frame).notices
    other = correct_survey(model, load_mag_cal_device("jd").frame).notices
    assert not any("one earth field" in n for n in own), own
    assert any("one earth field" in n for n in other), other
