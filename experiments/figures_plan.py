"""The preset plan of ``python -m experiments.figures`` (:data:`icgo.studies.icgo_relm.results.outputs.PLAN`): its job counts,
its run (each entry a multirun of ``experiments.run``) and the check of its ``--override``s."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import yaml

from experiments._preflight import CONF_DIR, check_overrides, check_plain_overrides
from icgo.core.errors import SettingError
from icgo.studies.icgo_relm.results.outputs import PLAN


def plan_jobs(preset: str, overrides=()) -> int:
    """How many jobs a plan entry's sweep runs: the preset's ``hydra.sweeper.params`` with the entry's overrides
    over them, the product of the number of values of each swept key."""
    cfg = yaml.safe_load((CONF_DIR / "experiment" / f"{preset}.yaml").read_text()) or {}
    params = {str(k).lstrip("+"): str(v) for k, v in ((cfg.get("hydra") or {}).get("sweeper") or {}).get(
        "params", {}).items()}
    for o in overrides:
        k, _, v = o.partition("=")
        params[k.lstrip("+")] = v
    n = 1
    for v in params.values():
        n *= len(v.split(","))
    return n


def _clock(seconds: float) -> str:
    m, sec = divmod(int(round(seconds)), 60)
    return f"{m // 60}:{m % 60:02d}:{sec:02d}" if m >= 60 else f"{m}:{sec:02d}"


def run_plan(base: Path, jobs: int, extra=()) -> tuple[list[Path], list[str]]:
    """Run the preset plan (:data:`PLAN`) as multiruns under ``base``; return their sweep dirs and the names
    of the presets whose sweep did not finish (exit status not 0).

    Before each entry a line ``[k/N] <entry>: J job(s), elapsed, ETA``; the ETA is the time per job of the
    entries done so far times the jobs left (none before the first entry has finished).
    """
    dirs, failed = [], []
    counts = [plan_jobs(preset, overrides) for _, preset, overrides in PLAN]
    total, done, t0 = sum(counts), 0, time.perf_counter()
    print(f"plan: {len(PLAN)} entries, {total} jobs, into {base}", flush=True)
    for k, ((name, preset, overrides), n) in enumerate(zip(PLAN, counts), 1):
        d = base / name
        cmd = [sys.executable, "-m", "experiments.run", "-m", f"experiment={preset}", *overrides,
               f"hydra.sweep.dir={d}", "progress=false", *extra]
        if jobs is not None:  # else the launcher's default: one job per core
            cmd += [f"hydra.launcher.workers={jobs}"]
        elapsed = time.perf_counter() - t0
        eta = f"ETA {_clock(elapsed / done * (total - done))}" if done else "ETA after the first entry"
        print(f"[{k}/{len(PLAN)}] {name}: {n} job(s); elapsed {_clock(elapsed)}, {eta}", flush=True)
        print("+", " ".join(cmd), flush=True)
        t = time.perf_counter()
        rc = subprocess.call(cmd, cwd=Path(__file__).resolve().parent.parent)
        print(f"  {name}: exit {rc}, {time.perf_counter() - t:.0f} s", flush=True)
        done += n
        dirs.append(d)
        if rc:
            failed.append(name)
    return dirs, failed


def check_plan_overrides(extra) -> None:
    """SettingError (one line) for an ``--override`` the study would refuse, before any preset runs."""
    for ov in extra:
        if ov.startswith("-") or "=" not in ov.lstrip("+~"):
            raise SettingError(f"--override {ov!r}: expected key=value (a Hydra override of experiments.run)")
    err = check_overrides(list(extra)) or check_plain_overrides(list(extra), "config")
    if err:
        raise SettingError(f"--override: {err}")
