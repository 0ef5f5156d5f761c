"""Transitional: the front-door helpers moved to :mod:`hydra_plugins.icgo_launcher.door`,
:mod:`hydra_plugins.icgo_launcher.jobs`, :mod:`icgo.core.devices` and :mod:`icgo.io.files`; what is left here
goes with the typed configs."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import NoReturn

from omegaconf import DictConfig, OmegaConf

from hydra_plugins.icgo_launcher.door import (  # noqa: F401
    CONF_DIR, EXIT_CONFIG, STUDY_GROUPS, check_overrides, check_plain_overrides, group_options, hydra_files,
    hydra_keep, one_line_errors, preflight, write_hydra_record)
from hydra_plugins.icgo_launcher.jobs import FAILED, format_traceback, one_line, previous_run, write_failure  # noqa: F401
from icgo.core.devices import enable_jax_cache, env_info, is_secondary_process, start_devices  # noqa: F401
from icgo.core.errors import SettingError
from icgo.io.files import RESULTS_DIR, results_output  # noqa: F401


def fail_line(e: BaseException) -> NoReturn:
    """Print ``error: <line>`` (one per problem of a SettingsError) and exit 2 for a bad setting, 1 for other
    errors of the input (:func:`icgo.core.settings.error_status`)."""
    from icgo.core.settings import error_status

    raise SystemExit(error_status(e) or EXIT_CONFIG)


def guarded(main) -> None:
    """Run an entry point's ``__main__`` body (:func:`icgo.core.settings.run_cli`): Ctrl-C or SIGTERM is one
    line and exit status 130; outputs are staged (:mod:`icgo.io.files`), so an interrupted command leaves
    every output directory as it was."""
    from icgo.core.settings import run_cli

    rc = run_cli(main)
    if rc:
        raise SystemExit(rc)


def bool_setting(cfg: DictConfig, key: str) -> bool:
    """The value of a true/false setting; anything else (``maybe``, ``'false'``, ``0``, null) is a SettingError."""
    v = OmegaConf.select(cfg, key)
    if not isinstance(v, bool):
        raise SettingError(f"{key}={v!r}: must be true or false")
    return v


def study_main(cfg: DictConfig, build_config, run) -> None:
    """Body of a study entry point's Hydra main: settings checked first (one line, exit 2), then ``run``.

    Args:
        cfg: the composed config. build_config: ``cfg -> the study's config dataclass``
            (raises ValueError on a bad setting). run: ``(cfg, models_dir, config) -> None``.
    """
    import logging

    from hydra.core.hydra_config import HydraConfig

    try:
        config = build_config(cfg)
    except ValueError as e:
        print(f"error: {one_line(e)}", file=sys.stderr)
        raise SystemExit(EXIT_CONFIG) from None
    logging.getLogger("icgo").setLevel(logging.INFO)
    run(cfg, Path(HydraConfig.get().runtime.output_dir) / "models", config)
