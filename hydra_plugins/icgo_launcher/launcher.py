"""The ``icgo_local`` Hydra launcher class (the work is in :mod:`._core`, imported when a sweep launches)."""

from __future__ import annotations

from typing import Optional, Sequence

from hydra.core.utils import JobReturn
from hydra.plugins.launcher import Launcher
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig


class IcgoLocalLauncher(Launcher):
    """Runs each sweep job in its own spawned process, ``workers`` at a time.

    A job whose process dies (killed by its PID, out of memory) costs only that
    job: it is marked ``FAILED`` ("killed by signal ...") and the sweep goes on.
    """

    def __init__(self, workers: Optional[int] = None, xla_threads: Optional[int] = 1) -> None:
        self.workers = workers
        self.xla_threads = xla_threads
        self.config: Optional[DictConfig] = None
        self.task_function: Optional[TaskFunction] = None
        self.hydra_context: Optional[HydraContext] = None

    def setup(self, *, hydra_context: HydraContext, task_function: TaskFunction, config: DictConfig) -> None:
        self.config = config
        self.task_function = task_function
        self.hydra_context = hydra_context

    def launch(self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int) -> Sequence[JobReturn]:
        from . import _core

        return _core.launch(self, job_overrides, initial_job_idx)
