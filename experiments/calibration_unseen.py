"""The calibrate door on devices it has never seen: ``python -m experiments.calibration_unseen [--out results]``.

Makes :data:`icgo.datasets.mag_cal_variants.N_VARIANTS` perturbed copies of each bundled device
(:mod:`icgo.datasets.mag_cal_variants`: other mounting, soft and hard iron, another non-linearity, accelerometer
errors, more noise), writes each as a circuitpython-mag-cal raw-layout JSON, and takes it through what
``python -m experiments.calibrate data=FILE mag_axes=.. grav_axes=..`` does with its defaults (the reader and its
layout, :func:`icgo.studies.calibration.study.evaluate`, the recommendation and its nested accuracy). Writes
``calibration_unseen.md`` and ``calibration_unseen.csv`` into ``--out`` (a shared results folder: only these
two files replaced): per variant the recommendation, its nested accuracy and every method's means, and the
goals (:mod:`icgo.studies.calibration.goals`) on the variants, beside the same goals on the 9 bundled devices
read from ``results/calibration_devices.csv`` (``make calibration``), in a section of their own.

Nothing in the door is tuned on these variants, and the numbers are reported as they come (docs/calibrate.md,
"Unseen devices": the perturbation sizes were revised once, after the first variant scored).
"""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _positive(text: str) -> int:
    """``--variants``: an integer >= 1."""
    import argparse

    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1, got {v}")
    return v


def main(argv=None) -> int:
    from icgo.core.settings import ArgumentParser

    ap = ArgumentParser(prog="python -m experiments.calibration_unseen", description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "results"), help="results folder (shared: only its two files replaced)")
    ap.add_argument("--peer", action="store_true", help="run circuitpython-mag-cal side by side too (slower)")
    ap.add_argument("--devices", nargs="*", default=None, help="bundled devices to perturb (default: all 9)")
    ap.add_argument("--variants", type=_positive, default=None, help="variants per device (default: N_VARIANTS)")
    a = ap.parse_args(argv)
    from icgo.io.files import Output
    from icgo.studies.calibration import unseen

    out = Output(Path(a.out), setting="--out", shared=True).check()
    df, vs, recs, seconds = unseen.run_variants(a.peer, a.devices, a.variants)
    t, lines = unseen.report(df, vs, recs, seconds, a.peer, ROOT / "results" / "calibration_devices.csv")
    with out.staged() as stage:
        unseen.write_results(t, lines, stage)
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    from icgo.core.settings import run_cli

    raise SystemExit(run_cli(main))
