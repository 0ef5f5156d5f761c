"""The published values every result puts beside ours, with where each comes from (one place, so a table and the
prose quote the same number).

Sources (the source documents named in README): the ICGO-RELM paper (Liang, Cheng et al., Chinese Journal of
Scientific Instrument), the MISMA paper (Yang, Cai) and patent CN1888384. The patent gives no accuracy figure (its
network is described, not scored), so it has no entry here. Angles in degrees.
"""

from __future__ import annotations

#: ICGO-RELM paper, test split. Tables 1-2 and Fig. 9: one split; Table 3: mean and std over 10 repeats;
#: Table 4: (inclination, azimuth, raw error mean, raw std, compensated mean, compensated std) per condition.
#: Metrics are (MAE, RMSE, R^2) in that order.
ICGO = {
    "table1": {"relm": (0.5111, 0.6035, 0.8660), "cgo-original": (0.0516, 0.0731, 0.9980)},
    # Fig. 9 gives PSO-RELM and GA-RELM as bars only; the text quotes CGO-RELM's values (section 3.2)
    "fig9": {"cgo-original": (0.052, 0.073, 0.998)},
    "table2": {"original": (0.0516, 0.0731, 0.9980), "chaos": (0.0393, 0.0532, 0.9990),
               "gaussian": (0.0527, 0.0707, 0.9982), "wavelet": (0.0365, 0.0521, 0.9990),
               "three_stage": (0.0300, 0.0417, 0.9994)},
    "table3": {"chaos": ((0.0486, 0.0100), (0.0682, 0.0098), (0.9984, 0.0005)),
               "gaussian": ((0.0444, 0.0060), (0.0693, 0.0097), (0.9984, 0.0002)),
               "wavelet": ((0.0434, 0.0103), (0.0676, 0.0155), (0.9985, 0.0006)),
               "three_stage": ((0.0391, 0.0100), (0.0453, 0.0070), (0.9987, 0.0004))},
    "table4": ((0.594, 30.0, 31.2905, 0.8895, 0.0459, 0.0370), (1.800, 60.0, 29.6639, 0.9838, 0.0719, 0.0656),
               (60.0, 135.0, 6.2256, 0.1378, 0.0115, 0.0103), (90.0, 150.0, 5.7334, 0.6672, 0.0473, 0.0295),
               (135.0, 210.0, 9.2645, 0.4551, 0.0049, 0.0117), (150.0, 270.0, 7.1916, 0.3263, 0.0621, 0.0521)),
    # abstract and section 3.3: three-stage ICGO-RELM against plain RELM
    "reduction_pct": {"mae": 94.1, "rmse": 93.1},
}

#: ICGO paper, test MAE (deg) of each method on its lab data (random 7:3 split), where the paper gives one, and
#: where: Table 3 (mean over 10 repeats) for the mutated strategies, Table 1 (one split) for RELM and CGO-RELM.
ICGO_LAB_MAE = {"relm": (0.5111, "Table 1, one split"), "cgo-original": (0.0516, "Table 1, one split"),
                **{f"cgo-{s}": (v[0][0], "Table 3, 10 repeats") for s, v in ICGO["table3"].items()}}

#: MISMA paper (Yang, Cai), section 3: the field runs at a coal mine in Jiaozuo (4 200 samples at 1 s, a stop every
#: 300 s), mean absolute azimuth error (deg) at the static survey points against the reference azimuth.
MISMA = {
    # Fig. 10, a section with strong magnetic interference: the mean absolute error of SMA "reaches 23.59" (平均值可達)
    # and MISMA's mean "stays within 2.81" (平均值保持在...以內); both are means over the static points, each said
    # with a bound word, not the peak of an error curve (raw not given)
    "fig10": {"raw": None, "sma": 23.59, "misma": 2.81},
    # Fig. 11, a more ordinary section: the first 2 static points, and the remaining ones
    "fig11_first2": {"raw": 32.46, "sma": 16.54, "misma": 2.37},
    "fig11_rest": {"raw": 14.22, "sma": 8.39, "misma": 1.66},
    # Fig. 7 (simulated drilling): MISMA converges 37.99 % faster than SMA (iterations, same fitness)
    "fig7_faster_pct": 37.99,
    # Table 3 (field run settings): population 30, 2 051 iterations, search bounds 128 / -68 uT, 12 parameters
    "table3": {"pop_size": 30, "n_iter": 2051, "upper_uT": 128.0, "lower_uT": -68.0},
}
