"""ICGO-RELM study, the Hydra front door: ``python -m experiments.run strategy=three_stage``.

Composes ``conf/config.yaml`` (groups: dataset, model, optimizer, strategy, schedule, budget, split, fitness,
experiment), makes it the typed :class:`icgo.studies.icgo_relm_run_config.RunConfig`, runs the study and writes
the run directory (``HydraConfig.get().runtime.output_dir``; its files: :mod:`icgo.studies.icgo_relm_run`), then
prints the summary table and a final line with the wall time.

Examples::

    python -m experiments.run strategy=three_stage            # make run
    python -m experiments.run strategy=all                    # five strategies, one vmapped call
    python -m experiments.run -m strategy=chaos,gaussian,wavelet,three_stage
    python -m experiments.run experiment=table3               # a paper preset (see conf/experiment)

JAX is imported inside the job (never at module import), so launchers that start worker processes never fork an
initialised XLA runtime. See docs/experiments.md.
"""

from __future__ import annotations

import sys
from pathlib import Path

import hydra
from omegaconf import DictConfig

from hydra_plugins.icgo_launcher.door import CONF_DIR, EXIT_CONFIG, check_overrides, one_line_errors, preflight


def run_job(cfg: DictConfig, outdir: Path, multirun: bool = False) -> dict | None:
    """Run one configured study into ``outdir`` (:func:`hydra_plugins.icgo_launcher.jobs.run_guarded`: a finished
    sweep job kept, a user's error one line, or a FAILED marker inside a sweep). Returns the run.json dictionary,
    or None for a failed or refused sweep job."""
    from experiments._relm_job import RelmJob
    from hydra_plugins.icgo_launcher.jobs import run_guarded

    return run_guarded(cfg, outdir, multirun, RelmJob())


@hydra.main(version_base="1.3", config_path=str(CONF_DIR), config_name="config")
@one_line_errors
def app(cfg: DictConfig) -> float | None:
    """Hydra task function: one job of a run or a sweep; returns its objective for a sweeper that minimises one
    (``hydra/sweeper=optuna``: :func:`icgo.studies.tracking_tables.objective`), None for a failed job."""
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    from icgo.studies.tracking_tables import objective

    hc = HydraConfig.get()
    record = run_job(cfg, Path(hc.runtime.output_dir), multirun=hc.mode == RunMode.MULTIRUN)
    return None if record is None else objective(Path(hc.runtime.output_dir))


def main() -> None:
    """Entry point: ``--help``, then reject unknown group options in one line, then hand over to Hydra."""
    if any(a in ("--help", "-h") for a in sys.argv[1:]):
        from hydra_plugins.icgo_launcher.run_help import run_help

        print(run_help())
        return
    preflight("config")
    err = check_overrides(sys.argv[1:])
    if err:
        print(f"error: {err}", file=sys.stderr)
        raise SystemExit(EXIT_CONFIG)
    app()


if __name__ == "__main__":
    from hydra_plugins.icgo_launcher.door import guarded

    guarded(main)
