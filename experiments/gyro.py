"""Gyro inclinometer study entry point: ``conf/gyro.yaml`` -> :mod:`icgo.studies.gyro` -> ``results/gyro_*``.

Tables and figures go to ``results/gyro_*`` (:mod:`icgo.studies.gyro_report`) with ``gyro_run.json``, the fitted
models (lookup table, networks, RELMs) into the Hydra run directory (``outputs/gyro/<time>/models/``)::

    .venv/bin/python -m experiments.gyro                       # full study
    .venv/bin/python -m experiments.gyro n_seeds=3 net.epochs=300 sweep.enabled=false relm.enabled=false
"""

from __future__ import annotations

import time
from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

from experiments._entry import enable_jax_cache, one_line_errors, study_main
from icgo.io.files import Output, staged_results
from icgo.studies.gyro_report import rate_qc_sentence, write_results, write_run_summary

ROOT = Path(__file__).resolve().parents[1]

#: Settings of the entry point, not of the study (excluded from the study's config dataclass).
ENTRY_KEYS = ("out_dir", "jax_cache")


def study_config(cfg: DictConfig):
    """:class:`icgo.studies.gyro.GyroConfig` from a composed config (unknown keys refused, one line)."""
    from icgo.core.settings import config_from_mapping
    from icgo.studies.gyro import GyroConfig

    values = {k: v for k, v in OmegaConf.to_container(cfg, resolve=True).items() if k not in ENTRY_KEYS}
    return config_from_mapping(GyroConfig, values, "conf/gyro.yaml")


def run(cfg: DictConfig, models_dir: Path | None = None, config=None) -> dict:
    """The whole study; writes ``results/gyro_*`` and the models (into ``models_dir``; None: not saved) and returns
    the ``gyro_run.json`` summary. ``config``: the study config if already built from ``cfg`` (else built here)."""
    import jax

    import icgo  # noqa: F401  (float64)
    from icgo.studies import gyro as study

    config = study_config(cfg) if config is None else config
    if cfg.get("jax_cache"):
        p = Path(str(cfg.jax_cache))
        enable_jax_cache(str(p if p.is_absolute() else ROOT / p))
    out = Path(str(cfg.out_dir))
    out = out if out.is_absolute() else ROOT / out
    Output(out, setting="out_dir", shared=True).check()  # a file in the way, a read-only folder: before the study
    t_start = time.perf_counter()
    data = study.load_data(config)
    result = study.run(data, config, jax.random.PRNGKey(config.seed))
    with staged_results(out, last="gyro_run.json") as stage:
        write_results(result, data, config, stage, models_dir)
        summary = write_run_summary(result, time.perf_counter() - t_start, OmegaConf.to_container(cfg, resolve=True),
                                    stage)
    print(rate_qc_sentence(result.summary["qc"]))
    print(f"[gyro] done in {summary['total_seconds']:.0f} s; results in {out}"
          + (f"; {len(result.models)} models in {models_dir}" if models_dir is not None else ""), flush=True)
    return summary


@hydra.main(config_path="../conf", config_name="gyro", version_base="1.3")
@one_line_errors
def main(cfg: DictConfig) -> None:
    """Hydra entry point: ``python -m experiments.gyro [overrides]``; a bad setting exits 2 with one line."""
    study_main(cfg, study_config, run)


def cli() -> None:
    from experiments._entry import preflight

    preflight("gyro")
    main()


if __name__ == "__main__":
    from experiments._entry import guarded

    guarded(cli)
