"""Per-stage roofline of the fast RELM fitness (:func:`icgo.models.relm.train_fitness`) on this CPU.

``python -m experiments.roofline [--batch 1200] [--quick] [--out FILE.json]`` prints a Markdown
table and, as its last line, one JSON object (also written to ``--out``). ``--ab SPEC [SPEC ...]`` instead times
settings of the kernel side by side at a Table 3 search's call, by process CPU time (:mod:`icgo.bench.kernel_ab`),
e.g. ``--ab base refine=1 chunk=5``. Run as a module it pins
itself to one core with one XLA thread (:func:`icgo.core.devices.xla_flags`, as the launcher's jobs,
set before JAX is imported); :mod:`icgo.bench.cpu` runs it in a child process for the same reason.
The stages, their counts and ceilings: :mod:`icgo.bench.roofline`.
"""

from __future__ import annotations

import os

if __name__ == "__main__":  # one XLA thread on one core, set before JAX is imported
    from icgo.core.devices import xla_flags

    os.environ["XLA_FLAGS"] = xla_flags(1, os.environ.get("XLA_FLAGS", ""))
    try:
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    except (AttributeError, OSError):  # no affinity on this OS or in this container: one thread still holds
        pass

import json  # noqa: E402
from pathlib import Path  # noqa: E402


def main(argv=None) -> dict:
    from icgo.core.settings import ArgumentParser

    p = ArgumentParser(prog="python -m experiments.roofline", description=__doc__.split("\n\n")[0])
    p.add_argument("--batch", type=int, default=None, help="thetas per call (default 1200, quick 120)")
    p.add_argument("--chunk", type=int, default=10, help="thetas per lax.map step of the kernel")
    p.add_argument("--refine", type=int, default=2, help="refinement steps")
    p.add_argument("--reps", type=int, default=None, help="timing rounds, best taken (default 7, quick 3)")
    p.add_argument("--quick", action="store_true", help="batch 120 and 3 rounds (smoke use, under a minute)")
    p.add_argument("--out", default=None, help="also write the JSON object to this file (refused if it exists)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out file")
    p.add_argument("--ab", nargs="+", default=None, metavar="SPEC",
                   help="instead: time these kernel settings side by side (e.g. base refine=1 chunk=5,refine=1)")
    p.add_argument("--rounds", type=int, default=10, help="--ab: rounds of the variants in turn (best taken)")
    a = p.parse_args(argv)
    if a.out:
        from icgo.io.files import check_output_file

        check_output_file(a.out, overwrite=a.overwrite, setting="--out", overwrite_hint="--overwrite")
    batch = a.batch if a.batch is not None else (120 if a.quick else 1200)
    reps = a.reps if a.reps is not None else (3 if a.quick else 7)
    if batch < 1 or a.chunk < 1 or a.refine < 0 or reps < 1:
        p.error("--batch, --chunk and --reps must be >= 1 and --refine >= 0")
    if a.ab:
        from icgo.bench import kernel_ab

        try:
            [kernel_ab.parse_spec(x) for x in a.ab]
        except ValueError as e:
            p.error(str(e))
        if a.rounds < 1:
            p.error("--rounds must be >= 1")
        res = kernel_ab.run(a.ab, rounds=a.rounds)
        show = kernel_ab.table
    else:
        from icgo.bench import roofline

        res = roofline.run(batch, a.chunk, a.refine, reps, a.quick)
        show = roofline.table
    line = json.dumps(res)
    if a.out:
        from icgo.io.recording import atomic_write_texts

        try:
            atomic_write_texts([(Path(a.out), line + "\n")])
        except OSError as e:
            from icgo.core.errors import OutputError

            raise OutputError(f"--out {a.out!r}: writing failed ({e.strerror}); nothing was written") from None
    print(show(res))
    print(line)
    return res


if __name__ == "__main__":
    from icgo.core.settings import run_cli

    raise SystemExit(run_cli(lambda: (main(), 0)[1]))
