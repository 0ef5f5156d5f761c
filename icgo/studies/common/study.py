"""The interface every study follows (see :mod:`icgo.studies`): its settings, its data, its run and its outputs.

A front door runs any registered study the same way (``experiments._run_study.run_study``)::

    data = study.load(config, **inputs)                 # simulated from the config, or read from the inputs
    result = study.run(data, config, study.key(config))
    with output.staged(last=study.last) as stage:       # all files at once, or none
        message = study.write(result, data, config, stage, invocation)
    print(message)
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, NamedTuple


class Invocation(NamedTuple):
    """How and where a front door runs a study: what its outputs record beside the results.

    Attributes:
        settings: the door's settings as composed (a plain, JSON-able mapping; {} for a command-line door).
        argv: the command line's arguments (named in a report's command line).
        started: ``time.perf_counter()`` when the door started loading (a report's wall time, s).
        out: the output directory the staged files become (a report names the final paths).
        models_dir: where the fitted models are saved, or None (not saved).
    """

    settings: dict
    argv: tuple
    started: float
    out: Path
    models_dir: Path | None = None


class Study(NamedTuple):
    """A registered study.

    Attributes:
        name: registry name.
        config_cls: frozen dataclass of the settings; ``config_cls()`` = the defaults
            (the one source every Hydra config is checked against).
        run: ``(data, config, key) -> result`` with ``result.models`` and ``result.records``.
        description: one line.
        example: ``() -> (data, config)``: a tiny but real instance of the study (seconds),
            used by the registry-wide tests and as a usage example.
        fits_models: False for a study that fits nothing to apply (the optimizer benchmark);
            every other study's result carries at least one fitted model.
        load: ``(config, **inputs) -> data`` for ``run``: simulated from the config, or read from the
            inputs (a front door's input settings: a data file and how to read it); None: ``run`` takes
            ``None`` and makes its own data.
        write: ``(result, data, config, stage, invocation) -> message``: every output file into the
            staging directory ``stage`` (:class:`icgo.io.files.Output`), the fitted models into
            ``invocation.models_dir``; returns what the door prints once the files are in place.
        last: the files the staged output writes last (their presence marks a complete output).
        objective: ``result -> float | None``: the one number a hyperparameter search minimises over this
            study's settings (``hydra/sweeper=optuna`` on its door), never a score on test data; None: the door
            returns nothing for a sweeper to minimise.
        seed_key: the config's seed, a dotted attribute path (``split.seed``); a config without it has no seed.
    """

    name: str
    config_cls: type
    run: Callable[[Any, Any, Any], Any]
    description: str = ""
    example: Callable[[], tuple] | None = None
    fits_models: bool = True
    load: Callable[..., Any] | None = None
    write: Callable[..., str] | None = None
    last: tuple = ()
    objective: Callable[[Any], float | None] | None = None
    seed_key: str = "seed"

    def records(self, result) -> dict:
        """Named tables the study writes (``result.records``)."""
        return dict(result.records)

    def key(self, config):
        """The PRNG key a front door runs the study with: ``PRNGKey`` of the config's seed (:attr:`seed_key`), or
        None (the study's own default) for a config without a seed."""
        import jax

        seed = config
        for name in self.seed_key.split("."):
            seed = getattr(seed, name, None)
        return None if seed is None else jax.random.PRNGKey(seed)
