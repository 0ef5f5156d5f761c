"""Every Hydra entry point refuses a key it does not know, also one added with ``+key=`` (issue 16, item 2).

Hydra composes ``+key=value`` into the config without complaint; each entry point then checks
the composed keys against its settings dataclass and exits 2 with one line naming the key.
"""

from __future__ import annotations

import subprocess
import sys

import pytest

from experiments._preflight import CONF_DIR

ROOT = CONF_DIR.parent


@pytest.mark.parametrize("entry,args,named", [
    ("run", ["+no_such=1"], "no_such"),
    ("run", ["no_such=1"], "no_such"),             # without '+': Hydra's own refusal is six lines, exit 1
    ("run", ["experiment=table3", "model.hiden=3"], "model.hiden"),
    ("apply", ["no_such=1"], "no_such"),
    ("calibrate", ["no_such=1"], "no_such"),
    ("misma", ["no_such=1"], "no_such"),
    ("gyro", ["data.no_such=1"], "data.no_such"),
    ("discrepancy", ["no_such=1"], "no_such"),
    ("apply", ["+no_such=1", "model=x", "data=y"], "no_such"),
    ("calibrate", ["+no_such=1", "data=x.csv"], "no_such"),
    ("misma", ["+real.data=shots.csv"], "data"),
    ("gyro", ["+data.no_such=1"], "no_such"),
    ("discrepancy", ["+no_such=1"], "no_such"),
])
def test_unknown_override_is_one_line_and_exit_2(tmp_path, entry, args, named):
    out = subprocess.run([sys.executable, "-m", f"experiments.{entry}", *args, f"hydra.run.dir={tmp_path}"],
                         cwd=ROOT, capture_output=True, text=True, timeout=300)
    err = out.stderr.strip()
    assert out.returncode == 2, (out.returncode, err)
    assert len(err.splitlines()) == 1 and "unknown setting" in err and named in err, err


@pytest.mark.parametrize("value, says", [("/proc/no_such/run", "cannot create the directory"),
                                         ("FILE", "is a file, not a directory")])
@pytest.mark.parametrize("key", ["hydra.run.dir", "hydra.sweep.dir"])
def test_a_run_dir_that_cannot_be_a_directory_is_one_line(tmp_path, key, value, says):
    if value == "FILE":
        value = str(tmp_path / "a_file")
        (tmp_path / "a_file").write_text("x")
    out = subprocess.run([sys.executable, "-m", "experiments.run", f"{key}={value}"], cwd=ROOT, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 2
    assert out.stderr.strip() == f"error: {key} {value!r}" + (": cannot create the directory (No such file or directory)"
                                                             if "proc" in value else " is a file, not a directory; "
                                                                                      "give a directory")


def test_multirun_flag_after_the_overrides_is_accepted():
    """``-m`` after an override is moved in front (Hydra's parser refuses it there), so the checks still run."""
    import sys as _sys

    from experiments._preflight import preflight

    argv = _sys.argv[:]
    try:
        _sys.argv[:] = ["run", "strategy=chaos", "-m", "figures=false"]
        preflight("config")
        assert _sys.argv == ["run", "-m", "strategy=chaos", "figures=false"]
    finally:
        _sys.argv[:] = argv
