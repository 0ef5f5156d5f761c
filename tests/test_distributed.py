"""A two-process ``jax.distributed`` job on one machine: the search sharded over both processes' devices gives the
one-process study bitwise (CPU kernel), and the plan says so (``@pytest.mark.slow``: about a minute, most of it
compiling in two processes whose compilations synchronise; ``make test-all``). How a process finds its job."""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from icgo.core import devices as D

ROOT = Path(__file__).resolve().parents[1]
APP = ROOT / "tests" / "distributed_app.py"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
@pytest.mark.skipif(jax.default_backend() != "cpu", reason="two processes on this machine's CPU (one device each)")
def test_two_local_processes_shard_the_search_and_give_the_one_process_study(tmp_path):
    from icgo.studies.icgo_relm import study
    from icgo.studies.icgo_relm.config import StudyConfig
    from tests.test_study import sim_frame

    port = _free_port()
    out = tmp_path / "result.npz"
    env = {k: v for k, v in os.environ.items() if not k.startswith(("SLURM_", "ICGO_", "XLA_FLAGS"))}
    env.update({D.ENV_COORDINATOR: f"127.0.0.1:{port}", D.ENV_PROCESSES: "2", "JAX_PLATFORMS": "cpu"})
    cache = str(ROOT / ".jax_cache")
    procs = [subprocess.Popen([sys.executable, str(APP), str(out), cache], cwd=ROOT, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True, env={**env, D.ENV_PROCESS_ID: str(i)})
             for i in range(2)]
    try:
        results = [p.communicate(timeout=300) for p in procs]
    finally:
        for p in procs:
            p.kill()
    for p, (_, err) in zip(procs, results):
        assert p.returncode == 0, err[-3000:]
    got = np.load(out)
    plan = json.loads(str(got["plan"]))
    assert plan["processes"] == 2 and plan["devices"] == 2 and plan["devices_seen"] == 2
    assert plan["request"]["cluster"] == "env" and "across 2 processes" in plan["why"]
    cfg = StudyConfig(split=dict(n_repeats=3, seed=2), model=dict(hidden=10), budget=dict(pop_size=6, iterations=3),
                      optimizer="cgo", strategies=("original", "wavelet"))
    one = study.run_study(sim_frame(), cfg)
    np.testing.assert_array_equal(got["theta"], one.model.params.theta)
    np.testing.assert_array_equal(got["curve"], one.curves["best_fitness"])
    np.testing.assert_array_equal(got["mae"], one.metrics.query("split == 'test'").sort_values(["method", "repeat"])
                                  .mae.to_numpy())


@pytest.mark.parametrize("env, want", [
    ({}, None),
    ({"SLURM_JOB_ID": "7", "SLURM_STEP_NODELIST": "n[1-2]", "SLURM_NTASKS": "2", "SLURM_PROCID": "1"},
     {"cluster": "slurm", "num_processes": 2, "process_id": 1}),
    ({"SLURM_JOB_ID": "7", "SLURM_STEP_NODELIST": "n1", "SLURM_NTASKS": "1"}, None),     # one task: one process
    ({"SLURM_JOB_ID": "7", "SLURM_NTASKS": "2"}, None),                                   # the batch script, no step
    ({D.ENV_COORDINATOR: "h:1", D.ENV_PROCESSES: "3", D.ENV_PROCESS_ID: "2"},
     {"cluster": "env", "coordinator_address": "h:1", "num_processes": 3, "process_id": 2}),
])
def test_the_job_a_process_belongs_to_is_read_from_its_environment(env, want):
    assert D.distributed_request(env) == want


@pytest.mark.parametrize("env, message", [
    ({D.ENV_COORDINATOR: "h:1", D.ENV_PROCESSES: "two", D.ENV_PROCESS_ID: "0"}, "must be integers"),
    ({D.ENV_COORDINATOR: "h:1", D.ENV_PROCESSES: "2", D.ENV_PROCESS_ID: "2"}, "0 <= process id < processes"),
])
def test_a_malformed_job_environment_is_one_line(env, message):
    with pytest.raises(ValueError, match=message):
        D.distributed_request(env)


def test_host_devices_follow_the_flags_and_the_affinity_mask():
    assert D.flagged_host_devices("--a=1 --xla_force_host_platform_device_count=8") == 8
    assert D.flagged_host_devices("--a=1") is None
    assert D.use_host_devices() == len(jax.devices("cpu"))  # the backend has started: its count stays
    assert len(D.available_cores()) >= 1
    assert D.xla_flags(1, "--x=1") == "--x=1 --xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
