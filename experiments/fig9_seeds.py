"""How often each CGO seed improves on its parent and is selected in Fig. 9's searches -> ``results/fig9_seeds.*``.

``python -m experiments.fig9_seeds [--out results] [--repeats N]``

The searches of Fig. 9's CGO-RELM (``lab_casing`` seed 0, the ICGO-RELM study's defaults: its splits, keys, fitness
and budget) counted seed by seed (:mod:`icgo.studies.icgo_relm.cgo_seeds`), for the default CGO and the 4th-seed options of
the Fig. 9 ablation that change which coordinates it moves or what it is (``results/fig9_ablation.md``).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    from icgo.core.settings import ArgumentParser

    ap = ArgumentParser(prog="python -m experiments.fig9_seeds", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default=str(ROOT / "results"), help="results/ (default) or a directory of its own")
    ap.add_argument("--overwrite", action="store_true", help="replace a used --out directory (not results/) whole")
    ap.add_argument("--repeats", type=int, default=None, help="repeats (default: the study's, Fig. 9's 10)")
    a = ap.parse_args(argv)

    import icgo  # noqa: F401  (float64)
    from icgo.io.files import results_output
    from icgo.core.errors import SettingError
    from icgo.datasets import casing_stations
    from icgo.optim.cgo import CGOConfig
    from icgo.studies.icgo_relm import cgo_seeds
    from icgo.studies.icgo_relm.config import StudyConfig

    if a.repeats is not None and a.repeats < 2:
        raise SettingError(f"--repeats {a.repeats}: must be >= 2")
    cfg = StudyConfig(strategies=("original",))
    if a.repeats is not None:
        cfg = cfg.replace(split={"n_repeats": a.repeats})
    output = results_output(a.out, overwrite=a.overwrite, writer="experiments.fig9_seeds")
    ds = casing_stations.lab_casing(0)
    t0 = time.perf_counter()
    runs = cgo_seeds.study(ds.frame, ds.meta, {k: CGOConfig.paper(**v) for k, v in cgo_seeds.CONFIGS.items()}, cfg)
    table = cgo_seeds.rates_table(runs)
    command = "python -m experiments.fig9_seeds" + (f" --repeats {a.repeats}" if a.repeats is not None else "")
    text = cgo_seeds.markdown(table, cfg, time.perf_counter() - t0, command)
    with output.staged(last=("fig9_seeds.md",)) as stage:
        cgo_seeds.write_results(table, text, stage)
    print(text)
    return 0


if __name__ == "__main__":
    from icgo.core.settings import run_cli

    sys.exit(run_cli(main))
