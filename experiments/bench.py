"""Benchmark of the ICGO-RELM study against the machine's limit and against mealpy: ``python -m experiments.bench``.

* without a mode option: the CPU benchmark (:mod:`icgo.bench.cpu`, whose docstring lists every measurement):
  kernels, roofline, the Table 3 study through its own path and the front door, mealpy, the JAX peers, scaling;
* ``--gpu-check``: the per-backend check in minutes (:mod:`icgo.bench.backend`);
* ``--rows 1e3,1e4,1e5,1e6``: the reader, the study and the discrepancy workflow on contract CSVs of that many
  rows, wall time and peak memory (:mod:`icgo.bench.rows`);
* ``--calibrate``: ``python -m experiments.calibrate`` on one bundled device, cold then warm.

It prints a Markdown table and, as its last line, one JSON object; ``--out NAME`` also writes
``results/bench_<NAME>.{md,json}``. ``--quick`` runs a small version of everything (smoke use, minutes).
The options, their checks and the modes: :mod:`icgo.bench.cli`.
"""

from __future__ import annotations

import json

from icgo.io.files import RESULTS_DIR, results_output


def main(argv=None) -> dict:
    from icgo.bench import cli

    p = cli.parser("python -m experiments.bench", __doc__.split("\n\n")[0])
    pl = cli.plan(p.parse_args(argv), p.error)
    res, text = cli.run(pl)
    if pl.mode in cli.PRINTED_ONLY:
        print(text)
        print(json.dumps(res))
        return res
    return _publish(res, text, pl.a.out)


def _publish(out: dict, md: str, name: str | None) -> dict:
    """Print the Markdown and, last, the JSON line; with ``name`` also write results/bench_<name>.{md,json}
    (both files or neither)."""
    line = json.dumps(out, default=float)
    if name:  # both files or neither, into the shared results folder
        with results_output(RESULTS_DIR, writer="experiments.bench").staged() as stage:
            (stage / f"bench_{name}.md").write_text(md + "\n")
            (stage / f"bench_{name}.json").write_text(line + "\n")
    print(md)
    print(line)
    return out


if __name__ == "__main__":
    from icgo.core.settings import run_cli

    raise SystemExit(run_cli(lambda: (main(), 0)[1]))
