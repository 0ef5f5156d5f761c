"""The command line of a Hydra door checked before Hydra starts, without composing: a bad override is one line and
exit 2 (Hydra: a block and exit 1, or a traceback). Hydra's own parser splits the line, so every flag it documents
(``--cfg job``, ``-c job``, ``--resolve``, ``--info``, ``-m``) keeps its meaning and only the overrides are checked:
their grammar, the group options, the run directories. What needs the composed config (an unknown key, a value a
typed schema refuses) is Hydra's own composition's error, one line (:mod:`experiments._hydra_errors`);
:func:`check_plain_overrides` composes once for a command that starts many runs (``make figures``' plan)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import OverrideType
from omegaconf import DictConfig, ListConfig, OmegaConf

from experiments._groups import CONF_DIR, group_options, searchpath_dirs
from experiments._schema import stored_nodes

#: Exit status of a bad setting or command line (every door).
EXIT_CONFIG = 2
#: Config groups of the ICGO-RELM study (``experiments.run``); the other doors have none.
STUDY_GROUPS = ("dataset", "model", "optimizer", "strategy", "schedule", "budget", "split", "fitness", "experiment",
                "debug")
MULTIRUN_FLAGS = ("-m", "--multirun")  # moved in front of the overrides (Hydra's parser refuses them after one)
HYDRA_DIR_KEYS = ("hydra.run.dir", "hydra.sweep.dir")  # directories Hydra creates before the task runs
#: Settings that no longer exist -> what replaced them, for every door (``"*"``) or one config name.
RENAMED_KEYS = {"*": {"workers": "use devices=N (the search is one program sharded over N devices: a CPU's cores as "
                                 "host devices, docs/performance.md) or leave devices=null for every device"},
                "config": {"dtype": "use precision= (the search fitness's precision: float32_features, float64 or "
                                    "float32)"}}


def hydra_args(argv: list[str]) -> argparse.Namespace:
    """The command line as Hydra's own parser reads it; a flag it refuses is a ValueError (one line)."""
    from hydra._internal.utils import get_args_parser

    parser = get_args_parser()

    def refuse(message):
        raise ValueError(f"{message} (Hydra's flags: --hydra-help)")
    parser.error = refuse
    return parser.parse_args(argv)


def check_overrides(args: list[str], groups=STUDY_GROUPS, conf_dir: Path = CONF_DIR) -> str | None:
    """One-line error for an override naming an unknown option of one of ``groups`` (also ``+g=a``, ``g=a,b``), the
    options of a ``hydra.searchpath`` folder among the choices."""
    extra = searchpath_dirs(args)
    for arg in args:
        if arg.startswith("-") or "=" not in arg:
            continue
        key, value = arg.split("=", 1)
        key = key.lstrip("+")
        if key not in groups:
            continue
        options = group_options(key, conf_dir, extra)
        allowed = options + (["null", ""] if key in ("experiment", "debug") else [])
        for v in (v.strip() for v in value.split(",")):
            if v not in allowed:
                return f"unknown {key} {v!r} in override {arg!r}; choose one of: {', '.join(options)}"
    return None


def check_hydra_dirs(args: list[str]) -> str | None:
    """One-line error for a ``hydra.run.dir`` / ``hydra.sweep.dir`` that cannot be a directory (created here first:
    Hydra would create it before the door's code runs, a traceback on failure; ``${now:...}`` is left to Hydra)."""
    for arg in args:
        key, sep, value = arg.lstrip("+").partition("=")
        if not sep or key not in HYDRA_DIR_KEYS or "${" in value:
            continue
        p = Path(value).expanduser()
        if p.exists() and not p.is_dir():
            return f"{key} {value!r} is a file, not a directory; give a directory"
        try:
            p.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            return f"{key} {value!r}: cannot create the directory ({e.strerror or type(e).__name__})"
    return None


def parsed_overrides(args: list[str]):
    """The overrides parsed by Hydra's grammar, or the one-line error of the first it cannot read."""
    parser = OverridesParser.create()
    for a in args:
        try:
            parser.parse_overrides([a])
        except Exception as e:  # noqa: BLE001  (Hydra's grammar error: three lines and a URL otherwise)
            why = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
            return (f"cannot read the override {a!r} ({why}); a value with special characters (=, ',', spaces, "
                    f"brackets) goes in quotes: key='a=b'")
    return parser.parse_overrides(args)


def override_prefix(ov) -> str:
    return {OverrideType.ADD: "+", OverrideType.FORCE_ADD: "++"}.get(ov.type, "")  # the override's + or ++


def check_plain_overrides(args: list[str], config_name: str, conf_dir: Path = CONF_DIR, groups=None) -> str | None:
    """One-line error for an override ``key=value`` whose key is not in the config composed with the line's group
    choices (Hydra: six lines, exit 1), checked once before a plan starts its runs (``experiments.figures_plan``).
    ``groups``: the door's (default: every folder of ``conf_dir``)."""
    overrides = parsed_overrides(args)
    if isinstance(overrides, str):
        return overrides
    is_group = (lambda k: (conf_dir / k).is_dir()) if groups is None else (lambda k: k in groups)
    chosen, plain = [], []
    for ov in overrides:
        key = ov.key_or_group
        if key == "hydra.searchpath":
            chosen.append(ov.input_line)  # a user's config folder: its group options compose as conf/'s
            continue
        if key.startswith("hydra") or (ov.type != OverrideType.CHANGE and not is_group(key)):
            continue  # Hydra's own settings; an added or deleted key (the entry points refuse unknown ones)
        if is_group(key):
            value = next(iter(ov.sweep_string_iterator())) if ov.is_sweep_override() else ov.get_value_element_as_str()
            chosen.append(f"{override_prefix(ov)}{key}={value}")
        else:
            plain.append(ov)
    if not plain:
        return None
    try:
        cfg = compose_config(config_name, chosen, conf_dir)
    except Exception:  # noqa: BLE001  (a bad group choice: check_overrides names it)
        return None
    renamed = RENAMED_KEYS["*"] | RENAMED_KEYS.get(config_name, {})
    key, line = next(((o.key_or_group, o.input_line) for o in plain if not _has_key(cfg, o.key_or_group)), (None,) * 2)
    if key in renamed:
        return f"setting {key!r} was replaced: {renamed[key]}"
    where = (conf_dir / f"{config_name}.yaml").relative_to(CONF_DIR.parent)
    return key and f"unknown setting {key!r} in override {line!r}: {where} (with the chosen groups) has no such key"


def compose_config(config_name: str, overrides: list[str], conf_dir: Path):
    """The config ``config_name`` composed with ``overrides`` (Hydra's global state left clear)."""
    stored_nodes(config_name, conf_dir)
    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(config_dir=str(conf_dir), version_base="1.3"):
            return compose(config_name=config_name, overrides=overrides)
    finally:
        GlobalHydra.instance().clear()


def _has_key(cfg, dotted: str) -> bool:
    """Whether the composed config has the key ``a.b.c`` (a mandatory ``???`` value counts as present)."""
    node = cfg
    for part in dotted.split("."):
        if isinstance(node, DictConfig) and part in node.keys():
            node = node._get_node(part)
        elif isinstance(node, ListConfig) and part.isdigit() and int(part) < len(node):
            node = node._get_node(int(part))
        else:
            return False
    return True


def preflight(config_name: str, args: list[str] | None = None, conf_dir: Path = CONF_DIR, groups=()) -> None:
    """Checks of a Hydra door's command line that need no composition (``-m`` moved in front, read by Hydra's parser,
    then the overrides' grammar, group options and run directories); one line on stderr and exit 2 on a bad one.
    Rewrites ``sys.argv`` (args None)."""
    argv = sys.argv[1:] if args is None else args
    flags, rest = [a for a in argv if a in MULTIRUN_FLAGS], [a for a in argv if a not in MULTIRUN_FLAGS]
    if args is None:
        sys.argv[1:] = flags + rest
    try:
        overrides = list(hydra_args(flags + rest).overrides)
    except ValueError as e:
        err = str(e)
    else:
        parsed = parsed_overrides(overrides)
        err = (check_overrides(overrides, groups, conf_dir) or check_hydra_dirs(overrides)
               or (parsed if isinstance(parsed, str) else None))
    if err:
        print(f"error: {err}", file=sys.stderr)
        raise SystemExit(EXIT_CONFIG)
