"""Hydra entry of the discrepancy workflow: load data, call the library, render.

    python -m experiments.discrepancy data=path/to/file.csv     # .meta.json next to it
    python -m experiments.discrepancy data=device.json [mag_axes=.. grav_axes=..] [groups=..]   # circuitpython-mag-cal
    python -m experiments.discrepancy data=lab_casing
    python -m experiments.discrepancy data=sim:hard_iron+accel_bias design=single_inclination
    python -m experiments.discrepancy data=mag_cal:ab
    python -m experiments.discrepancy study=hidden|devices|lab_casing   # results/discrepancy_<study>.md

Prints the search and the verdict; writes report.md, discrepancy.json, the
figures and the fitted physics model (``discrepancy_model.json`` + ``.npz``,
:class:`icgo.models.discrepancy.PhysicsModel`) into the run directory. A bad
setting (a workflow option, an unknown key, ``study=`` or ``design=``): one line
per problem on stderr (``error: ...``), exit status 2 like the other entry
points; bad input data (a bad file, an unknown effect in ``data=sim:...``):
one line, exit status 1. The workflow options are
:class:`icgo.discrepancy.WorkflowConfig` (``conf/discrepancy.yaml`` repeats its defaults).
"""

from __future__ import annotations

import sys
from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

import icgo  # noqa: F401  (float64)
from experiments._entry import EXIT_CONFIG, bool_setting, hydra_keep, one_line, one_line_errors, write_hydra_record
from icgo import discrepancy as D
from icgo.core.errors import DataError, SettingError, SettingsError
from icgo.core.settings import config_from_mapping
from icgo.discrepancy import report
from icgo.io import mag_cal_bundled
from icgo.io import recording as icgo_io
from icgo.io.files import Output
from icgo.io.shots import is_json
from icgo.models.discrepancy import PhysicsModel, station_qc
from icgo.physics.qc import qc_sentence
from icgo.studies import discrepancy_results
from icgo.studies.shots import read_shots

#: Settings of the entry point, not of the workflow (excluded from :class:`icgo.discrepancy.WorkflowConfig`).
ENTRY_KEYS = ("data", "study", "seed", "n_stations", "design", "results_dir", "overwrite", "hydra", "columns",
              "columns_file", "mag_axes", "grav_axes", "groups")

#: Largest ``n_stations`` of a simulated data set (the workflow's memory grows with it; a real recording is read
#: whole).
MAX_STATIONS = 100_000

#: ``study=`` values.
STUDIES = ("none", "hidden", "devices", "lab_casing")


def load_stations(spec: str, seed: int = 0, n: int = 240, design: str = "random", noise: D.Noise = D.NOISE,
                  columns: dict | None = None, shots: dict | None = None):
    """Stations and a description from a ``data=`` value (see conf/discrepancy.yaml); ``columns``: the column map
    of a field export (:func:`icgo.io.recording.column_map`); ``shots``: the grouped-shot settings (``mag_axes``,
    ``grav_axes``, ``groups``) for a file of grouped shots (a circuitpython-mag-cal JSON, or a contract CSV
    with ``groups=``; :func:`icgo.studies.shots.read_shots`).
    Returns (Stations, label, truth or None). Raises icgo.core.errors.DataError / ValueError.
    """
    spec = str(spec)
    shots = {k: v for k, v in (shots or {}).items() if v is not None}
    if spec.startswith("sim:"):
        names = [] if spec[4:] in ("", "none") else spec[4:].split("+")
        st, truth = D.hidden_stations(seed, names, n, design, noise)
        return st, f"simulated {n} stations ({design}) with hidden {names or 'nothing'}", truth
    if spec.startswith("mag_cal:"):
        rec = mag_cal_bundled.load_mag_cal_device(spec[8:])
        return D.stations_from_recording(rec), f"circuitpython-mag-cal device {spec[8:]}", None
    if spec == "lab_casing":
        from icgo.datasets.casing_stations import lab_casing

        ds = lab_casing(seed)
        rec = icgo_io.validate(ds.frame, ds.meta, source="lab_casing")
        return D.stations_from_recording(rec), f"icgo.datasets.casing_stations.lab_casing(seed={seed})", ds.truth
    if is_json(spec) or shots:
        rec = read_shots(spec, **shots)
        label = f"{spec} ({rec.meta.get('description', '')})"
    else:
        rec, label = icgo_io.read_recording(spec, columns=columns), spec
    for nt in rec.notices:
        print("notice:", nt)
    return D.stations_from_recording(rec), label, None


def workflow_config(cfg: DictConfig) -> D.WorkflowConfig:
    """The :class:`icgo.discrepancy.WorkflowConfig` of a composed config, and the entry settings checked.

    Raises:
        icgo.core.errors.SettingsError: one line per bad workflow option.
        ValueError: an unknown key, or a bad ``study=`` / ``design=`` (one line).
    """
    values = {k: v for k, v in OmegaConf.to_container(cfg, resolve=True).items() if k not in ENTRY_KEYS}
    config = config_from_mapping(D.WorkflowConfig, values, "conf/discrepancy.yaml")
    if str(cfg.study) not in STUDIES:
        raise ValueError(f"study={cfg.study!r}: choose one of {', '.join(STUDIES)}")
    if str(cfg.design) not in D.DESIGNS:
        raise ValueError(f"design={cfg.design!r}: choose one of {', '.join(D.DESIGNS)}")
    n = cfg.n_stations
    if not (isinstance(n, int) and not isinstance(n, bool) and D.MIN_STATIONS <= n <= MAX_STATIONS):
        raise ValueError(f"n_stations={n!r}: must be an integer {D.MIN_STATIONS} to {MAX_STATIONS} (simulated "
                         f"stations)")
    s = cfg.seed
    if not (isinstance(s, int) and not isinstance(s, bool) and 0 <= s < 2**32):
        raise ValueError(f"seed={s!r}: must be an integer 0 <= seed < 2**32")
    if not isinstance(cfg.data, str):
        raise ValueError(f"data={cfg.data!r}: must be a path, lab_casing, sim:EFFECT[+EFFECT] or mag_cal:DEVICE")
    bool_setting(cfg, "overwrite")
    return config


def run_study(name: str, config: D.WorkflowConfig, cfg: DictConfig) -> str:
    """Run ``study=name`` and return its Markdown (the lab_casing study also writes its full report)."""
    if name == "hidden":
        return report.hidden_study_markdown(discrepancy_results.hidden_study(config, int(cfg.seed), int(cfg.n_stations)))
    if name == "devices":
        return report.devices_study_markdown(discrepancy_results.devices_study(config), config)
    if name == "lab_casing":
        study = discrepancy_results.lab_casing_study(config, int(cfg.seed))
        D.write_report(study.result, "lab_casing (training split; QC on the test split)",
                       Path(cfg.results_dir) / "discrepancy_lab_casing_report", qc=study.qc,
                       protocol=report.lab_casing_report_protocol(study))
        return report.lab_casing_study_markdown(study)
    raise ValueError(f"study={name!r}: choose none, hidden, devices or lab_casing")


def main_body(cfg: DictConfig, out_dir: Path, keep=()) -> int:
    """Run one composed config; 0, :data:`EXIT_CONFIG` (2) for a bad setting, 1 for bad input data.

    The run directory (``out_dir``) is written all at once (:class:`icgo.io.files.Output`): refused before
    anything is computed when it already holds files, unless ``overwrite=true``.
    """
    try:
        config = workflow_config(cfg)
        cmap = icgo_io.column_map(OmegaConf.to_container(cfg.columns) if cfg.get("columns") else None,
                                  cfg.get("columns_file"))
        output = None if cfg.study != "none" else Output(out_dir, setting="hydra.run.dir", overwrite=cfg.overwrite,
                                                         keep=keep, writer="experiments.discrepancy").check()
    except SettingsError as err:
        for line in err.problems:
            print(f"error: {line}", file=sys.stderr)
        return EXIT_CONFIG
    except ValueError as err:
        print(f"error: {one_line(err)}", file=sys.stderr)
        return EXIT_CONFIG
    try:
        if cfg.study != "none":
            text = run_study(str(cfg.study), config, cfg)
            print(text)
            path = Path(cfg.results_dir) / f"discrepancy_{cfg.study}.md"
            path.parent.mkdir(parents=True, exist_ok=True)
            icgo_io.atomic_write_texts([(path, text + "\n")])
            print("wrote", path)
            return 0
        shots = {k: (OmegaConf.to_container(cfg[k]) if OmegaConf.is_list(cfg[k]) else cfg[k])
                 for k in ("mag_axes", "grav_axes", "groups")}
        st, label, truth = load_stations(cfg.data, int(cfg.seed), int(cfg.n_stations), str(cfg.design), config.noise,
                                         cmap, shots)
        D.check_stations(st)  # too few stations, NaN: one line here, not a traceback from the workflow
    except SettingError as err:
        print(f"error: {one_line(err)}", file=sys.stderr)
        return EXIT_CONFIG
    except (DataError, ValueError, FileNotFoundError) as err:
        print(f"error: {err}".splitlines()[0], file=sys.stderr)
        return 1
    print(f"data: {label} ({st.n} stations, {'reference attitude' if st.has_reference else 'groups, no reference'})")
    res = D.run_workflow(st, config)
    print("\n".join(report.search_log(res) + report.step_summary(res)))
    model = PhysicsModel.from_result(res, st.G, st.B)
    qc = station_qc(model, st)
    print(qc_sentence(qc) if qc else "survey QC: no reference field given")
    with output.staged(last=("report.md",)) as stage:
        write_hydra_record(stage, cfg)
        D.write_report(res, label, stage, truth, qc)
        model.save(stage / "discrepancy_model")
    print("report:", out_dir / "report.md")
    print("model:", out_dir / "discrepancy_model.json")
    return 0


@hydra.main(version_base="1.3", config_path="../conf", config_name="discrepancy")
@one_line_errors
def main(cfg: DictConfig) -> None:
    from hydra.core.hydra_config import HydraConfig

    rc = main_body(cfg, Path(HydraConfig.get().runtime.output_dir), keep=hydra_keep())
    if rc:
        sys.exit(rc)


def cli() -> None:
    from experiments._entry import preflight

    preflight("discrepancy")
    main()


if __name__ == "__main__":
    from experiments._entry import guarded

    guarded(cli)
