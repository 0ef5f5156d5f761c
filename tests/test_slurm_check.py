"""hydra_plugins.icgo_launcher.slurm_check: reading `sinfo` and refusing a request no node can hold (no cluster needed)."""

import stat
import subprocess

import pytest

from hydra_plugins.icgo_launcher import slurm_check
from hydra_plugins.icgo_launcher.slurm_check import cluster_offer, parse_sinfo, unschedulable

# `sinfo -h --exact -o '%P|%c|%m|%a'` as printed by scripts/slurm_cluster.sh's one-node cluster
ONE_NODE = "debug*|2|21695|up\n"
# a cluster with two kinds of node in `cpu`, a big-memory partition and a down one
CLUSTER = """cpu*|32|128000|up
cpu*|64|256000|up
bigmem|16|1024000|up
gpu|8+|n/a|down
"""


def test_parse_one_node():
    assert parse_sinfo(ONE_NODE) == {"debug": {"cpus": 2, "mem_mb": 21695, "default": True, "avail": "up"}}


def test_parse_takes_the_largest_node_of_each_partition():
    offer = parse_sinfo(CLUSTER)
    assert offer["cpu"] == {"cpus": 64, "mem_mb": 256000, "default": True, "avail": "up"}
    assert offer["bigmem"] == {"cpus": 16, "mem_mb": 1024000, "default": False, "avail": "up"}
    assert offer["gpu"] == {"cpus": 8, "mem_mb": 0, "default": False, "avail": "down"}  # '8+', 'n/a'


def test_parse_skips_blank_and_foreign_lines():
    assert parse_sinfo("\n   \nsinfo: warning: something\n" + ONE_NODE) == parse_sinfo(ONE_NODE)
    assert parse_sinfo("") == {}


def test_the_issue_case_fails_fast():
    # the old preset (4 CPUs) on a 2-CPU node: pending for ever with reason PartitionConfig
    msg = unschedulable(4, 8, None, parse_sinfo(ONE_NODE))
    assert msg == ("hydra.launcher.cpus_per_task=4 but partition debug offers at most 2 CPUs per node "
                   "(memory 21695 MB); lower it")


def test_the_new_defaults_fit_the_one_node_cluster():
    assert unschedulable(1, 4, None, parse_sinfo(ONE_NODE)) is None
    assert unschedulable(2, 21695 / 1024, "debug", parse_sinfo(ONE_NODE)) is None  # exactly the node


def test_memory_in_slurm_units():
    msg = unschedulable(1, 22, "debug", parse_sinfo(ONE_NODE))  # 22 GB = 22528 MB > 21695 MB
    assert msg == ("hydra.launcher.mem_gb=22 (22528 MB) but partition debug offers at most 21695 MB per node "
                   "(2 CPUs); lower it")


def test_both_too_large_is_one_line():
    msg = unschedulable(8, 64, None, parse_sinfo(ONE_NODE))
    assert "\n" not in msg and "cpus_per_task=8" in msg and "mem_gb=64" in msg and msg.endswith("lower them")


def test_tasks_per_node_multiply_the_cpus():
    offer = parse_sinfo(ONE_NODE)
    assert unschedulable(1, 1, None, offer, tasks_per_node=2) is None
    msg = unschedulable(2, 1, None, offer, tasks_per_node=2)
    assert msg.startswith("hydra.launcher.cpus_per_task=2 x tasks_per_node=2 but partition debug offers at most 2")


def test_default_partition_and_named_partitions():
    offer = parse_sinfo(CLUSTER)
    assert unschedulable(64, 200, None, offer) is None  # default `cpu`: its 64-CPU nodes
    assert "partition cpu offers at most 64 CPUs" in unschedulable(65, 1, None, offer)
    assert unschedulable(1, 900, "bigmem", offer) is None
    assert "partition cpu offers at most 256000 MB" in unschedulable(1, 900, "cpu", offer)
    assert unschedulable(1, 900, "cpu,bigmem", offer) is None  # any of a list may take it
    msg = unschedulable(128, 1, "cpu,bigmem", offer)
    assert msg.count("offers at most") == 2 and msg.endswith("lower them")


def test_unknown_partition():
    msg = unschedulable(1, 4, "long", parse_sinfo(ONE_NODE))
    assert msg == "hydra.launcher.partition=long but the cluster has no partition long (partitions: debug); set one of them"


def test_nothing_to_decide():
    assert unschedulable(64, 1000, None, None) is None  # sinfo missing or failing: go on
    assert unschedulable(None, None, None, parse_sinfo(ONE_NODE)) is None  # 1 CPU, no --mem
    assert unschedulable(1, 4, None, parse_sinfo("debug|2|21695|up\n")) is None  # no default partition


def _fake_sinfo(tmp_path, body):
    exe = tmp_path / "sinfo"
    exe.write_text("#!/bin/sh\n" + body)
    exe.chmod(exe.stat().st_mode | stat.S_IXUSR)
    return str(exe)


def test_cluster_offer_runs_sinfo(tmp_path):
    args = tmp_path / "args"
    exe = _fake_sinfo(tmp_path, f'echo "$@" > {args}\nprintf "debug*|2|21695|up\\n"\n')
    assert cluster_offer("debug", sinfo=exe) == parse_sinfo(ONE_NODE)
    assert args.read_text().split() == ["--noheader", "--exact", "--format", "%P|%c|%m|%a", "--partition", "debug"]
    assert cluster_offer(sinfo=exe) == parse_sinfo(ONE_NODE)
    assert "--partition" not in args.read_text()


def test_cluster_offer_unknown_partition_lists_the_others(tmp_path):
    # `sinfo -p long` prints nothing (exit 0): ask again for every partition
    exe = _fake_sinfo(tmp_path, 'case "$*" in *--partition*) exit 0;; esac\nprintf "debug*|2|21695|up\\n"\n')
    offer = cluster_offer("long", sinfo=exe)
    assert offer == parse_sinfo(ONE_NODE)
    assert "(partitions: debug)" in unschedulable(1, 4, "long", offer)


def test_cluster_offer_none_without_a_cluster(tmp_path):
    assert cluster_offer(sinfo=str(tmp_path / "no-such-sinfo")) is None
    failing = _fake_sinfo(tmp_path, 'echo "sinfo: fatal: Unable to process configuration file" >&2\nexit 1\n')
    assert cluster_offer(sinfo=failing) is None


def test_cluster_offer_none_on_timeout(monkeypatch, tmp_path):
    def hang(*args, **kwargs):
        raise subprocess.TimeoutExpired(args[0], kwargs.get("timeout"))

    monkeypatch.setattr(slurm_check.subprocess, "run", hang)
    assert cluster_offer(sinfo=_fake_sinfo(tmp_path, "exit 0\n")) is None


@pytest.mark.skipif(not slurm_check.shutil.which("sinfo"), reason="no sinfo here")
def test_cluster_offer_real_sinfo_shape():
    offer = cluster_offer()  # a running cluster (SLURM_CONF) or None; never an exception
    if offer is None:
        pytest.skip("sinfo is installed but no SLURM cluster answers (start one: scripts/slurm_cluster.sh; "
                    "make test-slurm runs this against a real one-node cluster)")
    assert offer and all({"cpus", "mem_mb", "default", "avail"} <= set(p) for p in offer.values())
    # the same partitions as sinfo's own answer, read here without cluster_offer
    raw = subprocess.run(["sinfo", "--noheader", "--exact", "--format", "%P|%c|%m|%a"], capture_output=True,
                         text=True, timeout=30, check=True).stdout
    assert offer == parse_sinfo(raw)


def test_the_shipped_slurm_preset_fits_a_small_node():
    # conf/hydra/launcher/slurm.yaml: two jobs side by side on a 2-CPU, 8 GB node
    # (scripts/slurm_cluster.sh gives such a node RealMemory = 90 % of 8 GB = 7372 MB)
    from pathlib import Path

    from omegaconf import OmegaConf

    cfg = OmegaConf.load(Path(__file__).resolve().parents[1] / "conf/hydra/launcher/slurm.yaml")
    small = parse_sinfo("debug*|2|7372|up\n")
    assert unschedulable(cfg.cpus_per_task, cfg.mem_gb, cfg.partition, small, tasks_per_node=cfg.tasks_per_node) is None
    assert 2 * cfg.cpus_per_task <= 2 and 2 * cfg.mem_gb * 1024 <= 7372
    assert any("--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1" in line for line in cfg.setup)
