"""``hydra/launcher=slurm``: submitit's SLURM launcher with icgo's survival and fail-fast rules.

Two changes to ``hydra_submitit_launcher``'s SlurmLauncher, whose ``launch``
ends in ``[j.results()[0] for j in jobs]``:

* a job that ends without a result (``scancel``, a node failure, the time
  limit, out of memory) no longer raises out of the sweep: its directory gets
  the ``FAILED`` marker ("killed: SLURM job <id> ended CANCELLED ...") and the
  other jobs' results are collected; the end-of-sweep report
  (:mod:`hydra_plugins.icgo_launcher.report`) then lists every job;
* a request no node of the partition can hold (more CPUs or memory per job)
  fails before submission, in one line saying what the cluster offers
  (:mod:`hydra_plugins.icgo_launcher.slurm_check`), instead of pending for ever.
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path
from typing import Sequence

from hydra.core.singleton import Singleton
from hydra.core.utils import JobReturn, JobStatus, filter_overrides
from omegaconf import OmegaConf

from hydra_plugins.hydra_submitit_launcher.config import BaseQueueConf
from hydra_plugins.hydra_submitit_launcher.submitit_launcher import SlurmLauncher
from hydra_plugins.icgo_launcher.jobs import previous_run, write_failure
from hydra_plugins.icgo_launcher.slurm_check import cluster_offer, unschedulable
from icgo.core.settings import first_line, interrupts_raise

log = logging.getLogger(__name__)

EXIT_CONFIG = 2


class IcgoSlurmLauncher(SlurmLauncher):
    """SlurmLauncher whose sweep loses only the jobs that died, and that refuses an unschedulable request."""

    def _check_request(self) -> None:
        p = self.params
        offer = cluster_offer(p.get("partition"))
        msg = unschedulable(p.get("cpus_per_task"), p.get("mem_gb"), p.get("partition"), offer,
                            tasks_per_node=p.get("tasks_per_node") or 1)
        if msg:
            print(f"error: {msg}", file=sys.stderr)
            raise SystemExit(EXIT_CONFIG)

    def _executor(self):
        import submitit  # here, not at the top: Hydra imports this module at every start (its plugin scan)

        init_keys = {"submitit_folder", "max_num_timeout"}
        executor = submitit.AutoExecutor(cluster=self._EXECUTOR, folder=self.params["submitit_folder"],
                                         **({f"{self._EXECUTOR}_max_num_timeout": self.params["max_num_timeout"]}
                                            if "max_num_timeout" in self.params else {}))
        base = set(OmegaConf.structured(BaseQueueConf).keys())
        executor.update_parameters(**{k if k in base else f"{self._EXECUTOR}_{k}": v
                                      for k, v in self.params.items() if k not in init_keys})
        return executor

    def launch(self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int) -> Sequence[JobReturn]:
        with interrupts_raise():  # Ctrl-C reaches submitit as KeyboardInterrupt, as before
            return self._launch(job_overrides, initial_job_idx)

    def _launch(self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int) -> Sequence[JobReturn]:
        self._check_request()
        for overrides in job_overrides:  # every job's config composed here first: a refused value submits nothing
            self.hydra_context.config_loader.load_sweep_config(self.config, list(overrides))
        sweep_dir = Path(str(self.config.hydra.sweep.dir))
        sweep_dir.mkdir(parents=True, exist_ok=True)
        log.info("SLURM sweep output dir: %s", sweep_dir)
        params = []
        for i, overrides in enumerate(job_overrides):
            idx = initial_job_idx + i
            log.info("\t#%d : %s", idx, " ".join(filter_overrides(overrides)))
            params.append((list(overrides), "hydra.sweep.dir", idx, f"job_id_for_{idx}", Singleton.get_state()))
        jobs = self._executor().map_array(self, *zip(*params))
        returns = []
        for (overrides, _, idx, _, _), job in zip(params, jobs):
            try:
                returns.append(job.results()[0])
                continue
            except Exception as e:  # UncompletedJobError (cancelled, timed out, node lost) or FailedJobError
                from submitit.core.utils import UncompletedJobError  # (submitit: see _executor)

                job_dir = sweep_dir / str(idx)  # the default hydra.sweep.subdir, as the sweep report reads it
                state = job.state
                if previous_run(job_dir) is None:
                    died = isinstance(e, UncompletedJobError)
                    write_failure(job_dir, f"{'killed' if died else 'failed'}: SLURM job {job.job_id} ended {state} "
                                           f"without a result ({type(e).__name__}: {first_line(e)})")
                log.error("job %d (SLURM %s) ended %s", idx, job.job_id, state)
            returns.append(JobReturn(overrides=overrides, cfg=None, hydra_cfg=None, working_dir=str(sweep_dir / str(idx)),
                                     task_name="", status=JobStatus.COMPLETED, _return_value=None))
        return returns
