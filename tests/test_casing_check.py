"""icgo's casing field against magpylib's magnetised tube (a peer library, closed form), at the lab's geometry."""

import numpy as np

from icgo.datasets import casing_stations
from icgo.datasets import instruments as ins
from icgo.studies.icgo_relm.casing_check import compare, magpylib_tube_field


def test_pole_pair_matches_the_magnetised_tube_at_every_lab_station_and_distance():
    df = compare(distances=(0.5, 1.0, 2.0))
    pole = df[df.model == "pole_pair"].set_index("distance_m")
    assert (pole.max_rel_diff < 0.005).all(), pole          # within 0.5 % of the casing field everywhere
    assert pole.loc[1.0, "max_diff_nT"] < 3.0               # at the paper's 1 m: a few nT, far below the noise
    assert pole.loc[0.5, "median_rel_diff"] > pole.loc[1.0, "median_rel_diff"]  # the annuli matter more up close


def test_tube_field_on_its_axis_far_away_is_the_pole_pair_to_second_order():
    c = casing_stations.LAB_CASING
    ax = np.asarray(c.axis_ned, float)
    far = np.asarray(c.end_ned) + (c.length_m + 20.0) * ax      # 20 m beyond the second end, on the axis
    tube = magpylib_tube_field(far[None], c)[0]
    pole = np.asarray(ins.casing_field_ned(far[None], c))[0]
    assert np.linalg.norm(tube - pole) / np.linalg.norm(pole) < 1e-4
