"""circuitpython-mag-cal JSON layouts (icgo.io.mag_cal_json) against the peer's own reader and axes; the instrument's
layout first, checked against the data (icgo.models.grouping, icgo.studies.common.shots)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from mag_cal.axes import Axes
from mag_cal.utils import read_fixture

from icgo.core.errors import DataError, SettingError
from icgo.io import mag_cal_bundled, schema
from icgo.io import __main__ as io_cli
from icgo.io.mag_cal_json import parse_axes
from icgo.io.mag_cal_json import read_mag_cal_json as read_file
from icgo.studies.common.shots import read_shots


def read_mag_cal_json(path, **kw):
    """The recording as read (its layout's groups or groups given), before any search of the data."""
    return read_file(path, **kw).recording

FIXTURE = mag_cal_bundled._mag_cal_dir().joinpath("ab.json")
INV = np.argsort(mag_cal_bundled.MAG_CAL_DEVICE_TO_TOOL)  # tool -> device columns


def test_fixture_layout_is_the_peers_reading_in_the_tool_frame():
    rec = read_mag_cal_json(FIXTURE)
    _, grav, mag = read_fixture(FIXTURE.read_text())
    np.testing.assert_array_equal(rec.G[:, INV], grav)
    np.testing.assert_allclose(rec.B[:, INV], mag * 1000.0, rtol=1e-15)
    assert rec.frame.group.tolist() == mag_cal_bundled.load_mag_cal_device("ab").frame.group.tolist()


@pytest.mark.parametrize("mag_axes,grav_axes", [("+x+y-z", "-y-x+z"), ("-Z+X-Y", None)])
def test_raw_layout_converts_axes_and_units_as_the_peer(tmp_path, mag_axes, grav_axes):
    dev = mag_cal_bundled.load_mag_cal_device("bh")
    g_dev, b_dev_ut = dev.G[:, INV], dev.B[:, INV] / 1000.0  # device frame, g and uT
    ga = grav_axes or mag_axes

    def to_sensor(v, axes):  # the inverse of mag_cal's Axes.fix_axes
        idx, sign = parse_axes(axes, "axes")
        out = np.empty_like(v)
        out[:, idx] = v * np.asarray(sign)
        return out

    mag_s, grav_s = to_sensor(b_dev_ut, mag_axes), to_sensor(g_dev, ga) * schema.STANDARD_GRAVITY
    # the peer maps our sensor data back to the device frame
    np.testing.assert_allclose(Axes(mag_axes.upper()).fix_axes(mag_s), b_dev_ut, rtol=1e-14)
    doc = {"mag": mag_s.tolist(), "grav": grav_s.tolist()}
    path = tmp_path / "raw.json"
    path.write_text(json.dumps(doc))
    rec = read_mag_cal_json(path, mag_axes=mag_axes, grav_axes=grav_axes)
    np.testing.assert_allclose(rec.B, dev.B, rtol=1e-12)
    np.testing.assert_allclose(rec.G, dev.G, rtol=1e-12, atol=1e-15)
    assert rec.frame.group.tolist() == dev.frame.group.tolist()  # the layout's
    assert "m/s^2 / 9.80665 -> g" in rec.meta["description"]
    # the strings may also come from the file itself
    path.write_text(json.dumps({**doc, "mag_axes": mag_axes, **({"grav_axes": grav_axes} if grav_axes else {})}))
    np.testing.assert_array_equal(read_mag_cal_json(path).B, rec.B)


@pytest.mark.parametrize("doc,kw,match", [
    ({"shots": {"mag": [1.0] * 72}}, {}, "expected a circuitpython-mag-cal JSON"),
    ({"shots": {"mag": ["a"] + [1.0] * 71, "grav": [1.0] * 72}}, {}, "'shots.mag' value 0 is not a finite number"),
    ({"mag": [[1, 2, 3]], "grav": [[0, 0, 9.8]], "mag_axes": "+x+x+z"}, {}, "the file's mag_axes '\\+x\\+x\\+z'.*each axis once"),
    ({"mag": [[1, 2, 3]], "grav": [[0, 0, 9.8]], "grav_axes": "xyz"}, {}, "the file's grav_axes 'xyz': expected 6 characters"),
    ({"mag": [[1, 2, 3]], "grav": [[0, 0, 9.8], [0, 0, 9.8]]}, {}, "one of each per shot"),
    ({"mag": [[1, 2, "a"]], "grav": [[0, 0, 9.8]]}, {}, r"'mag\[0\]' must be \[x, y, z\]"),
    ({"mag": [[30, 20, 10]], "grav": [[0, 0, 3.0]]}, {}, "neither g"),
    ({"mag": [[30000, 20000, 10000]], "grav": [[0, 0, 1.0]]}, {}, "expected the earth's field in uT.*looks like nT"),
    ({"shots": {"mag": [0.3, 0.2, 0.1] * 24, "grav": [0, 0, 1.0] * 24}}, {}, "looks like Gauss: multiply by 100"),
])
def test_bad_files_are_one_line(tmp_path, doc, kw, match):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(DataError, match=match) as e:
        read_mag_cal_json(path, **kw)
    assert "\n" not in str(e.value) and str(path) in str(e.value)


def test_fixture_layout_refuses_axes_and_check_reads_json(tmp_path, capsys):
    with pytest.raises(SettingError, match="device frame already"):
        read_mag_cal_json(FIXTURE, mag_axes="+x+y+z")
    assert io_cli.main(["check", str(FIXTURE)]) == 0
    assert "24 shots, 10 groups" in capsys.readouterr().out
    (tmp_path / "x.json").write_text("{}")
    assert io_cli.main(["check", str(tmp_path / "x.json")]) == 1
    assert "expected a circuitpython-mag-cal JSON" in capsys.readouterr().err


# ----------------------------------------------- real-looking files made from the bundled devices
from mag_cal_files import device_attitudes, join, roll, singles, synth, write_fixture, write_raw  # noqa: E402

MOUNT = ("-y+x+z", "+z-x-y")  # a mounting in which no sensor axis is a device axis of the same name


def _device(name="jd"):
    A, I, T = device_attitudes(name)
    return synth(name, A, I, T)


@pytest.mark.parametrize("keep", [slice(0, 16), slice(None)])
def test_fixture_files_in_the_layout_are_grouped_by_it_and_the_data_agree(tmp_path, keep):
    G, B = _device()
    path = tmp_path / "dev.json"
    write_fixture(path, G[keep], B[keep])
    n = len(G[keep])
    expect = list(range(8)) + [8] * 8 + ([9] * 8 if n == 24 else [])
    assert read_mag_cal_json(path).frame.group.tolist() == expect
    rec = read_shots(path)
    assert rec.frame.group.tolist() == expect
    g = rec.meta["grouping"]
    assert g["origin"] == "layout" and g["data_suggest"] is None and g["disagreements"] == []
    assert "8 single shots, then rolls of 8" in rec.meta["description"]


def test_a_count_outside_the_layout_has_its_rolls_found_from_the_data(tmp_path, capsys):
    G, B = _device()
    path = tmp_path / "dev.json"
    write_fixture(path, G[:20], B[:20])  # 8 singles, one roll, 4 shots of a second: no known layout
    assert "group" not in read_mag_cal_json(path).frame.columns
    rec = read_shots(path)
    assert rec.meta["grouping"]["origin"] == "data" and rec.meta["grouping"]["layout"] is None
    assert rec.frame.group.tolist()[8:16] == [rec.frame.group.iloc[8]] * 8
    assert "no known layout (20 shots is not 8 + 8 k)" in rec.meta["description"]
    # python -m icgo.io never searches: it reads the file, says so, and converts it without a group column
    assert io_cli.main(["check", str(path)]) == 0 and "not grouped here" in capsys.readouterr().out
    out = tmp_path / "dev.csv"
    assert io_cli.main(["convert", str(path), "--out", str(out)]) == 0
    assert "groups=auto finds the rolls" in capsys.readouterr().out
    assert read_shots(out, groups="auto").frame.group.tolist() == rec.frame.group.tolist()


def test_the_layout_is_used_where_the_data_disagree_and_both_groupings_are_named(tmp_path):
    # one roll first, then the singles: 16 shots, so the layout says singles 0-7 and a roll 8-15
    name = "hj"
    A, I, T = device_attitudes(name)
    G, B = synth(name, *join(roll(A[8:16].mean(), I[8:16].mean()), singles(name)))
    path = tmp_path / "one_roll.json"
    write_fixture(path, G, B)
    rec = read_shots(path)
    assert rec.frame.group.tolist() == list(range(8)) + [8] * 8  # the layout, used
    g = rec.meta["grouping"]
    assert g["used"] == "rolls at shots 8-15" and g["data_suggest"] == "rolls at shots 0-7"
    assert len(g["disagreements"]) == 1 and g["disagreements"][0].startswith("group 8 (shots 8-15) is not a plausible roll")
    assert any("the data suggest rolls at shots 0-7 (the layout: rolls at shots 8-15)" in n for n in rec.notices)
    # groups=auto takes the data's, and names the layout's
    auto = read_shots(path, groups="auto")
    assert auto.frame.group.tolist() == [8] * 8 + list(range(8))
    assert auto.meta["grouping"]["layout_grouping"] == "rolls at shots 8-15"


def test_raw_layout_mounting_from_keys_or_settings_and_the_cause_when_missing(tmp_path, capsys):
    G, B = _device("ab")
    with_keys, without = tmp_path / "keys.json", tmp_path / "nokeys.json"
    write_raw(with_keys, G, B, *MOUNT)
    write_raw(without, G, B, *MOUNT, keys=False)
    rec = read_mag_cal_json(with_keys)
    np.testing.assert_allclose(rec.G, G, atol=1e-12)
    np.testing.assert_allclose(rec.B, B, rtol=1e-12)
    assert rec.frame.group.tolist() == list(range(8)) + [8] * 8 + [9] * 8
    np.testing.assert_array_equal(read_mag_cal_json(without, mag_axes=MOUNT[0], grav_axes=MOUNT[1]).B, rec.B)
    with pytest.raises(DataError, match="deg or more from the pointing axis.*probable cause: the mounting is not "
                                           "given") as e:
        read_mag_cal_json(without)
    assert "\n" not in str(e.value)
    # the command line: the same settings, the same refusal (exit 1), a bad setting exit 2 naming itself
    assert io_cli.main(["check", str(without)]) == 1
    assert "mounting is not given" in capsys.readouterr().err
    assert io_cli.main(["check", str(without), f"mag_axes={MOUNT[0]}", f"grav_axes={MOUNT[1]}"]) == 0
    out = capsys.readouterr().out
    assert "roll: group 8, shots 8-15 (8)" in out and "roll: group 9, shots 16-23 (8)" in out
    assert io_cli.main(["check", str(without), "mag_axes=+x+y-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: mag_axes '+x+y-q'") and "grav_axes" not in err and len(err.splitlines()) == 1
    assert io_cli.main(["check", str(without), "mag_axis=+x+y+z"]) == 2
    assert "unknown setting 'mag_axis'" in capsys.readouterr().err


def test_convert_writes_the_contract_and_every_reader_sees_the_same_groups(tmp_path, capsys):
    G, B = _device("fb")
    src = tmp_path / "raw.json"
    write_raw(src, G, B, *MOUNT, keys=False)
    out = tmp_path / "out" / "fb.csv"
    out.parent.mkdir()
    assert io_cli.main(["convert", str(src), "--out", str(out), f"mag_axes={MOUNT[0]}", f"grav_axes={MOUNT[1]}"]) == 0
    assert "wrote" in capsys.readouterr().out
    back = read_shots(out)
    ref = read_shots(src, mag_axes=MOUNT[0], grav_axes=MOUNT[1])
    pd.testing.assert_frame_equal(back.frame, ref.frame)
    assert back.meta["grouping"]["origin"] == "column" and ref.meta["grouping"]["origin"] == "layout"
    assert back.meta["description"] == ref.meta["description"]
    assert io_cli.main(["check", str(out), "groups=column"]) == 0
    # bad uses: no --out, the input itself, not a CSV; nothing written
    for args in (["convert", str(src)], ["convert", str(src), "--out", str(src)],
                 ["convert", str(src), "--out", str(tmp_path / "x.txt")]):
        assert io_cli.main(args) == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "raw.json"]


def test_groups_setting_on_a_json_gives_the_rolls_and_checks_them(tmp_path):
    G, B = _device("bi")
    path = tmp_path / "bi.json"
    write_fixture(path, G, B)
    assert read_mag_cal_json(path, groups=((8, 15), (16, 23))).frame.group.tolist() == (
        read_mag_cal_json(path).frame.group.tolist())
    with pytest.raises(DataError, match=r"group 8 \(shots 8-23\) is not a plausible roll"):
        read_mag_cal_json(path, groups=((8, 23),))
