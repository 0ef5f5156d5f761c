"""MISMA study entry point: ``conf/misma.yaml`` -> :mod:`icgo.studies.misma` -> ``results/misma_*``.

One command writes every table and figure into ``results/misma_*`` and the
fitted calibrations into the Hydra run directory (``outputs/misma/<time>/models/``)::

    .venv/bin/python -m experiments.misma                    # full study
    .venv/bin/python -m experiments.misma simulated.repeats=3 simulated.n_iter=300 real.enabled=false

The science is in :mod:`icgo.studies.misma`, the tables, figures, summary and models in
:mod:`icgo.studies.misma_report`; this file composes the config, calls ``run`` and writes through the report.
"""

from __future__ import annotations

from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

from experiments._entry import one_line_errors, study_main
from icgo.io.files import Output, staged_results
from icgo.studies.misma_report import write_results

ROOT = Path(__file__).resolve().parents[1]

#: Settings of the entry point, not of the study (excluded from the study's config dataclass).
ENTRY_KEYS = ("out_dir",)


def study_config(cfg: DictConfig):
    """:class:`icgo.studies.misma_config.MismaConfig` from a composed config (unknown keys refused, one line)."""
    from icgo.core.settings import config_from_mapping
    from icgo.studies.misma_config import MismaConfig

    values = {k: v for k, v in OmegaConf.to_container(cfg, resolve=True).items() if k not in ENTRY_KEYS}
    return config_from_mapping(MismaConfig, values, "conf/misma.yaml")


def run(cfg: DictConfig, models_dir: Path | None = None, config=None):
    """Run the study described by ``cfg`` (conf/misma.yaml) and write its outputs; returns the study result.

    Args:
        cfg: the composed config. models_dir: where the fitted models go (None: not saved).
        config: the study config if already built from ``cfg`` (else built here).
    """
    import jax

    import icgo  # noqa: F401  (float64)
    from icgo.studies import misma as study

    config = study_config(cfg) if config is None else config
    out = Path(str(cfg.out_dir))
    out = out if out.is_absolute() else ROOT / out
    Output(out, setting="out_dir", shared=True).check()  # a file in the way, a read-only folder: before the study
    result = study.run(None, config, jax.random.PRNGKey(config.seed))
    with staged_results(out, last="misma_summary.json") as stage:
        write_results(result, OmegaConf.to_container(cfg, resolve=True), stage, models_dir, config)
    if models_dir is not None:
        print(f"[misma] {len(result.models)} fitted calibrations in {models_dir}")
    return result


@hydra.main(config_path="../conf", config_name="misma", version_base="1.3")
@one_line_errors
def main(cfg: DictConfig) -> None:
    """Hydra entry point: ``python -m experiments.misma [overrides]``; a bad setting exits 2 with one line."""
    study_main(cfg, study_config, run)


def cli() -> None:
    from experiments._entry import preflight

    preflight("misma")
    main()


if __name__ == "__main__":
    from experiments._entry import guarded

    guarded(cli)
