"""A command in a child process, timed: its wall time, its own peak memory and its exit status
(:func:`measure`), what every front-door measurement of the benchmark runs its commands through."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: Runs argv[2:] as its child and writes that child's peak resident memory (kB) to the file argv[1]. The
#: command must be started by a small process: a child's ru_maxrss includes the memory of the process it
#: was forked from (Linux carries the pre-exec high-water mark over exec), so forking it straight from a
#: benchmark that holds a large data set would report that data set as the command's own. With
#: ``ICGO_BENCH_CPUS`` (comma list) set, the launcher first cuts its affinity to those cores (the child
#: inherits it); set here rather than in the benchmark, which must not fork once JAX runs threads.
_SHIM = """import os, sys
cpus = os.environ.pop("ICGO_BENCH_CPUS", "")
if cpus:
    os.sched_setaffinity(0, {int(c) for c in cpus.split(",")})
pid = os.fork()
if pid == 0:
    os.execvp(sys.argv[2], sys.argv[2:])
_, status, ru = os.wait4(pid, 0)
open(sys.argv[1], "w").write(str(ru.ru_maxrss))
sys.exit(os.waitstatus_to_exitcode(status))
"""


def measure(cmd: list[str], timeout: float | None = None, cpus: list[int] | None = None) -> dict:
    """Run ``cmd`` in a child process: wall time (s), peak resident memory (GB), exit status, output tail.

    Peak memory is the command's own ``ru_maxrss`` (``os.wait4`` in a small launcher process, see
    :data:`_SHIM`), whatever the size of this process. ``cpus``: the child may run on these cores only
    (its affinity mask, inherited by everything it starts: the job then gives the CPU one host device per core of it).
    """
    with tempfile.TemporaryDirectory() as tmp:
        log_path, rss_path = Path(tmp) / "log", Path(tmp) / "rss"
        with open(log_path, "w") as log:
            t = time.perf_counter()
            env = None if cpus is None else {**os.environ, "ICGO_BENCH_CPUS": ",".join(str(c) for c in cpus)}
            proc = subprocess.Popen([sys.executable, "-c", _SHIM, str(rss_path), *cmd], stdout=log,
                                    stderr=subprocess.STDOUT, start_new_session=True, env=env)
            try:
                rc = proc.wait(timeout)
            except subprocess.TimeoutExpired:  # the launcher and the command are one process group
                os.killpg(proc.pid, 9)
                proc.wait()
                rc = None
            wall = time.perf_counter() - t
        rss_kb = float(rss_path.read_text()) if rss_path.exists() else float("nan")
        tail = log_path.read_text()[-2000:]
    return {"wall_s": wall, "peak_rss_gb": rss_kb * 1024 / 1e9, "rc": rc, "tail": tail}
