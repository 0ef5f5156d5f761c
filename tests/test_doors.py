"""The front doors as one family (issue 47, deliverable 3): each Hydra door's own ``--help``, Hydra's documented
flags (``--cfg job``, ``-c job``, ``--cfg job --resolve``, ``--info``), a group of another door refused in one line,
one outputs root, the ``icgo`` console script beside ``python -m``, ``next:`` lines runnable as printed."""

from __future__ import annotations

import dataclasses
import os
import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
import yaml

from experiments._door import DOORS
from experiments._help import door_help, field_docs, yaml_comments
from experiments.cli import COMMANDS
from icgo.core.commands import SCRIPT_ENV, door_command

ROOT = Path(__file__).resolve().parents[1]
ENV = {**{k: v for k, v in os.environ.items() if not k.startswith(("HYDRA_", "PYTEST", SCRIPT_ENV))},
       "PYTHONPATH": str(ROOT), "JAX_PLATFORMS": "cpu"}


def console_script(folder: Path) -> Path:
    """The ``icgo`` script as pip writes it for pyproject.toml's ``[project.scripts]`` entry (its template)."""
    target = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]["icgo"]
    module, func = target.split(":")
    path = folder / "icgo"
    path.write_text(f"#!{sys.executable}\nimport re\nimport sys\nfrom {module} import {func}\n"
                    f"if __name__ == '__main__':\n    sys.argv[0] = re.sub(r'(-script\\.pyw|\\.exe)?$', '', sys.argv[0])\n"
                    f"    sys.exit({func}())\n")
    path.chmod(0o755)
    return path


def _run(args, cwd=ROOT, timeout=180):
    return subprocess.run(args, cwd=cwd, capture_output=True, text=True, env=ENV, timeout=timeout)


# ---------------------------------------------------------------- --help: the door's own
@dataclasses.dataclass(frozen=True)
class _Doc:
    """A config.

    Attributes:
        a: first, in nT. b, c: shared (deg).
        d: a long one that
            goes on. e: on the same line; with a colon: inside.
    """

    a: float = 1.0
    b: int = 2
    c: int = 3
    d: str = "x"
    e: bool = True


def test_field_docs_reads_every_entry_of_the_attributes_section():
    assert field_docs(_Doc) == {"a": "first, in nT.", "b": "shared (deg).", "c": "shared (deg).",
                                "d": "a long one that goes on.", "e": "on the same line; with a colon: inside."}


def test_field_docs_of_a_section_that_mirrors_a_documented_class():
    from icgo.models.nets import NetConfig
    from icgo.studies.gyro.study import NetSection

    assert field_docs(NetSection) == field_docs(NetConfig) and "epochs" in field_docs(NetSection)


def test_yaml_comments_reads_the_line_and_the_lines_above(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("# the site\nsite:\n  lat: null   # deg\n  lon: null\nn: 3  # count\n      # and more\nm: 1\n")
    assert yaml_comments(p) == {"site": "the site", "site.lat": "deg", "n": "count and more"}


@pytest.mark.parametrize("name", sorted(DOORS))
def test_each_door_help_lists_its_own_settings_with_their_docs(name):
    d = DOORS[name]
    text = door_help(name, d)
    cfg = yaml.safe_load((d.conf_dir / f"{d.config_name}.yaml").read_text())
    own = [k for k in cfg if k not in ("defaults", "hydra")]
    settings = text.split("settings (KEY=VALUE")[-1]
    assert all(re.search(rf"^  {re.escape(k)}[ .\[]", settings, re.M) for k in own), name
    assert f"icgo {name}" in text and f"python -m experiments.{name}" in text and "--cfg job" in text
    groups = ("strategy", "budget", "cgo_ablation", "optimizer")
    if name == "run":
        assert "strategy    all, chaos" in text and "model.lam [0.001]" in text and "ridge lambda" in text
    else:
        assert "config groups" not in text and not any(re.search(rf"^  {g}\b", text, re.M) for g in groups)
    described = {"calibrate": "misma_iter [300]                 MISMA iterations.",
                 "discrepancy": "sigma_b_nT [15.0]", "apply": "qc.b_tol_nT [300.0]",
                 "misma": "simulated.gyro.window_s [10.0]   rotating seconds propagated on each side of a stop (s).",
                 "gyro": "n_seeds [10]", "run": "precision [float32_features]"}
    assert described[name] in text


def test_the_doors_table_matches_each_doors_hydra_main():
    for name, d in DOORS.items():
        src = (ROOT / "experiments" / f"{name}.py").read_text()
        assert f'config_name="{d.config_name}"' in src and f'door("{name}", main)' in src, name
        assert len(src.splitlines()) <= 35, name
    for p in (ROOT / "experiments").glob("_*.py"):
        assert len(p.read_text().splitlines()) <= 200, p.name
    assert sorted(p.name for p in (ROOT / "hydra_plugins" / "icgo_launcher").glob("*.py")) == [
        "__init__.py", "_core.py", "config.py", "jobs.py", "launcher.py", "report.py", "slurm.py", "slurm_check.py"]


def test_every_door_has_one_outputs_root():
    for name, d in DOORS.items():
        hydra = yaml.safe_load((d.conf_dir / f"{d.config_name}.yaml").read_text())["hydra"]
        assert hydra["run"]["dir"] == f"outputs/{name}/${{now:%Y-%m-%d}}/${{now:%H-%M-%S}}", name
        assert hydra["sweep"]["dir"] == f"multirun/{name}/${{now:%Y-%m-%d}}/${{now:%H-%M-%S}}", name


# ---------------------------------------------------------------- Hydra's flags, one-line refusals
FLAGS = (["--help"], ["--cfg", "job"], ["-c", "job"], ["--cfg", "job", "--resolve"], ["--info"])
FAST = {("run", 1), ("calibrate", 2), ("apply", 3)}  # make test; the whole matrix under -m slow


@pytest.mark.parametrize("name, k", [pytest.param(n, k, marks=() if (n, k) in FAST else pytest.mark.slow)
                                     for n in sorted(DOORS) for k in range(len(FLAGS))])
def test_hydra_flags_work_on_every_door(name, k):
    r = _run([sys.executable, "-m", f"experiments.{name}", *FLAGS[k]])
    assert r.returncode == 0, (r.returncode, r.stderr[-400:])
    if FLAGS[k][0] in ("--cfg", "-c"):
        cfg = yaml.safe_load(r.stdout)
        assert isinstance(cfg, dict) and "hydra" not in cfg
        assert ("${" in r.stdout) == ("--resolve" not in FLAGS[k] and name != "apply")  # jax_cache_dir's default


@pytest.mark.parametrize("args, says", [
    (["calibrate", "strategy=wavelet"], "unknown setting 'strategy'"),
    (["gyro", "network.enabled=maybe"], "unknown setting 'network.enabled' in override 'network.enabled=maybe'"),
    pytest.param(["discrepancy", "budget=smoke"], "unknown setting 'budget'", marks=pytest.mark.slow),
    (["run", "--cfg", "job", "strategy=bogus"], "unknown strategy 'bogus'"),
    pytest.param(["run", "--cfg", "bogus"], "--cfg", marks=pytest.mark.slow),
    pytest.param(["apply", "--info", "bogus"], "--info", marks=pytest.mark.slow),
])
def test_a_wrong_value_is_one_line_and_exit_2(args, says):
    r = _run([sys.executable, "-m", f"experiments.{args[0]}", *args[1:]])
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and lines[0].startswith("error: ") and says in lines[0], r.stderr


def test_a_sweep_whose_later_job_hydra_refuses_starts_no_job(tmp_path):
    """Hydra composes the config once, in the door (no second composition to check it): a key that only the sweep's
    second job lacks (lab_casing has no dataset.condition) is one line and exit 2, before the first job starts (the
    icgo launcher composes every job's config first), and no job directory is written."""
    sweep = tmp_path / "sweep"
    r = _run([sys.executable, "-m", "experiments.run", "-m", "budget=smoke", "split.n_repeats=1",
              "dataset=well_conditions,lab_casing", "dataset.condition=1", f"hydra.sweep.dir={sweep}"])
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1, r.stderr
    assert lines[0] == ("error: unknown setting 'dataset.condition' in override 'dataset.condition=1': "
                        "conf/config.yaml (with the chosen groups) has no such key")
    assert not sweep.exists() or not any(sweep.iterdir())


# ---------------------------------------------------------------- the icgo console script
def test_icgo_lists_every_command_of_the_readme(tmp_path):
    icgo = console_script(tmp_path)
    r = _run([str(icgo), "--help"], cwd=tmp_path)
    assert r.returncode == 0 and all(f"  {c} " in r.stdout for c in COMMANDS)
    readme = (ROOT / "README.md").read_text()
    modules = set(re.findall(r"python -m ((?:experiments|icgo)\.\w+)", readme))
    assert modules <= {m for m, _ in COMMANDS.values()}, modules - {m for m, _ in COMMANDS.values()}
    r = _run([str(icgo), "bogus"], cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.startswith("error: unknown command 'bogus'") and r.stderr.count("\n") == 1


@pytest.mark.parametrize("args", [["calibrate", "strategy=wavelet"], ["io", "check", "/no/such.csv"],
                                  pytest.param(["run", "-c", "job", "split.n_repeats=3"], marks=pytest.mark.slow),
                                  pytest.param(["bench", "--out", "../escape"], marks=pytest.mark.slow)])
def test_icgo_command_is_python_m_module(tmp_path, args):
    """``icgo CMD ARGS`` prints and exits exactly as ``python -m MODULE ARGS``."""
    icgo = console_script(tmp_path)
    a = _run([str(icgo), *args], cwd=tmp_path)
    b = _run([sys.executable, "-m", COMMANDS[args[0]][0], *args[1:]], cwd=tmp_path)
    assert (a.returncode, a.stdout, a.stderr) == (b.returncode, b.stdout, b.stderr)


def test_next_lines_are_runnable_as_printed(tmp_path, monkeypatch):
    monkeypatch.delenv(SCRIPT_ENV, raising=False)
    assert door_command("apply") == f"{sys.executable} -m experiments.apply"
    icgo = console_script(tmp_path)
    monkeypatch.setenv(SCRIPT_ENV, str(icgo))
    monkeypatch.setenv("PATH", "/usr/bin:/bin")
    assert door_command("apply") == f"{icgo} apply"
    monkeypatch.setenv("PATH", f"{tmp_path}:/usr/bin:/bin")
    assert door_command("apply") == "icgo apply"
    r = subprocess.run(f"{door_command('apply')} --help", shell=True, capture_output=True, text=True, cwd=tmp_path,
                       env={**ENV, "PATH": f"{tmp_path}:/usr/bin:/bin"}, timeout=180)
    assert r.returncode == 0 and r.stdout.startswith("Apply a fitted model")
