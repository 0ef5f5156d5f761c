"""Apply a fitted model to a new survey: ``python -m experiments.apply model=<run dir or model> data=<survey.csv>``.

Loads any saved model (:func:`icgo.models.registry.load_model`; a run directory of
``experiments.run`` gives its main model, ``relm_compensation``; one of ``experiments.calibrate`` the
calibration its record recommends), reads the
survey (:func:`icgo.io.recording.read_recording`), corrects it with
:func:`icgo.survey.apply.correct_survey` and writes ``<survey>_corrected.csv`` and
``<survey>_corrected.meta.json`` (the model, the QC counts before/after, the
metrics where the survey has a reference azimuth, the notices) into the run
directory (``outputs/apply/<date>/<time>/`` or ``out=``). Prints the MAE (or
"QC only") and the QC counts. A bad setting, model or survey is one line on
stderr and exit status 2; nothing is written then.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

from experiments._entry import CONF_DIR, EXIT_CONFIG, one_line

KEYS = ("model", "data", "method", "require_meta", "out", "qc")


def model_path(path: Path) -> Path:
    """The model file a ``model=`` setting names: a header, a run directory's main model, or the calibration a
    calibrate run directory recommends."""
    from icgo.reporting import records

    if path.is_dir() and (path / records.CALIBRATION_FILE).is_file():
        return records.recommended_model(path)
    if path.is_dir() and (path / records.RUN_FILE).is_file():
        run = records.read_run(path)
        if run.get("models"):
            return path / run["models"][0]
    return path


def run_apply(cfg: DictConfig, out_dir: Path) -> dict:
    """Check the settings, correct the survey, write the two files; return the meta dict.

    Raises:
        ValueError (ModelError, DataError, RecordError, SettingError): one line.
    """
    from icgo.core.settings import config_from_mapping
    from icgo.io.recording import atomic_write_texts, read_recording
    from icgo.models.registry import load_model
    from icgo.physics.qc import QCBands
    from icgo.survey.apply import correct_survey

    unknown = sorted(set(cfg.keys()) - set(KEYS))
    if unknown:
        raise ValueError(f"unknown setting(s) {unknown}; experiments.apply takes {list(KEYS)}")
    for k in ("model", "data"):
        if OmegaConf.is_missing(cfg, k) or cfg[k] in (None, ""):
            raise ValueError(f"{k}= is required: python -m experiments.apply model=<run dir or model .json> "
                             f"data=<survey.csv>")
    bands = config_from_mapping(QCBands, OmegaConf.to_container(cfg.qc, resolve=True), "qc")
    mpath = model_path(Path(str(cfg.model)).expanduser())
    model = load_model(mpath)
    rec = read_recording(Path(str(cfg.data)).expanduser(), require_meta=bool(cfg.require_meta), require_reference=False)
    res = correct_survey(model, rec.frame, rec.field, method=cfg.method, bands=bands)
    stem = Path(str(cfg.data)).stem
    meta = {"source": rec.source, "model": str(mpath), "model_kind": model.KIND,
            "method": cfg.method if cfg.method is not None else getattr(model, "selected", None),
            "model_data_hash": model.data_hash, "rows": int(len(res.table)), "metrics": res.metrics, "qc": res.qc,
            "qc_bands": OmegaConf.to_container(cfg.qc, resolve=True),
            "notices": list(rec.notices) + res.notices, "units": {"angles": "deg", "B": "nT", "G": "g"}}
    if rec.field is not None:
        meta.update({k: getattr(rec.field, k) for k in ("total_field_nT", "dip_deg", "declination_deg", "gravity_g")})
    out_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_texts([(out_dir / f"{stem}_corrected.csv", res.table.to_csv(index=False, lineterminator="\n")),
                        (out_dir / f"{stem}_corrected.meta.json", json.dumps(meta, indent=2) + "\n")])
    return meta


def report(meta: dict, out_dir: Path, stem: str) -> None:
    """The printed summary: metrics (or QC only), QC counts, notices, files."""
    m = meta["metrics"]
    if m:
        c = m["compensated"]
        raw = m.get("raw")
        print(f"corrected survey: {meta['rows']} stations, MAE {c['mae']:.4f} deg, RMSE {c['rmse']:.4f} deg, "
              f"R^2 {c['r2']:.4f}" + (f" (raw MAE {raw['mae']:.4f} deg)" if raw else ""))
    else:
        print(f"corrected survey: {meta['rows']} stations; no reference azimuth, QC only")
    for stage, counts in (meta["qc"] or {}).items():
        print(f"QC {stage}: {counts['any']} of {counts['n']} stations flagged "
              f"(|G| {counts['g']}, |B| {counts['b']}, dip {counts['dip']})")
    for n in meta["notices"]:
        print(f"notice: {n}")
    print(f"wrote {out_dir / (stem + '_corrected.csv')} and {stem}_corrected.meta.json")


@hydra.main(version_base="1.3", config_path=str(CONF_DIR / "apply"), config_name="apply")
def main(cfg: DictConfig) -> None:
    """Hydra task: one survey, one model."""
    from hydra.core.hydra_config import HydraConfig

    out = Path(str(cfg.out)).expanduser() if cfg.get("out") else Path(HydraConfig.get().runtime.output_dir)
    try:
        meta = run_apply(cfg, out)
    except ValueError as e:
        print(f"error: {one_line(e)}", file=sys.stderr)
        raise SystemExit(EXIT_CONFIG) from None
    report(meta, out, Path(str(cfg.data)).stem)


if __name__ == "__main__":
    from experiments._entry import preflight

    preflight("apply", conf_dir=CONF_DIR / "apply")
    main()
