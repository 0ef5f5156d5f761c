"""icgo.survey.trajectory: positions by minimum curvature through welleng, checked against the closed form."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from icgo.core.errors import DataError
from icgo.survey import trajectory as T


def min_curvature(md, inc, azi):
    """Minimum curvature in float64 numpy (Bourgoyne et al., Applied Drilling Engineering, eq. 8.48): N, E, TVD."""
    i, a = np.radians(inc), np.radians(azi)
    i1, i2, a1, a2 = i[:-1], i[1:], a[:-1], a[1:]
    cosb = np.cos(i2 - i1) - np.sin(i1) * np.sin(i2) * (1.0 - np.cos(a2 - a1))
    b = np.arccos(np.clip(cosb, -1.0, 1.0))
    rf = np.where(b > 1e-9, 2.0 / np.where(b > 1e-9, b, 1.0) * np.tan(b / 2.0), 1.0)
    h = np.diff(md) / 2.0 * rf
    d = np.stack([h * (np.sin(i1) * np.cos(a1) + np.sin(i2) * np.cos(a2)),
                  h * (np.sin(i1) * np.sin(a1) + np.sin(i2) * np.sin(a2)), h * (np.cos(i1) + np.cos(i2))], 1)
    return np.vstack([np.zeros(3), np.cumsum(d, 0)])


@settings(max_examples=25, deadline=None)
@given(st.lists(st.tuples(st.floats(1.0, 60.0), st.floats(0.5, 120.0), st.floats(-30.0, 30.0)), min_size=2, max_size=12))
def test_positions_are_minimum_curvature(steps):
    dmd, inc, dazi = (np.array(x) for x in zip(*steps))
    md = np.concatenate([[0.0], np.cumsum(dmd)])
    inc = np.concatenate([[inc[0]], inc])
    azi = np.mod(np.concatenate([[40.0], 40.0 + np.cumsum(dazi)]), 360.0)
    got = T.positions(md, inc, azi)[["north_m", "east_m", "tvd_m"]].to_numpy()
    np.testing.assert_allclose(got, min_curvature(md, inc, azi), atol=1e-6 * md[-1])


def test_bottom_hole_change_of_a_constant_azimuth_offset():
    """A straight hole: an azimuth offset of d deg rotates the bottom hole by d about the wellhead."""
    md = np.linspace(0.0, 1000.0, 21)
    inc = np.full(21, 30.0)
    table, s = T.position_change(md, inc, np.full(21, 10.0), inc, np.full(21, 12.0), inc, np.full(21, 12.0))
    horiz = 1000.0 * np.sin(np.radians(30.0))
    assert s["correction"]["horizontal_m"] == pytest.approx(2 * horiz * np.sin(np.radians(1.0)), rel=1e-9)
    assert s["correction"]["tvd_m"] == pytest.approx(0.0, abs=1e-9)
    assert s["corrected_vs_reference"]["distance_m"] == pytest.approx(0.0, abs=1e-9)
    assert s["raw_vs_reference"]["distance_m"] == pytest.approx(s["correction"]["distance_m"])
    assert list(table.columns) == ["north_raw_m", "east_raw_m", "tvd_raw_m", "north_m", "east_m", "tvd_m"]
    assert "moves 17.45 m with the correction" in T.trajectory_sentence(s)


def test_md_must_increase():
    with pytest.raises(DataError, match=r"column 'md' must increase .* \(row 3: 10 m after 20 m\)"):
        T.check_md([0.0, 20.0, 10.0])
    with pytest.raises(DataError, match="at least two stations"):
        T.check_md([5.0])


def test_apply_gives_positions_where_the_survey_has_depth(tmp_path):
    """The front door's library path: a lab_casing survey given a depth column gets both trajectories."""
    from icgo.datasets import casing_stations
    from icgo.studies.icgo_relm import study as icgo_relm
    from icgo.studies.icgo_relm.config import StudyConfig
    from icgo.survey.apply import correct_survey

    res = icgo_relm.run_study(casing_stations.lab_casing(0, toolface_step_deg=60.0).frame,
                              StudyConfig(split=dict(n_repeats=2), model=dict(hidden=8), optimizer=None))
    new = casing_stations.lab_casing(3, toolface_step_deg=60.0).frame
    new = new.assign(md=10.0 * np.arange(len(new)))
    out = correct_survey(res.model, new)
    t = out.table
    ref = min_curvature(new["md"].to_numpy(), t["inclination_compensated"].to_numpy(), t["azimuth_compensated"].to_numpy())
    np.testing.assert_allclose(t[["north_m", "east_m", "tvd_m"]].to_numpy(), ref, atol=1e-6 * new["md"].iloc[-1])
    raw = min_curvature(new["md"].to_numpy(), t["inclination_compensated"].to_numpy(), t["azimuth_raw"].to_numpy())
    c = out.trajectory["correction"]
    assert [c["north_m"], c["east_m"], c["tvd_m"]] == pytest.approx(list(ref[-1] - raw[-1]), abs=1e-6)
    assert out.trajectory["corrected_vs_reference"]["distance_m"] < out.trajectory["raw_vs_reference"]["distance_m"]
    shuffled = new.assign(md=new["md"].to_numpy()[::-1])
    assert correct_survey(res.model, shuffled).trajectory is None
    assert any("no positions" in n for n in correct_survey(res.model, shuffled).notices)
    assert pd.api.types.is_float_dtype(t["north_raw_m"])
