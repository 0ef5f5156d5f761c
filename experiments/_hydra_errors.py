"""Hydra's composition errors as one line: a door runs its ``@hydra.main`` inside :func:`composition_errors`, so the
config is composed once, by Hydra, and an unknown key, a refused value or a missing config is ``error: <line>`` and
exit 2 (Hydra: a block of lines and exit 1). The checks that need no composition run before Hydra starts
(:mod:`experiments._preflight`); a sweep's jobs are composed before the first starts (the icgo launcher composes
them all; on a schema door, whose Hydra launcher composes a job as it starts it, :func:`check_sweep_values`)."""

from __future__ import annotations

import contextlib
import os
import re
import sys
from pathlib import Path

from hydra.core.override_parser.types import OverrideType
from omegaconf import OmegaConf

from experiments._preflight import (CONF_DIR, EXIT_CONFIG, RENAMED_KEYS, compose_config, hydra_args, override_prefix,
                                   parsed_overrides)
from icgo.core.settings import first_line


def composition_error(e: BaseException, config_name: str, args: list[str], conf_dir: Path = CONF_DIR) -> str | None:
    """The one line of an error Hydra raised composing the door's config (Hydra: a block of lines and exit 1): an
    unknown key (or one that was renamed), a value the typed schema refuses (:mod:`experiments._schema`), any other
    composition error's first line; None for an error that is not Hydra's or OmegaConf's."""
    from hydra.errors import HydraException
    from omegaconf.errors import ConfigAttributeError, ConfigKeyError, OmegaConfBaseException, ValidationError

    if not isinstance(e, (HydraException, OmegaConfBaseException)):
        return None
    cause = e
    while cause is not None and not isinstance(cause, OmegaConfBaseException):
        cause = cause.__cause__ or cause.__context__
    where = (conf_dir / f"{config_name}.yaml").relative_to(CONF_DIR.parent)
    if isinstance(cause, ValidationError):
        return f"setting {cause.full_key!r}: {first_line(cause)} ({where}'s schema)"
    named = re.match(r"Could not override '([^']+)'", str(e))  # the key as typed (also a group the door lacks)
    key = named.group(1) if named else (getattr(cause, "full_key", None)
                                        if isinstance(cause, (ConfigAttributeError, ConfigKeyError)) else None)
    if key:
        renamed = RENAMED_KEYS["*"] | RENAMED_KEYS.get(config_name, {})
        if key in renamed:
            return f"setting {key!r} was replaced: {renamed[key]}"
        line = next((a for a in args if a.lstrip("+~").split("=", 1)[0] == key), key)
        return f"unknown setting {key!r} in override {line!r}: {where} (with the chosen groups) has no such key"
    return first_line(e)


@contextlib.contextmanager
def composition_errors(config_name: str, conf_dir: Path = CONF_DIR):
    """Run a door's ``@hydra.main`` inside: Hydra's composition error (of the run's config, or of a sweep job's,
    every one composed before the first job starts: :mod:`hydra_plugins.icgo_launcher`) is one line on stderr and
    exit 2 (:func:`composition_error`). Hydra raises it instead of printing it (``HYDRA_FULL_ERROR``). A schema door's
    later sweep values are checked first (:func:`check_sweep_values`)."""
    err = check_sweep_values(list(hydra_args(sys.argv[1:]).overrides), config_name, conf_dir)
    if err:
        print(f"error: {err}", file=sys.stderr)
        raise SystemExit(EXIT_CONFIG)
    before = os.environ.get("HYDRA_FULL_ERROR")
    os.environ["HYDRA_FULL_ERROR"] = "1"
    try:
        yield
    except Exception as e:  # noqa: BLE001  (only Hydra's and OmegaConf's are answered here)
        err = composition_error(e, config_name, sys.argv[1:], conf_dir)
        if err is None:
            raise
        print(f"error: {err}", file=sys.stderr)
        raise SystemExit(EXIT_CONFIG) from None
    finally:
        if before is None:
            os.environ.pop("HYDRA_FULL_ERROR", None)
        else:
            os.environ["HYDRA_FULL_ERROR"] = before


def check_sweep_values(args: list[str], config_name: str, conf_dir: Path = CONF_DIR) -> str | None:
    """One-line error (:func:`composition_error`) for a sweep value Hydra refuses on a door with a typed schema
    (:mod:`experiments._schema`). Hydra's own launcher (the schema doors') composes each job as it starts it, so a
    refused later value would stop a sweep half run: each sweep value after the first is composed once here (the
    first is Hydra's own composition's)."""
    defaults = OmegaConf.load(conf_dir / f"{config_name}.yaml").get("defaults") or []
    if not any(str(d).endswith("_schema") for d in defaults):
        return None
    choices = [(override_prefix(ov) + ov.key_or_group,
                list(ov.sweep_string_iterator()) if ov.is_sweep_override() else [ov.get_value_element_as_str()])
               for ov in parsed_overrides(args)
               if not ov.key_or_group.startswith("hydra") and ov.type != OverrideType.DEL]
    first = [f"{k}={values[0]}" for k, values in choices]
    for i, (k, values) in enumerate(choices):
        for v in values[1:]:
            try:
                compose_config(config_name, first[:i] + [f"{k}={v}"] + first[i + 1:], conf_dir)
            except Exception as e:  # noqa: BLE001  (only Hydra's and OmegaConf's errors are named here)
                err = composition_error(e, config_name, [f"{k}={v}"], conf_dir)
                if err:
                    return err
    return None
