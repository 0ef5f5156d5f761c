"""A progress bar over an ICGO-RELM search's iterations, and the study run with it (the ``progress`` setting).

Nothing here enters the compiled programs: the study calls the bar on the host between chunks of iterations.
"""

from __future__ import annotations

import sys

from icgo.core.errors import SettingError


class Progress:
    """A tqdm bar over the search's iterations, fed by ``run_study(progress=...)`` between chunks of iterations.

    The study runs its search in a few jitted chunks and calls this on the host after each
    (:func:`icgo.optim.sharded.run_members`); nothing enters the compiled programs, so the compilation
    cache keeps them. The bar starts after the first chunk, i.e. after
    compiling (or loading) the program, so its rate and ETA measure the search alone.
    """

    def __init__(self, desc: str):
        self.desc, self.bar = desc, None
        print(f"{desc}: compiling or loading the search program, then the bar starts", file=sys.stderr)

    def __call__(self, done: int, total: int) -> None:
        if self.bar is None:
            from tqdm.auto import tqdm

            self.bar = tqdm(total=total, initial=done, desc=self.desc, unit="it", mininterval=0.2,
                            dynamic_ncols=True, file=sys.stderr)
            return
        self.bar.update(done - self.bar.n)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def progress_enabled(setting, accelerator: bool = False) -> bool:
    """``progress`` option: ``auto`` (a bar when stderr is a terminal and the search runs on a CPU: on an
    accelerator the bar's host callback would be a round trip inside the iteration loop), true or false."""
    if isinstance(setting, bool):
        return setting
    if setting in (None, "auto"):
        return sys.stderr.isatty() and not accelerator
    raise SettingError(f"progress must be auto, true or false, got {setting!r}")


def run_with_progress(frame, scfg, meta, progress, desc: str, target=None, timings: dict | None = None):
    """``icgo.studies.icgo_relm.run_study`` with a progress bar over the optimizer's iterations (:class:`Progress`).

    The bar follows the search's iterations on the host (``run_study(progress=...)``); without an optimizer (plain
    RELM), or on an accelerator under
    ``progress=auto``, there is no bar. ``progress``: the ``progress`` setting (:func:`progress_enabled`).
    ``timings``: see ``run_study``. Prints the execution plan (``search: ...``).
    """
    from icgo.core.execution import is_accelerator
    from icgo.studies import icgo_relm as study

    plan = scfg.execution()
    enable = progress_enabled(progress, is_accelerator(plan.backend))
    print(f"search: {plan.why}")  # information, on stdout: stderr is for the one error or interruption line
    if not enable or scfg.optimizer is None:
        return study.run_study(frame, scfg, meta, target=target, timings=timings)
    bar = Progress(desc)
    try:
        return study.run_study(frame, scfg, meta, target=target, timings=timings, progress=bar)
    finally:
        bar.close()
