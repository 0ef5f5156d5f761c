"""The workflow's studies (``results/discrepancy_*``), returning data.

:func:`hidden_study` (every effect hidden alone, three pairs and noise only, on
random attitudes, plus what each design cannot separate), :func:`devices_study`
(the 9 real circuitpython-mag-cal devices) and :func:`lab_casing_study` (the
workflow against ICGO-RELM on the same split). :mod:`icgo.discrepancy.report`
renders them as Markdown. (Not :mod:`icgo.studies.discrepancy`, the workflow as a
registered study.)
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import numpy as np

from icgo.discrepancy.config import WorkflowConfig
from icgo.discrepancy.identifiability import separability
from icgo.discrepancy.inversion import physics_params, predict
from icgo.discrepancy.search import Result, run_workflow
from icgo.discrepancy.stations import DESIGNS, hidden_stations, select_stations, simulate, stations_from_recording
from icgo.physics import effects as _fx
from icgo.physics.frames import angle_diff, azimuth_from_gv

#: Effect sets hidden by :func:`hidden_study`: each effect alone, three pairs, nothing.
HIDDEN_CASES = tuple((e,) for e in _fx.names_for_rig(None)) + (
    ("hard_iron", "accel_bias"), ("external_field", "mag_scale"), ("mag_misalignment", "accel_scale"), ())


class HiddenRun(NamedTuple):
    """One hidden-effect case: the effects hidden and the workflow's result."""

    hidden: tuple
    result: Result


class HiddenStudy(NamedTuple):
    """:func:`hidden_study`'s outcome (``designs``: (design name, :class:`Separability`) pairs)."""

    runs: tuple
    designs: tuple
    seed: int
    n_stations: int
    config: WorkflowConfig


def hidden_study(config: WorkflowConfig = WorkflowConfig(), seed: int = 0, n_stations: int = 240,
                 cases=HIDDEN_CASES) -> HiddenStudy:
    """Hide each case's effects at random realistic magnitudes (:func:`hidden_stations`,
    random attitudes, the config's noise) and run the workflow; then the
    separability of every design (:data:`DESIGNS`) with ``n_stations`` stations."""
    runs = []
    for c in cases:
        st, _ = hidden_stations(seed, c, n_stations, "random", config.noise)
        runs.append(HiddenRun(tuple(c), run_workflow(st, config)))
    designs = []
    for dz in DESIGNS:
        st = simulate(jax.random.PRNGKey(seed), n_stations, {}, design=dz, noise=config.noise)
        designs.append((dz, separability(st, config=config)))
    return HiddenStudy(tuple(runs), tuple(designs), seed, n_stations, config)


class DeviceRun(NamedTuple):
    """One real device: its name and the workflow's result (group mode, no reference)."""

    device: str
    result: Result


def devices_study(config: WorkflowConfig = WorkflowConfig()) -> tuple:
    """Run the workflow on each of the 9 real circuitpython-mag-cal devices.

    Returns:
        tuple of :class:`DeviceRun`, in :func:`icgo.io.mag_cal_bundled.mag_cal_devices` order.
    """
    from icgo.io import mag_cal_bundled

    return tuple(DeviceRun(dev, run_workflow(stations_from_recording(mag_cal_bundled.load_mag_cal_device(dev)), config))
                 for dev in mag_cal_bundled.mag_cal_devices())


class LabCasingStudy(NamedTuple):
    """:func:`lab_casing_study`'s outcome. Errors are azimuth errors (deg) on the test rows.

    Attributes:
        result: the workflow on the training rows.
        error_raw: standard formula on the raw data. error_model: the fitted
            physics model inverted (:func:`icgo.discrepancy.inversion.predict`).
        error_methods: ICGO study method -> its compensated error (repeat 0).
        error_msa: MSA only (repeat 0).
        truth_effects: effects the simulation injected besides the casing.
        seed: data-set and study seed.
        qc: survey-QC counts of the test stations, raw and after the physics model
            (:func:`icgo.artifacts.discrepancy.station_qc`).
        icgo_config: the ICGO study's :class:`~icgo.studies.icgo_relm.config.StudyConfig` (its split, its budget).
        casing: the simulated casing (the data set's ``truth["casing"]``), which ``magnetic_body`` models.
    """

    result: Result
    error_raw: np.ndarray
    error_model: np.ndarray
    error_methods: dict
    error_msa: np.ndarray
    truth_effects: dict
    seed: int
    qc: dict | None = None
    icgo_config: Any = None
    casing: dict | None = None


def lab_casing_study(config: WorkflowConfig = WorkflowConfig(), seed: int = 0) -> LabCasingStudy:
    """lab_casing: name effects on the ICGO study's training rows (repeat 0), then score
    the physics model + named effects and ICGO-RELM on the same test rows."""
    from icgo.datasets.casing_stations import lab_casing
    from icgo.io import recording as icgo_io
    from icgo.studies.icgo_relm import run_study
    from icgo.studies.icgo_relm import StudyConfig

    ds = lab_casing(seed)
    rec = icgo_io.validate(ds.frame, ds.meta, source="lab_casing")
    icgo_config = StudyConfig(split=dict(n_repeats=1, seed=int(seed)), strategies=("three_stage",))
    sres = run_study(ds.frame, icgo_config, ds.meta)
    pred = sres.predictions
    p0 = pred[pred["repeat"] == pred["repeat"].iloc[0]]
    meth = list(p0["method"].unique())
    rows_train = p0[(p0["split"] == "train") & (p0["method"] == meth[0])]["row"].to_numpy()
    rows_test = p0[(p0["split"] == "test") & (p0["method"] == meth[0])]["row"].to_numpy()
    st_all = stations_from_recording(rec)
    pos = {r: i for i, r in enumerate(ds.frame.index)}
    itr = np.array([pos[r] for r in rows_train])
    ite = np.array([pos[r] for r in rows_test])
    res = run_workflow(select_stations(st_all, itr), config)
    a_corr = predict(physics_params(res), np.hstack([st_all.G[ite], st_all.B[ite]])).azimuth
    err = np.asarray(angle_diff(np.asarray(a_corr), st_all.azimuth[ite]))
    err_raw = np.asarray(angle_diff(np.asarray(azimuth_from_gv(st_all.G[ite], st_all.B[ite])), st_all.azimuth[ite]))
    test = p0[p0["split"] == "test"]
    methods = {m: test[test["method"] == m]["error_compensated"].to_numpy() for m in meth}
    err_msa = test[test["method"] == meth[0]]["error_msa"].to_numpy()
    truth = {k: np.asarray(v, float) for k, v in (ds.truth.get("effects") or {}).items()}
    from icgo.artifacts.discrepancy import PhysicsModel, station_qc

    qc = station_qc(PhysicsModel.from_result(res, st_all.G[itr], st_all.B[itr]), select_stations(st_all, ite))
    return LabCasingStudy(res, err_raw, err, methods, err_msa, truth, int(seed), qc, icgo_config,
                          ds.truth.get("casing"))
