"""``python -m icgo.io check|convert|export-mag-cal``: check a recording, convert a JSON to the contract, export.

    python -m icgo.io check FILE.csv|FILE.json [...] [mag_axes=+x+y-z] [grav_axes=-y-x+z] [groups=auto|column|8-15,16-23]
    python -m icgo.io convert FILE.json --out FILE.csv [mag_axes=...] [grav_axes=...] [groups=...]
    python -m icgo.io export-mag-cal OUTDIR

Settings are ``key=value`` words anywhere after the command (the keys of :data:`icgo.io.shots.SETTINGS`),
the same keys the Hydra front doors take. A ``.json`` file is a circuitpython-mag-cal recording (either layout,
:func:`icgo.io.shots.read_shots`); a CSV is checked against the data contract, and with ``groups=`` also its
groups. ``convert`` writes the contract CSV and its ``.meta.json`` (atomically, both or neither) with the
``group`` column, so every front door that reads the contract can use the recording. Exit status: 0 ok,
1 bad data (one line), 2 a bad setting or usage (one line).
"""

from __future__ import annotations

import sys
from pathlib import Path

from icgo.core.errors import DataError, SettingError
from icgo.io.grouping import roll_table
from icgo.io.recording import load_mag_cal_device, mag_cal_devices, read_recording, write_recording
from icgo.io.shots import SETTINGS, is_json, read_shots

USAGE = ("usage: python -m icgo.io check FILE.csv|FILE.json [...] [mag_axes=..] [grav_axes=..] [groups=..] | "
         "convert FILE.json --out FILE.csv [mag_axes=..] [grav_axes=..] [groups=..] | export-mag-cal OUTDIR")


def _split_args(args: list[str]) -> tuple[list[str], dict]:
    """(paths, settings) of a command's words; a word with ``=`` is a setting (SettingError if unknown)."""
    paths, settings = [], {}
    for a in args:
        key, sep, value = a.partition("=")
        if not sep:
            paths.append(a)
        elif key in SETTINGS:
            settings[key] = value
        else:
            raise SettingError(f"unknown setting {key!r} in {a!r}; python -m icgo.io takes {', '.join(SETTINGS)}")
    return paths, settings


def _describe_shots(p, rec) -> list[str]:
    lines = [(f"{p}: ok, {len(rec.frame)} shots, {rec.frame['group'].nunique()} groups; "
              f"{rec.meta.get('description', '')}")]
    for r in roll_table(rec.frame).itertuples():
        lines.append(f"  roll: group {r.group}, shots {r.shots} ({r.n}), raw inclination {r.inclination_deg:.1f} deg, "
                     f"roll span {r.roll_span_deg:.0f} deg, off its plane {r.plane_g:.4f} g / {r.plane_b:.4f} |B|, "
                     f"axis {r.axis_to_z_deg:.1f} deg from tool z")
    return lines


def check(args: list[str]) -> None:
    """Print one ``ok`` block per file (its rolls for grouped shots) and the notices; raise on the first bad one."""
    paths, settings = _split_args(args)
    if not paths:
        raise SettingError("check: no file given; " + USAGE)
    for p in paths:
        if is_json(p) or settings:
            rec = read_shots(p, **settings)
            lines = _describe_shots(p, rec)
        else:
            rec = read_recording(p)
            f = rec.field
            fdesc = (f"field {f.total_field_nT:.1f} nT, dip {f.dip_deg:.3f}, decl {f.declination_deg:.3f} "
                     f"({f.origin})" if f else "no reference field")
            lines = [f"{p}: ok, {len(rec.frame)} rows, columns {', '.join(rec.frame.columns)}; {fdesc}"]
        print("\n".join(lines + [f"  notice: {n}" for n in rec.notices]))


def convert(args: list[str]) -> None:
    """``FILE.json --out FILE.csv [settings]``: the contract CSV + ``.meta.json`` with the checked groups."""
    out = None
    if "--out" in args:
        i = args.index("--out")
        if i + 1 >= len(args):
            raise SettingError("convert: --out needs a file name (FILE.csv)")
        out = args[i + 1]
        args = args[:i] + args[i + 2:]
    paths, settings = _split_args(args)
    if len(paths) != 1 or out is None:
        raise SettingError("convert: give one FILE.json and --out FILE.csv; " + USAGE)
    if not str(out).lower().endswith(".csv"):
        raise SettingError(f"convert: --out {out!r} must name a .csv file (its .meta.json is written beside it)")
    if Path(out).resolve() == Path(paths[0]).resolve():
        raise SettingError("convert: --out must not be the input file")
    rec = read_shots(paths[0], **settings)
    write_recording(out, rec.frame, rec.meta)
    print("\n".join(_describe_shots(paths[0], rec) + [f"  notice: {n}" for n in rec.notices]
                    + [f"wrote {out} and {Path(out).name[:-4]}.meta.json"]))


def main(argv=None) -> int:
    """The command line; one line on stderr and exit 1 for bad data, 2 for a bad setting or usage."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if len(argv) < 2 or argv[0] not in ("check", "convert", "export-mag-cal"):
        print(USAGE, file=sys.stderr)
        return 2
    try:
        if argv[0] == "check":
            check(argv[1:])
        elif argv[0] == "convert":
            convert(argv[1:])
        else:
            out = Path(argv[1])
            out.mkdir(parents=True, exist_ok=True)
            for name in mag_cal_devices():
                rec = load_mag_cal_device(name)
                write_recording(out / f"mag_cal_{name}.csv", rec.frame, rec.meta)
                print(out / f"mag_cal_{name}.csv")
    except SettingError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except DataError as e:
        print(str(e), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
