"""Ask a SLURM cluster what it offers, so that a sweep that can never be scheduled fails fast.

SLURM accepts a job that asks for more CPUs or memory than any node of its partition has and
leaves it pending for ever (reason ``PartitionConfig`` or ``Resources``); submitit then waits
without a word. :func:`cluster_offer` reads the partitions' largest nodes with one ``sinfo``
call and :func:`unschedulable` turns a request that cannot fit into a one-line message::

    offer = cluster_offer(cfg.partition)
    msg = unschedulable(cfg.cpus_per_task, cfg.mem_gb, cfg.partition, offer,
                        tasks_per_node=cfg.tasks_per_node)
    if msg:
        raise SystemExit(msg)

Only the partition's node configuration is compared (``sinfo --exact -o '%P|%c|%m|%a'``:
CPUs and RealMemory per node); limits set elsewhere (``MaxCPUsPerNode``, ``MaxMemPerNode``,
QOS, accounts) are not seen. A node that is down or drained still counts: it may come back.
Memory follows SLURM's units (``--mem=4GB`` is 4 x 1024 MB). docs/slurm.md.
"""
from __future__ import annotations

import shutil
import subprocess

SINFO_FORMAT = "%P|%c|%m|%a"
"""Partition (default one marked ``*``), CPUs per node, memory per node in MB, availability."""


def _number(text: str) -> int | None:
    """``'2'`` -> 2, ``'2+'`` -> 2 (a grouped minimum), ``'n/a'`` or empty -> None."""
    digits = text.strip().rstrip("+")
    return int(digits) if digits.isdigit() else None


def parse_sinfo(text: str) -> dict:
    """Partitions from ``sinfo -h --exact -o '%P|%c|%m|%a'`` output.

    Returns ``{name: {"cpus": int, "mem_mb": int, "default": bool, "avail": str}}`` with, for each
    partition, the largest CPU count and the largest memory found on any of its node groups (one
    line per group of identical nodes). Unreadable lines are skipped; a number that cannot be read
    counts as 0.
    """
    offer: dict = {}
    for line in text.splitlines():
        fields = line.strip().split("|")
        if len(fields) < 3 or not fields[0].strip():
            continue
        name = fields[0].strip()
        default = name.endswith("*")
        name = name.rstrip("*")
        cpus = _number(fields[1]) or 0
        mem_mb = _number(fields[2]) or 0
        avail = fields[3].strip() if len(fields) > 3 else ""
        part = offer.setdefault(name, {"cpus": 0, "mem_mb": 0, "default": False, "avail": avail})
        part["cpus"] = max(part["cpus"], cpus)
        part["mem_mb"] = max(part["mem_mb"], mem_mb)
        part["default"] = part["default"] or default
    return offer


def cluster_offer(partition: str | None = None, *, sinfo: str = "sinfo", timeout: float = 20.0) -> dict | None:
    """What the cluster offers per partition (:func:`parse_sinfo`), from one ``sinfo`` call.

    ``partition`` (a name or a comma-separated list, as sbatch takes it) limits the answer to
    those partitions (to all of them when none of those exists, so that the message can name
    them); None asks for all (the default partition is marked ``"default": True``).
    None when ``sinfo`` is not installed, or fails (no cluster configured or reachable): then
    nothing can be checked and the caller should go on.
    """
    exe = shutil.which(sinfo)
    if exe is None:
        return None
    cmd = [exe, "--noheader", "--exact", "--format", SINFO_FORMAT]
    offer = _run_sinfo(cmd + ["--partition", str(partition)] if partition else cmd, timeout)
    if partition and offer == {}:
        offer = _run_sinfo(cmd, timeout)  # none of those partitions exists: name the ones that do
    return offer


def _run_sinfo(cmd: list, timeout: float) -> dict | None:
    try:
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False)
    except (OSError, subprocess.SubprocessError):
        return None
    return parse_sinfo(done.stdout) if done.returncode == 0 else None


def unschedulable(cpus_per_task: int | None, mem_gb: float | None, partition: str | None,
                  offer: dict | None, *, tasks_per_node: int | None = 1) -> str | None:
    """A one-line message when the request can never be scheduled on ``offer``; None when it fits.

    ``cpus_per_task * tasks_per_node`` CPUs and ``mem_gb`` GB (per node, as submitit's
    ``--mem``) must fit on one node of the partition; ``partition`` None means the cluster's
    default partition, a comma-separated list fits when any of them fits. ``offer`` None
    (:func:`cluster_offer` could not ask) or a request of nothing is never refused.
    """
    if offer is None:
        return None
    if partition:
        names = [p.strip() for p in str(partition).split(",") if p.strip()]
    else:
        names = [name for name, part in offer.items() if part.get("default")]
        if not names:
            return None  # no default partition: sbatch itself refuses a job without --partition
    missing = [name for name in names if name not in offer]
    present = [name for name in names if name in offer]
    if not present:
        have = ", ".join(sorted(offer)) or "none"
        return (f"hydra.launcher.partition={partition} but the cluster has no partition "
                f"{' or '.join(missing)} (partitions: {have}); set one of them")
    tasks = int(tasks_per_node or 1)
    cpus = int(cpus_per_task or 1) * tasks
    mem_mb = int(round(float(mem_gb) * 1024)) if mem_gb else 0
    messages = []
    for name in present:
        part = offer[name]
        problems = []
        if cpus > part["cpus"]:
            what = (f"hydra.launcher.cpus_per_task={cpus_per_task}" if tasks == 1 else
                    f"hydra.launcher.cpus_per_task={cpus_per_task} x tasks_per_node={tasks}")
            problems.append(f"{what} but partition {name} offers at most {part['cpus']} CPUs per node "
                            f"(memory {part['mem_mb']} MB)")
        if mem_mb > part["mem_mb"]:
            problems.append(f"hydra.launcher.mem_gb={mem_gb:g} ({mem_mb} MB) but partition {name} offers "
                            f"at most {part['mem_mb']} MB per node ({part['cpus']} CPUs)")
        if not problems:
            return None
        messages.append("; ".join(problems))
    several = len(messages) > 1 or "; " in messages[0]
    return " | ".join(messages) + ("; lower them" if several else "; lower it")
