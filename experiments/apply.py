"""Apply a fitted model to a new survey: ``python -m experiments.apply model=<run dir or model> data=<survey.csv>``.

Loads any saved model (:func:`icgo.artifacts.registry.load_model`; a run directory of ``experiments.run`` gives its
main model, ``relm_compensation``; one of ``experiments.calibrate`` the calibration its record recommends), corrects
the survey and writes ``<survey>_corrected.csv`` and ``<survey>_corrected.meta.json`` into the run directory
(``outputs/apply/<date>/<time>/`` or ``out=``), both or neither (:mod:`icgo.survey.apply_run`; a directory that
already holds files is refused unless ``overwrite=true``, which replaces its content whole). Prints the MAE (or "QC
only") and the QC counts. A bad setting is one line on stderr and exit status 2, a bad model, survey or output place
exit status 1; nothing is written then.
"""

from __future__ import annotations

from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

from experiments._entry import CONF_DIR, bool_setting, hydra_keep, one_line_errors, write_hydra_record

KEYS = ("model", "data", "method", "require_meta", "out", "qc", "columns", "columns_file", "overwrite", "max_mb",
        "stream_mb", "chunk_rows")


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
    from icgo.core.settings import config_from_mapping
    from icgo.io.files import Output
    from icgo.io.recording import column_map
    from icgo.artifacts.registry import load_model
    from icgo.physics.qc import QCBands
    from icgo.survey.apply_run import apply_survey, model_path

    check_settings(cfg)
    bands = config_from_mapping(QCBands, OmegaConf.to_container(cfg.qc, resolve=True), "qc")
    output = Output(out_dir, setting="out" if cfg.out else "hydra.run.dir", overwrite=cfg.overwrite, keep=keep,
                    writer="experiments.apply").check()
    mpath = model_path(Path(str(cfg.model)).expanduser())
    model = load_model(mpath)
    data = Path(str(cfg.data)).expanduser()
    cmap = column_map(OmegaConf.to_container(cfg.columns) if cfg.get("columns") else None, cfg.get("columns_file"))
    max_bytes, stream_above, chunk_rows = size_settings(cfg)
    return apply_survey(output, model, mpath, data, str(cfg.data), columns=cmap, max_bytes=max_bytes,
                        stream_above=stream_above, chunk_rows=chunk_rows, require_meta=cfg.require_meta,
                        method=cfg.method, bands=bands, qc_bands=OmegaConf.to_container(cfg.qc, resolve=True),
                        write_record=lambda stage: write_hydra_record(stage, cfg))


@hydra.main(version_base="1.3", config_path=str(CONF_DIR / "apply"), config_name="apply")
@one_line_errors
def main(cfg: DictConfig) -> None:
    """Hydra task: one survey, one model (a bad setting exits 2, a bad model or survey 1, one line each)."""
    from hydra.core.hydra_config import HydraConfig

    from icgo.survey.apply_run import report

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
