"""``python -m icgo.io check FILE.csv|FILE.json [...] [--columns MAP]`` and ``python -m icgo.io export-mag-cal OUTDIR``."""

from __future__ import annotations

import sys
from pathlib import Path

from icgo.core.errors import DataError, SettingError
from icgo.io.mag_cal_json import read_mag_cal_json
from icgo.io.recording import column_map, load_mag_cal_device, mag_cal_devices, read_recording, write_recording


def main(argv=None) -> int:
    """``check FILE.csv|FILE.json [...]`` or ``export-mag-cal OUTDIR``; a DataError prints one line, exit 1.

    A ``.json`` file is read as a circuitpython-mag-cal recording (either layout,
    :func:`icgo.io.mag_cal_json.read_mag_cal_json`). ``--columns MAP`` (a JSON or YAML column map,
    :mod:`icgo.io.columns`) reads field exports whose column names differ from the contract's.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    usage = "usage: python -m icgo.io check FILE.csv|FILE.json [...] [--columns MAP] | export-mag-cal OUTDIR"
    cmap = None
    if "--columns" in argv:
        i = argv.index("--columns")
        if i + 1 >= len(argv):
            print(usage, file=sys.stderr)
            return 2
        try:
            cmap = column_map(None, argv[i + 1], "--columns")
        except SettingError as e:
            print(str(e), file=sys.stderr)
            return 2
        del argv[i:i + 2]
    if len(argv) < 2 or argv[0] not in ("check", "export-mag-cal"):
        print(usage, file=sys.stderr)
        return 2
    try:
        if argv[0] == "check":
            for p in argv[1:]:
                if str(p).lower().endswith(".json"):
                    rec = read_mag_cal_json(p)
                    print(f"{p}: ok, {len(rec.frame)} shots, {rec.frame['group'].nunique()} groups; "
                          f"{rec.meta['description']}")
                    continue
                rec = read_recording(p, columns=cmap)
                f = rec.field
                fdesc = (f"field {f.total_field_nT:.1f} nT, dip {f.dip_deg:.3f}, decl {f.declination_deg:.3f} "
                         f"({f.origin})" if f else "no reference field")
                print(f"{p}: ok, {len(rec.frame)} rows, columns {', '.join(rec.frame.columns)}; {fdesc}")
                for n in rec.notices:
                    print(f"  notice: {n}")
        else:
            out = Path(argv[1])
            out.mkdir(parents=True, exist_ok=True)
            for name in mag_cal_devices():
                rec = load_mag_cal_device(name)
                write_recording(out / f"mag_cal_{name}.csv", rec.frame, rec.meta)
                print(out / f"mag_cal_{name}.csv")
    except DataError as e:
        print(str(e), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
