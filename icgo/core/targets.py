"""A user's own code named in a config: ``_target_: my_package.my_module.name`` (Hydra's key, read here without
Hydra), so a researcher's strategy, optimizer or data set comes from their own module (docs/extending.md).

The module is imported by its dotted path (from ``sys.path``: the directory a door is run from comes first);
every failure is one line naming the setting, as every other config error.
"""

from __future__ import annotations

import functools
import importlib
import re

from icgo.core.errors import SettingError

#: ``package.module.name`` or ``package.module:name`` (identifiers joined by dots, at least two parts).
_PATH = re.compile(r"[A-Za-z_]\w*(\.[A-Za-z_]\w*)*[.:][A-Za-z_]\w*(\.[A-Za-z_]\w*)*")


def load_target(path, key: str):
    """The object ``path`` names: ``package.module.name`` (or ``package.module:name``).

    Args:
        path: the dotted path; the module part is imported, the last part is read from it (an attribute chain
            such as ``module.Class.method`` works too).
        key: the setting that holds it, for the one-line error (``strategy.define.levy._target_``).

    Raises:
        SettingError: not a dotted path, a module that cannot be imported (its own error's first line), or a
            name the module lacks.
    """
    if not isinstance(path, str) or not _PATH.fullmatch(path):
        raise SettingError(key, f"must be a dotted path module.name to your function or class, got {path!r}")
    mod_path, _, attrs = path.partition(":") if ":" in path else (None, None, None)
    parts = path.split(".") if mod_path is None else [mod_path, *attrs.split(".")]
    errors = []
    for cut in range(len(parts) - 1, 0, -1) if mod_path is None else (1,):
        module_name = ".".join(parts[:cut]) if mod_path is None else mod_path
        try:
            obj = importlib.import_module(module_name)
        except ModuleNotFoundError as e:
            if e.name and module_name.startswith(e.name) and not errors:
                errors.append(f"cannot import module {module_name!r} (run from the folder that holds it, or put "
                              f"it on PYTHONPATH)")
            elif not (e.name and module_name.startswith(e.name)):
                raise SettingError(key, f"{path!r}: importing {module_name!r} failed: {_first(e)}") from None
            continue
        except Exception as e:  # noqa: BLE001  (the user's module failed at import: its first line)
            raise SettingError(key, f"{path!r}: importing {module_name!r} failed: {_first(e)}") from None
        for a in (parts[cut:] if mod_path is None else attrs.split(".")):
            if not hasattr(obj, a):
                raise SettingError(key, f"{path!r}: {getattr(obj, '__name__', obj)!s} has no {a!r}")
            obj = getattr(obj, a)
        return obj
    raise SettingError(key, f"{path!r}: {errors[0] if errors else 'cannot import it'}")


def target_callable(spec: dict, key: str, reserved=()) -> tuple:
    """``(callable, rest)`` of a mapping ``{_target_: path, <reserved keys>..., **kwargs}``: the named function
    with ``kwargs`` bound (``functools.partial``, Hydra's ``_partial_`` reading), and the reserved keys' values.

    Raises:
        SettingError: not a mapping with ``_target_``, or a target that is not callable (one line).
    """
    if not isinstance(spec, dict) or "_target_" not in spec:
        raise SettingError(key, f"must be a mapping with _target_: module.function (and its keyword arguments), "
                                f"got {spec!r}")
    obj = load_target(spec["_target_"], f"{key}._target_")
    if not callable(obj):
        raise SettingError(f"{key}._target_", f"{spec['_target_']!r} is not a function or class")
    kwargs = {k: v for k, v in spec.items() if k != "_target_" and k not in reserved}
    rest = {k: spec[k] for k in reserved if k in spec}
    return (functools.partial(obj, **kwargs) if kwargs else obj), rest


def _first(e: BaseException) -> str:
    text = str(e).strip()
    return f"{type(e).__name__}: {text.splitlines()[0]}" if text else type(e).__name__
