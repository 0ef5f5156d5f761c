"""Rolls: what one is (icgo.physics.rolls), found (icgo.models.rolls) or given (icgo.io.grouping), on real-looking
files made from the bundled devices."""

from __future__ import annotations

import numpy as np
import pytest
from mag_cal_files import INDUSTRIAL, device_attitudes, join, roll, singles, synth

from icgo.core.errors import DataError, SettingError
from icgo.io import mag_cal_bundled
from icgo.io import recording as io
from icgo.io.grouping import check_given, groups_from_ranges, parse_groups
from icgo.models.rolls import find_rolls
from icgo.physics import rolls
from icgo.physics.frames import sensors_from_attitude

PEER_GROUPS = np.r_[np.arange(8), [8] * 8, [9] * 8]


def test_bundled_rolls_are_plausible_and_merged_rolls_are_not():
    # the numbers the module doc quotes for the tolerances
    plane_g, plane_b, agree, to_z, merged_g, merged_b = [], [], [], [], [], []
    for name in mag_cal_bundled.mag_cal_devices():
        rec = mag_cal_bundled.load_mag_cal_device(name)
        G, B = rec.G, rec.B
        found = find_rolls(G, B)
        assert found.groups.tolist() == rec.frame.group.tolist() == PEER_GROUPS.tolist(), name
        for c in rolls.check_groups(G, B, PEER_GROUPS).values():
            assert c.ok, (name, c.reasons)
            plane_g.append(c.plane_g)
            plane_b.append(c.plane_b)
            agree.append(c.axis_agree_deg)
            to_z.append(c.axis_to_z_deg)
        one = np.where(PEER_GROUPS >= 8, 8, PEER_GROUPS)  # both rolls given as one group
        c = rolls.check_groups(G, B, one)[8]
        assert not c.ok and c.plane_g > rolls.PLANE_TOL_G and c.plane_b > rolls.PLANE_TOL_B
        merged_g.append(c.plane_g)
        merged_b.append(c.plane_b)
    assert max(plane_g) < 0.0036 and max(plane_b) < 0.002 and max(agree) < 1.8 and 1.2 < min(to_z) < max(to_z) < 3.9
    assert 0.063 < min(merged_g) and max(merged_g) < 0.07 and 0.082 < min(merged_b) and max(merged_b) < 0.11


@pytest.mark.parametrize("sep_g", [0.2, 0.1])
@pytest.mark.parametrize("noise", [0, 30, 250])
def test_two_consecutive_rolls_apart_along_the_pointing_axis_are_never_merged(sep_g, noise):
    # same azimuth, inclinations whose raw pointing-axis gravity differs by sep_g; noise in multiples of the
    # industrial assumption (0.3 mg, 15 nT per axis)
    for name in ("ab", "ee", "jd"):
        A, _, _ = device_attitudes(name)
        inc1, inc2 = np.degrees(np.arccos(-sep_g / 2)), np.degrees(np.arccos(sep_g / 2))
        att = join(singles(name), roll(A[8:16].mean(), inc1), roll(A[8:16].mean(), inc2, start=30.0))
        for seed in range(3):
            G, B = synth(name, *att, noise_g=noise * INDUSTRIAL[0], noise_b_nT=noise * INDUSTRIAL[1], seed=seed)
            found = find_rolls(G, B)
            assert all(len(set(PEER_GROUPS[a:b])) == 1 for a, b in found.runs), (name, seed, found.runs)
            if noise <= 30:
                assert found.runs == ((8, 16), (16, 24)), (name, seed, found.runs)
            # given as one group, they are refused with the reason
            frame = io.validate(_frame(G, B, np.where(PEER_GROUPS >= 8, 8, PEER_GROUPS)), {},
                                require_reference=False).frame
            with pytest.raises(DataError, match=r"group 8 \(shots 8-23\) is not a plausible roll: .*two rolls"):
                check_given(frame, frame.group.to_numpy(), "f.csv")


def _frame(G, B, groups=None):
    import pandas as pd

    d = {"station": np.arange(len(G)), "gx": G[:, 0], "gy": G[:, 1], "gz": G[:, 2],
         "bx": B[:, 0], "by": B[:, 1], "bz": B[:, 2]}
    return pd.DataFrame({**d, **({} if groups is None else {"group": groups})})


def test_each_criterion_of_a_roll_on_exact_shots():
    def shots(A, I, T):
        G, B = (np.asarray(x) for x in sensors_from_attitude(np.asarray(A, float), np.asarray(I, float),
                                                             np.asarray(T, float), 50_000.0, 60.0)[:2])
        return G, B

    ok = rolls.check_roll(*shots(*roll(30.0, 95.0)), 50_000.0)
    assert ok.ok and ok.plane_g < 1e-12 and ok.span_deg == pytest.approx(315.0)
    assert ok.inclination_deg == pytest.approx(95.0)
    narrow = rolls.check_roll(*shots(np.full(5, 30.0), np.full(5, 95.0), np.linspace(0, 60, 5)), 50_000.0)
    assert narrow.reasons == ("roll angles span 60 deg < 90",)
    vertical = rolls.check_roll(*shots(*roll(30.0, 3.0)), 50_000.0)
    assert "barely turn" in vertical.reasons[0]
    # the same roll with the tool rotated 90 deg about x: the readings turn about tool y
    G, B = shots(*roll(30.0, 95.0))
    Rx = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    tilted = rolls.check_roll(G @ Rx.T, B @ Rx.T, 50_000.0)
    assert tilted.reasons == ("the roll axis is 90.0 deg from the pointing axis (tool z) > 25",)
    # repeated shots in one attitude are one direction but not a roll
    assert not rolls.check_roll(*shots(np.full(6, 30.0), np.full(6, 95.0), np.full(6, 10.0)), 50_000.0).ok


def test_a_roll_with_half_its_shots_pointing_elsewhere_is_refused_or_split():
    # shift the second half of one roll by 4 deg of inclination: as given groups it is refused, found from
    # the data it is never one roll
    name = "bh"
    A, I, T = device_attitudes(name)
    I2 = I.copy()
    I2[20:24] += 4.0  # its planes tilt by 2.7 (gravity) and 3.1 deg (field), within the plane tolerances
    G, B = synth(name, A, I2, T)
    frame = io.validate(_frame(G, B, PEER_GROUPS), {}, require_reference=False).frame
    with pytest.raises(DataError, match=r"group 8 \(shots 8-15\) is not a plausible roll: it turns about an axis 3.1 deg from group 9"):
        check_given(frame, frame.group.to_numpy(), "shifted.csv")
    found = find_rolls(G, B)
    assert (16, 24) not in found.runs and (8, 16) in found.runs


@pytest.mark.parametrize("spec,expect", [
    (None, None), ("auto", "auto"), ("COLUMN", "column"), ("8-15,16-23", ((8, 15), (16, 23))),
    (["16-23", "8-15"], ((8, 15), (16, 23))), ("3", ((3, 3),)),
])
def test_parse_groups(spec, expect):
    assert parse_groups(spec) == expect


@pytest.mark.parametrize("spec,match", [
    ("8-15,12-20", "overlap"), ("15-8", "ends before it starts"), ("a-b", "is not a shot range"), ([], "expected"),
])
def test_parse_groups_refuses_bad_ranges(spec, match):
    with pytest.raises(SettingError, match=match):
        parse_groups(spec)


def test_given_ranges_make_the_groups_and_too_short_ranges_are_a_setting_error():
    rec = mag_cal_bundled.load_mag_cal_device("ai")
    station = rec.frame.station.to_numpy()
    assert groups_from_ranges(station, parse_groups("8-15,16-23")).tolist() == PEER_GROUPS.tolist()
    with pytest.raises(SettingError, match="range 8-10 holds 3 shot"):
        groups_from_ranges(station, parse_groups("8-10"))


def test_off_plane_shots_names_the_shots_of_another_roll():
    # group 8 given as shots 8-15 plus the first 3 of the next roll: those 3 are named, nothing else
    rec = mag_cal_bundled.load_mag_cal_device("ai")
    G, B = rec.G[8:19], rec.B[8:19]
    scale = float(np.median(np.linalg.norm(rec.B, axis=1)))
    assert rolls.off_plane_shots(G, B, scale) == [8, 9, 10]
    assert rolls.off_plane_shots(rec.G[8:16], rec.B[8:16], scale) == []


def test_the_layout_is_checked_and_used_and_the_data_are_asked_for_a_second_opinion():
    from icgo.models.grouping import by_data, by_layout

    rec = mag_cal_bundled.load_mag_cal_device("bh")
    G, B, station = rec.G, rec.B, rec.frame.station.to_numpy()
    g = by_layout(G, B, station, PEER_GROUPS, "the layout", "bh.json")
    assert g.groups.tolist() == PEER_GROUPS.tolist() and g.record["data_suggest"] is None
    assert g.record["disagreements"] == [] and g.notices == ("grouped by the the layout",)
    # a layout one shot off (rolls 7-14, 15-22): used as given, the shots that disagree named, the data's rolls shown
    off = np.r_[np.arange(7), [7] * 8, [8] * 8, [9]]
    g = by_layout(G, B, station, off, "a layout", "bh.json")
    assert g.groups.tolist() == off.tolist()
    assert g.record["data_suggest"] == "rolls at shots 8-15; 16-23" and len(g.record["disagreements"]) == 2
    assert "shots 7 leave its roll plane" in g.record["disagreements"][0]
    d = by_data(G, B, station, "bh.json", layout=("a layout", off))
    assert d.groups.tolist() == PEER_GROUPS.tolist() and d.record["layout_grouping"] == "rolls at shots 7-14; 15-22"


def test_a_corrupt_shot_is_refused_by_the_reader_before_any_fit(tmp_path):
    """One value of 1e300 (numpy's least squares on it never returned) is refused in one line naming the shot; the
    ellipsoid fit itself refuses a reading it cannot square."""
    import json
    import time

    from icgo.io.mag_cal_json import read_mag_cal_json
    from icgo.models.calibration import ellipsoid_fit

    d = json.loads(mag_cal_bundled._mag_cal_dir().joinpath("ab.json").read_text())
    d["shots"]["mag"][31] = 1e300  # shot 10's third component
    path = tmp_path / "huge.json"
    path.write_text(json.dumps(d))
    t0 = time.perf_counter()
    with pytest.raises(DataError, match=r"huge.json: shot 10: \|B\| = 1e\+300 uT while the median is 11\d uT") as e:
        read_mag_cal_json(path)
    assert time.perf_counter() - t0 < 5.0 and "inf" not in str(e.value) and "nan" not in str(e.value)
    B = mag_cal_bundled.load_mag_cal_device("ab").B.copy()
    B[10, 2] = 1e300
    with pytest.raises(ValueError, match="too large to square"):
        ellipsoid_fit(B, 1.0, check=False)
