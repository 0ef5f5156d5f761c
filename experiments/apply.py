"""Apply a fitted model to a new survey: ``python -m experiments.apply model=<run dir or model> data=<survey.csv>``.

Loads any saved model (:func:`icgo.models.registry.load_model`; a run directory of
``experiments.run`` gives its main model, ``relm_compensation``; one of ``experiments.calibrate`` the
calibration its record recommends), reads the
survey (:func:`icgo.io.recording.read_recording`), corrects it with
:func:`icgo.survey.apply.correct_survey` and writes ``<survey>_corrected.csv`` and
``<survey>_corrected.meta.json`` (the model, the QC counts before/after, the
metrics where the survey has a reference azimuth, the notices) into the run
directory (``outputs/apply/<date>/<time>/`` or ``out=``), both or neither
(:class:`icgo.io.files.Output`: a directory that already holds files is refused
unless ``overwrite=true``, which replaces its content whole). Prints the MAE (or
"QC only") and the QC counts. A bad setting is one line on stderr and exit
status 2, a bad model, survey or output place exit status 1; nothing is written
then. A survey that already holds a correction's output columns (a corrected
survey) is refused: its columns would mix with the new model's.
"""

from __future__ import annotations

from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

from experiments._entry import CONF_DIR, bool_setting, hydra_keep, one_line_errors, write_hydra_record
from icgo.core.errors import DataError

KEYS = ("model", "data", "method", "require_meta", "out", "qc", "columns", "columns_file", "overwrite", "max_mb",
        "stream_mb", "chunk_rows")


def model_path(path: Path) -> Path:
    """The model file a ``model=`` setting names: a header, a run directory's main model (the first of its
    ``run.json``'s ``models``, which must be a file in that directory), or the calibration a calibrate run
    directory recommends."""
    from icgo.models.format import run_model_path
    from icgo.reporting import records

    if path.is_dir() and (path / records.CALIBRATION_FILE).is_file():
        return records.recommended_model(path)
    if path.is_dir() and ((path / records.RUN_FILE).exists() or (path / records.RUN_FILE).is_symlink()):
        return run_model_path(path)
    return path


def check_settings(cfg: DictConfig) -> None:
    """Every setting checked before anything is read or written (one SettingError line)."""
    from icgo.core.errors import SettingError

    unknown = sorted(set(cfg.keys()) - set(KEYS))
    if unknown:
        raise SettingError(f"unknown setting(s) {unknown}; experiments.apply takes {list(KEYS)}")
    for k in ("model", "data"):
        if OmegaConf.is_missing(cfg, k) or cfg[k] in (None, ""):
            raise SettingError(f"{k}= is required: python -m experiments.apply model=<run dir or model .json> "
                               f"data=<survey.csv>")
        if not isinstance(cfg[k], str):
            raise SettingError(f"{k}={cfg[k]!r}: must be a path")
    if cfg.method is not None and not isinstance(cfg.method, str):
        raise SettingError(f"method={cfg.method!r}: must be a method name or null")
    if cfg.out is not None and not isinstance(cfg.out, str):
        raise SettingError(f"out={cfg.out!r}: must be a directory path or null")
    for k in ("require_meta", "overwrite"):
        bool_setting(cfg, k)
    size_settings(cfg)


def size_settings(cfg: DictConfig) -> tuple[int, int, int]:
    """(max bytes, stream above bytes, rows per chunk) from ``max_mb``, ``stream_mb`` and ``chunk_rows``
    (defaults in conf/apply/apply.yaml; docs/data.md)."""
    from icgo.core.errors import SettingError
    from icgo.core.settings import is_int

    out = []
    for k, scale in (("max_mb", 1 << 20), ("stream_mb", 1 << 20), ("chunk_rows", 1)):
        v = cfg.get(k)
        if not (is_int(v) and v >= 1):
            raise SettingError(f"{k}={v!r}: must be an integer >= 1")
        out.append(int(v) * scale)
    return out[0], out[1], out[2]


def run_apply(cfg: DictConfig, out_dir: Path, keep=()) -> dict:
    """Check the settings, correct the survey, write the two files (all or none); return the meta dict.

    Args:
        cfg: the composed config. out_dir: the output directory (refused if it holds files, unless
            ``overwrite=true``; :class:`icgo.io.files.Output`). keep: names in it to leave alone (Hydra's log).
    Raises:
        ValueError (ModelError, DataError, RecordError, SettingError, OutputError): one line.
    """
    import pandas as pd

    from icgo.core.settings import config_from_mapping
    from icgo.io.files import Output, json_text
    from icgo.io.recording import column_map
    from icgo.io.stream import read_chunks
    from icgo.models.registry import load_model
    from icgo.physics.qc import QCBands
    from icgo.survey.apply import correct_rows, merge_rows, output_columns_in, summarise
    from icgo.survey.verdict import survey_verdict

    check_settings(cfg)
    bands = config_from_mapping(QCBands, OmegaConf.to_container(cfg.qc, resolve=True), "qc")
    output = Output(out_dir, setting="out" if cfg.out else "hydra.run.dir", overwrite=cfg.overwrite, keep=keep,
                    writer="experiments.apply").check()
    mpath = model_path(Path(str(cfg.model)).expanduser())
    model = load_model(mpath)
    data = Path(str(cfg.data)).expanduser()
    cmap = column_map(OmegaConf.to_container(cfg.columns) if cfg.get("columns") else None, cfg.get("columns_file"))
    max_bytes, stream_above, chunk_rows = size_settings(cfg)
    chunks = read_chunks(data, max_bytes=max_bytes, stream_above=stream_above, chunk_rows=chunk_rows,
                         require_meta=cfg.require_meta, require_reference=False, columns=cmap)
    stem = data.stem
    with output.staged(last=(f"{stem}_corrected.meta.json",)) as stage:
        out_csv, parts, notices, rec, n_rows = stage / f"{stem}_corrected.csv", [], [], None, 0
        for k, rec in enumerate(chunks):  # a small survey is one chunk; a large one streams in bounded memory
            if k == 0:
                held = output_columns_in(rec.frame.columns)
                if held:
                    raise DataError(f"{data}: already holds the output columns of a correction ({', '.join(held[:4])}"
                                    f"{', ...' if len(held) > 4 else ''}): it is a corrected survey; apply the model "
                                    f"to the original survey (mixing two models' columns is refused)")
            notices += rec.notices
            n_rows += len(rec.frame)
            parts.append(correct_rows(model, rec.frame, rec.field, method=cfg.method, bands=bands))
            if k == 1:  # streaming: the first chunk's table goes out now, every later one as it comes
                parts[0].table.to_csv(out_csv, index=False, lineterminator="\n")
                parts[0] = parts[0]._replace(table=pd.DataFrame())  # (not a slice: a slice keeps the table)
            if k >= 1:
                parts[k].table.to_csv(out_csv, index=False, lineterminator="\n", header=False, mode="a")
                parts[k] = parts[k]._replace(table=pd.DataFrame())
        streamed = len(parts) > 1
        res = summarise(model, merge_rows(parts) if streamed else parts[0], rec.field, positions_table=not streamed)
        if not streamed:  # one chunk: its table, positions included, is the file
            res.table.to_csv(out_csv, index=False, lineterminator="\n")
        elif res.trajectory:
            res.trajectory.pop("table").to_csv(stage / f"{stem}_positions.csv", index=False, lineterminator="\n")
        verdict = survey_verdict(res, model, bands, out_csv=str(out_dir / f"{stem}_corrected.csv"),
                                 model_path=str(mpath), survey_path=str(cfg.data), method=cfg.method)
        meta = {"source": rec.source, "model": str(mpath), "model_kind": model.KIND,
                "method": cfg.method if cfg.method is not None else getattr(model, "selected", None),
                "model_data_hash": model.data_hash, "rows": n_rows,
                "chunks": len(parts), "metrics": res.metrics, "qc": res.qc,
                "qc_bands": OmegaConf.to_container(cfg.qc, resolve=True),
                "notices": notices + res.notices, "doubts": res.doubts,
                "units": {"angles": "deg", "B": "nT", "G": "g"},
                "trajectory": res.trajectory, "verdict": verdict.as_dict()}
        if streamed and res.trajectory:
            meta["positions_file"] = f"{stem}_positions.csv"
        if rec.field is not None:
            meta.update({k: getattr(rec.field, k) for k in ("total_field_nT", "dip_deg", "declination_deg",
                                                             "gravity_g")})
        (stage / f"{stem}_corrected.meta.json").write_text(json_text(meta))
        write_hydra_record(stage, cfg)
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
    from icgo.survey.verdict import from_dict

    print(from_dict(meta["verdict"]).text())


@hydra.main(version_base="1.3", config_path=str(CONF_DIR / "apply"), config_name="apply")
@one_line_errors
def main(cfg: DictConfig) -> None:
    """Hydra task: one survey, one model (a bad setting exits 2, a bad model or survey 1, one line each)."""
    from hydra.core.hydra_config import HydraConfig

    check_settings(cfg)  # out= among them, before it is used
    out = Path(str(cfg.out)).expanduser() if cfg.get("out") else Path(HydraConfig.get().runtime.output_dir)
    meta = run_apply(cfg, out, keep=hydra_keep())
    report(meta, out, Path(str(cfg.data)).stem)
    if meta["verdict"]["exit_code"]:  # far outside the training domain (icgo.survey.verdict.EXIT_OUT_OF_DOMAIN)
        raise SystemExit(meta["verdict"]["exit_code"])


def cli() -> None:
    from experiments._entry import preflight

    preflight("apply", conf_dir=CONF_DIR / "apply")
    main()


if __name__ == "__main__":
    from experiments._entry import guarded

    guarded(cli)
