"""Table 1, Table 3 and Fig. 9 over independent simulated worlds: ``results/{table1,table3,fig9}_worlds.{md,csv}``.

``python -m experiments.worlds_tables [--out results] [--run] [RUN_DIR ...]``: the tables of the worlds runs under
the given directories (default: ``multirun/worlds``), built by :mod:`icgo.studies.icgo_relm.results.worlds_tables`
(what each holds is said there), and the tests of every pair of their methods (``worlds_orders.{md,csv}``:
:mod:`icgo.studies.icgo_relm.results.worlds_orders`). ``--run`` first runs the presets into its ``PLAN``'s
directories (one at a time); with ``--plan instruments`` the presets over a family of instruments
(``results/{table3,table1}_instruments.*``). ``--orders`` writes only ``worlds_orders`` from the per-world rows already in ``--out``
(no run needed).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

from icgo.studies.icgo_relm.results.worlds_tables import INSTRUMENT_PLAN, PLAN, build, plan_command

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dirs", nargs="*", type=Path, help="run directories (default: multirun/worlds)")
    ap.add_argument("--out", type=Path, default=ROOT / "results", help="where the tables go (default: results/)")
    ap.add_argument("--run", action="store_true", help="first run the presets into multirun/worlds (one at a time)")
    ap.add_argument("--plan", choices=("worlds", "instruments"), default="worlds",
                    help="which presets --run runs: the noise-only worlds (default) or the family of instruments")
    ap.add_argument("--orders", action="store_true", help="only the pairwise order tests, from the per-world rows in "
                                                          "--out (no runs read)")
    a = ap.parse_args(argv)
    if a.orders:
        from icgo.studies.icgo_relm.results import worlds_orders

        if not worlds_orders.build(a.out):
            print(f"error: no *_worlds_per_world.csv in {a.out}", file=sys.stderr)
            return 2
        print(f"wrote: {a.out / worlds_orders.NAME}.md")
        return 0
    if a.run:
        for name, *_ in (INSTRUMENT_PLAN if a.plan == "instruments" else PLAN):
            cmd = plan_command(name)
            print("running:", " ".join(cmd[1:]), flush=True)
            t0 = time.perf_counter()
            rc = subprocess.run(cmd, cwd=ROOT).returncode
            print(f"  {name}: exit {rc}, {time.perf_counter() - t0:.0f} s", flush=True)
            if rc:
                return rc
    dirs = a.dirs or [ROOT / "multirun" / "worlds"]
    done = build(dirs, a.out)
    if not done:
        print(f"error: no worlds runs under {', '.join(map(str, dirs))}; run with --run (or the presets, "
              "docs/relm_study.md)", file=sys.stderr)
        return 1
    print("wrote: " + ", ".join(f"{a.out / n}.md" for n in done))
    return 0


if __name__ == "__main__":
    from icgo.core.settings import run_cli

    raise SystemExit(run_cli(main))
