"""The interface every study follows (see :mod:`icgo.studies`)."""

from __future__ import annotations

from typing import Any, Callable, NamedTuple


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
    """

    name: str
    config_cls: type
    run: Callable[[Any, Any, Any], Any]
    description: str = ""
    example: Callable[[], tuple] | None = None
    fits_models: bool = True

    def records(self, result) -> dict:
        """Named tables the study writes (``result.records``)."""
        return dict(result.records)
