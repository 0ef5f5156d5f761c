"""The ICGO-RELM job behind ``python -m experiments.run``, as the launcher runs it
(:func:`hydra_plugins.icgo_launcher.jobs.run_guarded`): the composed config made typed
(:class:`icgo.studies.icgo_relm_run_config.RunConfig`), the study run and its directory written
(:mod:`icgo.studies.icgo_relm_run`) with Hydra's record of the job. Nothing here imports JAX at module import.
"""

from __future__ import annotations

import time
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from hydra_plugins.icgo_launcher.jobs import FAILURE_FILES, cfg_hash


def run_config(cfg: DictConfig):
    """The typed config of a composed config (``hydra`` node excluded): every key and check, one line naming
    the key."""
    from icgo.studies.icgo_relm_run_config import RunConfig

    return RunConfig.from_mapping(OmegaConf.to_container(cfg, resolve=True))


def _hydra_log() -> tuple[str, ...]:
    """Hydra's job log in the run directory (left alone), if this is a Hydra job."""
    from hydra.core.hydra_config import HydraConfig

    return (f"{HydraConfig.get().job.name}.log",) if HydraConfig.initialized() else ()


class RelmJob:
    """:class:`hydra_plugins.icgo_launcher.jobs.Job` of the ICGO-RELM door (one data set or ``worlds=N``)."""

    def check(self, cfg: DictConfig, outdir: Path):
        from icgo.studies.icgo_relm_run import run_output

        run = run_config(cfg)
        run_output(outdir, run.overwrite, _hydra_log(), FAILURE_FILES)
        return run

    def compute(self, run, t0: float):
        from icgo.core.devices import enable_jax_cache, start_devices
        from icgo.studies import icgo_relm_run

        devices = start_devices()  # before JAX's backend starts: jax.distributed, the CPU's host devices
        scfg = run.study_config()  # every check before any computation (imports the study, JAX with it)
        timings = {"import_s": time.perf_counter() - t0}
        enable_jax_cache(run.jax_cache_dir)
        computed = icgo_relm_run.compute(run, scfg, timings)
        return computed, icgo_relm_run.run_info(run, computed.desc, timings, devices, t0)

    def write(self, outdir: Path, cfg: DictConfig, run, computed) -> dict:
        from hydra.core.hydra_config import HydraConfig

        from hydra_plugins.icgo_launcher.door import hydra_files
        from icgo.studies.icgo_relm_run import write_run

        hydra = {f".hydra/{k}": v for k, v in hydra_files(cfg).items()} if HydraConfig.initialized() else {}
        return write_run(outdir, run, *computed, config_yaml=OmegaConf.to_yaml(cfg, resolve=True),
                         config_sha256=cfg_hash(cfg), records=hydra, keep=_hydra_log(), ignore=FAILURE_FILES)

    def report(self, run, computed, record: dict, outdir: Path, t0: float) -> None:
        from icgo.studies.icgo_relm_run import print_run

        print_run(run, computed[0], record, outdir, t0)
