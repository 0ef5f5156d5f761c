"""SLURM for real (issue 19 item 6): a one-node cluster on this machine runs sweeps through ``hydra/launcher=slurm``.

``make test-slurm`` (also part of ``make test-all``). The cluster is started and
stopped by ``scripts/slurm_cluster.sh`` (Debian's slurm-wlm and munge, installed
when missing; needs root). Without root or packages the test fails with the
script's one-line reason: it never passes without having run. It is marked
``slurm`` and ``slow``, so ``make test`` (CI) leaves it out. One test function,
so that pytest-xdist never runs two clusters at once.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.test_sweeps import APP, ROOT, _wait_for

pytestmark = [pytest.mark.slow, pytest.mark.slurm]

SCRIPT = ROOT / "scripts" / "slurm_cluster.sh"


def _report(sweep: Path) -> list[tuple[str, str]]:
    return [(j["status"], j["reason"]) for j in json.loads((sweep / "sweep_report.json").read_text())["jobs"]]


def _squeue_task(env, task: int, timeout: float = 60.0) -> str:
    """The SLURM id (``<array>_<task>``) of a running array task."""
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        out = subprocess.run(["squeue", "-h", "-t", "RUNNING", "-o", "%i"], env=env, capture_output=True,
                             text=True).stdout.split()
        hit = [j for j in out if j.endswith(f"_{task}")]
        if hit:
            return hit[0]
        time.sleep(0.2)
    raise AssertionError(f"array task {task} never ran")


def test_sweeps_through_a_one_node_slurm_cluster(tmp_path):
    state = tmp_path / "cluster"
    env = dict(os.environ, PATH=f"{os.environ.get('PATH', '')}:/usr/sbin:/sbin")
    start = subprocess.run(["bash", str(SCRIPT), "start", str(state)], capture_output=True, text=True, env=env,
                           timeout=300)
    if start.returncode != 0:
        reason = (start.stderr.strip().splitlines() or ["no output"])[-1]
        pytest.fail(f"the one-node cluster did not start (it needs root and Debian's slurm-wlm): {reason}")
    env["SLURM_CONF"] = str(state / "slurm.conf")
    try:
        # 1. the study itself through hydra/launcher=slurm
        sweep = tmp_path / "study"
        run = subprocess.run([sys.executable, "-m", "experiments.run", "-m", "strategy=chaos,wavelet", "budget=smoke",
                              "figures=false", "hydra/launcher=slurm", f"hydra.sweep.dir={sweep}",
                              f"jax_cache_dir={tmp_path / 'jax'}"], cwd=ROOT, env=env, capture_output=True,
                             text=True, timeout=600)
        assert run.returncode == 0, run.stderr[-3000:]
        assert _report(sweep) == [("ok", ""), ("ok", "")]
        assert all((sweep / d / "run.json").is_file() for d in ("0", "1"))

        # 1b. one job as two SLURM tasks (one process per node on a real cluster; two on this one node): the
        # processes join one JAX runtime (jax.distributed, from SLURM's variables), the search is sharded over both
        # processes' devices, and only the first process writes the run directory
        sweep = tmp_path / "distributed"
        run = subprocess.run([sys.executable, "-m", "experiments.run", "-m", "strategy=chaos", "budget=smoke",
                              "figures=false", "hydra/launcher=slurm", "hydra.launcher.tasks_per_node=2",
                              f"hydra.sweep.dir={sweep}", f"jax_cache_dir={tmp_path / 'jax'}"], cwd=ROOT, env=env,
                             capture_output=True, text=True, timeout=600)
        assert run.returncode == 0, run.stderr[-3000:]
        rec = json.loads((sweep / "0" / "run.json").read_text())
        # each process has one host device per core of its affinity mask (this cluster binds no cores to a task:
        # task/none, so both see the node's); the search spans both processes' devices
        assert rec["execution"]["processes"] == 2, rec["execution"]
        assert rec["execution"]["devices"] == min(2 * rec["devices"]["host_devices"], 10), rec["execution"]
        assert rec["devices"]["distributed"]["cluster"] == "slurm" and rec["devices"]["distributed"]["num_processes"] == 2

        # 2. scancel one running job: it costs only itself, the report names it
        sweep = tmp_path / "cancel"
        sweep.mkdir()
        (sweep / "hold-a").touch()  # job a holds until killed
        proc = subprocess.Popen([sys.executable, str(APP), "-m", "job=a,b,c", "hydra/launcher=slurm",
                                 f"hydra.searchpath=[file://{ROOT / 'conf'}]", f"hydra.sweep.dir={sweep}"],
                                cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        _wait_for(sweep / "0" / "pid", proc, timeout=120)
        subprocess.run(["scancel", _squeue_task(env, 0)], env=env, check=True)
        out, err = proc.communicate(timeout=300)
        assert proc.returncode == 1, err[-3000:]
        report = _report(sweep)
        assert report[0][0] == "killed" and "CANCELLED" in report[0][1], report
        assert report[1:] == [("ok", ""), ("ok", "")]
        assert "3 job(s): 2 ok, 1 killed" in err and "Traceback" not in err

        # 3. a request no node can hold fails at once, in one line saying what the cluster offers
        bad = subprocess.run([sys.executable, "-m", "experiments.run", "-m", "strategy=chaos,wavelet",
                              "hydra/launcher=slurm", "hydra.launcher.cpus_per_task=64",
                              f"hydra.sweep.dir={tmp_path / 'bad'}"], cwd=ROOT, env=env, capture_output=True,
                             text=True, timeout=120)
        assert bad.returncode == 2
        last = bad.stderr.strip().splitlines()[-1]
        assert last.startswith("error: hydra.launcher.cpus_per_task=64 but partition") and "offers at most" in last
        queued = subprocess.run(["squeue", "-h"], env=env, capture_output=True, text=True).stdout.strip()
        assert queued == ""
    finally:
        subprocess.run(["bash", str(SCRIPT), "stop", str(state)], capture_output=True, env=env, timeout=120)
