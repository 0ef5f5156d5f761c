"""Apply a fitted model to a new survey: ``python -m experiments.apply model=<run dir or model> data=<survey.csv>``.

Loads any saved model (:func:`icgo.artifacts.registry.load_model`; a run directory of ``experiments.run`` gives its
main model, ``relm_compensation``; one of ``experiments.calibrate`` the calibration its record recommends), corrects
the survey and writes ``<survey>_corrected.csv`` and ``<survey>_corrected.meta.json`` into the run directory
(``outputs/apply/<date>/<time>/`` or ``out=``), both or neither (:mod:`icgo.survey.apply_settings`; a directory that
already holds files is refused unless ``overwrite=true``, which replaces its content whole). Prints the MAE (or "QC
only") and the QC counts. A bad setting is one line on stderr and exit status 2, a bad model, survey or output place
exit status 1; nothing is written then.
"""

from __future__ import annotations

from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

from hydra_plugins.icgo_launcher.door import CONF_DIR, hydra_cli, hydra_keep, one_line_errors, write_hydra_record


def settings(cfg: DictConfig) -> dict:
    """The composed config as a plain mapping, a mandatory value not given (``???``) as None."""
    return {k: None if OmegaConf.is_missing(cfg, k) else v
            for k, v in OmegaConf.to_container(cfg, resolve=True, throw_on_missing=False).items()}


def run_apply(cfg: DictConfig, out_dir: Path, keep=()) -> dict:
    """:func:`icgo.survey.apply_settings.run_apply` of a composed config, Hydra's record written with the files."""
    from icgo.survey.apply_settings import run_apply

    return run_apply(settings(cfg), out_dir, keep, lambda stage: write_hydra_record(stage, cfg))


@hydra.main(version_base="1.3", config_path=str(CONF_DIR / "apply"), config_name="apply")
@one_line_errors
def main(cfg: DictConfig) -> None:
    """Hydra task: one survey, one model (a bad setting exits 2, a bad model or survey 1, one line each)."""
    from hydra.core.hydra_config import HydraConfig

    from icgo.survey.apply_run import report
    from icgo.survey.apply_settings import check_settings

    check_settings(settings(cfg))  # out= among them, before it is used
    out = Path(str(cfg.out)).expanduser() if cfg.get("out") else Path(HydraConfig.get().runtime.output_dir)
    meta = run_apply(cfg, out, keep=hydra_keep())
    report(meta, out, Path(str(cfg.data)).stem)
    from hydra_plugins.icgo_launcher.tracking_hooks import track_job

    track_job(OmegaConf.to_container(cfg, resolve=True), out, door="apply")  # MLflow, where installed and not off
    if meta["verdict"]["exit_code"]:  # far outside the training domain (icgo.survey.verdict.EXIT_OUT_OF_DOMAIN)
        raise SystemExit(meta["verdict"]["exit_code"])


if __name__ == "__main__":
    hydra_cli("apply", main, conf_dir=CONF_DIR / "apply")
