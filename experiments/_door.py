"""What every Hydra front door of icgo shares: its name, config and groups (:data:`DOORS`), its ``__main__``
(:func:`door`: its own ``--help``, the command line checked, a user's error one line and an exit status) and
Hydra's record of the job staged with the job's own files. The one study main is :mod:`experiments._study_main`.

Errors the user can fix (a bad override, a missing data file) are :class:`icgo.core.errors.SettingError`
(or :class:`icgo.core.errors.DataError`), both one line; the door prints ``error: <line>`` and exits 2
(a bad setting) or 1 (bad data), before any computation.

Nothing here imports JAX at module import: a sweep launcher may start worker processes after it is imported,
and JAX must be initialised inside the job, never forked.
"""

from __future__ import annotations

import functools
import logging
import sys
import warnings
from pathlib import Path
from typing import NamedTuple

from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from experiments._hydra_errors import composition_errors
from experiments._preflight import CONF_DIR, STUDY_GROUPS, preflight
from icgo.core.settings import error_status




class Door(NamedTuple):
    """A Hydra front door.

    Attributes:
        config_name: its primary config (``<conf_dir>/<config_name>.yaml``). conf_dir: its config directory.
        groups: the config groups it uses (an override of another is refused). classes: dotted key prefix
            (``""``: the top level) -> the ``"module:Class"`` of each config dataclass whose field docs its
            ``--help`` shows (the study's, then the door's own settings'). summary: what it does, one or two lines.
            examples: command lines after ``icgo <door>``.
    """

    config_name: str
    conf_dir: Path
    groups: tuple
    classes: dict
    summary: str
    examples: tuple


#: The compilation cache setting of the study doors whose config does not hold it (their ConfigStore node adds it).
CACHE_SETTING = "icgo.core.devices:CacheSetting"
DOORS = {
    "run": Door("config", CONF_DIR, STUDY_GROUPS, {"": ("icgo.studies.icgo_relm.run_config:RunConfig",)},
                "ICGO-RELM study: MSA, then a RELM whose hidden layer an optimizer searches; writes a run directory\n"
                "(metrics, models, figures, summary.md with the verdict) and prints the summary and the verdict.",
                ("strategy=three_stage                 # make run", "experiment=table3                    # a paper "
                 "preset", "-m strategy=chaos,wavelet           # a sweep (one process per job)",
                 "dataset=csv dataset.path=FILE.csv    # your own recording (docs/data.md)")),
    "apply": Door("apply", CONF_DIR / "apply", (), {"qc": ("icgo.physics.qc:QCBands",)},
                  "Apply a fitted model (a run directory or a model .json) to a new survey: the corrected survey\n"
                  "(CSV + meta), the MAE where it has a reference azimuth, QC before/after and the verdict.",
                  ("model=outputs/run/<date>/<time> data=survey.csv", "model=m.json data=big.csv stream_mb=16")),
    "calibrate": Door("calibrate", CONF_DIR, (), {"": ("icgo.studies.calibration:CalibrationConfig", CACHE_SETTING)},
                      "Magnetometer calibration of grouped static shots: every method fitted and scored held out,\n"
                      "one recommended (report.md, calibration.csv, models/), or why none (exit 4).",
                      ("data=shots.csv", "data=device.json site.lat=51.5 site.lon=-0.1 site.date=2024-06-01",
                       "data=raw.json mag_axes=+x+y-z grav_axes=-y-x+z", "data=bundled   # the 9 bundled devices")),
    "discrepancy": Door("discrepancy", CONF_DIR, (), {"": ("icgo.discrepancy.config:WorkflowConfig", CACHE_SETTING)},
                        "Discrepancy workflow: where simulated and measured sensor data disagree, the missing\n"
                        "physical effect named, added to the model, the gap shown to shrink.",
                        ("data=FILE.csv", "data=sim:hard_iron+accel_bias design=single_inclination",
                         "data=mag_cal:ab", "study=hidden   # results/discrepancy_hidden.md")),
    "misma": Door("misma", CONF_DIR, (), {"": ("icgo.studies.misma.config:MismaConfig", CACHE_SETTING)},
                  "MISMA study: the 12-parameter magnetometer model identified while the drill string rotates,\n"
                  "against SMA; tables and figures into results/misma_*, the calibrations into the run directory.",
                  ("", "simulated.repeats=3 simulated.n_iter=300 real.enabled=false")),
    "gyro": Door("gyro", CONF_DIR, (), {"": ("icgo.studies.gyro:GyroConfig", CACHE_SETTING)},
                 "Gyro inclinometer study: the 3-8-8-1 network against the lookup table it replaced (plus RELM,\n"
                 "ICGO-RELM); tables and figures into results/gyro_*, the models into the run directory.",
                 ("", "n_seeds=3 net.epochs=300 sweep.enabled=false relm.enabled=false")),
}


def door(name: str, main) -> None:
    """The ``__main__`` of the Hydra door ``name``: ``--help`` is the door's own (:mod:`experiments._help`);
    otherwise the command line is checked (:func:`experiments._preflight.preflight`) and ``main`` (the
    ``@hydra.main`` task) runs, its composition errors one line (:func:`experiments._hydra_errors.composition_errors`),
    under :func:`guarded`. Every other flag is Hydra's (``--cfg job``, ``--info`` ...)."""
    d = DOORS[name]

    def cli() -> None:
        if any(a in ("--help", "-h") for a in sys.argv[1:]):
            from experiments._help import door_help

            print(door_help(name, d))
            return
        preflight(d.config_name, conf_dir=d.conf_dir, groups=d.groups)
        with composition_errors(d.config_name, d.conf_dir):
            main()

    guarded(cli)


def guarded(main) -> None:
    """Run a door's ``__main__`` body (:func:`icgo.core.settings.run_cli`): Ctrl-C or SIGTERM is one line and exit
    status 130; outputs are staged (:mod:`icgo.io.files`), so an interrupted command leaves every output directory
    as it was."""
    from icgo.core.settings import run_cli

    rc = run_cli(main)
    if rc:
        raise SystemExit(rc)


def one_line_errors(task):
    """Decorator of a Hydra task function: a user's error becomes one line and an exit status, never a traceback.

    ``ValueError`` (every :class:`~icgo.core.errors.IcgoError`), a disk's ``OSError`` and ``MemoryError`` are
    printed by :func:`icgo.core.settings.error_status` (exit 2 or 1); Hydra would print each with a traceback.
    Numerical ``RuntimeWarning`` lines are not printed (a result that matters is checked and raised as an error).
    """
    @functools.wraps(task)
    def wrapper(cfg):
        # JAX's backend probe ("Unable to initialize backend 'tpu'") is noise on a terminal, not a second line.
        logging.getLogger("jax._src.xla_bridge").setLevel(logging.WARNING)
        warnings.simplefilter("ignore", RuntimeWarning)
        try:
            return task(cfg)
        except (ValueError, OSError, MemoryError) as e:
            rc = error_status(e)
            if rc is None:
                raise
            raise SystemExit(rc) from None

    return wrapper


def hydra_keep() -> tuple[str, ...]:
    """Names Hydra writes into this job's run directory before the task runs (its job log), which an output
    directory leaves alone; none outside a Hydra job."""
    return (f"{HydraConfig.get().job.name}.log",) if HydraConfig.initialized() else ()


def hydra_files(cfg: DictConfig) -> dict[str, str]:
    """Hydra's ``.hydra/`` record of this job (``config.yaml`` unresolved, ``hydra.yaml``, ``overrides.yaml``); {}
    outside a Hydra job. The configs set ``hydra.output_subdir: null``, so Hydra does not write it into the run
    directory before the task runs (it would rewrite the record of the run a refused command was refused to
    replace); the door stages it with its other files instead."""
    if not HydraConfig.initialized():
        return {}
    hc = HydraConfig.get()
    return {"config.yaml": OmegaConf.to_yaml(cfg), "hydra.yaml": OmegaConf.to_yaml({"hydra": hc}),
            "overrides.yaml": OmegaConf.to_yaml(hc.overrides.task)}


def write_hydra_record(stage: Path, cfg: DictConfig) -> None:
    """Write :func:`hydra_files` into ``stage/.hydra`` (nothing outside a Hydra job, e.g. a library call)."""
    files = hydra_files(cfg)
    if files:
        (stage / ".hydra").mkdir(exist_ok=True)
    for name, text in files.items():
        (stage / ".hydra" / name).write_text(text)


def bool_setting(cfg: DictConfig, key: str) -> bool:
    """The value of a true/false setting; anything else (``maybe``, ``'false'``, ``0``, null) is a SettingError."""
    from icgo.core.errors import SettingError

    v = OmegaConf.select(cfg, key)
    if not isinstance(v, bool):
        raise SettingError(f"{key}={v!r}: must be true or false")
    return v


def repo_path(value) -> Path:
    """A path setting: absolute as given, relative to the repository root (the folder of ``conf/``) otherwise."""
    p = Path(str(value))
    return p if p.is_absolute() else CONF_DIR.parent / p
