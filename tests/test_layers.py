"""The import graph of the library: packages in layers, no circle, nothing imports upward.

Read from the source (every ``import`` statement, function-level ones included), so a lazy import
inside a function cannot hide an upward arrow. The order is the README's "Layers" section.
"""

from __future__ import annotations

import ast
from collections import Counter
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: Bottom to top: a module may import its own package and any package listed before it.
LAYERS = ("icgo.core", "icgo.physics", "icgo.maths", "icgo.optim", "icgo.reporting", "icgo.models", "icgo.io",
          "icgo.datasets", "icgo.discrepancy", "icgo.artifacts", "icgo.survey", "icgo.studies", "icgo.bench")


def _module_name(path: Path) -> str:
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules(top: str) -> dict[str, Path]:
    return {_module_name(p): p for p in sorted((ROOT / top).rglob("*.py"))}


def _imports(name: str, path: Path, known) -> set[str]:
    """The project modules ``name`` imports (``from pkg import sub`` counts as ``pkg.sub`` when that is a module)."""
    tree = ast.parse(path.read_text())
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                stem = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(stem + ([base] if base else []))
            for a in node.names:
                full = f"{base}.{a.name}"
                out.add(full if full in known else base)
    return {m for m in out if m.split(".")[0] in ("icgo", "experiments", "hydra", "omegaconf") and m != name}


def _graph(top: str = "icgo") -> dict[str, set[str]]:
    mods = _modules(top)
    known = set(mods) | set(_modules("experiments"))
    return {name: _imports(name, path, known) for name, path in mods.items()}


def _layer(module: str) -> int | None:
    for i, pkg in enumerate(LAYERS):
        if module == pkg or module.startswith(pkg + "."):
            return i
    return None


def test_every_module_is_in_a_layer():
    loose = [m for m in _modules("icgo") if m != "icgo" and _layer(m) is None]
    assert not loose, f"modules outside every layer (add them to a package): {loose}"


def test_nothing_imports_upward_or_outside_the_library():
    bad = []
    for mod, deps in _graph().items():
        for dep in deps:
            if dep.split(".")[0] != "icgo":
                bad.append(f"{mod} -> {dep} (the library never imports experiments/Hydra)")
            elif dep != "icgo" and mod != "icgo" and _layer(dep) > _layer(mod):
                bad.append(f"{mod} -> {dep} (upward: {LAYERS[_layer(mod)]} is below {LAYERS[_layer(dep)]})")
    assert not bad, "\n".join(sorted(bad))


def _circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in graph:
                continue
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in graph:
        if v not in index:
            visit(v)
    return out


@pytest.mark.parametrize("top", ["icgo", "experiments"])
def test_no_import_circle(top):
    graph = _graph(top) if top == "icgo" else {
        name: _imports(name, path, set(_modules("experiments")) | set(_modules("icgo")))
        for name, path in _modules("experiments").items()}
    assert _circles(graph) == []


def test_the_checks_find_a_circle_and_an_upward_import():
    assert _circles({"a": {"b"}, "b": {"a"}, "c": {"a"}}) == [["a", "b"]]
    assert _layer("icgo.physics.frames") < _layer("icgo.studies.common.splits")
    assert _layer("icgo.bogus") is None


def _private_uses(path: Path, known) -> list[str]:
    """``alias._name`` where ``alias`` is a project module, and ``from <project module> import _name``."""
    tree = ast.parse(path.read_text())
    aliases, out = {}, []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name in known and a.asname:
                    aliases[a.asname] = a.name
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            for a in node.names:
                full = f"{node.module}.{a.name}"
                if full in known:
                    aliases[a.asname or a.name] = full
                elif node.module in known and a.name.startswith("_") and not a.name.startswith("__"):
                    out.append(f"from {node.module} import {a.name}")
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in aliases
                and node.attr.startswith("_") and not node.attr.startswith("__")):
            out.append(f"{aliases[node.value.id]}.{node.attr}")
    return out


@pytest.mark.parametrize("top", ["icgo", "experiments"])
def test_no_module_calls_another_modules_private_name(top):
    known = set(_modules("icgo")) | set(_modules("experiments"))
    bad = {f"{name}: {u}" for name, path in _modules(top).items() for u in _private_uses(path, known)}
    assert not bad, "\n".join(sorted(bad))


def test_hydra_only_in_the_doors_and_the_launcher():
    """Hydra (and OmegaConf) appear only in ``experiments/`` (the doors) and ``hydra_plugins/`` (the launcher, which
    keeps nothing of the doors: it never imports ``experiments``); the library takes plain arguments."""
    def imported(path: Path) -> set[str]:
        tree = ast.parse(path.read_text())
        names = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
        return names | {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module and not n.level}

    bad = [f"{p.relative_to(ROOT)} imports {m}" for p in sorted(ROOT.rglob("*.py"))
           if p.relative_to(ROOT).parts[0] not in ("experiments", "hydra_plugins", "tests", ".venv", ".jax_cache")
           for m in imported(p) if m.split(".")[0] in ("hydra", "omegaconf")]
    bad += [f"{p.relative_to(ROOT)} imports {m}" for p in sorted((ROOT / "hydra_plugins").rglob("*.py"))
            for m in imported(p) if m.split(".")[0] == "experiments"]
    assert not bad, "\n".join(bad)


# --- a study per package (issue 47; added by move_studies.py) ---

#: The shared study machinery: the one part of icgo.studies every study may import.
STUDY_COMMON = "icgo.studies.common"
#: The registry of studies: it imports every study's face.
STUDY_REGISTRY = "icgo.studies.registry"
#: The studies built on another study: the other studies whose FACE (the package's ``__init__``) each may import.
STUDY_USES = {'discrepancy': ('icgo_relm',), 'generalisation': ('icgo_relm',), 'misma': ('calibration',)}


def _study(module: str) -> str | None:
    """The study package a module of icgo.studies belongs to (None: the common machinery, the registry, the face of
    icgo.studies itself)."""
    if not module.startswith("icgo.studies."):
        return None
    top = module.split(".")[2]
    return None if f"icgo.studies.{top}" in (STUDY_COMMON, STUDY_REGISTRY) else top


def _study_rule_breaks(graph: dict[str, set[str]]) -> list[str]:
    bad = []
    for mod, deps in graph.items():
        mine = _study(mod)
        for dep in deps:
            if not dep.startswith("icgo.studies"):
                continue
            theirs = _study(dep)
            if mod.startswith(STUDY_COMMON) and not dep.startswith(STUDY_COMMON):
                bad.append(f"{mod} -> {dep} (the common machinery names no study)")
            elif mine and dep == STUDY_REGISTRY:
                bad.append(f"{mod} -> {dep} (a study never imports the registry)")
            elif mine and theirs and theirs != mine:
                if theirs not in STUDY_USES.get(mine, ()):
                    bad.append(f"{mod} -> {dep} (a study imports only the common machinery)")
                elif dep != f"icgo.studies.{theirs}":
                    bad.append(f"{mod} -> {dep} (another study only through its face, icgo.studies.{theirs})")
            elif mod == STUDY_REGISTRY and theirs and dep != f"icgo.studies.{theirs}":
                bad.append(f"{mod} -> {dep} (the registry imports each study's face)")
    return sorted(bad)


def test_a_study_imports_only_the_common_machinery_and_the_faces_it_is_built_on():
    assert _study_rule_breaks(_graph()) == []


def test_reporting_names_no_study():
    bad = [f"{m} -> {d}" for m, deps in _graph().items() if m.startswith("icgo.reporting")
           for d in deps if d.startswith("icgo.studies")]
    assert bad == []


def test_every_study_is_a_package_with_its_face_and_every_use_of_another_study_is_real():
    studies_dir = ROOT / "icgo" / "studies"
    top = sorted(p.name for p in studies_dir.iterdir() if not p.name.startswith(("__pycache__", ".")))
    assert len(top) <= 10, top
    for folder in [studies_dir, *(p for p in studies_dir.rglob("*") if p.is_dir() and p.name != "__pycache__")]:
        stems = [p.stem for p in folder.iterdir() if p.suffix == ".py" and p.stem != "__init__"]
        stems += [p.name for p in folder.iterdir() if p.is_dir() and (p / "__init__.py").exists()]
        prefixes = Counter(s.split("_")[0] for s in stems)
        assert max(prefixes.values(), default=0) < 3, (folder, prefixes.most_common(3))
    graph = _graph()
    used = {(_study(m), _study(d)) for m, deps in graph.items() for d in deps
            if _study(m) and _study(d) and _study(m) != _study(d)}
    assert used == {(a, b) for a, bs in STUDY_USES.items() for b in bs}, "STUDY_USES lists exactly the uses"


def test_the_study_rule_finds_a_study_importing_another():
    graph = {"icgo.studies.gyro.study": {"icgo.studies.misma.config"},
             "icgo.studies.misma.study": {"icgo.studies.calibration.study"},
             "icgo.studies.common.splits": {"icgo.studies.gyro"}}
    assert _study_rule_breaks(graph) == [
        "icgo.studies.common.splits -> icgo.studies.gyro (the common machinery names no study)",
        "icgo.studies.gyro.study -> icgo.studies.misma.config (a study imports only the common machinery)",
        "icgo.studies.misma.study -> icgo.studies.calibration.study (another study only through its face, "
        "icgo.studies.calibration)"]


@pytest.mark.parametrize("top", ["icgo", "experiments", "hydra_plugins"])
def test_no_module_is_over_600_lines(top):
    """A module that outgrows 600 lines holds more than one job: split it by job before it lands."""
    long = {n: len(p.read_text().splitlines()) for n, p in _modules(top).items()}
    assert not {n: k for n, k in long.items() if k > 600}
