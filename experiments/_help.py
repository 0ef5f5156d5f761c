"""``icgo <door> --help`` (= ``python -m experiments.<door> --help``): the door's own usage, read from ``conf/`` and
the config dataclasses, so it never lists a group or a setting the door does not have.

Each setting is shown with its default (the door's YAML) and its description: the field's entry in the
``Attributes:`` section of the config dataclass's docstring (:data:`experiments._door.DOORS`: ``classes``), units
included, or else the YAML line's comment. Only the config groups the door uses are listed. Nothing here imports
JAX.
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import re
import textwrap
import typing
from pathlib import Path

import yaml
from omegaconf import OmegaConf

from experiments._preflight import group_options

#: A mapping with more entries than this, all null (a column map), is shown as one line ``key.NAME``.
MAP_LINE = 8


def field_docs(cls, names=None) -> dict[str, str]:
    """Field name -> its text in the ``Attributes:`` section of ``cls``'s docstring (``a, b: text`` gives both;
    several entries may share a line: ``a: text. b: text``). A docstring without one that names a class first
    (``:class:`icgo.models.nets.NetConfig` defaults ...``) takes that class's entries for the same fields."""
    doc = inspect.getdoc(cls) or ""
    names = set(names or (f.name for f in dataclasses.fields(cls)) if dataclasses.is_dataclass(cls)
                else cls._fields)
    m = re.search(r"^Attributes:\n((?:[ \t]+\S.*\n?)+)", doc, re.M)
    if not m:
        ref = re.match(r":class:`~?([\w.]+)\.(\w+)`", doc)
        if ref is None:
            return {}
        try:
            return field_docs(getattr(importlib.import_module(ref.group(1)), ref.group(2)), names)
        except (ImportError, AttributeError):
            return {}
    text = " ".join(line.strip() for line in m.group(1).splitlines())
    anchors = [a for a in re.finditer(r"((?:[A-Za-z_]\w*, )*[A-Za-z_]\w*): ", text)
               if all(n in names for n in a.group(1).split(", "))
               and (a.start() == 0 or text[:a.start()].rstrip().endswith((".", ";")))]
    out = {}
    for a, nxt in zip(anchors, anchors[1:] + [None]):
        body = text[a.end():nxt.start() if nxt else len(text)].strip()
        for n in a.group(1).split(", "):
            out[n] = body
    return out


def nested_classes(cls) -> dict[str, type]:
    """Field name -> the config dataclass of a nested node (the first dataclass of a union)."""
    try:
        hints = typing.get_type_hints(cls)
    except Exception:  # noqa: BLE001  (an annotation that cannot be resolved: no nested docs)
        return {}
    out = {}
    for f in dataclasses.fields(cls):
        tp = hints.get(f.name)
        for t in (tp, *typing.get_args(tp)):
            if dataclasses.is_dataclass(t):
                out[f.name] = t
                break
    return out


def plain(text: str) -> str:
    """A docstring's text as a command line reads it: reST roles and literals unmarked, Python's None as null."""
    text = re.sub(r":\w+:`~?([^`]+)`", r"\1", text).replace("``", "")
    return re.sub(r"\bNone\b", "null", text)


def class_docs(spec: str, prefix: str = "") -> tuple[dict[str, str], set]:
    """(dotted key -> description of every field of the dataclass ``module:Class`` and its nested nodes, the dotted
    keys that are nested nodes). A documented field that is not a node is one setting (a free mapping included)."""
    module, name = spec.split(":")
    cls = getattr(importlib.import_module(module), name)
    docs, nodes = {}, set()

    def walk(c, pre):
        docs.update({f"{pre}{k}": plain(v) for k, v in field_docs(c).items()})
        for k, sub in nested_classes(c).items():
            nodes.add(f"{pre}{k}")
            walk(sub, f"{pre}{k}.")

    walk(cls, f"{prefix}." if prefix else "")
    return docs, nodes


def yaml_comments(path: Path, prefix: str = "") -> dict[str, str]:
    """Dotted key -> the comment on its line in a YAML file (and the comment lines right under it, indented
    deeper), or else the comment lines right above it."""
    out, stack, last, above = {}, [], None, []
    for line in path.read_text().splitlines():
        m = re.match(r"^(\s*)([A-Za-z_][\w]*):(.*)$", line)
        if m and not line.lstrip().startswith("#"):
            indent = len(m.group(1))
            stack = [(i, k) for i, k in stack if i < indent] + [(indent, m.group(2))]
            key = prefix + ".".join(k for _, k in stack)
            value, _, comment = m.group(3).partition(" #")
            last = (key, indent)
            text = comment.strip().lstrip("#").strip() or " ".join(above)
            if text:
                out[key] = text
            above = []
            continue
        elif line.lstrip().startswith("#") and last and len(line) - len(line.lstrip()) > last[1] + 2 \
                and last[0] in out:
            out[last[0]] += " " + line.strip().lstrip("#").strip()
        elif line.strip():
            last = None
        above = above + [line.strip().lstrip("#").strip()] if line.lstrip().startswith("#") and last is None else []
    return out


def _leaves(node: dict, leaf=lambda key: False, prefix: str = ""):
    """(dotted key, default) of every setting of a YAML mapping; a column map is one ``key.NAME`` line, a mapping
    ``leaf(key)`` says is one setting one line."""
    for k, v in node.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict) and len(v) > MAP_LINE and all(x is None for x in v.values()):
            yield f"{key}.NAME", None
        elif isinstance(v, dict) and v and not leaf(key):
            yield from _leaves(v, leaf, key + ".")
        else:
            yield key, v


def _value(v) -> str:
    """A default as it is written on the command line."""
    if v is None or isinstance(v, (bool, list, dict)):
        return yaml.safe_dump(v, default_flow_style=True, width=1 << 16).strip().removesuffix("\n...").strip()
    return str(v)


def _settings(node: dict, docs: dict, nodes: set, comments: dict, width: int) -> list[str]:
    lines = []
    def leaf(k):  # a documented field that is not a node: one setting, unless its YAML documents its keys
        return k in docs and k not in nodes and not any(c.startswith(k + ".") for c in comments)

    for key, v in _leaves(node, leaf):
        base = key[:-5] if key.endswith(".NAME") else key
        text = docs.get(base) or comments.get(base) or ""
        head = f"  {key} [{_value(v)}]"
        if len(head) >= 34 and text:
            lines.append(head)
        lines += textwrap.wrap(text, width, initial_indent=f"{head:<34} " if len(head) < 34 else " " * 35,
                               subsequent_indent=" " * 35) if text else [head]
    return lines


def schema_defaults(spec: str) -> dict:
    """The defaults of the config dataclass ``module:Class`` as a door's YAML would write them (the one source of a
    schema door's study settings: its YAML does not repeat them)."""
    from icgo.core.settings import defaults_of

    module, name = spec.split(":")
    return defaults_of(getattr(importlib.import_module(module), name))


def door_help(name: str, d, width: int = 118) -> str:
    """The help of the Hydra door ``name``, ``d`` its :class:`experiments._door.Door`."""
    path = d.conf_dir / f"{d.config_name}.yaml"
    cfg = yaml.safe_load(path.read_text()) or {}
    docs, nodes = {}, set()
    for prefix, specs in d.classes.items():
        for spec in specs:
            more, more_nodes = class_docs(spec, prefix)
            docs, nodes = {**docs, **more}, nodes | more_nodes
    comments = yaml_comments(path)
    lines = [d.summary, "", f"usage: icgo {name} [-m] " + ("[GROUP=OPTION ...] " if d.groups else "")
             + "[KEY=VALUE ...]", f"   or: python -m experiments.{name} (the same arguments)"]
    defaults = {k: v for x in cfg.get("defaults", []) if isinstance(x, dict) for k, v in x.items()}
    stored = {f"{d.config_name}_schema", f"{d.config_name}_defaults"} & set(map(str, cfg.get("defaults", [])))
    base = {k: v for s in d.classes.get("", ()) for k, v in schema_defaults(s).items()} if stored else {}
    if d.groups:
        lines += ["", "config groups (GROUP=OPTION; default in brackets):"]
        for g in d.groups:
            lines.append(f"  {g:<11} {', '.join(group_options(g, d.conf_dir))}  [{defaults.get(g) or 'none'}]")
    for g in d.groups:
        option = defaults.get(g)
        if option:
            gpath = d.conf_dir / g / f"{option}.yaml"
            node = OmegaConf.to_container(OmegaConf.merge(base.get(g) or {}, yaml.safe_load(gpath.read_text()) or {}))
            lines += ["", f"{g}={option} settings ({g}.KEY=VALUE; default in brackets):"]
            lines += _settings({g: node}, docs, nodes, yaml_comments(gpath, f"{g}."), width)
    own = {**{k: v for k, v in base.items() if k not in d.groups},
           **{k: v for k, v in cfg.items() if k not in ("defaults", "hydra")}}
    lines += ["", "settings (KEY=VALUE; default in brackets):"] + _settings(own, docs, nodes, comments, width)
    lines += ["", "examples:"] + [f"  icgo {name} {e}".rstrip() for e in d.examples]
    lines += ["", "Hydra's flags: --cfg job [--resolve] (the composed config, nothing run), --info, -m (a sweep), "
              "--hydra-help", f"run directory: outputs/{name}/<date>/<time> (hydra.run.dir=DIR); "
              "docs: docs/experiments.md, README.md"]
    return "\n".join(lines)
