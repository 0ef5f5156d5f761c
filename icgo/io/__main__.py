"""``python -m icgo.io check|convert|export-mag-cal``: check a recording, convert a JSON to the contract, export.

    python -m icgo.io check FILE.csv|FILE.json [...] [columns.gx=Gx ...] [columns_file=MAP] [require_meta=true]
        [require_reference=true] [mag_axes=+x+y-z] [grav_axes=-y-x+z] [groups=auto|column|8-15,16-23]
    python -m icgo.io convert FILE.json --out FILE.csv [mag_axes=...] [grav_axes=...] [groups=...] [--overwrite]
    python -m icgo.io export-mag-cal OUTDIR [--overwrite]

Settings are ``key=value`` words anywhere after the command: exactly the front doors' (:data:`CHECK_SETTINGS`):
the column map of a field export (``columns.<contract column>=<export column>``, ``columns_file=MAP``, JSON or
YAML: :mod:`icgo.io.columns`), ``require_meta=`` (default false: a CSV without its ``.meta.json`` is read as ``{}``,
as experiments.apply and experiments.calibrate read it), ``require_reference=`` (default false, as those two
doors; true: the reference attitude or a group column required, as experiments.run's ``dataset=csv``), and the
grouped shots' ``mag_axes=``, ``grav_axes=``, ``groups=`` (:data:`icgo.io.shots.SETTINGS`). A ``.json`` file is a
circuitpython-mag-cal recording (either layout, :func:`icgo.io.shots.read_shot_file`); a CSV is checked against
the data contract by the doors' own reader, **every failure at once** (one ``error:`` line each; the first is the
one the doors refuse the file with: :class:`icgo.io.checks.Lazy`), and with ``groups=`` also its groups. The groups
printed are the ones known without searching the data: a layout's (each checked against the data: the groups
and shots that disagree are named), a ``group`` column or shot ranges given (checked: refused when not rolls).
Finding rolls in the data (``groups=auto``, or a recording in no known layout) is the calibrate and
discrepancy doors' (:func:`icgo.studies.common.shots.read_shots`): here such a recording is read and left ungrouped.
``convert`` writes the contract CSV and its ``.meta.json`` (atomically, both or neither; an existing file is
refused unless ``--overwrite``) with the ``group`` column when the groups are known, so every front door that
reads the contract can use the recording.
``export-mag-cal`` writes the bundled devices into a directory of its own (all files or none). Exit status: 0 ok,
1 bad data (one line per bad file; the others are still checked), 2 a bad setting or usage (one line).
"""

from __future__ import annotations

from icgo.core.settings import startup_interrupts

if __name__ == "__main__":
    startup_interrupts()  # a Ctrl-C while the modules below load: one line (run_cli takes over in main)

import sys  # noqa: E402
from pathlib import Path  # noqa: E402

from icgo.core.errors import DataError, SettingError  # noqa: E402
from icgo.core.settings import ArgumentParser, run_cli  # noqa: E402
from icgo.io.files import Output  # noqa: E402
from icgo.io.grouping import roll_table  # noqa: E402
from icgo.io.mag_cal_bundled import load_mag_cal_device, mag_cal_devices  # noqa: E402
from icgo.io.recording import column_map, read_recording, write_recording  # noqa: E402
from icgo.io.shots import SETTINGS, is_json, read_shot_file  # noqa: E402
from icgo.physics.rolls import group_findings  # noqa: E402


#: The settings ``check`` takes besides :data:`icgo.io.shots.SETTINGS`: the doors' (``columns.<name>`` too).
CHECK_SETTINGS = ("columns_file", "require_meta", "require_reference")


def split_words(words: list[str], extra: tuple = ()) -> tuple[list[str], dict]:
    """(paths, settings) of a command's words; a word with ``=`` is a setting (SettingError if unknown). ``extra``:
    more keys taken (``columns.<name>`` among them when ``"columns"`` is one)."""
    paths, settings = [], {}
    for w in words:
        key, sep, value = w.partition("=")
        if not sep:
            paths.append(w)
        elif key in SETTINGS or key in extra or ("columns" in extra and key.startswith("columns.")):
            if len(value) >= 2 and value[0] == value[-1] and value[0] in "'\"":
                value = value[1:-1]  # quoted as on the Hydra doors: columns.station='Survey #'
            settings[key] = value
        else:
            taken = list(SETTINGS) + [("columns.<contract column>" if k == "columns" else k) for k in extra]
            raise SettingError(f"unknown setting {key!r} in {w!r}; python -m icgo.io takes {', '.join(taken)}")
    return paths, settings


def _flag(settings: dict, key: str) -> bool:
    v = str(settings.pop(key, "false")).strip().lower()
    if v not in ("true", "false"):
        raise SettingError(f"{key}={v!r}: must be true or false")
    return v == "true"


def check_settings(settings: dict) -> tuple[dict | None, bool, bool, dict]:
    """(column map or None, require_meta, require_reference, the grouped shots' settings) of ``check``'s settings,
    each checked as the doors check it (:func:`icgo.io.recording.column_map`)."""
    settings = dict(settings)
    cols = {k.split(".", 1)[1]: settings.pop(k) for k in [k for k in settings if k.startswith("columns.")]}
    cmap = column_map(cols or None, settings.pop("columns_file", None)) or None
    return cmap, _flag(settings, "require_meta"), _flag(settings, "require_reference"), settings


def describe_shots(p, shots) -> list[str]:
    """The ``ok`` line of a file of grouped shots (:class:`icgo.io.mag_cal_json.ShotFile`), one line per roll, and
    for a layout's groups the ones the data disagree with."""
    rec = shots.recording
    if "group" not in rec.frame.columns:
        how = ("groups=auto" if shots.layout is not None else
               "no known layout, no group column")
        return [f"{p}: ok, {len(rec.frame)} shots, not grouped here ({how}): experiments.calibrate and "
                f"experiments.discrepancy find the rolls from the data, or give groups=[first-last,...]; "
                f"{rec.meta.get('description', '')}"]
    origin = {"layout": "by its layout", "column": "by its group column", "ranges": "by groups="}[shots.origin]
    lines = [(f"{p}: ok, {len(rec.frame)} shots, {rec.frame['group'].nunique()} groups ({origin}); "
              f"{rec.meta.get('description', '')}")]
    for r in roll_table(rec.frame).itertuples():
        lines.append(f"  roll: group {r.group}, shots {r.shots} ({r.n}), raw inclination {r.inclination_deg:.1f} deg, "
                     f"roll span {r.roll_span_deg:.0f} deg, off its plane {r.plane_g:.4f} g / {r.plane_b:.4f} |B|, "
                     f"axis {r.axis_to_z_deg:.1f} deg from tool z")
    if shots.origin == "layout":
        f = rec.frame
        lines += [f"  the data disagree with the layout: {x}" for x in group_findings(
            f[["gx", "gy", "gz"]].to_numpy(float), f[["bx", "by", "bz"]].to_numpy(float), f["station"].to_numpy(),
            f["group"].to_numpy()).values()]
    return lines


def check(words: list[str]) -> int:
    """Print one ``ok`` block per file (its rolls for grouped shots) and the notices; a bad file gives one
    ``error:`` line per failure on stderr (every failure of a CSV at once) and the others are still checked. Exit
    status 1 if any was bad; a bad setting raises SettingError."""
    from icgo.io.checks import DataErrors

    paths, settings = split_words(words, ("columns",) + CHECK_SETTINGS)
    if not paths:
        raise SettingError("check: no file given")
    cmap, require_meta, require_reference, shot_settings = check_settings(settings)
    bad = 0
    for p in paths:
        try:
            if is_json(p) or shot_settings:
                shots = read_shot_file(p, columns=cmap, lazy=True, **shot_settings)
                rec = shots.recording
                lines = describe_shots(p, shots)
            else:
                rec = read_recording(p, require_meta=require_meta, require_reference=require_reference, columns=cmap,
                                     lazy=True)
                f = rec.field
                fdesc = (f"field {f.total_field_nT:.1f} nT, dip {f.dip_deg:.3f}, decl {f.declination_deg:.3f} "
                         f"({f.origin})" if f else "no reference field")
                lines = [f"{p}: ok, {len(rec.frame)} rows, columns {', '.join(rec.frame.columns)}; {fdesc}"]
                if not rec.has_reference and "group" not in rec.frame.columns:
                    lines.append(f"  notice: {p}: no reference attitude and no group column: experiments.apply "
                                 "corrects it; experiments.run (dataset=csv) needs azimuth_deg and inclination_deg "
                                 "(require_reference=true checks for it) and experiments.calibrate a group column")
        except SettingError:
            raise
        except DataErrors as e:
            print("\n".join(f"error: {x}" for x in e.lines), file=sys.stderr)
            bad += 1
            continue
        except DataError as e:
            print(f"error: {e}", file=sys.stderr)
            bad += 1
            continue
        print("\n".join(lines + [f"  notice: {n}" for n in rec.notices]))
    return 1 if bad else 0


def convert(words: list[str], out: str | None, overwrite: bool) -> int:
    """``FILE.json --out FILE.csv [settings]``: the contract CSV + ``.meta.json``, with the groups where they are known
    (its ``instrument`` metadata lets a later reader group it by its layout)."""
    from icgo.io.recording import meta_path_for

    paths, settings = split_words(words)
    if len(paths) != 1 or out is None:
        raise SettingError("convert: give one FILE.json and --out FILE.csv")
    if not str(out).lower().endswith(".csv"):
        raise SettingError(f"convert: --out {out!r} must name a .csv file (its .meta.json is written beside it)")
    if Path(out).resolve() == Path(paths[0]).resolve():
        raise SettingError("convert: --out must not be the input file")
    held = [p for p in (Path(out), meta_path_for(out)) if p.exists() or p.is_symlink()]
    if held and not overwrite:
        raise SettingError(f"convert: {held[0]} already exists; give --overwrite to replace it (and its pair)")
    shots = read_shot_file(paths[0], **settings)
    rec = shots.recording
    grouped = "group" in rec.frame.columns
    write_recording(out, rec.frame, rec.meta, require_reference=grouped)
    if not grouped:
        rec = rec._replace(notices=rec.notices + [f"{out} has no group column (no known layout, no groups given): "
                                                  f"experiments.calibrate data={out} groups=auto finds the rolls"])
    print("\n".join(describe_shots(paths[0], shots) + [f"  notice: {n}" for n in rec.notices]
                    + [f"wrote {out} and {meta_path_for(out).name}"]))
    return 0


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
    """The command line; one line on stderr and exit 1 for bad data, 2 for a bad setting or usage."""
    ap = ArgumentParser(prog="python -m icgo.io", description="Check recordings, convert a JSON recording to the "
                        "data contract, export the bundled devices.")
    sub = ap.add_subparsers(dest="command", required=True)
    c = sub.add_parser("check", help="read and check contract CSVs and circuitpython-mag-cal JSON files")
    c.add_argument("words", nargs="+", metavar="FILES",
                   help=f"files to check, and the doors' settings columns.<contract column>=, "
                        f"{', '.join(f'{k}=' for k in CHECK_SETTINGS + SETTINGS)}")
    v = sub.add_parser("convert", help="write a JSON recording as a contract CSV + meta.json with its groups")
    v.add_argument("words", nargs="+", metavar="FILE.json", help=f"the recording, and settings "
                   f"{', '.join(f'{k}=' for k in SETTINGS)}")
    v.add_argument("--out", metavar="FILE.csv", help="the contract CSV to write (required)")
    v.add_argument("--overwrite", action="store_true", help="replace an existing FILE.csv and its meta.json")
    e = sub.add_parser("export-mag-cal", help="write the 9 bundled devices as contract CSV + meta.json")
    e.add_argument("outdir")
    e.add_argument("--overwrite", action="store_true", help="replace a used OUTDIR whole")
    a, extra = ap.parse_known_args(argv)  # key=value settings may also follow an option (convert ... --out F k=v)
    if extra and (a.command == "export-mag-cal" or any(w.startswith("-") or "=" not in w for w in extra)):
        ap.error(f"unrecognized arguments: {' '.join(extra)}")
    if extra:
        a.words += extra
    try:
        if a.command == "check":
            return check(a.words)
        if a.command == "convert":
            return convert(a.words, a.out, a.overwrite)
        return export_mag_cal(Path(a.outdir), a.overwrite)
    except SettingError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(run_cli(main))
