"""Every Hydra entry point refuses a key it does not know, also one added with ``+key=`` (issue 16, item 2).

Hydra composes ``+key=value`` into the config without complaint; each entry point then checks
the composed keys against its settings dataclass and exits 2 with one line naming the key.
"""

from __future__ import annotations

import subprocess
import sys

import pytest

from experiments._common import CONF_DIR

ROOT = CONF_DIR.parent


@pytest.mark.parametrize("entry,args,named", [
    ("run", ["+no_such=1"], "no_such"),
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
