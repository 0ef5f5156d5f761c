"""A door's config directory and groups: ``conf/`` (with the run door's defaults stored in Hydra's ConfigStore), the
options of a group in conf/ and in a user's own config folder (``hydra.searchpath``, docs/extending.md), read before
Hydra starts."""

from __future__ import annotations

from pathlib import Path

from hydra.core.override_parser.overrides_parser import OverridesParser

from experiments._schema import register_defaults
from icgo.studies.icgo_relm.run_config import RunConfig

#: Hydra config directory of the front doors (absolute, so runs work from any working directory).
CONF_DIR = Path(__file__).resolve().parents[1] / "conf"

# conf/config.yaml (the run door) composes RunConfig's defaults first: stored here, where every user of CONF_DIR
# (the doors, the preflight, a test's compose) imports it before Hydra composes.
register_defaults("config", RunConfig)


def group_options(group: str, conf_dir: Path = CONF_DIR, extra=()) -> list[str]:
    """Names of the options of a config group (its ``*.yaml`` files), in ``conf_dir`` and the folders ``extra``."""
    return sorted({p.stem for d in (conf_dir, *extra) for p in (Path(d) / group).glob("*.yaml")})


def searchpath_dirs(args: list[str]) -> list[Path]:
    """The ``file://`` folders of a ``hydra.searchpath=[file://...]`` override: a user's own config folder, whose
    group options (``strategy/levy.yaml``) Hydra composes beside conf/'s (docs/extending.md)."""
    out = []
    for a in args:
        key, sep, _ = a.lstrip("+").partition("=")
        if not sep or key != "hydra.searchpath":
            continue
        try:
            value = OverridesParser.create().parse_overrides([a])[0].value()
        except Exception:  # noqa: BLE001  (a malformed value: check_plain_overrides names it)
            continue
        out += [Path(str(v)[len("file://"):]) for v in (value if isinstance(value, list) else [value])
                if str(v).startswith("file://")]
    return out
