"""``python -m icgo.datasets NAME --out DIR [--seed S] [--overwrite]``: write a simulated data set (CSV + meta + truth).

``DIR`` is a data folder (:class:`icgo.io.files.Output`, shared): the three files ``NAME.csv``,
``NAME.meta.json`` and ``NAME.truth.json`` are written all at once or not at all, beside whatever the folder
already holds (another data set written there stays), and files of the same names are refused unless
``--overwrite`` (which replaces those three only).
"""

from __future__ import annotations

from icgo.core.settings import startup_interrupts

if __name__ == "__main__":
    startup_interrupts()  # a Ctrl-C while the modules below load: one line (run_cli takes over in main)

from pathlib import Path  # noqa: E402

from icgo.core.settings import ArgumentParser, run_cli  # noqa: E402
from icgo.datasets.dataset import write_dataset  # noqa: E402
from icgo.datasets.registry import DATASETS  # noqa: E402
from icgo.io.files import Output  # noqa: E402


def seed(text: str) -> int:
    """``--seed``: an integer 0 <= S < 2**63."""
    import argparse

    try:
        s = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None
    if not 0 <= s < 2**63:
        raise argparse.ArgumentTypeError(f"must be 0 <= S < 2**63, got {s}")
    return s


def main(argv=None) -> int:
    """``python -m icgo.datasets NAME --out DIR [--seed S] [--overwrite]``."""
    p = ArgumentParser(prog="python -m icgo.datasets", description="Write a simulated data set (CSV + meta + truth).")
    p.add_argument("name", choices=sorted(DATASETS))
    p.add_argument("--out", required=True, help="output folder (created if missing; may hold other data sets)")
    p.add_argument("--seed", type=seed, default=0, help="noise seed (default 0)")
    p.add_argument("--overwrite", action="store_true", help="replace this data set's files in --out (others stay)")
    a = p.parse_args(argv)
    output = Output(Path(a.out), setting="--out", overwrite=a.overwrite, shared=True,
                    names=tuple(f"{a.name}{ext}" for ext in (".csv", ".meta.json", ".truth.json")),
                    writer=f"python -m icgo.datasets {a.name}", overwrite_hint="--overwrite").check()
    ds = DATASETS[a.name](a.seed)
    with output.staged(last=(f"{a.name}.csv",)) as stage:
        write_dataset(ds, stage, a.name)
    path = output.path / f"{a.name}.csv"
    print(f"wrote {path} ({a.name}.meta.json, {a.name}.truth.json)")
    return 0


if __name__ == "__main__":
    raise SystemExit(run_cli(main))
