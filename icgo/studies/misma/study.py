"""The MISMA study: MISMA vs SMA on ``rotating_drill`` and the 9 real devices.

Simulated part (per ``rotating_drill`` variant, :func:`icgo.studies.misma.simulated.simulated_variant`):
MISMA and the standard SMA minimise the penalised MISMA fitness
(:class:`icgo.models.misma_objective.MismaObjective`: dot invariance eq. 5, Pearson
constraint eqs. 6-7, field modulus eq. 8 and, in the paper's magneto-inertial
reading, the gyro term J_gyro on the reference field M_omega of
:mod:`icgo.models.gyro_reference`) over the 12 parameters ``[R^-1, b]`` (eqs. 2-4),
``repeats`` vmapped repeats each, population ``pop_size``. The comparison runs
one contribution at a time (:mod:`icgo.studies.misma.compare`: boxes,
coordinates, operators, objective; same repeat keys, paired tests), and
:func:`icgo.studies.misma.simulated.gyro_sweep` repeats MISMA over gyro grades. MISMA searches the box
around U (eqs. 9-10: the gyro-reference fit, or the modulus fit without the
gyro term; ``bounds=paper``: the paper's 128 / -68 uT), SMA a prior box around
``R^-1 = I, b = 0``. Scored by: iterations to reach ``threshold_factor *
F(true)`` and the convergence comparison, recovered vs true parameters, |B|
before and after, and the absolute azimuth error at the static survey points
(raw, SMA, MISMA and the deterministic baselines).

Real part (:func:`real_study`): the 9 circuitpython-mag-cal devices through
:mod:`icgo.studies.calibration` (ellipsoid fit, 12-parameter least squares +
axis, MISMA + axis in a box in the data's units, the joint fit, least squares +
axis + RELM, the peer's pipeline side by side; in-sample and held out; physical
sanity per fit).

Randomness: ``run(data, config, key)`` draws the simulated searches from
``offset_key(key, 1)`` and the real-device MISMA runs from ``offset_key(key,
7)``; with ``key = PRNGKey(seed)`` these are ``PRNGKey(seed + 1)`` and
``PRNGKey(seed + 7)``, the streams the study has always used. The data sets'
noise comes from ``config.seed`` (:func:`load_data`). The reported seed is never
one of :data:`icgo.studies.misma.config.DEVELOPMENT_SEEDS`, the seeds the study's choices were made on.

Equation numbers are the MISMA paper's (Yang & Cai); the reconstructions are
listed in ``docs/misma.md``. The settings are :mod:`icgo.studies.misma.config`, the
simulated part :mod:`icgo.studies.misma.simulated`.
"""

from __future__ import annotations

import logging
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

from icgo.datasets import drill_string as datasets
from icgo.io.mag_cal_bundled import load_mag_cal_device, mag_cal_devices
from icgo.studies import calibration
from icgo.studies.misma import compare
from icgo.studies.misma import report as misma_report
from icgo.studies.misma.config import GyroConfig, MismaConfig, RealConfig, SimulatedConfig
from icgo.studies.misma.simulated import simulated_table, simulated_variant
from icgo.studies.common.study import Study

log = logging.getLogger(__name__)


class MismaData(NamedTuple):
    """What the study runs on.

    Attributes:
        simulated: variant name -> :class:`icgo.datasets.dataset.Dataset` (rotating_drill).
        devices: device name -> :class:`icgo.io.recording.Recording` (24 shots, ``group`` column).
    """

    simulated: dict
    devices: dict


def load_data(config: MismaConfig) -> MismaData:
    """The rotating_drill variants (seed ``config.seed``) and the 9 vendored devices, as configured."""
    sims = {}
    if config.simulated.enabled:
        sims = {name: datasets.rotating_drill(config.seed, **ov) for name, ov in config.simulated.variants.items()}
    devices = {name: load_mag_cal_device(name) for name in mag_cal_devices()} if config.real.enabled else {}
    return MismaData(sims, devices)


def offset_key(key, k: int):
    """``key`` with ``k`` added to its last word: ``PRNGKey(s + k)`` when ``key = PRNGKey(s)`` (a named stream)."""
    key = jnp.asarray(key) if not isinstance(key, jax.Array) else key
    typed = jnp.issubdtype(key.dtype, jax.dtypes.prng_key)
    raw = jax.random.key_data(key) if typed else key.astype(jnp.uint32)
    raw = raw.at[..., -1].add(jnp.uint32(k))
    return jax.random.wrap_key_data(raw) if typed else raw


def real_study(devices: dict, rcfg: RealConfig, key) -> tuple[pd.DataFrame, dict]:
    """All devices through :func:`icgo.studies.calibration.study.evaluate` (scores, sanity, the peer side by side).

    Returns:
        (long table: device, split, method, score_deg, sanity columns; {"<device>_<method>": in-sample calibration}).
    """
    config = calibration.CalibrationConfig(peer=rcfg.peer, misma_iter=rcfg.misma_iter,
                                           misma_repeats=rcfg.misma_repeats)
    df, models = calibration.evaluate(devices, config, key)
    return df.rename(columns={"recording": "device"}), models


class MismaResult(NamedTuple):
    """Result of :func:`run`.

    Attributes:
        records: ``params_<variant>`` and ``modulus_<variant>`` (index = method), ``fair_<variant>`` (the
            comparison rows), ``tests_<variant>`` (paired tests of the contrasts), ``gyro_sweep``, ``simulated``
            (scalar summary, one column per variant), ``real_devices``, ``real_summary`` (index = method).
        models: fitted :class:`MagCalibration` s: ``<variant>_{misma,sma,modulus,twelve}``,
            ``<device>_{ellipsoid,twelve_axis,misma_axis,joint,twelve_axis_relm}`` (in-sample fits).
        summary: ``{"simulated": [variant summary, ...], "real": {column: {method: deg}}}`` (JSON-able).
        plots: variant -> :class:`icgo.studies.misma.simulated.VariantPlot`.
    """

    records: dict
    models: dict
    summary: dict
    plots: dict


def run(data: MismaData | None, config: MismaConfig, key) -> MismaResult:
    """Run the study: the simulated variants, then the real devices (see the module doc).

    Args:
        data: :class:`MismaData`, or None for :func:`load_data` ``(config)``.
        config: :class:`icgo.studies.misma.config.MismaConfig`.
        key: JAX PRNG key (the entry point passes ``PRNGKey(config.seed)``).
    """
    data = load_data(config) if data is None else data
    records, models, summary, plots = {}, {}, {}, {}
    if config.simulated.enabled:
        sims, sweeps, head = [], [], []
        for name in config.simulated.variants:
            log.info("[simulated] rotating_drill variant %r ...", name)
            v = simulated_variant(name, data.simulated[name], config.simulated, offset_key(key, 1))
            sims.append(v.summary)
            head.append(v.headline_errors)
            records[f"params_{name}"], records[f"modulus_{name}"] = v.params, v.modulus
            records[f"fair_{name}"], records[f"tests_{name}"] = v.fair, v.tests
            sweeps.append(v.sweep)
            plots[name] = v.plot
            models.update(v.models)
        compare.headline_tests(sims, head)
        summary["simulated"] = sims
        records["simulated"] = simulated_table(sims)
        if config.simulated.gyro.sweep:
            records["gyro_sweep"] = compare.sweep_family(pd.concat(sweeps, ignore_index=True))
    if config.real.enabled:
        log.info("[real] circuitpython-mag-cal devices ...")
        df, real_models = real_study(data.devices, config.real, offset_key(key, 7))
        records["real_devices"], records["real_summary"] = df, calibration.summary(df)
        summary["real"] = records["real_summary"].to_dict()
        models.update(real_models)
    return MismaResult(records, models, summary, plots)


def example() -> tuple[MismaData, MismaConfig]:
    """A tiny real instance (seconds): a 600 s rotating_drill run, 2 repeats of 5 iterations, no real devices."""
    cfg = MismaConfig(simulated=SimulatedConfig(variants={"short": {"duration_s": 600.0}}, repeats=2, n_iter=5,
                                                pop_size=6, gyro=GyroConfig(sweep=(0.0,))),
                      real=RealConfig(enabled=False))
    return load_data(cfg), cfg


def objective(result: MismaResult) -> float | None:
    """What a hyperparameter search minimises (``hydra/sweeper=optuna`` on the misma door): MISMA's own fitness
    at the end of its searches (the median over repeats of the best eq.-objective value on the run's samples), averaged
    over the simulated variants; never the azimuth error at the static points, which the study reports. None without
    the simulated part."""
    values = [v["MISMA_best_f_median"] for v in result.summary.get("simulated", [])]
    return float(np.mean(values)) if values else None


STUDY = Study("misma", MismaConfig, run,
              "MISMA vs SMA 12-parameter magnetometer calibration: rotating_drill and 9 real devices",
              example, load=load_data, write=misma_report.write, last=("misma_summary.json",),
              objective=objective)
