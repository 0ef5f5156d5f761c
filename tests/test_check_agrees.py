"""``python -m icgo.io check`` and the doors read files with one reader (issue 48): over the hostile battery's data
files (tests/hostile_battery.py, the ``io/`` cases that write a CSV and its metadata), the checker and the doors
(experiments.apply's ``run_apply``, experiments.calibrate's reader ``read_shot_file``) accept and refuse the same
files, with the same first line; the checker lists every failure of a file at once, takes the doors' options,
shares their synonyms table and names the units row that disagrees with the values."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
import hostile_battery as B  # noqa: E402

from icgo.core.errors import SettingError  # noqa: E402
from icgo.io.__main__ import main as io_main  # noqa: E402

#: The io cases that are not files of data (pipes, devices, directories, a 300 MB sparse file): the battery runs
#: them through the checker alone (tests/test_hostile.py).
NOT_FILES = ("io/csv-fifo", "io/csv-dir", "io/csv-dev-zero", "io/csv-missing", "io/csv-symlink-loop", "io/meta-fifo",
             "io/meta-dir", "io/csv-huge")
FILE_CASES = [c for c in B.io_cases() if c.argv[len(B._mod("icgo.io")):][:1] == ["check"] and "{w}/c.csv" in c.argv
              and c.name not in NOT_FILES]


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    """A calibration in earth units (device ab's, any kind would do: the door's reading is what is compared)."""
    from icgo.artifacts.calibration import mag_calibration
    from icgo.io.mag_cal_bundled import load_mag_cal_device
    from icgo.models.calibration import ellipsoid_fit

    rec = load_mag_cal_device("ab")
    scale = float(np.median(np.linalg.norm(rec.B, axis=1)))
    return mag_calibration("ellipsoid", ellipsoid_fit(rec.B, scale, rec.G), rec.G, rec.B, {}).save(
        tmp_path_factory.mktemp("model") / "ab")


def _words(case, w: Path) -> list[str]:
    return [x.replace("{w}", str(w)) for x in case.argv[len(B._mod("icgo.io")) + 1:]]


def _door_settings(words: list[str]) -> dict:
    """The words' settings as the apply door takes them (``columns.x='A b'`` is Hydra's quoting there)."""
    out = {"columns": {}, "columns_file": None, "require_meta": False}
    for word in words:
        key, sep, value = word.partition("=")
        if not sep:
            continue
        value = value[1:-1] if len(value) >= 2 and value[0] == value[-1] and value[0] in "'\"" else value
        if key.startswith("columns."):
            out["columns"][key.split(".", 1)[1]] = value
        elif key == "require_meta":
            out["require_meta"] = value == "true"
        else:
            out[key] = value
    return out


def _apply(model: Path, data: Path, door: dict, out: Path):
    from icgo.survey.apply_settings import run_apply

    settings = {"model": str(model), "data": str(data), "method": None, "out": str(out), "overwrite": False,
                "qc": {"g_tol_g": 0.0025, "b_tol_nT": 300.0, "dip_tol_deg": 0.25}, "max_mb": 4096, "stream_mb": 64,
                "chunk_rows": 200000, "site": None, **door}
    try:
        run_apply(settings, out)
        return None
    except ValueError as e:  # DataError, SettingError, ModelError: one line
        return str(e)


def _shots(data: Path, door: dict):
    from icgo.io.recording import column_map
    from icgo.io.shots import read_shot_file

    try:
        read_shot_file(str(data), groups="auto",  # the reading; the rolls are the calibrate door's next step
                       columns=column_map(door["columns"] or None, door["columns_file"]) or None)
        return None
    except ValueError as e:
        return str(e)


@pytest.mark.parametrize("case", FILE_CASES, ids=lambda c: c.name)
def test_the_checker_and_the_doors_accept_and_refuse_the_same_files(case, model, tmp_path, capsys):
    w = tmp_path / "w"
    w.mkdir()
    if case.setup:
        case.setup(w, tmp_path)
    words = _words(case, w)
    capsys.readouterr()
    rc = io_main(["check", *words])
    err = [x for x in capsys.readouterr().err.splitlines() if x.strip()]
    door = _door_settings(words)
    applied = _apply(model, w / "c.csv", door, w / "out")
    assert (rc == 0) == (applied is None), (case.name, rc, err[:2], applied)
    assert rc == 0 or err[0] == f"error: {applied}", (err[0], applied)  # the same first line
    if not door["require_meta"]:  # calibrate's reader reads a CSV without its metadata too
        shots = _shots(w / "c.csv", door)
        assert (rc == 0) == (shots is None), (case.name, rc, err[:2], shots)
    expect_ok = case.expect == "ok"
    assert (rc == 0) == expect_ok, (case.name, rc, err[:2])


def test_every_failure_of_a_file_at_once(tmp_path, capsys):
    """Lazy validation: a file with a missing column, a text cell, a NaN and an inclination out of range lists all
    four, the doors' own refusal first; the hints come from the doors' one synonyms table."""
    p = tmp_path / "e.csv"
    p.write_text("Survey #,gx,gy,gz,bx,by,bz,Inc,Azi\n0,0.1,0.2,0.97,20000,1000,nan,12,10\n"
                 "1,0.1,abc,0.97,20000,1000,40000,12,10\n")
    assert io_main(["check", str(p)]) == 1
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 3 and all(x.startswith(f"error: {p}") for x in err)
    assert "missing required column(s) station" in err[0] and "columns.station='Survey #'" in err[0]
    assert "columns.inclination_deg=Inc" in err[0] and "columns.azimuth_deg=Azi" in err[0]
    assert "column 'gy': non-numeric value 'abc'" in err[1] and "column 'bz': NaN" in err[2]
    # the doors refuse it with the first of them
    assert _shots(p, {"columns": {}, "columns_file": None}) == err[0][len("error: "):]
    # mapped as the doors map it, the station refusal goes and the other two stay
    assert io_main(["check", str(p), "columns.station='Survey #'", "columns.inclination_deg=Inc",
                    "columns.azimuth_deg=Azi"]) == 1
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2 and "'gy'" in err[0] and "'bz'" in err[1]
    # an unknown column that looks like a contract column is named in the doors' notice too
    ok = tmp_path / "ok.csv"
    ok.write_text("station,gx,gy,gz,bx,by,bz,Inc,Azi\n0,0.1,0.2,0.97,20000,1000,40000,12,10\n")
    assert io_main(["check", str(ok)]) == 0
    out = capsys.readouterr().out
    assert "`Inc` looks like inclination_deg: columns.inclination_deg=Inc" in out
    from icgo.io.recording import read_recording

    rec = read_recording(ok, require_meta=False, require_reference=False)
    assert any("`Azi` looks like azimuth_deg" in n for n in rec.notices)


def test_a_units_row_that_disagrees_with_the_values_is_named(tmp_path, capsys):
    p = tmp_path / "u.csv"
    p.write_text("station,gx,gy,gz,bx,by,bz\n,g,g,g,uT,uT,uT\n0,0.1,0.2,0.97,20000,1000,40000\n"
                 "1,0.1,0.25,0.97,21000,1000,40000\n")
    assert io_main(["check", str(p)]) == 1
    (line,) = capsys.readouterr().err.splitlines()
    assert "median |B| = 4.4" in line and "read as uT by the units row (line 2)" in line
    assert "the units row (line 2) disagrees with the values" in line
    h = tmp_path / "h.csv"
    h.write_text("station,gx,gy,gz,Bx [uT],By [uT],Bz [uT]\n0,0.1,0.2,0.97,20000,1000,40000\n")
    assert io_main(["check", str(h)]) == 1
    (line,) = capsys.readouterr().err.splitlines()
    assert "by the header ('Bx [uT]')" in line and re.search(r"x1000\b", line)


def test_the_checker_takes_the_doors_options_and_no_other(tmp_path, capsys):
    p = tmp_path / "c.csv"
    p.write_text("station,gx,gy,gz,bx,by,bz\n0,0.1,0.2,0.97,20000,1000,40000\n")
    assert io_main(["check", str(p)]) == 0  # no .meta.json: read as {}, as the doors read it
    assert "no metadata file; read as {}" in capsys.readouterr().out
    assert io_main(["check", str(p), "require_meta=true"]) == 1
    assert "c.meta.json: metadata file not found" in capsys.readouterr().err
    assert io_main(["check", str(p), "require_reference=true"]) == 1
    assert "missing required columns azimuth_deg, inclination_deg" in capsys.readouterr().err
    assert io_main(["check", str(p), "columns.bogus=x"]) == 2
    assert "columns.bogus" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        io_main(["check", str(p), "--columns", "m.json"])  # the old option: gone, the doors' columns_file= instead
    assert io_main(["check", str(p), "require_meta=maybe"]) == 2
    assert "require_meta" in capsys.readouterr().err
