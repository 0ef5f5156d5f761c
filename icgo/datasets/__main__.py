"""``python -m icgo.datasets NAME --out DIR [--seed S]``: write a simulated data set (CSV + meta + truth)."""

from __future__ import annotations

import argparse
import sys

from icgo.datasets.protocols import DATASETS, write_dataset


def main(argv=None) -> int:
    """``python -m icgo.datasets NAME --out DIR [--seed S]``."""
    p = argparse.ArgumentParser(prog="python -m icgo.datasets", description="Write a simulated data set (CSV + meta + truth).")
    p.add_argument("name", choices=sorted(DATASETS))
    p.add_argument("--out", required=True, help="output directory (created if missing)")
    p.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    a = p.parse_args(argv)
    try:
        path = write_dataset(DATASETS[a.name](a.seed), a.out, a.name)
    except ValueError as e:  # includes icgo.io.recording.DataError: one line, no traceback
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"wrote {path} ({path.with_name(a.name + '.meta.json').name}, {a.name}.truth.json)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
