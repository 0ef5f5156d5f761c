"""Sweeps that lose only the killed job (issue 19 item 2): the ``icgo_local`` launcher and the end-of-sweep report.

The fast tests drive a tiny Hydra app (``tests/sweep_app``: each job holds while
a file exists, then writes a run record) so a job can be killed by its PID or the
sweep interrupted at a known moment; the slow test kills a real study job.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from hydra_plugins.icgo_launcher._core import resolve_workers, slot_cores
from icgo.core.devices import xla_flags

ROOT = Path(__file__).resolve().parents[1]
APP = ROOT / "tests" / "sweep_app" / "app.py"


def _default_sigint() -> None:
    # a shell's background job starts with SIGINT ignored, which Python then keeps: restore the default so
    # that the sweep sees Ctrl-C as a terminal user's would, however the test suite was started
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _start(sweep: Path, jobs: str, *extra: str, cwd=ROOT) -> subprocess.Popen:
    # the app is a script (sys.path[0] is its folder): PYTHONPATH makes it import this tree's launcher
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))}
    return subprocess.Popen([sys.executable, str(APP), "-m", f"job={jobs}", f"hydra.sweep.dir={sweep}", *extra],
                            cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_default_sigint, env=env)


def _wait_for(path: Path, proc: subprocess.Popen, timeout: float = 60.0) -> str:
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        if path.is_file() and path.read_text():
            return path.read_text()
        if proc.poll() is not None:
            raise AssertionError(f"sweep ended before {path} appeared:\n{proc.stderr.read()}")
        time.sleep(0.05)
    proc.kill()
    raise AssertionError(f"{path} did not appear in {timeout} s")


def _report(sweep: Path) -> dict:
    return {j["overrides"][0]: (j["status"], j["reason"])
            for j in json.loads((sweep / "sweep_report.json").read_text())["jobs"]}


def test_a_killed_job_costs_only_itself(tmp_path):
    sweep = tmp_path / "sweep"
    sweep.mkdir()
    for job in ("a", "b"):
        (sweep / f"hold-{job}").touch()
    proc = _start(sweep, "a,b,c", "hydra.launcher.workers=2")
    pid_a = int(_wait_for(sweep / "0" / "pid", proc))
    _wait_for(sweep / "1" / "pid", proc)           # job b is running beside job a
    os.kill(pid_a, signal.SIGKILL)
    time.sleep(0.5)
    (sweep / "hold-b").unlink()                     # job b finishes after a's death; job c then runs
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 1, err
    report = _report(sweep)
    assert report["job=a"][0] == "killed" and "SIGKILL" in report["job=a"][1]
    assert report["job=b"] == ("ok", "") and report["job=c"] == ("ok", "")
    assert (sweep / "0" / "FAILED").read_text().startswith("killed by SIGKILL")
    assert "Traceback" not in err
    assert "3 job(s): 2 ok, 1 killed" in err
    assert [ln.split()[2] for ln in err.splitlines() if ln.startswith("  job ")] == ["killed", "ok", "ok"]


def test_ctrl_c_stops_the_sweep_and_reports_every_job(tmp_path):
    sweep = tmp_path / "sweep"
    sweep.mkdir()
    (sweep / "hold-b").touch()
    proc = _start(sweep, "a,b,c", "hydra.launcher.workers=1")
    _wait_for(sweep / "1" / "pid", proc)            # a finished, b holds, c waits
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "interrupted" in err and "Traceback" not in err
    report = _report(sweep)
    assert report["job=a"][0] == "ok"
    assert report["job=b"][0] == "killed" and "SIGTERM" in report["job=b"][1]
    assert report["job=c"][0] == "not run"
    assert not (sweep / "1" / "run.json").exists()


def test_jobs_are_pinned_to_distinct_cores_with_a_plain_runs_device_count(tmp_path):
    """Pinned jobs get no thread flag (JAX's cache key hashes XLA_FLAGS) and the host-device count of a plain run on
    the sweep's cores (left out of the key), so they load the programs a single run compiled."""
    sweep = tmp_path / "sweep"
    proc = _start(sweep, "a,b", "hydra.launcher.workers=2")
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0, err
    runs = [json.loads((sweep / d / "run.json").read_text()) for d in ("0", "1")]
    cpus = sorted(os.sched_getaffinity(0))
    for run in runs:
        if len(cpus) >= 2:  # pinned: no thread flag
            assert "xla_cpu_multi_thread_eigen" not in run["xla_flags"], run["xla_flags"]
            assert "intra_op_parallelism_threads" not in run["xla_flags"], run["xla_flags"]
        assert f"--xla_force_host_platform_device_count={len(cpus)}" in run["xla_flags"].split()
    if len(cpus) >= 2:
        assert all(len(r["affinity"]) == 1 for r in runs)
        assert runs[0]["affinity"] != runs[1]["affinity"]
    assert "2 job(s): 2 ok" in err


def test_a_bad_launcher_setting_is_one_line(tmp_path):
    proc = _start(tmp_path / "sweep", "a", "hydra.launcher.workers=0")
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 2
    assert err.strip().splitlines()[-1] == ("error: hydra.launcher.workers must be a positive integer or null "
                                             "(one per CPU), got 0")


@pytest.mark.parametrize("workers, n_jobs, cpus, expect", [(None, 5, 2, 2), (None, 1, 2, 1), (4, 10, 2, 4),
                                                           (3, 2, 8, 2)])
def test_resolve_workers(workers, n_jobs, cpus, expect):
    assert resolve_workers(workers, n_jobs, cpus) == expect


@pytest.mark.parametrize("cpus, workers, slots", [
    (range(16), 3, [[0, 1, 2, 3, 4], [5, 6, 7, 8, 9], [10, 11, 12, 13, 14, 15]]), (range(2), 2, [[0], [1]]),
    (range(2), 1, [[0, 1]]), ([4, 6, 9], 2, [[4], [6, 9]])])
def test_the_cores_are_shared_out_among_the_worker_slots(cpus, workers, slots):
    """Each slot a contiguous block of the cores (its job then has one host device per core of it)."""
    got = [slot_cores(list(cpus), workers, k) for k in range(workers)]
    assert got == slots and sorted(sum(got, [])) == sorted(cpus)


@pytest.mark.parametrize("bad", [0, -1, 1.5, True, "2"])
def test_resolve_workers_rejects(bad):
    with pytest.raises(ValueError, match="hydra.launcher.workers"):
        resolve_workers(bad, 3, 2)


def test_xla_flags_replace_only_the_thread_flags():
    assert xla_flags(None, "--a=1") == "--a=1"
    assert xla_flags(1, "--a=1 --xla_cpu_multi_thread_eigen=true intra_op_parallelism_threads=8") == \
        "--a=1 --xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
    assert xla_flags(2, "") == "--xla_cpu_multi_thread_eigen=true intra_op_parallelism_threads=2"


def test_the_study_app_defaults_to_the_icgo_local_launcher():
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    from experiments._preflight import CONF_DIR

    GlobalHydra.instance().clear()
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose(config_name="config", return_hydra_config=True)
    assert cfg.hydra.launcher._target_ == "hydra_plugins.icgo_launcher.launcher.IcgoLocalLauncher"
    assert cfg.hydra.launcher.workers is None and cfg.hydra.launcher.xla_threads == 1


@pytest.mark.slow
def test_killing_a_study_job_costs_only_it_and_the_rerun_resumes(tmp_path):
    """The real study: kill job 0's process mid-run; jobs 1-2 finish; a re-run redoes job 0 only."""
    sweep = tmp_path / "sweep"
    cmd = [sys.executable, "-m", "experiments.run", "-m", "strategy=chaos,wavelet,gaussian", "budget=smoke",
           "figures=false", "hydra.launcher.workers=1", f"hydra.sweep.dir={sweep}",
           f"jax_cache_dir={tmp_path / 'jax'}"]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    # the job's log, which Hydra opens as the job starts (its .hydra record is staged with its outputs, at the end)
    _wait_for(sweep / "0" / "run.log", proc, timeout=120)
    children = [int(p) for p in Path(f"/proc/{proc.pid}/task/{proc.pid}/children").read_text().split()]
    job = [c for c in children if "spawn_main" in Path(f"/proc/{c}/cmdline").read_text()]
    assert len(job) == 1
    os.kill(job[0], signal.SIGKILL)
    out, err = proc.communicate(timeout=600)
    assert proc.returncode == 1, err
    statuses = [j["status"] for j in json.loads((sweep / "sweep_report.json").read_text())["jobs"]]
    assert statuses == ["killed", "ok", "ok"]
    kept = {d: (sweep / d / "run.json").read_bytes() for d in ("1", "2")}
    rerun = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert rerun.returncode == 0, rerun.stderr
    assert [j["status"] for j in json.loads((sweep / "sweep_report.json").read_text())["jobs"]] == ["ok"] * 3
    assert {d: (sweep / d / "run.json").read_bytes() for d in ("1", "2")} == kept   # finished jobs kept
    assert not (sweep / "0" / "FAILED").exists()
    single = tmp_path / "single"                    # a job in its pinned one-thread process == a plain run
    subprocess.run([sys.executable, "-m", "experiments.run", "strategy=wavelet", "budget=smoke", "figures=false",
                    f"hydra.run.dir={single}", f"jax_cache_dir={tmp_path / 'jax'}"], cwd=ROOT, check=True,
                   capture_output=True, timeout=600)
    for table in ("metrics.csv", "predictions.csv"):
        assert (single / table).read_bytes() == (sweep / "1" / table).read_bytes()


def test_a_sweep_job_keeps_a_plain_runs_device_count_and_cache_key_flags():
    """A pinned job adds no thread flag (JAX's cache key hashes XLA_FLAGS) and gets the plain run's host-device
    count (left out of the key), so it loads the programs a plain run compiled; an unpinned job keeps the flags."""
    from icgo.core.devices import flagged_host_devices, sweep_job_flags

    assert sweep_job_flags(1, True, 2, "") == "--xla_force_host_platform_device_count=2"
    assert sweep_job_flags(1, True, 16, "--a=1") == "--a=1 --xla_force_host_platform_device_count=16"
    unpinned = sweep_job_flags(1, False, 2, "")
    assert "--xla_cpu_multi_thread_eigen=false" in unpinned and flagged_host_devices(unpinned) == 2
    assert flagged_host_devices(sweep_job_flags(1, True, 2, "--xla_force_host_platform_device_count=4")) == 4
