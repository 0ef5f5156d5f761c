"""Config node of the ``icgo_local`` launcher (``hydra/launcher=icgo_local``, the default of experiments.run)."""

from dataclasses import dataclass
from typing import Optional

from hydra.core.config_store import ConfigStore


@dataclass
class IcgoLocalLauncherConf:
    _target_: str = "hydra_plugins.icgo_launcher.launcher.IcgoLocalLauncher"
    #: Jobs running at once; null: one per CPU core (``os.cpu_count()``), never more than there are jobs.
    workers: Optional[int] = None
    #: XLA CPU threads per job; null leaves XLA's default (all cores). With one job per core, one
    #: thread each: XLA's intra-op threads add nothing at the study's shapes (results/performance.md).
    xla_threads: Optional[int] = 1


ConfigStore.instance().store(group="hydra/launcher", name="icgo_local", node=IcgoLocalLauncherConf,
                             provider="icgo")
