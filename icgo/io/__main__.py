"""``python -m icgo.io check FILE.csv|FILE.json [...] [--columns MAP]`` and ``python -m icgo.io export-mag-cal OUTDIR [--overwrite]``."""

from __future__ import annotations

from icgo.core.settings import startup_interrupts

if __name__ == "__main__":
    startup_interrupts()  # a Ctrl-C while the modules below load: one line (run_cli takes over in main)

import sys  # noqa: E402
from pathlib import Path  # noqa: E402

from icgo.core.errors import DataError  # noqa: E402
from icgo.core.settings import ArgumentParser, run_cli  # noqa: E402
from icgo.io.files import Output  # noqa: E402
from icgo.io.mag_cal_json import read_mag_cal_json  # noqa: E402
from icgo.io.recording import (  # noqa: E402
    column_map,
    load_mag_cal_device,
    mag_cal_devices,
    read_recording,
    write_recording,
)


def check(paths, columns=None) -> int:
    """Read each file and say what it holds; a bad one is one line on stderr. Exit status 1 if any was bad.

    ``columns``: a column map file (JSON or YAML, :mod:`icgo.io.columns`) for field exports whose column names
    differ from the contract's (a bad map is a SettingError, exit 2).
    """
    cmap = column_map(None, columns, "--columns") if columns else None
    bad = 0
    for p in paths:
        try:
            if str(p).lower().endswith(".json"):
                rec = read_mag_cal_json(p)
                print(f"{p}: ok, {len(rec.frame)} shots, {rec.frame['group'].nunique()} groups; "
                      f"{rec.meta['description']}")
                continue
            rec = read_recording(p, columns=cmap)
        except DataError as e:
            print(f"error: {e}", file=sys.stderr)
            bad += 1
            continue
        f = rec.field
        fdesc = (f"field {f.total_field_nT:.1f} nT, dip {f.dip_deg:.3f}, decl {f.declination_deg:.3f} "
                 f"({f.origin})" if f else "no reference field")
        print(f"{p}: ok, {len(rec.frame)} rows, columns {', '.join(rec.frame.columns)}; {fdesc}")
        for n in rec.notices:
            print(f"  notice: {n}")
    return 1 if bad else 0


def export_mag_cal(out: Path, overwrite: bool) -> int:
    """The bundled devices as contract CSV + meta.json into ``out`` (a directory of its own: all files or none)."""
    output = Output(out, setting="OUTDIR", overwrite=overwrite, writer="python -m icgo.io export-mag-cal",
                    overwrite_hint="--overwrite").check()
    recs = {name: load_mag_cal_device(name) for name in mag_cal_devices()}
    with output.staged() as stage:
        for name, rec in recs.items():
            write_recording(stage / f"mag_cal_{name}.csv", rec.frame, rec.meta)
    for name in recs:
        print(out / f"mag_cal_{name}.csv")
    return 0


def main(argv=None) -> int:
    """``check FILE ...`` (exit 1 if a file is bad, one line each) or ``export-mag-cal OUTDIR [--overwrite]``.

    A ``.json`` file is read as a circuitpython-mag-cal recording (either layout,
    :func:`icgo.io.mag_cal_json.read_mag_cal_json`), anything else as a contract CSV.
    """
    ap = ArgumentParser(prog="python -m icgo.io", description="Check recordings; export the bundled devices.")
    sub = ap.add_subparsers(dest="command", required=True)
    c = sub.add_parser("check", help="read and check contract CSVs and circuitpython-mag-cal JSON files")
    c.add_argument("files", nargs="+")
    c.add_argument("--columns", metavar="MAP", help="a JSON or YAML column map for field exports (docs/data.md)")
    e = sub.add_parser("export-mag-cal", help="write the 9 bundled devices as contract CSV + meta.json")
    e.add_argument("outdir")
    e.add_argument("--overwrite", action="store_true", help="replace a used OUTDIR whole")
    a = ap.parse_args(argv)
    if a.command == "check":
        return check(a.files, a.columns)
    return export_mag_cal(Path(a.outdir), a.overwrite)


if __name__ == "__main__":
    raise SystemExit(run_cli(main))
