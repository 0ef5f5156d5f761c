"""Tests for the data contract (icgo.io.recording, schema, checks, csv_text): the reader/writer, its one-line errors,
and the bundled circuitpython-mag-cal devices (icgo.io.mag_cal_bundled)."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from icgo.core.errors import DataError
from icgo.io import csv_text, mag_cal_bundled, schema
from icgo.io import __main__ as io_cli
from icgo.io import recording as io
from icgo.physics.frames import angle_diff, attitude_from_sensors

DATA = Path(__file__).parent / "data"


def _copy(tmp_path, *names):
    for n in names:
        shutil.copy(DATA / n, tmp_path / n)
    return tmp_path / names[0]


def _one_line_error(fn, *args, **kw) -> str:
    with pytest.raises(DataError) as e:
        fn(*args, **kw)
    msg = str(e.value)
    assert "\n" not in msg and msg.strip() == msg and msg
    return msg


# ------------------------------------------------------------- good files
def test_survey_reads_with_types_field_and_consistent_attitude():
    rec = io.read_recording(DATA / "survey.csv")
    f = rec.frame
    assert list(f.columns) == ["station", "gx", "gy", "gz", "bx", "by", "bz", "azimuth_deg",
                               "inclination_deg", "toolface_deg", "time_s", "temperature_c"]
    assert f["station"].dtype == np.int64 and f["gx"].dtype == np.float64
    assert f["station"].tolist() == [1, 2, 3, 4, 5, 6]
    assert rec.notices == []
    assert rec.field == schema.ReferenceField(48000.0, 65.0, 0.0, 1.0, "metadata")
    assert rec.has_reference
    # The file's sensors (rounded to 1e-6 g, 1e-3 nT) reproduce its reference attitude.
    att = attitude_from_sensors(rec.G, rec.B)
    np.testing.assert_allclose(np.asarray(angle_diff(att.azimuth, f["azimuth_deg"])), 0.0, atol=2e-4)
    np.testing.assert_allclose(np.asarray(att.inclination), f["inclination_deg"], atol=2e-4)
    np.testing.assert_allclose(np.asarray(angle_diff(rec.toolface_deg(), f["toolface_deg"])), 0.0, atol=2e-4)
    np.testing.assert_allclose(np.linalg.norm(rec.B, axis=1), 48000.0, atol=2e-3)


def test_groups_without_reference_get_field_from_site():
    from icgo.physics.field import reference_field

    rec = io.read_recording(DATA / "groups.csv")
    assert not rec.has_reference and rec.frame["group"].tolist() == [1] * 6 + [2] * 6
    ref = reference_field(51.5, -0.13, 0.0, "2024-06-01")
    assert rec.field.origin == "field model"
    assert rec.field[:3] == tuple(ref)
    assert rec.field.gravity_g == 1.0
    # The data were simulated in that field: |B| and the G-B angle (90 - dip) agree.
    G, B = rec.G, rec.B
    np.testing.assert_allclose(np.linalg.norm(B, axis=1), ref.total_field_nT, atol=2e-3)
    dip = np.degrees(np.arcsin(np.sum(G * B, 1) / np.linalg.norm(G, axis=1) / np.linalg.norm(B, axis=1)))
    np.testing.assert_allclose(dip, ref.dip_deg, atol=1e-4)


def test_unknown_columns_and_keys_kept_with_notices():
    rec = io.read_recording(DATA / "extras.csv")
    assert rec.frame["operator"].tolist() == ["jd"] * 6
    assert rec.meta["rig"] == "bench A" and rec.meta["calibrated_by"] == "nobody"
    text = "\n".join(rec.notices)
    assert "unknown column(s) kept, not used: operator" in text
    assert "unknown metadata key(s) kept, not used: calibrated_by" in text
    # row 2's toolface column was set 30 deg off the toolface from G
    tf = [n for n in rec.notices if "toolface_deg" in n]
    assert len(tf) == 1 and "by up to 30 deg (row 2; 1 row(s)" in tf[0]
    assert rec.frame["toolface_deg"][1] == 120.0  # kept as given


# --------------------------------------------------- bad CSVs: one line each
@pytest.mark.parametrize(
    "name, expected",
    [
        ("bad_missing_column.csv", ["bad_missing_column.csv", "missing required column(s) bz"]),
        ("bad_nan.csv", ["bad_nan.csv", "row 3 (line 4)", "column 'bx'", "NaN"]),
        ("bad_empty_cell.csv", ["bad_empty_cell.csv", "row 5 (line 6)", "column 'gz'", "empty cell"]),
        ("bad_non_numeric.csv", ["bad_non_numeric.csv", "row 2 (line 3)", "column 'by'", "'93z8.998'"]),
        ("bad_b_in_uT.csv", ["bad_b_in_uT.csv", "all rows, columns 'bx', 'by', 'bz'", "uT given as nT: multiply by 1000"]),
        ("bad_b_in_gauss.csv", ["bad_b_in_gauss.csv", "all rows, columns 'bx', 'by', 'bz'", "Gauss given as nT"]),
        ("bad_g_in_ms2.csv", ["bad_g_in_ms2.csv", "all rows, columns 'gx', 'gy', 'gz'", "m/s^2: divide by 9.80665"]),
        ("bad_inclination.csv", ["bad_inclination.csv", "row 4 (line 5)", "column 'inclination_deg'",
                                 "190.0 deg outside [0, 180]"]),
        ("bad_inclination_negative.csv", ["row 6 (line 7)", "-2.0 deg outside [0, 180]"]),
        ("bad_empty.csv", ["bad_empty.csv", "empty file"]),
        ("bad_header_only.csv", ["bad_header_only.csv", "no data rows"]),
        ("bad_no_reference.csv", ["missing required columns azimuth_deg, inclination_deg", "'group'"]),
        ("bad_ragged.csv", ["bad_ragged.csv", "row 3 (line 4)", "11 fields, the header has 12"]),
        ("bad_station_not_integer.csv", ["row 4 (line 5)", "column 'station'", "4.5 is not an integer"]),
    ],
)
def test_bad_csv_gives_one_line(name, expected):
    msg = _one_line_error(io.read_recording, DATA / name)
    for piece in expected:
        assert piece in msg, (piece, msg)


def test_a_carriage_return_inside_a_field_is_one_line(tmp_path):
    """The csv module refuses a bare CR inside an unquoted field (here the header's): the fast reader leaves it to
    the exact one, which names the line (found by the long fuzz test)."""
    text = (DATA / "survey.csv").read_text()
    head, first, *rest = text.split("\n")
    path = tmp_path / "cr.csv"
    path.write_text("\n".join([head[:3] + "\r" + head[3:], first, *rest]), newline="")
    msg = _one_line_error(io.read_recording, path, require_meta=False)
    assert "cr.csv" in msg and "CSV syntax error at line" in msg


def test_cli_prints_only_the_line(capsys):
    assert io_cli.main(["check", str(DATA / "bad_nan.csv")]) == 1
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and "row 3 (line 4), column 'bx'" in err
    assert io_cli.main(["check", str(DATA / "extras.csv")]) == 0
    out, _ = capsys.readouterr()
    assert "ok, 6 rows" in out and "notice: " in out


# ---------------------------------------------------- bad metadata: one line each
def _survey_with_meta(tmp_path, meta_text):
    csv = _copy(tmp_path, "survey.csv")
    if meta_text is not None:
        (tmp_path / "survey.meta.json").write_text(meta_text)
    return csv


@pytest.mark.parametrize(
    "meta_text, expected",
    [
        (None, ["survey.meta.json", "metadata file not found"]),
        ("", ["survey.meta.json", "empty metadata file"]),
        ('{"total_field_nT": 48000,\n "dip_deg": }', ["survey.meta.json", "invalid JSON at line 2"]),
        ("[1, 2]", ["metadata must be a JSON object"]),
        ('{"total_field_nT": 48.0, "dip_deg": 65}', ["'total_field_nT'", "looks like uT: multiply by 1000"]),
        ('{"total_field_nT": 0.48, "dip_deg": 65}', ["'total_field_nT'", "looks like Gauss"]),
        ('{"total_field_nT": 48000}', ["'total_field_nT' given without 'dip_deg'"]),
        ('{"total_field_nT": NaN, "dip_deg": 65}', ["NaN is not allowed in metadata"]),
        ('{"total_field_nT": "48000", "dip_deg": 65}', ["'total_field_nT': expected a finite number"]),
        ('{"total_field_nT": 1' + "0" * 400 + ', "dip_deg": 65}', ["'total_field_nT': expected a finite number",
                                                                  "(401 characters)"]),
        ("[" * 100_000 + "]" * 100_000, ["metadata nested too deeply"]),
        ('{"total_field_nT": 48000, "dip_deg": 95}', ["'dip_deg': 95 outside [-90.0, 90.0] deg"]),
        ('{"total_field_nT": 48000, "dip_deg": 65, "gravity_g": 9.81}', ["'gravity_g'", "m/s^2"]),
        ('{"latitude": 51.5, "longitude": 0.0}', ["site given without date"]),
        ('{"latitude": 51.5, "longitude": 0.0, "date": "2024-13-01"}', ["'date'", "neither YYYY-MM-DD"]),
        ('{"latitude": 95, "longitude": 0.0, "date": 2024.5}', ["'latitude': 95 outside [-90.0, 90.0]"]),
        ('{"name": 7}', ["'name': expected a string"]),
    ],
)
def test_bad_metadata_gives_one_line(tmp_path, meta_text, expected):
    msg = _one_line_error(io.read_recording, _survey_with_meta(tmp_path, meta_text))
    for piece in expected:
        assert piece in msg, (piece, msg)


def test_missing_metadata_allowed_when_asked(tmp_path):
    rec = io.read_recording(_survey_with_meta(tmp_path, None), require_meta=False)
    assert rec.meta == {} and rec.field is None and "no metadata file" in rec.notices[0]


# ----------------------------------------------------- in-memory validation
def _frame(n=5, seed=0):
    rng = np.random.default_rng(seed)
    g = rng.normal(size=(n, 3))
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    b = rng.normal(size=(n, 3)) * 30_000.0
    return pd.DataFrame({
        "station": np.arange(n), "gx": g[:, 0], "gy": g[:, 1], "gz": g[:, 2],
        "bx": b[:, 0], "by": b[:, 1], "bz": b[:, 2],
        "azimuth_deg": rng.uniform(0, 360, n), "inclination_deg": rng.uniform(0, 180, n),
    })


def test_validate_names_row_and_column_for_in_memory_frames(tmp_path):
    f = _frame().astype({"bx": object})
    f.loc[1, "bx"] = "abc"
    msg = _one_line_error(io.write_recording, tmp_path / "x.csv", f, {})
    assert "x.csv (to write), row 2 (line 3), column 'bx': non-numeric value 'abc'" in msg
    assert not (tmp_path / "x.csv").exists() and not (tmp_path / "x.meta.json").exists()


def test_partial_gyro_and_gyro_units():
    f = _frame()
    f["wx"] = 1.0
    assert "wx, wy, wz together" in _one_line_error(io.validate, f)
    f["wy"], f["wz"] = 1e-5, 7e-5  # rad/s-sized earth rate
    f["wx"] = 2e-5
    assert "below the earth rate" in _one_line_error(io.validate, f)


def test_reference_column_alone_is_refused():
    f = _frame().drop(columns="azimuth_deg")
    assert "'inclination_deg' given without 'azimuth_deg'" in _one_line_error(io.validate, f)


# ------------------------------------------------------------- round trips
def test_round_trip_full_precision(tmp_path):
    rng = np.random.default_rng(7)
    f = _frame(50, seed=3)
    f["toolface_deg"] = np.asarray(io.Recording(f, {}, [], None, "").toolface_deg())
    f["group"] = np.repeat(np.arange(10), 5)
    f["time_s"] = np.cumsum(rng.uniform(0, 1, 50))
    f["wx"], f["wy"], f["wz"] = (rng.normal(size=(3, 50)) * 15.0)
    f["temperature_c"] = rng.uniform(-20, 150, 50)
    f["extra_note"] = ["a,b"] * 25 + ['quote "q"'] * 25  # unknown text column with CSV specials
    f["extra_num"] = rng.normal(size=50) * 1e-300
    meta = {"total_field_nT": 48123.456789012345, "dip_deg": 64.1234567890123,
            "declination_deg": -3.3, "gravity_g": 0.99987654321, "name": "rt", "custom": {"k": [1, 2]}}
    written = io.write_recording(tmp_path / "rt.csv", f, meta)
    back = io.read_recording(tmp_path / "rt.csv")
    pd.testing.assert_frame_equal(back.frame, written.frame, check_exact=True)
    for c in f.columns:  # the values given, bit for bit
        assert np.array_equal(back.frame[c].to_numpy(), f[c].to_numpy()), c
    assert back.meta == meta
    assert back.field == schema.ReferenceField(48123.456789012345, 64.1234567890123, -3.3, 0.99987654321, "metadata")
    assert any("extra_note, extra_num" in n for n in back.notices)


def test_round_trip_of_a_hand_written_file(tmp_path):
    rec = io.read_recording(DATA / "groups.csv")
    io.write_recording(tmp_path / "g.csv", rec.frame, rec.meta)
    back = io.read_recording(tmp_path / "g.csv")
    pd.testing.assert_frame_equal(back.frame, rec.frame, check_exact=True)
    assert back.meta == rec.meta and back.field == rec.field


# ------------------------------------------------------------------ atomic
def test_failed_write_leaves_existing_files_intact(tmp_path, monkeypatch):
    target = tmp_path / "s.csv"
    io.write_recording(target, _frame(4, seed=1), {"name": "old"})
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    assert sorted(before) == ["s.csv", "s.meta.json"]

    real_fsync, calls = os.fsync, []

    def failing_fsync(fd):  # the second temp file (metadata) hits a full disk
        calls.append(fd)
        if len(calls) == 2:
            raise OSError(28, "No space left on device")
        return real_fsync(fd)

    monkeypatch.setattr(io.os, "fsync", failing_fsync)
    with pytest.raises(OSError, match="No space left"):
        io.write_recording(target, _frame(9, seed=2), {"name": "new"})
    assert len(calls) == 2  # the new CSV was fully written to its temp file before the failure
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before  # no temp left, nothing changed
    monkeypatch.undo()

    # a frame that breaks the contract writes nothing either
    bad = _frame(4, seed=5)
    bad.loc[2, "inclination_deg"] = 181.0
    _one_line_error(io.write_recording, target, bad, {"name": "bad"})
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before

    # a successful overwrite replaces both and leaves no temp files
    io.write_recording(target, _frame(9, seed=2), {"name": "new"})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.csv", "s.meta.json"]
    assert json.loads((tmp_path / "s.meta.json").read_text()) == {"name": "new"}
    assert len(io.read_recording(target).frame) == 9


# ------------------------------------------------- real devices (mag_cal 1.4.1)
def test_mag_cal_devices_load_with_the_expected_picture():
    names = mag_cal_bundled.mag_cal_devices()
    assert names == ["ab", "ai", "bh", "bi", "ee", "fb", "hj", "hj2", "jd"]
    for name in names:
        rec = mag_cal_bundled.load_mag_cal_device(name)
        f = rec.frame
        assert len(f) == 24 and f["station"].tolist() == list(range(24)) and not rec.has_reference
        assert f["group"].tolist() == list(range(8)) + [8] * 8 + [9] * 8
        assert rec.field is None and rec.notices == []
        g = np.linalg.norm(rec.G, axis=1)
        assert np.all((g > 0.9) & (g < 1.1)) and abs(np.median(g) - 1.0) < 0.03, (name, g)
        b = np.linalg.norm(rec.B, axis=1)
        assert b.max() / b.min() > 2.0 and b.std() / b.mean() > 0.2, (name, b)
        # ... and the spread is hard iron: a sphere fit (centre c) leaves |B - c| within a few %
        A = np.c_[2.0 * rec.B, np.ones(24)]
        c = np.linalg.lstsq(A, np.sum(rec.B**2, 1), rcond=None)[0][:3]
        r = np.linalg.norm(rec.B - c, axis=1)
        assert r.std() / r.mean() < 0.02 and np.linalg.norm(c) > 10_000.0, name
        # rolled runs: one pointing direction (inclination within a few deg), toolface all round
        for gid in (8, 9):
            att = attitude_from_sensors(rec.G[f["group"] == gid], rec.B[f["group"] == gid])
            assert np.ptp(np.asarray(att.inclination)) < 10.0
            tf = np.sort(np.asarray(att.toolface))
            assert np.max(np.diff(np.r_[tf, tf[0] + 360.0])) < 90.0  # no gap of a quarter turn


def test_mag_cal_converter_matches_the_package_side_by_side():
    """Same numbers as mag_cal's own read_fixture, and the same angles as its get_angles."""
    from mag_cal.calibration import Calibration
    from mag_cal.utils import read_fixture

    from icgo.studies.calibration.peer import peer_numpy

    perm = list(mag_cal_bundled.MAG_CAL_DEVICE_TO_TOOL)
    for name in mag_cal_bundled.mag_cal_devices():
        text = (Path(io.__file__).parents[1] / "data" / "mag_cal" / f"{name}.json").read_text()
        aligned, grav, mag = read_fixture(text)
        rec = mag_cal_bundled.load_mag_cal_device(name)
        assert np.array_equal(rec.G, grav[:, perm]) and np.array_equal(rec.B, 1000.0 * mag[:, perm])
        for gid, (m, g) in zip((8, 9), aligned):
            assert np.array_equal(rec.B[rec.frame["group"] == gid], 1000.0 * m[:, perm])
        with peer_numpy():  # numpy >= 2.5's complex eig, as the calibrate door runs the peer
            cal = Calibration()
            cal.fit_ellipsoid(mag, grav)
            az, inc, roll = cal.get_angles(mag, grav)  # device frame, its own conventions
        att = attitude_from_sensors(cal.grav.apply(grav)[:, perm], cal.mag.apply(mag)[:, perm])
        np.testing.assert_allclose(np.asarray(angle_diff(att.azimuth, az)), 0.0, atol=1e-9)
        np.testing.assert_allclose(np.asarray(att.inclination) - 90.0, inc, atol=1e-9)  # mag_cal: up positive
        np.testing.assert_allclose(np.asarray(angle_diff(att.toolface, roll)), 0.0, atol=1e-9)


def test_mag_cal_unknown_device_and_export(tmp_path, capsys):
    assert "unknown device 'zz'" in _one_line_error(mag_cal_bundled.load_mag_cal_device, "zz")
    assert io_cli.main(["export-mag-cal", str(tmp_path)]) == 0
    files = sorted(p.name for p in tmp_path.glob("*.csv"))
    assert files == [f"mag_cal_{n}.csv" for n in mag_cal_bundled.mag_cal_devices()]
    back = io.read_recording(tmp_path / "mag_cal_hj2.csv")
    pd.testing.assert_frame_equal(back.frame, mag_cal_bundled.load_mag_cal_device("hj2").frame, check_exact=True)
    assert back.meta["license"].startswith("MIT") and back.field is None


def test_mag_cal_files_are_package_data_with_licence():
    from importlib import resources

    d = resources.files("icgo").joinpath("data").joinpath("mag_cal")
    assert "Permission is hereby granted" in d.joinpath("LICENSE").read_text()
    assert "Phil Underwood" in d.joinpath("LICENSE").read_text()


def test_a_pipe_or_device_is_refused_at_once(tmp_path):
    import os

    fifo = tmp_path / "fifo.csv"
    os.mkfifo(fifo)
    for p in (fifo, "/dev/zero", tmp_path):
        with pytest.raises(DataError, match="not a regular file") as e:
            io.read_recording(p)
        assert "\n" not in str(e.value)


def test_plain_files_take_the_fast_reader_and_read_as_the_exact_one():
    """A plain contract CSV is parsed by pandas' C parser (no Python object per cell) with the same
    frame, dtypes and notices as the csv-module reader; quoted text is left to the exact reader."""
    for name in ("survey.csv", "extras.csv", "groups.csv", "handwritten_axial.csv"):
        text = (DATA / name).read_text(encoding="utf-8-sig")
        notes_fast, notes_exact = [], []
        fast = csv_text._read_fast(text, name, notes_fast, True)
        exact = csv_text._read_exact(text, name, notes_exact, True)
        assert fast is not None, name
        pd.testing.assert_frame_equal(fast, exact, check_exact=True)
        assert notes_fast == notes_exact
    assert csv_text._read_fast(text.replace("\n", '\n""\n', 1), "q.csv", [], True) is None


# ------------------------------------------- values a reader used to accept silently (issue 19)
def _survey_with(tmp_path, edit, name="s.csv"):
    """survey.csv (+ its metadata) with ``edit(lines) -> lines`` applied to its text lines."""
    lines = (DATA / "survey.csv").read_text().splitlines()
    path = tmp_path / name
    path.write_text("\n".join(edit(lines)) + "\n")
    shutil.copy(DATA / "survey.meta.json", tmp_path / name.replace(".csv", ".meta.json"))
    return path


def _cell(lines, row, col, value):
    cells = lines[row].split(",")
    cells[col] = value
    return lines[:row] + [",".join(cells)] + lines[row + 1:]


@pytest.mark.parametrize("row, col, value, expect", [
    (3, 0, "1e300", "row 3 (line 4), column 'station': 1e+300 is too large for an id (at most 9,007,199,254,740,992 "
                    "in magnitude)"),
    (2, 7, "1e300", "row 2 (line 3), column 'azimuth_deg': 1e+300 deg outside [-360, 720]"),
    (2, 9, "-400", "row 2 (line 3), column 'toolface_deg': -400.0 deg outside [-360, 720]"),
    (4, 4, "1_000_000", "row 4 (line 5), column 'bx': non-numeric value '1_000_000'"),
])
def test_values_out_of_their_domain_are_one_line(tmp_path, row, col, value, expect):
    path = _survey_with(tmp_path, lambda ls: _cell(ls, row, col, value))
    assert _one_line_error(io.read_recording, path) == f"{path}, {expect}"


def test_rows_in_other_units_are_named(tmp_path):
    def half_in_uT(lines):
        out = lines[:1]
        for i, ln in enumerate(lines[1:]):
            c = ln.split(",")
            if i % 2:
                c[4:7] = [repr(float(v) / 1000) for v in c[4:7]]
            out.append(",".join(c))
        return out

    path = _survey_with(tmp_path, half_in_uT)
    msg = _one_line_error(io.read_recording, path)
    assert msg.startswith(f"{path}, row 2 (line 3), columns 'bx', 'by', 'bz': |B| = 48 while the median is ")
    assert msg.endswith("nT (3 row(s) more than 10x off: rows in other units?)")


def test_a_file_without_its_last_newline_gets_a_notice(tmp_path):
    path = tmp_path / "cut.csv"
    path.write_text((DATA / "survey.csv").read_text().rstrip("\n")[:-2])  # the last value cut short
    shutil.copy(DATA / "survey.meta.json", tmp_path / "cut.meta.json")
    rec = io.read_recording(path)
    assert f"{path}: the file does not end with a newline; check that its last row (row 6) is complete" in rec.notices


@pytest.mark.parametrize("date, notice", [("2099-01-01", True), (1901.5, True), ("2024-06-01", False)])
def test_a_field_model_date_outside_its_years_gets_a_notice(tmp_path, date, notice):
    shutil.copy(DATA / "groups.csv", tmp_path / "g.csv")
    meta = json.loads((DATA / "groups.meta.json").read_text()) | {"date": date}
    (tmp_path / "g.meta.json").write_text(json.dumps(meta))
    rec = io.read_recording(tmp_path / "g.csv")
    said = [n for n in rec.notices if "outside the field model's years (2020-2030" in n]
    assert bool(said) == notice, rec.notices
