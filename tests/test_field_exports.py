"""Field exports through the contract reader (icgo.io.columns): names, a column map, comments, a units row."""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from icgo.core.errors import DataError, SettingError
from icgo.io import schema
from icgo.io import columns as export
from icgo.io import recording as io

DATA = Path(__file__).parent / "data"
CONF = Path(__file__).resolve().parent.parent / "conf"


@pytest.fixture
def survey():
    """The contract's own survey (tests/data/survey.csv): the reference every export must read back as."""
    return io.read_recording(DATA / "survey.csv")


def _write(tmp_path: Path, name: str, text: str) -> Path:
    p = tmp_path / name
    p.write_text(text)
    shutil.copy(DATA / "survey.meta.json", tmp_path / (p.stem + ".meta.json"))
    return p


def _export(frame: pd.DataFrame, names: dict, scale: dict | None = None, units_row: dict | None = None,
            preamble: str = "", every: str = "") -> str:
    """A field export of ``frame``: renamed columns, values scaled, an optional units row, comment lines."""
    f = frame[[c for c in names]].copy()
    for c, k in (scale or {}).items():
        f[c] = f[c] * k
    f.columns = [names[c] for c in names]
    body = f.to_csv(index=False, lineterminator="\n", float_format="%.17g").splitlines()
    lines = [body[0]]
    if units_row is not None:
        lines.append(",".join(units_row.get(c, "") for c in names))
    for row in body[1:]:
        lines.append(row)
        if every:
            lines.append(every)
    return preamble + "\n".join(lines) + "\n"


SENSORS = ["station", "gx", "gy", "gz", "bx", "by", "bz", "azimuth_deg", "inclination_deg"]


def test_mixed_case_names_comments_and_a_units_row_read_as_the_contract_file(tmp_path, survey):
    names = {c: c.upper() if c[0] in "gb" else c.title() for c in SENSORS}
    units = {"gx": "m/s^2", "gy": "m/s^2", "gz": "m/s^2", "bx": "uT", "by": "[uT]", "bz": "µT",
             "azimuth_deg": "rad", "inclination_deg": "deg"}
    scale = ({c: 1 / schema.STANDARD_GRAVITY ** -1 for c in ("gx", "gy", "gz")} | {c: 1e-3 for c in ("bx", "by", "bz")}
             | {"azimuth_deg": math.pi / 180})
    text = _export(survey.frame, names, scale, units, preamble="# rig 7 export\n#, , , ,\n", every="# checked")
    rec = io.read_recording(_write(tmp_path, "field.csv", text))
    for c in SENSORS:
        np.testing.assert_allclose(rec.frame[c], survey.frame[c], rtol=1e-12, atol=1e-9, err_msg=c)
    notes = "\n".join(rec.notices)
    assert "line 4 read as the units row" in notes
    assert "'GX' -> gx" in notes and "'Azimuth_Deg' -> azimuth_deg" in notes
    assert "bx uT -> nT (x1000); by [uT] -> nT" in notes and "azimuth_deg rad -> deg" in notes


def test_a_column_map_from_settings_and_from_a_file(tmp_path, survey):
    names = dict(zip(SENSORS, ["Stn", "Accel X", "Accel Y", "Accel Z", "Mag X", "Mag Y", "Mag Z", "Azi", "Inc"]))
    p = _write(tmp_path, "mapped.csv", _export(survey.frame, names))
    with pytest.raises(DataError, match=r"found 'Accel X': use columns.gx='Accel X'.*found `Inc`: use "
                                        r"columns.inclination_deg=Inc|found `Stn`: use columns.station=Stn"):
        io.read_recording(p)
    cmap = {c: n for c, n in names.items()}
    rec = io.read_recording(p, columns=cmap)
    pd.testing.assert_frame_equal(rec.frame[SENSORS], survey.frame[SENSORS])
    (tmp_path / "map.yaml").write_text(yaml.safe_dump({"columns": cmap}))
    (tmp_path / "map.json").write_text(json.dumps({k: v for k, v in cmap.items() if k != "station"}))
    for f in ("map.yaml", "map.json"):
        m = io.column_map({"station": "Stn"}, tmp_path / f)
        assert m == cmap
        pd.testing.assert_frame_equal(io.read_recording(p, columns=m).frame[SENSORS], survey.frame[SENSORS])


def test_column_map_errors_name_the_setting(tmp_path, survey):
    p = _write(tmp_path, "s.csv", _export(survey.frame, {c: c for c in SENSORS}))
    with pytest.raises(SettingError, match=r"columns.gxx is not a contract column"):
        io.read_recording(p, columns={"gxx": "G"})
    with pytest.raises(DataError, match=r"columns.gx='Gravity X': the header has no such column"):
        io.read_recording(p, columns={"gx": "Gravity X"})
    with pytest.raises(SettingError, match=r"columns_file '.*none.json': file not found"):
        io.column_map(None, tmp_path / "none.json")
    (tmp_path / "bad.json").write_text("{gx: 1")
    with pytest.raises(SettingError, match=r"not valid JSON"):
        io.column_map(None, tmp_path / "bad.json")
    # two export columns for one contract column
    q = _write(tmp_path, "two.csv", _export(survey.frame, {c: c for c in SENSORS}).replace("station,gx", "station,Gx")
               .replace("inclination_deg\n", "inclination_deg\n", 1))
    text = q.read_text().splitlines()
    text[0] += ",GX"
    q.write_text("\n".join([text[0]] + [r + ",1" for r in text[1:]]) + "\n")
    with pytest.raises(DataError, match=r"columns 'Gx' and 'GX' both read as the contract column 'gx'"):
        io.read_recording(q)


def test_units_row_errors_and_what_stays_strict(tmp_path, survey):
    names = {c: c for c in SENSORS}
    bad = _export(survey.frame, names, units_row={"bx": "furlong", "by": "uT", "bz": "uT", "gx": "g"})
    with pytest.raises(DataError, match=r"line 2 looks like a units row, but 'furlong' is not a unit of magnetic field "
                                        r"\(column 'bx'; accepted: nT, uT, G, mG"):
        io.read_recording(_write(tmp_path, "u1.csv", bad))
    wrong_kind = _export(survey.frame, names, units_row={"gx": "deg"})
    with pytest.raises(DataError, match=r"'deg' is not a unit of gravity"):
        io.read_recording(_write(tmp_path, "u2.csv", wrong_kind))
    # the field in uT without a units row is still refused, now with the way out named
    in_ut = _export(survey.frame, names, scale={c: 1e-3 for c in ("bx", "by", "bz")})
    with pytest.raises(DataError, match=r"looks like uT given as nT: multiply by 1000; or give the unit in a units row"):
        io.read_recording(_write(tmp_path, "u3.csv", in_ut))
    # a bracketed unit in the header converts too, and disagrees with a units row in one line
    br = _export(survey.frame, names | {"bx": "bx (uT)", "by": "by (uT)", "bz": "bz (uT)"},
                 scale={c: 1e-3 for c in ("bx", "by", "bz")})
    rec = io.read_recording(_write(tmp_path, "u4.csv", br))
    np.testing.assert_allclose(rec.B, survey.B, rtol=1e-12)
    both = _export(survey.frame, names | {"bx": "bx (uT)"}, scale={"bx": 1e-3}, units_row={"bx": "nT"})
    with pytest.raises(DataError, match=r"column 'bx': the header says 'uT', the units row \(line 2\) 'nT'"):
        io.read_recording(_write(tmp_path, "u5.csv", both))


def test_comment_lines_keep_the_file_line_numbers(tmp_path, survey):
    text = _export(survey.frame, {c: c for c in SENSORS}, preamble="# a, b, c, d, e, f, g, h, i, j, k, l, m, n\n",
                   every="# note, with, commas")
    lines = text.splitlines()
    assert lines[5].startswith("#")
    lines[6] = lines[6].rsplit(",", 1)[0]  # row 3 loses a field; it is line 7 of the file
    p = _write(tmp_path, "c.csv", "\n".join(lines) + "\n")
    with pytest.raises(DataError, match=r"row 3 \(line 7\): 8 fields, the header has 9"):
        io.read_recording(p)
    lines[6] = lines[6] + ",abc"
    p.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=r"row 3 \(line 7\), column 'inclination_deg': non-numeric value 'abc'"):
        io.read_recording(p)
    only = _write(tmp_path, "only.csv", "# nothing\n# here\n")
    with pytest.raises(DataError, match=r"only comment lines"):
        io.read_recording(only)


@pytest.mark.parametrize("unit,factor,column", [("G", 1e-5, "bx"), ("mG", 1e-2, "bx"), ("nT", 1.0, "bx"),
                                                ("T", 1e-9, "bx"), ("mg", 1e3, "gx"), ("ft/s^2", 1 / 0.3048 * 9.80665,
                                                                                       "gx")])
def test_every_named_unit_converts_back_exactly(tmp_path, survey, unit, factor, column):
    triple = [column[0] + a for a in "xyz"]
    text = _export(survey.frame, {c: c for c in SENSORS}, {c: factor for c in triple}, {c: unit for c in triple})
    rec = io.read_recording(_write(tmp_path, "x.csv", text))
    np.testing.assert_allclose(rec.frame[triple], survey.frame[triple], rtol=1e-12, atol=1e-12)


def test_measured_depth_in_feet_and_depth_m_alias(tmp_path, survey):
    f = survey.frame[SENSORS].assign(MD=np.arange(len(survey.frame)) * 100.0)
    text = f.to_csv(index=False, lineterminator="\n").splitlines()
    text.insert(1, ",,,,,,,,,ft")
    rec = io.read_recording(_write(tmp_path, "md.csv", "\n".join(text) + "\n"))
    np.testing.assert_allclose(rec.frame["md"], np.arange(len(f)) * 30.48)
    g = survey.frame[SENSORS].assign(depth_m=np.arange(len(survey.frame)) * 10.0)
    rec = io.read_recording(_write(tmp_path, "dm.csv", g.to_csv(index=False)))
    assert "md" in rec.frame.columns and rec.frame["md"].iloc[-1] == 10.0 * (len(g) - 1)


def test_temperature_offsets_and_unit_tokens():
    assert export.unit_token(" [m/s^2] ") == "m/s^2" and export.unit_token("(μT)") == "µt"
    conv = export.conversions({"temperature_c": "k", "bx": "nt", "wx": "rad/s"})
    scale, offset, _ = conv["temperature_c"]
    assert scale * 300.0 + offset == pytest.approx(26.85)
    assert "bx" not in conv and conv["wx"][0] == pytest.approx(3600 * 180 / math.pi)


def test_hydra_configs_list_every_contract_column():
    for path, node in ((CONF / "dataset" / "csv.yaml", None), (CONF / "apply" / "apply.yaml", None),
                       (CONF / "discrepancy.yaml", None)):
        cfg = yaml.safe_load(path.read_text())
        assert list(cfg["columns"]) == list(schema.KNOWN_COLUMNS), path
        assert all(v is None for v in cfg["columns"].values()) and cfg["columns_file"] is None
