"""experiments.apply / icgo.survey.apply: a saved model corrects a new survey; QC, metrics, one-line errors."""

from __future__ import annotations

import dataclasses
import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra

from experiments import _preflight as entry
from experiments._data_doors import run_apply
from icgo.core.errors import ModelError
from icgo.datasets import casing_stations
from icgo.io.recording import read_recording, write_recording
from icgo.artifacts.format import SCHEMA_VERSION
from icgo.physics.qc import QCBands
from icgo.studies.icgo_relm import study as icgo_relm
from icgo.studies.icgo_relm.config import StudyConfig

ROOT = Path(__file__).resolve().parent.parent
META_KEYS = ("total_field_nT", "dip_deg", "declination_deg", "gravity_g", "name")


def _cfg(overrides):
    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(entry.CONF_DIR / "apply"), version_base="1.3"):
        return compose(config_name="apply", overrides=list(overrides))


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    """A small fitted ICGO-RELM model saved to disk, and a new lab_casing draw written as a survey."""
    tmp = tmp_path_factory.mktemp("apply")
    res = icgo_relm.run_study(casing_stations.lab_casing(0, toolface_step_deg=30.0).frame,
                              StudyConfig(split=dict(n_repeats=2), model=dict(hidden=8), budget=dict(pop_size=6,
                                          iterations=3), optimizer="pso"))
    model = res.model.save(tmp / "relm_compensation")
    new = casing_stations.lab_casing(5, toolface_step_deg=30.0)
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
    def files():  # every file, nested ones too
        return {p.relative_to(out): p.read_bytes() for p in out.rglob("*") if p.is_file()}

    before = files()
    with pytest.raises(ValueError, match="already holds files"):
        run_apply(_cfg([f"model={path}", f"data={survey}"]), out)
    assert files() == before
    (out / "stale.txt").write_text("old")
    run_apply(_cfg([f"model={path}", f"data={survey}", "overwrite=true"]), out)
    assert not (out / "stale.txt").exists()


@pytest.mark.parametrize("value", ["maybe", "'false'", "0", "null"])
def test_require_meta_takes_only_true_or_false(setup, tmp_path, value):
    _, _, path, survey = setup
    with pytest.raises(ValueError, match="require_meta=.*must be true or false"):
        run_apply(_cfg([f"model={path}", f"data={survey}", f"require_meta={value}"]), tmp_path / "o")


def _ab_calibration():
    """Device ab's ellipsoid calibration, in nT (a model of one device)."""
    from icgo.io.mag_cal_bundled import load_mag_cal_device
    from icgo.models.calibration import ellipsoid_fit
    from icgo.artifacts.calibration import mag_calibration

    ab = load_mag_cal_device("ab")
    scale = float(np.median(np.linalg.norm(ab.B, axis=1)))
    model = mag_calibration("ellipsoid", ellipsoid_fit(ab.B / scale, 1.0), ab.G, ab.B / scale, {},
                            field_scale_nT=scale)
    x = model.params.x_mag
    return dataclasses.replace(model, params=dataclasses.replace(model.params, x_mag=np.r_[x[:9], x[9:] * scale]),
                               field_scale_nT=1.0)


def test_another_devices_calibration_changes_the_verdict(tmp_path):
    """Device ab's calibration: its own shots give one earth field; device jd's do not, and the verdict says not to
    use the result (status, model and next lines, exit status 3), not only a notice."""
    from icgo.io.mag_cal_bundled import load_mag_cal_device
    from icgo.survey.apply import correct_survey
    from icgo.survey.verdict import EXIT_OUT_OF_DOMAIN

    model = _ab_calibration()
    own = correct_survey(model, load_mag_cal_device("ab").frame)
    other = correct_survey(model, load_mag_cal_device("jd").frame)
    assert not own.doubts and not any("one earth field" in n for n in own.notices)
    assert "other_device" in other.doubts and any("one earth field" in n for n in other.notices)
    path = model.save(tmp_path / "ab_cal")
    for name in ("ab", "jd"):
        write_recording(tmp_path / f"{name}.csv", load_mag_cal_device(name).frame.drop(columns="group"), {},
                        require_reference=False)
    meta = run_apply(_cfg([f"model={path}", f"data={tmp_path / 'jd.csv'}"]), tmp_path / "o_jd")
    v = meta["verdict"]
    assert v["status"] == "other device" and v["exit_code"] == EXIT_OUT_OF_DOMAIN
    assert v["domain"].startswith("NOT this model's device") and v["model"].startswith("none for this survey")
    assert "calibrate this device" in v["next"] and "IN the training domain" not in v["domain"]
    own_meta = run_apply(_cfg([f"model={path}", f"data={tmp_path / 'ab.csv'}"]), tmp_path / "o_ab")
    assert own_meta["verdict"]["status"] != "other device" and not own_meta["doubts"]


def test_a_reference_in_radians_changes_the_verdict(setup, tmp_path, capsys):
    """The survey's azimuth_deg and inclination_deg written in radians: no MAE reported as a result, the status says
    the reference is in doubt, and the next step is to convert it (exit status 3)."""
    from icgo.survey.apply import radians_doubt

    _, _, path, survey = setup
    rec = read_recording(survey)
    rad = rec.frame.assign(azimuth_deg=np.radians(rec.frame.azimuth_deg), inclination_deg=np.radians(
        rec.frame.inclination_deg))
    write_recording(tmp_path / "rad.csv", rad, {k: v for k, v in rec.meta.items() if k in META_KEYS})
    meta = run_apply(_cfg([f"model={path}", f"data={tmp_path / 'rad.csv'}"]), tmp_path / "o")
    v = meta["verdict"]
    assert v["status"] == "reference in doubt" and v["exit_code"] == 3
    assert "NOT measured on this survey" in v["accuracy"] and "looks like radians" in v["accuracy"]
    assert "MAE" not in v["accuracy"] and "convert the survey's reference angles" in v["next"]
    assert "reference_units" in meta["doubts"]
    # no MAE line printed above the verdict that says it means nothing (issue 48)
    from icgo.survey.apply_run import report

    capsys.readouterr()
    report(meta, tmp_path / "o", "rad")
    printed = capsys.readouterr().out
    assert not re.search(r"MAE [0-9]", printed) and "no MAE: the survey's reference angles look like radians" in printed
    # the same survey in degrees: no doubt; a survey heading north (azimuths 0-6 deg, in degrees) is not taken for
    # radians: the model's own azimuth agrees with it read as degrees
    assert run_apply(_cfg([f"model={path}", f"data={survey}"]), tmp_path / "o2")["verdict"]["status"] != \
        "reference in doubt"
    north = np.linspace(0.5, 6.0, 20)
    assert radians_doubt(north, north + 0.2, "azimuth_deg") is None
    assert "looks like radians" in radians_doubt(np.radians(north * 40), north * 40 + 0.3, "azimuth_deg")


def test_a_large_survey_streams_and_gives_what_the_whole_survey_gives(setup, tmp_path):
    """stream_mb=0 cannot be asked; the smallest streaming (a survey over 1 MiB, chunks of 500 rows) gives the same
    corrected rows, metrics, QC and verdict as reading it whole; its positions go to their own file."""
    _, _, path, _ = setup
    new = casing_stations.lab_casing(6, toolface_step_deg=2.0)
    frame = pd.concat([new.frame] * 6, ignore_index=True).assign(station=lambda f: np.arange(len(f)))
    frame["md"] = 10.0 * np.arange(len(frame))
    survey = tmp_path / "big.csv"
    write_recording(survey, frame, {k: v for k, v in new.meta.items() if k in META_KEYS})
    assert survey.stat().st_size > 1 << 20
    whole = run_apply(_cfg([f"model={path}", f"data={survey}"]), tmp_path / "whole")
    streamed = run_apply(_cfg([f"model={path}", f"data={survey}", "stream_mb=1", "chunk_rows=500"]),
                         tmp_path / "streamed")
    assert whole["chunks"] == 1 and streamed["chunks"] == -(-len(frame) // 500) and streamed["rows"] == len(frame)
    a = pd.read_csv(tmp_path / "whole" / "big_corrected.csv")
    b = pd.read_csv(tmp_path / "streamed" / "big_corrected.csv")
    pos = pd.read_csv(tmp_path / "streamed" / "big_positions.csv")
    pd.testing.assert_frame_equal(a[list(b.columns)], b)
    pd.testing.assert_frame_equal(a[list(pos.columns)], pos)
    # streamed, the survey-level numbers are sums over chunks (icgo.survey.apply_stream): the same up to the order
    # of the sums; counts, medians, doubts and the verdict's lines exactly the same
    assert whole["metrics"].keys() == streamed["metrics"].keys()
    for stage, m in whole["metrics"].items():
        assert streamed["metrics"][stage] == pytest.approx(m, rel=1e-12, abs=1e-14), stage
    for k in ("qc", "doubts", "notices"):
        assert whole[k] == streamed[k], k
    for k in ("accuracy", "domain", "qc", "model", "status", "exit_code"):
        assert whole["verdict"][k] == streamed["verdict"][k], k
    assert whole["trajectory"].keys() == streamed["trajectory"].keys()
    for k, v in whole["trajectory"].items():
        assert streamed["trajectory"][k] == (pytest.approx(v, rel=1e-12, abs=1e-9) if isinstance(v, dict) else v), k
    # a bad value in a later chunk is named by its row and line in the file
    lines = survey.read_text().splitlines(keepends=True)
    lines[1203] = lines[1203].replace(lines[1203].split(",")[1], "nan", 1)
    (tmp_path / "bad.csv").write_text("".join(lines))
    (tmp_path / "bad.meta.json").write_text((tmp_path / "big.meta.json").read_text())
    with pytest.raises(ValueError, match=r"bad.csv, row 1203 \(line 1204\), column 'gx': NaN"):
        run_apply(_cfg([f"model={path}", f"data={tmp_path / 'bad.csv'}", "stream_mb=1", "chunk_rows=500"]),
                  tmp_path / "bad_out")
    assert not (tmp_path / "bad_out").exists()
    with pytest.raises(ValueError, match="over the 1 MiB limit"):
        run_apply(_cfg([f"model={path}", f"data={survey}", "max_mb=1"]), tmp_path / "o3")
    for k in ("max_mb", "stream_mb", "chunk_rows"):
        with pytest.raises(ValueError, match=f"{k}=0: must be an integer >= 1"):
            run_apply(_cfg([f"model={path}", f"data={survey}", f"{k}=0"]), tmp_path / "o4")


def test_the_size_defaults_are_the_library_s():
    from icgo.io import stream

    cfg = _cfg(["model=x", "data=y"])
    assert cfg.max_mb << 20 == stream.MAX_SURVEY_BYTES and cfg.stream_mb << 20 == stream.STREAM_ABOVE_BYTES
    assert cfg.chunk_rows == stream.CHUNK_ROWS


def _streamed_vs_whole(model, frame, field, tmp_path, n_chunks=5):
    """summarise + survey_verdict of the whole frame, and the same from StreamedSurvey fed its chunks."""
    from icgo.survey.apply import correct_rows, summarise
    from icgo.survey.apply_stream import StreamedSurvey
    from icgo.survey.verdict import survey_verdict

    bands = QCBands()
    whole = summarise(model, correct_rows(model, frame, field, bands=bands), field)
    args = dict(out_csv="o.csv", model_path="m.json", survey_path="s.csv")
    v_whole = survey_verdict(whole, model, bands, **args)
    with StreamedSurvey(tmp_path / "pos.csv") as s:
        for idx in np.array_split(np.arange(len(frame)), n_chunks):
            s.add(correct_rows(model, frame.iloc[idx].reset_index(drop=True), field, bands=bands))
        res = s.result(model, field)
        v = s.verdict(res, model, bands, **args)
    assert not s.scratch.exists()
    assert (res.notices, res.doubts, res.qc, res.domain) == (whole.notices, whole.doubts, whole.qc, whole.domain)
    assert (res.metrics is None) == (whole.metrics is None)
    for stage, m in (whole.metrics or {}).items():
        assert res.metrics[stage] == pytest.approx(m, rel=1e-12, abs=1e-14), stage
    assert v.lines() == v_whole.lines() and (v.status, v.exit_code) == (v_whole.status, v_whole.exit_code)
    return res, v


def test_streamed_sums_give_the_whole_surveys_doubts_and_verdict(setup, tmp_path):
    """A streamed survey's result (icgo.survey.apply_stream) against the whole survey's, chunk by chunk: a RELM model
    on a survey with metrics, QC and interval coverage, the same survey with its reference in radians, and a
    calibration applied to another device's shots with a reference field (the |B| and dip deviations' medians)."""
    from icgo.io.mag_cal_bundled import load_mag_cal_device

    _, model, _, survey = setup
    rec = read_recording(survey)
    res, v = _streamed_vs_whole(model, rec.frame, rec.field, tmp_path / "a")
    assert res.metrics and res.qc and not res.doubts
    rad = rec.frame.assign(azimuth_deg=np.radians(rec.frame.azimuth_deg),
                           inclination_deg=np.radians(rec.frame.inclination_deg))
    res, v = _streamed_vs_whole(model, rad, rec.field, tmp_path / "b")
    assert "reference_units" in res.doubts and v.status == "reference in doubt"
    res, v = _streamed_vs_whole(_ab_calibration(), load_mag_cal_device("jd").frame.drop(columns="group"), rec.field,
                                tmp_path / "c", n_chunks=3)
    assert "other_device" in res.doubts and "median |B| deviation" in v.qc


def test_streaming_apply_peak_memory_does_not_grow_with_the_rows(setup, tmp_path):
    """Peak resident memory (ru_maxrss of its own process) of streaming apply on 10,000 and 60,000 rows with depth
    (chunks of 1,000 rows): within 10 MB (before the streamed sums every station's arrays and positions were kept:
    measured 90 MB more at 120,000 rows than at 20,000, ~900 bytes a row; now 0.3 MB)."""
    import sys

    from icgo.bench.process import measure
    from icgo.bench.rows import write_large_recording

    _, _, path, _ = setup
    peak = {}
    for n in (10_000, 60_000):
        csv = tmp_path / f"s{n}.csv"
        write_large_recording(csv, n, md_step_m=0.1)
        m = measure([sys.executable, "-m", "experiments.apply", f"model={path}", f"data={csv}", "stream_mb=1",
                     "chunk_rows=1000", f"out={tmp_path / f'o{n}'}"])
        assert m["rc"] == 0, m["tail"]
        assert (tmp_path / f"o{n}" / f"s{n}_positions.csv").exists()
        peak[n] = m["peak_rss_gb"] * 1e3
        csv.unlink()
    assert peak[60_000] - peak[10_000] < 10.0, peak
