"""Config dataclass helpers shared by every layer: checks that raise one-line settings errors,
and the mapping <-> dataclass conversions every entry point uses."""

from __future__ import annotations

import argparse
import dataclasses
import errno
import math
import sys

import numpy as np

from icgo.core.errors import IcgoError, SettingError, SettingsError


def need(cond: bool, field: str, problem: str | None = None, *, error: type[IcgoError] = SettingError) -> None:
    """The one check of the project: raise ``error`` unless ``cond``.

    A config check reads ``need(cond, field, problem)`` and raises :class:`~icgo.core.errors.SettingError`
    ``(field, problem)`` (entry points rename ``field`` to their own key); another kind of check names its
    error, e.g. a model file's ``need(cond, message, error=ModelError)``, whose one line is ``field`` (with
    ``problem`` appended when given).
    """
    if cond:
        return
    if error is SettingError:
        raise SettingError(field, problem)
    raise error(field if problem is None else f"{field} {problem}")


def is_int(x) -> bool:
    """True for a Python/numpy integer that is not a bool."""
    return isinstance(x, (int, np.integer)) and not isinstance(x, bool)


def is_real(x) -> bool:
    """True for a finite real number that is not a bool."""
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def config_from_mapping(cls, values: dict, where: str = "config", _prefix: str = ""):
    """Build a config dataclass from a plain mapping, refusing unknown keys in one line.

    A field whose type (or default) is a dataclass is built recursively from a mapping, an optional one
    (``X | None``) too; a field with ``metadata={"variants": {tag: class}, "tag": key}`` is built as the
    class its mapping's ``key`` names (a config group whose options take different keys), or, with
    ``"default": class`` in the metadata, as that class for any other tag (which then checks the tag).

    Args:
        cls: the config dataclass.
        values: field name -> value (nested dataclass fields given as mappings are built recursively).
        where: the name of the mapping in error messages (e.g. ``"conf/misma.yaml"``).
    Raises:
        SettingError: an unknown key (named by its dotted path), or the dataclass's own validation.
    """
    if not isinstance(values, dict):
        raise SettingError(f"{where}: expected a mapping of settings, got {type(values).__name__}")
    names = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - set(names))
    if unknown:
        raise SettingError(f"{where}: unknown setting(s) {[_prefix + k for k in unknown]}; known: {sorted(names)}")
    hints = _type_hints(cls)
    kwargs = {}
    for k, v in values.items():
        field, key = names[k], f"{_prefix}{k}"
        variants = field.metadata.get("variants")
        sub = _dataclass_in(hints.get(k)) or (type(field.default) if dataclasses.is_dataclass(field.default) else None)
        if variants is not None:
            tag = field.metadata["tag"]
            chosen = v.get(tag) if isinstance(v, dict) else None
            other = field.metadata.get("default")  # the class of every other tag (which checks the tag itself)
            if chosen not in variants and (other is None or not isinstance(chosen, str)):
                raise SettingError(f"{key}.{tag}", f"must be one of {sorted(variants)}, got {chosen!r}")
            v = config_from_mapping(variants.get(chosen, other), v, f"{where}.{k}", f"{key}.")
        elif sub is not None and isinstance(v, dict):
            v = config_from_mapping(sub, v, f"{where}.{k}", f"{key}.")
        elif sub is not None and not isinstance(v, sub) and not (v is None and _optional(hints.get(k))):
            raise SettingError(key, f"must be a group of settings ({key}.<key>=value), got {v!r}")
        elif str(field.type) == "bool" and not isinstance(v, bool):  # "maybe", "false", 0: never read as a bool
            raise SettingError(key, f"must be true or false, got {v!r}")
        kwargs[k] = v
    return cls(**kwargs)


def _type_hints(cls) -> dict:
    """The resolved field types of a dataclass ({} where they cannot be resolved)."""
    import typing

    try:
        return typing.get_type_hints(cls)
    except Exception:  # noqa: BLE001  (a name only imported for type checkers: fall back to the defaults)
        return {}


def _dataclass_in(tp):
    """The dataclass a field type names (``X`` or ``X | None``), else None."""
    import typing

    for t in (tp, *typing.get_args(tp)):
        if isinstance(t, type) and dataclasses.is_dataclass(t):
            return t
    return None


def _optional(tp) -> bool:
    """Whether a field type admits None (``X | None``)."""
    import typing

    return type(None) in typing.get_args(tp)


def config_to_mapping(config) -> dict:
    """The inverse of :func:`config_from_mapping`: a nested plain dict of the fields (tuples as lists)."""
    def plain(v):
        if dataclasses.is_dataclass(v) and not isinstance(v, type):
            return {f.name: plain(getattr(v, f.name)) for f in dataclasses.fields(v)}
        if isinstance(v, (tuple, list)):
            return [plain(x) for x in v]
        if isinstance(v, dict):
            return {k: plain(x) for k, x in v.items()}
        return v

    return plain(config)


def defaults_of(cls) -> dict:
    """The defaults of the config dataclass ``cls`` as a plain nested mapping (:func:`config_to_mapping`): every
    field that has a default (or a default factory); a field without one (a config group's choice) is absent."""
    out = {}
    for f in dataclasses.fields(cls):
        if f.default is not dataclasses.MISSING:
            out[f.name] = config_to_mapping(f.default)
        elif f.default_factory is not dataclasses.MISSING:
            out[f.name] = config_to_mapping(f.default_factory())
    return out


def config_overrides(config) -> list[str]:
    """The command-line overrides (``key=value``, Hydra's syntax) that turn the class defaults into ``config``.

    One per field whose value differs from the default of ``type(config)()`` (nested dataclasses as dotted keys),
    in field order; ``[]`` for the defaults. Values: ``true`` / ``false``, ``null``, ``[a,b]`` for a sequence.
    """
    def value(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if v is None:
            return "null"
        if isinstance(v, list):
            return "[" + ",".join(value(x) for x in v) + "]"
        return str(v)

    def diff(cur: dict, default: dict, prefix: str) -> list[str]:
        out = []
        for k, v in cur.items():
            if isinstance(v, dict) and isinstance(default.get(k), dict):
                out += diff(v, default[k], f"{prefix}{k}.")
            elif v != default.get(k):
                out.append(f"{prefix}{k}={value(v)}")
        return out

    return diff(config_to_mapping(config), config_to_mapping(type(config)()), "")


__all__ = ["need", "is_int", "is_real", "config_from_mapping", "config_to_mapping", "config_overrides",
           "SettingError", "SettingsError", "ArgumentParser", "interrupted", "error_status", "run_cli", "on_interrupt",
           "interrupts_raise", "startup_interrupts"]


class ArgumentParser(argparse.ArgumentParser):
    """``argparse.ArgumentParser`` whose usage errors are one line (``error: ...; see --help``) and exit 2.

    The standard parser prints its usage block before the error; a command-line front door of icgo
    says what is wrong in one line, like its config errors.
    """

    def error(self, message: str):  # noqa: D401  (argparse's hook)
        print(f"error: {self.prog}: {message}; see {self.prog} --help", file=sys.stderr)
        raise SystemExit(2)


#: Errors of the disk or the place written to (full, read-only, permissions): one line, not a traceback.
DISK_ERRNOS = frozenset({errno.ENOSPC, errno.EROFS, errno.EACCES, errno.EPERM, errno.EDQUOT, errno.EFBIG, errno.EIO,
                         errno.ENOTDIR, errno.EISDIR, errno.ENOENT, errno.EEXIST, errno.ENAMETOOLONG, errno.ELOOP})


def error_status(e: BaseException) -> int | None:
    """Print the one line of a user's error and return its exit status, or None for anything else (a bug).

    A bad setting (:class:`~icgo.core.errors.SettingError`) exits 2, one line per problem of a
    :class:`~icgo.core.errors.SettingsError`; any other ``ValueError`` (bad data, a bad model file, an
    output that could not be written, a fit the data cannot support) exits 1; so do an ``OSError`` of
    the disk (:data:`DISK_ERRNOS`) and ``MemoryError``.
    """
    if isinstance(e, ValueError):
        for line in getattr(e, "problems", None) or (first_line(e),):
            print(f"error: {line}", file=sys.stderr)
        return 2 if isinstance(e, SettingError) else 1
    if isinstance(e, OSError) and e.errno in DISK_ERRNOS:
        where = f"{e.filename}: " if getattr(e, "filename", None) else ""
        print(f"error: {where}{e.strerror or type(e).__name__}", file=sys.stderr)
        return 1
    if isinstance(e, MemoryError):
        print("error: out of memory; give a smaller input (docs/data.md lists the limits)", file=sys.stderr)
        return 1
    return None


def first_line(e: BaseException) -> str:
    """First line of an exception's message (its type's name when it has none)."""
    text = str(e).strip()
    return text.splitlines()[0] if text else type(e).__name__


#: What a command does on Ctrl-C or SIGTERM (:func:`on_interrupt`): the clean-ups of the outputs being staged
#: (registered by :class:`icgo.io.files.Output`), and how many callers currently handle KeyboardInterrupt
#: themselves (:func:`interrupts_raise`).
INTERRUPT = {"cleanups": [], "raise": 0}


def on_interrupt(signum=None, frame=None):
    """Signal handler of a command: remove the outputs being staged, print one line, exit 130 at once.

    Exiting from the handler (``os._exit``) instead of raising KeyboardInterrupt is deliberate: the
    exception would surface wherever Python happens to be, inside JAX's import or a garbage-collection
    callback, where it is printed as "Exception ignored" or crashes the interpreter. Outputs are
    staged and committed with the signals blocked (:class:`icgo.io.files.Output`), so there is nothing
    to finish: dropping the staging folders leaves every output directory as it was. Inside
    :func:`interrupts_raise` (a sweep's launcher, which stops its jobs and reports) it raises instead.
    """
    import os

    if INTERRUPT["raise"]:
        raise KeyboardInterrupt
    where = None
    for cleanup in list(INTERRUPT["cleanups"]):
        try:
            where = cleanup() or where
        except Exception:  # noqa: BLE001  (best effort: the exit below must happen)
            pass
    os._exit(interrupted(where))


class interrupts_raise:
    """Context: within it, Ctrl-C and SIGTERM raise KeyboardInterrupt (for code that stops and reports itself)."""

    def __enter__(self):
        INTERRUPT["raise"] += 1
        return self

    def __exit__(self, *exc):
        INTERRUPT["raise"] -= 1
        return False


def startup_interrupts() -> None:
    """Ctrl-C or SIGTERM while a command is still importing its modules ends it at once with the one line of
    :func:`interrupted` (:func:`on_interrupt`; nothing has been written yet)."""
    import signal

    if signal.getsignal(signal.SIGINT) is not signal.SIG_IGN:
        signal.signal(signal.SIGINT, on_interrupt)
    signal.signal(signal.SIGTERM, on_interrupt)


def run_cli(main, *args) -> int:
    """Run a command-line front door: its user errors one line each (:func:`error_status`), Ctrl-C or SIGTERM
    one line and exit status 130 (:func:`interrupted`); returns the exit status (``main``'s, 0 for None)."""
    startup_interrupts()
    try:
        rc = main(*args)
    except KeyboardInterrupt as e:  # raised by the code itself (a library call, interrupts_raise)
        return interrupted(getattr(e, "icgo_unchanged", None))
    except BrokenPipeError:  # the reader of stdout stopped (``| head``): stop quietly, as a SIGPIPE would
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 141
    except (ValueError, OSError, MemoryError) as e:
        rc = error_status(e)
        if rc is None:
            raise
    return int(rc or 0)


def interrupted(where: str | None = None) -> int:
    """Print the one line of a command stopped by Ctrl-C and return its exit status (130).

    Args:
        where: the output directory left unchanged, if the interruption came while writing into it.
    """
    print("interrupted: " + (f"nothing in {where} was changed" if where else
                             "stopped; outputs are written all at once, so none was left half-written"),
          file=sys.stderr)
    return 130
