"""Any registered study (:data:`icgo.studies.registry.STUDIES`) run from its settings: its typed config, load ->
run -> write with every output file staged (all at once, or none) and Hydra's record of the job beside them. The
Hydra doors reach it through the one study main (:func:`experiments._study_main.study_main`), the command-line doors
(``generalisation``, ``optimizers``) directly. Nothing here imports JAX at module import.
"""

from __future__ import annotations

import logging
import sys
import time
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from experiments._door import repo_path, write_hydra_record
from icgo.core.settings import first_line


def study_config(name: str, cfg: DictConfig, entry_keys=(), config_name: str | None = None):
    """The typed config of ``STUDIES[name]`` (its ``config_cls``) from a composed config, the door's own settings
    (``entry_keys``) left out: an unknown key or a bad value is one ``ValueError`` line naming it (the YAML named in
    it: ``conf/<config_name or name>.yaml``)."""
    from icgo.core.settings import config_from_mapping
    from icgo.studies.registry import get_study

    values = {k: v for k, v in OmegaConf.to_container(cfg, resolve=True).items() if k not in entry_keys}
    return config_from_mapping(get_study(name).config_cls, values, f"conf/{config_name or name}.yaml")


def progress_to_stdout(name: str) -> None:
    """The progress lines of ``STUDIES[name]`` (its run module's INFO log) printed as they are, one a line (a
    command-line door; a Hydra door logs through Hydra's handlers)."""
    from icgo.studies.registry import get_study

    log_ = logging.getLogger(get_study(name).run.__module__)
    if not log_.handlers:
        handler = logging.StreamHandler(sys.stdout)
        handler.setFormatter(logging.Formatter("%(message)s"))
        log_.addHandler(handler)
        log_.setLevel(logging.INFO)


def run_study(name: str, config, output, *, inputs: dict | None = None, models_dir: Path | None = None,
              settings: dict | None = None, argv=(), cfg: DictConfig | None = None):
    """Load -> run -> write of ``STUDIES[name]``: the outputs into ``output`` (a checked
    :class:`icgo.io.files.Output`) all at once, the models into ``models_dir`` (None: not saved); prints what the
    study's ``write`` returns and returns the study's result. ``inputs``: keyword inputs of the study's ``load``;
    ``settings``: the composed settings the outputs record; ``argv``: the command line's arguments; ``cfg``: the
    composed config of a Hydra job, whose record is staged with the outputs.

    Raises:
        icgo.core.errors.DataError: an input file that is not there (one line), as any bad data.
    """
    import icgo  # noqa: F401  (float64)
    from icgo.core.errors import DataError
    from icgo.studies.registry import get_study
    from icgo.studies.common.study import Invocation

    study = get_study(name)
    started = time.perf_counter()
    try:
        data = study.load(config, **(inputs or {})) if study.load is not None else None
    except FileNotFoundError as e:
        raise DataError(first_line(e)) from None
    result = study.run(data, config, study.key(config))
    invocation = Invocation(dict(settings or {}), tuple(argv), started, output.path, models_dir)
    with output.staged(last=study.last) as stage:
        if cfg is not None:
            write_hydra_record(stage, cfg)
        message = study.write(result, data, config, stage, invocation)
        written = [p.relative_to(stage) for p in stage.rglob("*") if p.is_file()]
    if message:
        print(message, flush=True)
    from experiments._tracking import track_job

    track_job(dict(settings or {}), output.path, written, door=name)  # MLflow, where installed and not off
    return result


def run_composed(name: str, cfg: DictConfig, models_dir: Path | None = None, config=None, entry_keys=("out_dir",)):
    """:func:`run_study` of a composed config: tables into ``out_dir`` (relative to the repository root; a shared
    results folder: the study's files replace their namesakes), the models into ``models_dir``; ``jax_cache_dir``
    (where the door has it) turns on the compilation cache. ``config``: the typed config if already built."""
    from icgo.core.devices import enable_jax_cache
    from icgo.io.files import Output

    config = study_config(name, cfg, entry_keys) if config is None else config
    if cfg.get("jax_cache_dir"):
        enable_jax_cache(str(repo_path(cfg.jax_cache_dir)))
    output = Output(repo_path(cfg.out_dir), setting="out_dir", shared=True).check()  # before the study runs
    return run_study(name, config, output, models_dir=models_dir, settings=OmegaConf.to_container(cfg, resolve=True))
