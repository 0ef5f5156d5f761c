"""Comparison figures and tables: simulated data sets next to the papers.

    python -m experiments.dataset_figures [--out results] [--seed 0]

Writes into ``--out``:
* ``datasets_lab_casing_fig6.png`` / ``.csv`` / ``.md``: raw and multi-station-analysis
  azimuth per true azimuth (mean +- std over toolface), ICGO Fig. 6;
* ``datasets_lab_casing_fig7.png``: raw and MSA azimuth error vs toolface, ICGO Fig. 7;
* ``datasets_well_conditions_table4.csv`` / ``.md`` / ``.png``: raw error mean and
  std per condition next to the paper's Table 4 "original" columns.
The tables and figures are drawn by :mod:`icgo.studies.icgo_relm.dataset_figures`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from icgo.studies.icgo_relm.dataset_figures import lab_casing_figures, well_conditions_table


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m experiments.dataset_figures", description=__doc__.splitlines()[0])
    p.add_argument("--out", default="results", help="output directory (default results/)")
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    print(lab_casing_figures(out, a.seed).round(3).to_string(index=False))
    print(well_conditions_table(out, a.seed).round(3).to_string(index=False))
    print(f"wrote {out}/datasets_*")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
