"""Cross-check of the casing model against an established magnetics library (the casing sweeps, ``experiment=sweep_casing*``).

``python -m experiments.casing_check`` writes ``results/casing_model_check.{md,csv}``
(:mod:`icgo.studies.icgo_relm.casing_check`: icgo's pole pair and dipole line against magpylib's magnetised tube at every
lab_casing station, the casing at 0.5 to 2 m from the turntable axis).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent.parent / "results"))
    a = ap.parse_args(argv)
    from icgo.io.files import staged_results
    from icgo.studies.icgo_relm.casing_check import compare, markdown, write_results

    df = compare()
    md = markdown(df)
    with staged_results(Path(a.out)) as stage:  # both files, or neither
        write_results(df, md, stage)
    print("\n".join(md))
    return 0


if __name__ == "__main__":
    sys.exit(main())
