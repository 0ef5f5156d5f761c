"""One discrepancy job of the front door (``experiments.discrepancy``): a ``data=`` value read into stations, the
entry settings checked, one ``study=`` run and written, or the workflow fitted and its report and physics model
written (:mod:`icgo.discrepancy`, :class:`icgo.artifacts.discrepancy.PhysicsModel`).
"""

from __future__ import annotations

import json
from pathlib import Path

from icgo import discrepancy as D
from icgo.core.errors import SettingError
from icgo.core.settings import config_from_mapping
from icgo.discrepancy import report
from icgo.io import mag_cal_bundled
from icgo.io import recording as icgo_io
from icgo.io.shots import is_json
from icgo.artifacts.discrepancy import PhysicsModel
from icgo.studies.discrepancy import results as discrepancy_results
from icgo.studies.common.shots import read_shots

#: Settings of the entry point, not of the workflow (excluded from :class:`icgo.discrepancy.WorkflowConfig`).
ENTRY_KEYS = ("data", "study", "seed", "n_stations", "design", "results_dir", "overwrite", "hydra", "columns",
              "columns_file", "mag_axes", "grav_axes", "groups", "jax_cache_dir")

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
    with ``groups=``; :func:`icgo.studies.common.shots.read_shots`).
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
    return D.stations_from_recording(rec), label, read_truth(spec)


def read_truth(spec: str) -> dict | None:
    """The ground truth beside a recording (``NAME.truth.json`` beside ``NAME.csv``, as ``python -m icgo.datasets``
    writes it), or None when there is none or it is not a JSON object."""
    path = Path(spec)
    truth = path.with_name(path.stem + ".truth.json") if path.suffix == ".csv" else None
    if truth is None or not truth.is_file():
        return None
    try:
        out = json.loads(truth.read_text())
    except (OSError, ValueError):
        return None
    return out if isinstance(out, dict) else None


def workflow_config(values: dict) -> D.WorkflowConfig:
    """The :class:`icgo.discrepancy.WorkflowConfig` of a composed config (a plain mapping), the entry settings
    (:data:`ENTRY_KEYS`) checked.

    Raises:
        icgo.core.errors.SettingsError: one line per bad workflow option.
        ValueError: an unknown key, or a bad entry setting (one line).
    """
    config = config_from_mapping(D.WorkflowConfig, {k: v for k, v in values.items() if k not in ENTRY_KEYS},
                                 "conf/discrepancy.yaml")
    check_entry_settings(values["study"], values["design"], values["n_stations"], values["seed"], values["data"])
    if not isinstance(values.get("overwrite"), bool):
        raise SettingError(f"overwrite={values.get('overwrite')!r}: must be true or false")
    return config


def check_entry_settings(study, design, n_stations, seed, data) -> None:
    """The entry settings besides the workflow's: ``study=``, ``design=``, ``n_stations=``, ``seed=``, ``data=``.

    Raises:
        ValueError: the first bad one (one line naming it).
    """
    if str(study) not in STUDIES:
        raise ValueError(f"study={study!r}: choose one of {', '.join(STUDIES)}")
    if str(design) not in D.DESIGNS:
        raise ValueError(f"design={design!r}: choose one of {', '.join(D.DESIGNS)}")
    if not (isinstance(n_stations, int) and not isinstance(n_stations, bool)
            and D.MIN_STATIONS <= n_stations <= MAX_STATIONS):
        raise ValueError(f"n_stations={n_stations!r}: must be an integer {D.MIN_STATIONS} to {MAX_STATIONS} "
                         "(simulated stations)")
    if not (isinstance(seed, int) and not isinstance(seed, bool) and 0 <= seed < 2**32):
        raise ValueError(f"seed={seed!r}: must be an integer 0 <= seed < 2**32")
    if not isinstance(data, str):
        raise ValueError(f"data={data!r}: must be a path, lab_casing, sim:EFFECT[+EFFECT] or mag_cal:DEVICE")


def run_study(name: str, config: D.WorkflowConfig, seed: int, n_stations: int, results_dir: Path) -> str:
    """Run ``study=name`` and return its Markdown (the lab_casing study also writes its full report into
    ``results_dir``)."""
    if name == "hidden":
        return report.hidden_study_markdown(discrepancy_results.hidden_study(config, seed, n_stations))
    if name == "devices":
        return report.devices_study_markdown(discrepancy_results.devices_study(config), config)
    if name == "lab_casing":
        study = discrepancy_results.lab_casing_study(config, seed)
        D.write_report(study.result, "lab_casing (training split; QC on the test split)",
                       Path(results_dir) / "discrepancy_lab_casing_report", qc=study.qc,
                       protocol=report.lab_casing_report_protocol(study))
        return report.lab_casing_study_markdown(study)
    raise ValueError(f"study={name!r}: choose none, hidden, devices or lab_casing")


def write_study(name: str, config: D.WorkflowConfig, seed: int, n_stations: int, results_dir: Path) -> Path:
    """Run ``study=name``, print its Markdown and write it to ``results_dir/discrepancy_<name>.md`` (returned)."""
    text = run_study(name, config, seed, n_stations, results_dir)
    print(text)
    path = Path(results_dir) / f"discrepancy_{name}.md"
    path.parent.mkdir(parents=True, exist_ok=True)
    icgo_io.atomic_write_texts([(path, text + "\n")])
    return path


def write_fit(stage: Path, res, label: str, truth, qc, model: PhysicsModel) -> None:
    """``report.md``, ``discrepancy.json``, the figures and ``discrepancy_model.json`` + ``.npz`` into ``stage``."""
    D.write_report(res, label, stage, truth, qc)
    model.save(stage / "discrepancy_model")
