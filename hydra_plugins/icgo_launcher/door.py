"""What every Hydra front door of icgo shares: the command line checked before Hydra starts, a user's error
as one line and an exit status, and Hydra's record of the job staged with the job's own files.

Nothing here imports JAX (Hydra imports this module at every start, when it scans its plugins): the
launchers may start worker processes after it is imported, and JAX must be initialised inside the job,
never forked.

Errors the user can fix (a bad override, a missing data file) are :class:`icgo.core.errors.SettingError`
(or :class:`icgo.core.errors.DataError`), both one line; the front door prints ``error: <line>`` and
exits with :data:`EXIT_CONFIG` (2), before any computation.

The one study main (:func:`study_main`, :func:`run_study`) runs any registered study
(:data:`icgo.studies.registry.STUDIES`): composed config -> the study's typed config -> load -> run -> write.
"""

from __future__ import annotations

import functools
import logging
import sys
import warnings
from pathlib import Path

from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.core.hydra_config import HydraConfig
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import OverrideType
from omegaconf import DictConfig, ListConfig, OmegaConf

from icgo.core.settings import error_status, first_line

#: Hydra config directory of the front doors (absolute, so runs work from any working directory).
CONF_DIR = Path(__file__).resolve().parents[2] / "conf"

#: Config groups of the study app whose options are checked before Hydra composes.
STUDY_GROUPS = ("dataset", "model", "optimizer", "strategy", "schedule", "budget", "split", "fitness",
                "experiment", "debug")


EXIT_CONFIG = 2


def group_options(group: str, conf_dir: Path = CONF_DIR) -> list[str]:
    """Names of the options of a config group (its ``*.yaml`` files)."""
    return sorted(p.stem for p in (conf_dir / group).glob("*.yaml"))


def check_overrides(args: list[str], groups=STUDY_GROUPS, conf_dir: Path = CONF_DIR) -> str | None:
    """One-line error for an override that names an unknown group option, else None.

    Handles ``group=a``, ``+group=a``, ``~group`` (ignored) and sweeps
    ``group=a,b,c``; anything else is left to Hydra.

    Args:
        args: command-line arguments (without the program name).
        groups: config groups to check.
        conf_dir: the config directory.
    Returns:
        The error line, or None when every group override names an existing option.
    """
    for arg in args:
        if arg.startswith("-") or "=" not in arg:
            continue
        key, value = arg.split("=", 1)
        key = key.lstrip("+")
        if key not in groups:
            continue
        options = group_options(key, conf_dir)
        for v in value.split(","):
            v = v.strip()
            if v in ("null", "") and key == "experiment":
                continue
            if v not in options:
                return f"unknown {key} {v!r} in override {arg!r}; choose one of: {', '.join(options)}"
    return None


#: Hydra's run-mode flags that take no value (moved in front of the overrides by :func:`preflight`).
MULTIRUN_FLAGS = ("-m", "--multirun")


#: Hydra's flags whose next argument is their value, not an override.
VALUE_FLAGS = ("--config-path", "-cp", "--config-name", "-cn", "--config-dir", "-cd", "--experimental-rerun",
               "--package", "-p", "--info", "-i")


#: Overrides naming a directory Hydra creates before the task function runs.
HYDRA_DIR_KEYS = ("hydra.run.dir", "hydra.sweep.dir")


def check_hydra_dirs(args: list[str]) -> str | None:
    """One-line error for a ``hydra.run.dir`` / ``hydra.sweep.dir`` that cannot be a directory, else None.

    Hydra creates these before any entry-point code runs, and a failure there is
    a traceback; so the directory is created here first (a value with an
    interpolation, e.g. ``${now:...}``, is left to Hydra).
    """
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


#: Settings that no longer exist -> what replaced them (named in the one-line error for an override of one), for
#: every door (``"*"``) or the door of one config name.
RENAMED_KEYS = {"*": {"workers": "use devices=N (the search is one program sharded over N devices: a CPU's cores as "
                                 "host devices, docs/performance.md) or leave devices=null for every device"},
                "config": {"dtype": "use precision= (the search fitness's precision: float32_features, float64 or "
                                    "float32)"}}


def check_plain_overrides(args: list[str], config_name: str, conf_dir: Path = CONF_DIR) -> str | None:
    """One-line error for an override ``key=value`` (no ``+``) whose key is not in the composed config.

    Hydra refuses such an override itself, but with a six-line block and exit
    status 1; this composes the config the way the entry point will (with the
    command line's group choices, a sweep's first value) and names the key.
    """
    parser = OverridesParser.create()
    candidates = [a for i, a in enumerate(args) if not a.startswith("-") and not (i and args[i - 1] in VALUE_FLAGS)]
    for a in candidates:
        try:
            parser.parse_overrides([a])
        except Exception as e:  # noqa: BLE001  (Hydra's grammar error: three lines and a URL otherwise)
            why = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
            return (f"cannot read the override {a!r} ({why}); a value with special characters (=, ',', spaces, "
                    f"brackets) goes in quotes: key='a=b'")
    overrides = parser.parse_overrides(candidates)
    groups, plain = [], []
    for ov in overrides:
        key = ov.key_or_group
        if key.startswith("hydra") or (ov.type != OverrideType.CHANGE and not (conf_dir / key).is_dir()):
            continue  # Hydra's own settings; an added or deleted key (the entry points refuse unknown ones)
        if (conf_dir / key).is_dir():
            value = next(iter(ov.sweep_string_iterator())) if ov.is_sweep_override() else ov.get_value_element_as_str()
            prefix = {OverrideType.ADD: "+", OverrideType.FORCE_ADD: "++"}.get(ov.type, "")
            groups.append(f"{prefix}{key}={value}")
        else:
            plain.append(ov)
    if not plain:
        return None
    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(config_dir=str(conf_dir), version_base="1.3"):
            cfg = compose(config_name=config_name, overrides=groups)
    except Exception:  # a bad group choice: the entry point's own checks name it
        return None
    finally:
        GlobalHydra.instance().clear()
    renamed = RENAMED_KEYS["*"] | RENAMED_KEYS.get(config_name, {})
    for ov in plain:
        if ov.key_or_group in renamed and not _has_key(cfg, ov.key_or_group):
            return f"setting {ov.key_or_group!r} was replaced: {renamed[ov.key_or_group]}"
        if not _has_key(cfg, ov.key_or_group):
            where = (conf_dir / f"{config_name}.yaml").relative_to(CONF_DIR.parent)
            return (f"unknown setting {ov.key_or_group!r} in override {ov.input_line!r}: {where} (with the chosen "
                    f"groups) has no such key")
    return None


def check_schema(args: list[str], config_name: str, conf_dir: Path = CONF_DIR) -> str | None:
    """One-line error for an override whose value the config's typed schema refuses (a config whose defaults list
    names a ``*_schema``: :mod:`hydra_plugins.icgo_launcher.schema`), else None.

    Hydra checks the schema when it composes, and would print its refusal as a block with exit status 1; this
    composes the config with the command line's overrides (each value of a sweep once) and names the key.
    """
    from omegaconf.errors import ValidationError

    defaults = OmegaConf.load(conf_dir / f"{config_name}.yaml").get("defaults") or []
    if not any(str(d).endswith("_schema") for d in defaults):
        return None
    candidates = [a for i, a in enumerate(args) if not a.startswith("-") and not (i and args[i - 1] in VALUE_FLAGS)]
    choices = []  # (key with its + or ++, every value of a sweep or the one value)
    for ov in OverridesParser.create().parse_overrides(candidates):  # the grammar checked by check_plain_overrides
        if ov.key_or_group.startswith("hydra") or ov.type == OverrideType.DEL:
            continue
        prefix = {OverrideType.ADD: "+", OverrideType.FORCE_ADD: "++"}.get(ov.type, "")
        values = list(ov.sweep_string_iterator()) if ov.is_sweep_override() else [ov.get_value_element_as_str()]
        choices.append((prefix + ov.key_or_group, values))
    first = [f"{k}={values[0]}" for k, values in choices]
    trials = [first] + [first[:i] + [f"{k}={v}"] + first[i + 1:]
                        for i, (k, values) in enumerate(choices) for v in values[1:]]  # each sweep value once
    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(config_dir=str(conf_dir), version_base="1.3"):
            for overrides in trials:
                try:
                    compose(config_name=config_name, overrides=overrides)
                except Exception as e:  # noqa: BLE001  (only a value the schema refuses is named here)
                    while e is not None and not isinstance(e, ValidationError):
                        e = e.__cause__ or e.__context__
                    if e is not None:
                        return f"setting {e.full_key!r}: {first_line(e)} (conf/{config_name}.yaml's schema)"
    finally:
        GlobalHydra.instance().clear()
    return None


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


def preflight(config_name: str, args: list[str] | None = None, conf_dir: Path = CONF_DIR) -> None:
    """Checks of a Hydra entry point's command line before Hydra starts; one line and exit 2 on a bad one.

    Moves ``-m``/``--multirun`` in front of the overrides (Hydra's parser refuses
    them after one), then :func:`check_hydra_dirs`, :func:`check_plain_overrides` and :func:`check_schema`.
    Rewrites ``sys.argv`` when ``args`` is None.
    """
    argv = sys.argv[1:] if args is None else args
    flags = [a for a in argv if a in MULTIRUN_FLAGS]
    rest = [a for a in argv if a not in MULTIRUN_FLAGS]
    if args is None:
        sys.argv[1:] = flags + rest
    err = (check_hydra_dirs(rest) or check_plain_overrides(rest, config_name, conf_dir)
           or check_schema(rest, config_name, conf_dir))
    if err:
        print(f"error: {err}", file=sys.stderr)
        raise SystemExit(EXIT_CONFIG)


def one_line_errors(task):
    """Decorator of a Hydra task function: a user's error becomes one line and an exit status, never a traceback.

    ``ValueError`` (every :class:`~icgo.core.errors.IcgoError`), a disk's ``OSError`` and ``MemoryError``
    are printed by :func:`icgo.core.settings.error_status` (exit 2 or 1); Hydra would print each with a
    traceback. Numerical ``RuntimeWarning`` lines are not printed (a result that matters is checked and
    raised as an error).
    """
    @functools.wraps(task)
    def wrapper(cfg):
        # JAX's backend probe ("Unable to initialize backend 'tpu'") is noise on a terminal, not a second line.
        logging.getLogger("jax._src.xla_bridge").setLevel(logging.WARNING)
        warnings.simplefilter("ignore", RuntimeWarning)
        try:
            return task(cfg)
        except (ValueError, OSError, MemoryError) as e:
            rc = error_status(e)
            if rc is None:
                raise
            raise SystemExit(rc) from None

    return wrapper


def hydra_keep() -> tuple[str, ...]:
    """Names Hydra writes into the run directory of this job before the task runs (its job log), which an
    output directory leaves alone."""
    return (f"{HydraConfig.get().job.name}.log",)


def hydra_files(cfg: DictConfig) -> dict[str, str]:
    """Hydra's ``.hydra/`` record of this job (``config.yaml`` unresolved, ``hydra.yaml``, ``overrides.yaml``).

    The configs set ``hydra.output_subdir: null``, so Hydra does not write it into the run directory
    before the task runs (it would rewrite the record of the run a refused command was refused to
    replace); the entry point stages it with its other files instead.
    """
    hc = HydraConfig.get()
    return {"config.yaml": OmegaConf.to_yaml(cfg), "hydra.yaml": OmegaConf.to_yaml({"hydra": hc}),
            "overrides.yaml": OmegaConf.to_yaml(hc.overrides.task)}


def write_hydra_record(stage: Path, cfg: DictConfig) -> None:
    """Write :func:`hydra_files` into ``stage/.hydra`` (nothing outside a Hydra job, e.g. a library call)."""
    if not HydraConfig.initialized():
        return
    d = stage / ".hydra"
    d.mkdir(exist_ok=True)
    for name, text in hydra_files(cfg).items():
        (d / name).write_text(text)


def guarded(main) -> None:
    """Run an entry point's ``__main__`` body (:func:`icgo.core.settings.run_cli`): Ctrl-C or SIGTERM is one
    line and exit status 130; outputs are staged (:mod:`icgo.io.files`), so an interrupted command leaves
    every output directory as it was."""
    from icgo.core.settings import run_cli

    rc = run_cli(main)
    if rc:
        raise SystemExit(rc)


def hydra_cli(config_name: str, main, conf_dir: Path = CONF_DIR) -> None:
    """A Hydra entry point run as a command: :func:`preflight` of its command line, then ``main`` (the
    ``@hydra.main`` task), under :func:`guarded`."""
    def cli() -> None:
        preflight(config_name, conf_dir=conf_dir)
        main()

    guarded(cli)


def bool_setting(cfg: DictConfig, key: str) -> bool:
    """The value of a true/false setting; anything else (``maybe``, ``'false'``, ``0``, null) is a SettingError."""
    from icgo.core.errors import SettingError

    v = OmegaConf.select(cfg, key)
    if not isinstance(v, bool):
        raise SettingError(f"{key}={v!r}: must be true or false")
    return v


def repo_path(value) -> Path:
    """A path setting: absolute as given, relative to the repository root (the folder of ``conf/``) otherwise."""
    p = Path(str(value))
    return p if p.is_absolute() else CONF_DIR.parent / p


def study_config(name: str, cfg: DictConfig, entry_keys=(), config_name: str | None = None):
    """The typed config of ``STUDIES[name]`` (its ``config_cls``) from a composed config, the entry point's own
    settings (``entry_keys``) left out: an unknown key or a bad value is one ``ValueError`` line naming it.

    Args:
        name: the registry name. cfg: the composed config. entry_keys: top-level keys that are settings of the
            entry point, not of the study. config_name: the YAML named in errors (default ``name``).
    """
    from icgo.core.settings import config_from_mapping
    from icgo.studies.registry import get_study

    values = {k: v for k, v in OmegaConf.to_container(cfg, resolve=True).items() if k not in entry_keys}
    return config_from_mapping(get_study(name).config_cls, values, f"conf/{config_name or name}.yaml")


def progress_to_stdout(name: str) -> None:
    """The progress lines of ``STUDIES[name]`` (its run module's INFO log) printed as they are, one a line (a
    command-line door; a Hydra door logs through Hydra's handlers)."""
    from icgo.studies.registry import get_study

    log = logging.getLogger(get_study(name).run.__module__)
    if not log.handlers:
        handler = logging.StreamHandler(sys.stdout)
        handler.setFormatter(logging.Formatter("%(message)s"))
        log.addHandler(handler)
        log.setLevel(logging.INFO)


def run_study(name: str, config, output, *, inputs: dict | None = None, models_dir: Path | None = None,
              settings: dict | None = None, argv=(), cfg: DictConfig | None = None):
    """Load -> run -> write of ``STUDIES[name]``: the outputs into ``output`` all at once (staged), the models
    into ``models_dir``; prints what the study's ``write`` returns and returns the study's result.

    Args:
        name: the registry name. config: its typed config. output: the checked :class:`icgo.io.files.Output`
            of the tables and figures. inputs: keyword inputs of the study's ``load`` (a data file and how to
            read it). models_dir: where the fitted models go (None: not saved). settings: the composed settings
            the outputs record. argv: the command line's arguments. cfg: the composed config of a Hydra job
            whose output directory also holds Hydra's record (:func:`write_hydra_record`).
    Raises:
        icgo.core.errors.DataError: an input file that is not there (one line), as any bad data.
    """
    import time

    import icgo  # noqa: F401  (float64)
    from icgo.core.errors import DataError
    from icgo.studies.registry import get_study
    from icgo.studies.study import Invocation

    study = get_study(name)
    started = time.perf_counter()
    try:
        data = study.load(config, **(inputs or {})) if study.load is not None else None
    except FileNotFoundError as e:
        raise DataError(first_line(e)) from None
    result = study.run(data, config, study.key(config))
    invocation = Invocation(dict(settings or {}), tuple(argv), started, output.path, models_dir)
    with output.staged(last=study.last) as stage:
        if cfg is not None:
            write_hydra_record(stage, cfg)
        message = study.write(result, data, config, stage, invocation)
        written = [p.relative_to(stage) for p in stage.rglob("*") if p.is_file()]
    if message:
        print(message, flush=True)
    from hydra_plugins.icgo_launcher.tracking_hooks import track_job

    track_job(dict(settings or {}), output.path, written, door=name)  # MLflow, where installed and not off
    return result


def run_composed(name: str, cfg: DictConfig, models_dir: Path | None = None, config=None, entry_keys=("out_dir",)):
    """:func:`run_study` of a composed config: tables into ``out_dir`` (relative to the repository root; a shared
    results folder: the study's files replace their namesakes), the models into ``models_dir``; ``jax_cache``
    (where the YAML has it) turns on the compilation cache. ``config``: the typed config if already built."""
    from icgo.core.devices import enable_jax_cache
    from icgo.io.files import Output

    config = study_config(name, cfg, entry_keys) if config is None else config
    if cfg.get("jax_cache"):
        enable_jax_cache(str(repo_path(cfg.jax_cache)))
    output = Output(repo_path(cfg.out_dir), setting="out_dir", shared=True).check()  # before the study runs
    return run_study(name, config, output, models_dir=models_dir, settings=OmegaConf.to_container(cfg, resolve=True))


def study_main(name: str, cfg: DictConfig, entry_keys=("out_dir",)) -> None:
    """Body of a study's Hydra main: the typed config first (a bad setting: one line, exit 2), then
    :func:`run_composed` with the models into the Hydra run directory's ``models/``."""
    try:
        config = study_config(name, cfg, entry_keys)
    except ValueError as e:
        print(f"error: {first_line(e)}", file=sys.stderr)
        raise SystemExit(EXIT_CONFIG) from None
    logging.getLogger("icgo").setLevel(logging.INFO)
    run_composed(name, cfg, Path(HydraConfig.get().runtime.output_dir) / "models", config, entry_keys)
