"""circuitpython-mag-cal JSON layouts (icgo.io.mag_cal_json) against the peer's own reader and axes."""

from __future__ import annotations

import json

import numpy as np
import pytest
from mag_cal.axes import Axes
from mag_cal.utils import read_fixture

from icgo.io import __main__ as io_cli
from icgo.io import recording as io
from icgo.io.mag_cal_json import parse_axes, read_mag_cal_json, roll_groups

FIXTURE = io._mag_cal_dir().joinpath("ab.json")
INV = np.argsort(io.MAG_CAL_DEVICE_TO_TOOL)  # tool -> device columns


def test_fixture_layout_is_the_peers_reading_in_the_tool_frame():
    rec = read_mag_cal_json(FIXTURE)
    _, grav, mag = read_fixture(FIXTURE.read_text())
    np.testing.assert_array_equal(rec.G[:, INV], grav)
    np.testing.assert_allclose(rec.B[:, INV], mag * 1000.0, rtol=1e-15)
    assert rec.frame.group.tolist() == io.load_mag_cal_device("ab").frame.group.tolist()


@pytest.mark.parametrize("mag_axes,grav_axes", [("+x+y-z", "-y-x+z"), ("-Z+X-Y", None)])
def test_raw_layout_converts_axes_and_units_as_the_peer(tmp_path, mag_axes, grav_axes):
    dev = io.load_mag_cal_device("bh")
    g_dev, b_dev_ut = dev.G[:, INV], dev.B[:, INV] / 1000.0  # device frame, g and uT
    ga = grav_axes or mag_axes

    def to_sensor(v, axes):  # the inverse of mag_cal's Axes.fix_axes
        idx, sign = parse_axes(axes, "axes")
        out = np.empty_like(v)
        out[:, idx] = v * np.asarray(sign)
        return out

    mag_s, grav_s = to_sensor(b_dev_ut, mag_axes), to_sensor(g_dev, ga) * io.STANDARD_GRAVITY
    # the peer maps our sensor data back to the device frame
    np.testing.assert_allclose(Axes(mag_axes.upper()).fix_axes(mag_s), b_dev_ut, rtol=1e-14)
    doc = {"mag": mag_s.tolist(), "grav": grav_s.tolist()}
    path = tmp_path / "raw.json"
    path.write_text(json.dumps(doc))
    rec = read_mag_cal_json(path, mag_axes=mag_axes, grav_axes=grav_axes)
    np.testing.assert_allclose(rec.B, dev.B, rtol=1e-12)
    np.testing.assert_allclose(rec.G, dev.G, rtol=1e-12, atol=1e-15)
    assert rec.frame.group.tolist() == dev.frame.group.tolist()  # the rolls are found from the data
    assert "m/s^2 / 9.80665 -> g" in rec.meta["description"]
    # the strings may also come from the file itself
    path.write_text(json.dumps({**doc, "mag_axes": mag_axes, **({"grav_axes": grav_axes} if grav_axes else {})}))
    np.testing.assert_array_equal(read_mag_cal_json(path).B, rec.B)


def test_roll_groups_find_both_rolls_on_every_bundled_device():
    for name in io.mag_cal_devices():
        rec = io.load_mag_cal_device(name)
        assert roll_groups(rec.G, rec.B).tolist() == rec.frame.group.tolist(), name


@pytest.mark.parametrize("doc,kw,match", [
    ({"shots": {"mag": [1.0] * 72}}, {}, "expected a circuitpython-mag-cal JSON"),
    ({"shots": {"mag": ["a"] + [1.0] * 71, "grav": [1.0] * 72}}, {}, "'shots.mag' value 0 is not a finite number"),
    ({"mag": [[1, 2, 3]], "grav": [[0, 0, 9.8]]}, {"mag_axes": "+x+x+z"}, "each axis once"),
    ({"mag": [[1, 2, 3]], "grav": [[0, 0, 9.8]]}, {"mag_axes": "xyz"}, "expected 6 characters"),
    ({"mag": [[1, 2, 3]], "grav": [[0, 0, 9.8], [0, 0, 9.8]]}, {}, "one of each per shot"),
    ({"mag": [[1, 2, "a"]], "grav": [[0, 0, 9.8]]}, {}, r"'mag\[0\]' must be \[x, y, z\]"),
    ({"mag": [[30, 20, 10]], "grav": [[0, 0, 3.0]]}, {}, "neither g"),
    ({"mag": [[30000, 20000, 10000]], "grav": [[0, 0, 1.0]]}, {}, "expected the earth's field in uT"),
])
def test_bad_files_are_one_line(tmp_path, doc, kw, match):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(io.DataError, match=match) as e:
        read_mag_cal_json(path, **kw)
    assert "\n" not in str(e.value) and str(path) in str(e.value)


def test_fixture_layout_refuses_axes_and_check_reads_json(tmp_path, capsys):
    with pytest.raises(io.DataError, match="device frame already"):
        read_mag_cal_json(FIXTURE, mag_axes="+x+y+z")
    assert io_cli.main(["check", str(FIXTURE)]) == 0
    assert "24 shots, 10 groups" in capsys.readouterr().out
    (tmp_path / "x.json").write_text("{}")
    assert io_cli.main(["check", str(tmp_path / "x.json")]) == 1
    assert "expected a circuitpython-mag-cal JSON" in capsys.readouterr().err
