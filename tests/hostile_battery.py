"""A hostile battery of icgo's front doors: bad files, edited model files, pipes, huge inputs, full disks,
used output directories, sweeps re-run into their directory, Ctrl-C, SIGTERM and SIGKILL.

Every case is one invocation of a front door (``python -m experiments.<door> ...``, ``python -m icgo.io``,
``python -m icgo.datasets``, the same through the ``icgo`` console script (:func:`console_cases`), or the library door ``icgo.artifacts.registry.load_model`` followed by
``icgo.survey.apply.correct_survey`` in a fresh interpreter) on inputs written into the case's own
folder. Each ends in exactly one outcome:

* ``clean``: what the case expects: a refusal in one line (``error: ...`` on stderr, naming the file or
  setting the case names) with exit status 1 or 2, a success (exit 0), or for an interrupted command one
  ``interrupted: ...`` line and exit status 130; and the case's integrity check holds;
* ``traceback``: a Python traceback, or an exit by a signal the case did not send, or an exit status
  outside 0, 1, 2, 130;
* ``silent``: exit status 0 where the case expects a refusal (bad input accepted without a word);
* ``mixed``: the integrity check failed: an output directory damaged, half written, mixed with an
  older one, or a kept file rewritten;
* ``hang``: the command did not end within the case's time limit;
* ``oom``: the command's processes passed :data:`RSS_CAP_MB` of resident memory (killed);
* ``unclear``: a refusal, but not one line, or not naming what the case says it must name; or a refusal
  where the case expects success.

Run it: ``.venv/bin/python tests/hostile_battery.py [--fast] [--jobs 2] [--root DIR] [--json FILE]``
(``--root`` runs another checkout of icgo, e.g. the code before a change). The pytest module
``tests/test_hostile.py`` runs the fast part in ``make test`` and the whole battery under ``-m slow``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path
from typing import Callable

ROOT = Path(__file__).resolve().parents[1]
PY = sys.executable
OUTCOMES = ("clean", "traceback", "silent", "mixed", "hang", "oom", "unclear")
#: Resident memory of a case's processes above which it is killed and counted ``oom``.
RSS_CAP_MB = 4000
#: Bytes a process may write per file in the "full disk" cases (RLIMIT_FSIZE: writes beyond fail with EFBIG).
FULL_DISK_BYTES = 16 * 1024
#: Size of the compressed extra member of the zip-bomb model (never to be read).
BOMB_BYTES = 3 << 30

# ============================================================ the cases


@dataclasses.dataclass
class Case:
    """One invocation. ``argv`` (after ``python``) may use ``{w}`` (the case folder) and ``{a}`` (the shared,
    read-only assets); ``setup(w, a)`` writes the case's inputs; ``check(w, a, res) -> problem or None`` is the
    integrity check, run after the command."""

    name: str
    door: str
    argv: list
    expect: str = "refuse"            # refuse | ok | interrupt | outside (apply: exit status 3) | norecommend
    #                                   (calibrate: report written, exit status 4)
    says: tuple = ()                  # words the error line must contain (case-insensitive)
    setup: Callable | None = None
    check: Callable | None = None
    signal_after: tuple | None = None  # (signal, seconds or a path whose appearance triggers it)
    fsize: int | None = None          # RLIMIT_FSIZE (bytes) for the full-disk cases
    timeout: float = 180.0
    fast: bool = False                # in the fast subset (make test)
    needs: str | None = None          # "mount": needs a read-only mount (root); skipped otherwise
    report: bool = False              # a refusal may print a multi-line report (a sweep's job list)


@dataclasses.dataclass
class Result:
    case: str
    door: str
    outcome: str
    detail: str
    rc: int | None
    seconds: float
    peak_mb: float


def _mod(door):
    return ["-m", door]


# ------------------------------------------------------------ assets (built once per session)
def build_assets(a: Path) -> None:
    """Valid inputs every case starts from: one model of each kind, a survey (CSV + meta), a fake run
    directory, circuitpython-mag-cal JSON files (both layouts), contract CSV exports of the bundled devices,
    the zip bomb."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import hostile_models as H
    import numpy as np

    from icgo.io.mag_cal_bundled import load_mag_cal_device
    from icgo.io.recording import write_recording

    a.mkdir(parents=True, exist_ok=True)
    models = a / "models"
    models.mkdir()
    for kind, m in H.models().items():
        m.save(models / kind)
    s = H.survey()
    meta = {"total_field_nT": 50_000.0, "dip_deg": 60.0, "declination_deg": 0.0, "gravity_g": 1.0}
    write_recording(a / "survey.csv", s, meta)
    # a survey far outside the models' training domain (inclination and field)
    far = s.copy()
    far[["bx", "by", "bz"]] *= 1.6
    write_recording(a / "far_survey.csv", far, {**meta, "total_field_nT": 80_000.0})
    run = a / "run"
    run.mkdir()
    for kind in ("relm_compensation", "msa"):
        for ext in (".json", ".npz"):
            shutil.copy(models / f"{kind}{ext}", run / f"{kind}{ext}")
    (run / "run.json").write_text(json.dumps(_run_record(["relm_compensation.json", "msa.json"])))
    rec = load_mag_cal_device("ab")
    dev = a / "device.csv"
    write_recording(dev, rec.frame, rec.meta, require_reference=False)
    d = json.loads((ROOT / "icgo" / "data" / "mag_cal" / "ab.json").read_text())
    (a / "fixture.json").write_text(json.dumps(d))
    # the raw layout: the same shots as [[x, y, z], ...] in the device's sensor frame (uT, g)
    def triples(values):  # the fixture pads with null / NaN (as circuitpython-mag-cal's read_fixture drops them)
        return np.asarray([v for v in values if v is not None and v == v], float).reshape(-1, 3)

    mag, grav = triples(d["shots"]["mag"]), triples(d["shots"]["grav"])
    (a / "raw.json").write_text(json.dumps({"mag": mag.tolist(), "grav": grav.tolist()}))
    # one corrupt value: finite, but 1e300 (numpy's least squares on it never returned)
    huge = json.loads(json.dumps(d))
    huge["shots"]["mag"][31] = 1e300
    (a / "fixture_1e300.json").write_text(json.dumps(huge))
    mag_huge = mag.copy()
    mag_huge[10, 1] = 1e300
    (a / "raw_1e300.json").write_text(json.dumps({"mag": mag_huge.tolist(), "grav": grav.tolist()}))
    # the accelerometer's axes inconsistent with the magnetometer's (one sign wrong): one dip, not the site's
    (a / "raw_bad_axes.json").write_text(json.dumps({"mag": mag.tolist(), "grav": (grav * [1, 1, -1]).tolist()}))
    # the device's shots as a field export: other column names, a comment line
    exp = rec.frame.rename(columns={"gx": "Gx", "gy": "Gy", "gz": "Gz", "bx": "Bx", "by": "By", "bz": "Bz",
                                    "group": "Set"})
    (a / "export.csv").write_text("# exported by a logger\n" + exp.to_csv(index=False))
    # the survey's reference angles in radians
    rad = s.assign(azimuth_deg=np.radians(s.azimuth_deg), inclination_deg=np.radians(s.inclination_deg))
    write_recording(a / "survey_rad.csv", rad, meta)
    # device ab's calibration (in nT) and device jd's shots: a model of another device
    from icgo.models.calibration import ellipsoid_fit
    from icgo.artifacts.calibration import mag_calibration

    scale = float(np.median(np.linalg.norm(rec.B, axis=1)))
    cal = mag_calibration("ellipsoid", ellipsoid_fit(rec.B, scale, rec.G), rec.G, rec.B, {})
    cal.save(models / "ab_calibration")
    write_recording(a / "jd_survey.csv", load_mag_cal_device("jd").frame.drop(columns="group"), {},
                    require_reference=False)
    # a longer survey (about 1.9 MB): streams with stream_mb=1
    import pandas as pd

    long = pd.concat([H.survey(600, seed=k) for k in range(20)], ignore_index=True)
    write_recording(a / "long_survey.csv", long.assign(station=np.arange(len(long))), meta)
    write_console_script(a / "bin")
    (a / "ready").write_text("ok\n")


def write_console_script(folder: Path) -> Path:
    """The ``icgo`` console script as pip writes it (its template) for pyproject.toml's ``[project.scripts]``."""
    import tomllib

    module, func = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]["icgo"].split(":")
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "icgo").write_text(f"#!{PY}\nimport re\nimport sys\nfrom {module} import {func}\n"
                                 f"if __name__ == '__main__':\n"
                                 f"    sys.argv[0] = re.sub(r'(-script\\.pyw|\\.exe)?$', '', sys.argv[0])\n"
                                 f"    sys.exit({func}())\n")
    (folder / "icgo").chmod(0o755)
    return folder / "icgo"


def _run_record(models):
    return {"records_version": 2, "status": "ok", "label": None, "dataset": "lab_casing", "condition": None,
            "description": "fake", "optimizer": "pso", "strategies": ["original"], "schedule": {},
            "optimizer_params": {}, "total_time_s": 1.0, "pid": 1, "cpu_count": 1, "seed": 0, "wall_time_s": 1.0,
            "methods": ["relm"], "n_evals": {}, "n_rows": 1, "n_repeats": 1, "repeat_ids": [0], "models": models,
            "qc": None}


def bomb(a: Path) -> Path:
    """The zip-bomb model arrays (made once, on first use: deflating the zeros takes ~10 s)."""
    p = a / "bomb.npz"
    if not p.exists():
        tmp = a / f".bomb.{os.getpid()}.{id(p)}"
        _zip_bomb(a / "models" / "relm_compensation.npz", tmp)
        os.replace(tmp, p)
    return p


def _zip_bomb(src: Path, dst: Path) -> None:
    """The model's own members plus ``bomb.npy``: BOMB_BYTES of zeros, deflated to a few MB."""
    with zipfile.ZipFile(src) as z, zipfile.ZipFile(dst, "w", zipfile.ZIP_DEFLATED) as out:
        for info in z.infolist():
            out.writestr(info, z.read(info))
        with out.open(zipfile.ZipInfo("bomb.npy"), "w", force_zip64=True) as fh:
            chunk = b"\0" * (64 << 20)
            for _ in range(BOMB_BYTES // len(chunk)):
                fh.write(chunk)


# ------------------------------------------------------------ file helpers used by setups
def copy_model(a: Path, w: Path, kind: str, stem: str = "m") -> Path:
    """Copy a model of ``kind`` from the assets into ``w`` as ``stem.json`` + ``stem.npz``; return the header."""
    head = json.loads((a / "models" / f"{kind}.json").read_text())
    shutil.copy(a / "models" / f"{kind}.npz", w / f"{stem}.npz")
    head["arrays"] = f"{stem}.npz"
    (w / f"{stem}.json").write_text(json.dumps(head))
    return w / f"{stem}.json"


class Raw(str):
    """Returned by a header edit: the header's text itself (e.g. with a NaN literal)."""


def edit_header(kind: str, fn, stem: str = "m"):
    """Setup: a copy of the ``kind`` model whose header dict ``fn`` edits in place (or replaces by a :class:`Raw`)."""
    def setup(w, a):
        p = copy_model(a, w, kind, stem)
        head = json.loads(p.read_text())
        new = fn(head)
        p.write_text(new if isinstance(new, Raw) else json.dumps(head))
    return setup


def edit_arrays(kind: str, fn, stem: str = "m"):
    """Setup: a copy of the ``kind`` model whose arrays (a dict) ``fn`` edits in place."""
    def setup(w, a):
        import numpy as np

        copy_model(a, w, kind, stem)
        with np.load(w / f"{stem}.npz", allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        fn(arrays)
        with open(w / f"{stem}.npz", "wb") as fh:
            np.savez(fh, **arrays)
    return setup


def edit_npz_bytes(kind: str, fn, stem: str = "m"):
    def setup(w, a):
        copy_model(a, w, kind, stem)
        p = w / f"{stem}.npz"
        out = fn(p.read_bytes(), w)
        if out is not None:
            p.write_bytes(out)
    return setup


def snapshot(d: Path) -> dict:
    """name -> sha256 of every file under ``d`` (hidden included), for "unchanged" checks."""
    if not d.exists():
        return {}
    return {str(p.relative_to(d)): hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir"
            for p in sorted(d.rglob("*")) if not p.is_symlink()}


def unchanged(rel: str):
    """Check: the folder ``w/rel`` is exactly as the setup left it (its snapshot, stored beside it)."""
    def check(w, a, res):
        before = json.loads((w / f".{Path(rel).name}.snapshot").read_text())
        after = snapshot(w / rel)
        after = {k: v for k, v in after.items() if not k.endswith(".log")}  # Hydra's job log may grow
        before = {k: v for k, v in before.items() if not k.endswith(".log")}
        if before != after:
            changed = sorted(set(before) ^ set(after) | {k for k in before if after.get(k) != before[k]})
            return f"{rel} changed: {changed[:5]}"
        return None
    return check


def remember(rel: str):
    """Setup step: store the snapshot of ``w/rel`` for :func:`unchanged`."""
    def setup(w, a):
        (w / f".{Path(rel).name}.snapshot").write_text(json.dumps(snapshot(w / rel)))
    return setup


def absent_or_complete(rel: str, files: tuple):
    """Check: ``w/rel`` does not exist, is empty (only Hydra's log), or holds every one of ``files``; never a
    part of them or a staging folder left behind."""
    def check(w, a, res):
        d = w / rel
        if not d.exists():
            return None
        names = {p.name for p in d.iterdir() if not p.name.endswith(".log")}
        present = [f for f in files if f in names]
        if present and len(present) != len(files):
            return f"{rel} holds {sorted(present)} but not {sorted(set(files) - set(present))}: half written"
        cut = [n for n in names if n.startswith((".staging", ".replaced"))]
        if cut and res.outcome_hint != "killed":
            return f"{rel} holds a working folder {cut}"
        return None
    return check


def absent(rel: str):
    def check(w, a, res):
        d = w / rel
        if d.exists() and any(not p.name.endswith(".log") for p in d.iterdir()):
            return f"{rel} exists after a refused command: {sorted(p.name for p in d.iterdir())[:5]}"
        return None
    return check


def chain(*fns):
    def run(*args):
        for f in fns:
            if f is None:
                continue
            r = f(*args)
            if r:
                return r
        return None
    return run


def write(rel: str, text, mode: str = "w"):
    def setup(w, a):
        p = w / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(text, bytes):
            p.write_bytes(text)
        else:
            p.write_text(text if isinstance(text, str) else text(w, a))
    return setup


def sparse(rel: str, head: str, size: int):
    """Setup: a file that starts with ``head`` and is ``size`` bytes long (the rest a hole of NUL bytes)."""
    def setup(w, a):
        p = w / rel
        p.write_text(head)
        os.truncate(p, size)
    return setup


def fifo(rel: str):
    def setup(w, a):
        os.mkfifo(w / rel)
    return setup


def mkdir(rel: str):
    def setup(w, a):
        (w / rel).mkdir(parents=True, exist_ok=True)
    return setup


def copy(src_rel: str, rel: str):
    def setup(w, a):
        s = a / src_rel
        if s.is_dir():
            shutil.copytree(s, w / rel)
        else:
            (w / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy(s, w / rel)
            meta = s.with_name(s.name[:-4] + ".meta.json") if s.name.endswith(".csv") else None
            if meta is not None and meta.exists():
                shutil.copy(meta, (w / rel).with_name((w / rel).name[:-4] + ".meta.json"))
    return setup


def symlink(target, rel: str):
    def setup(w, a):
        os.symlink(target if isinstance(target, str) else target(w, a), w / rel)
    return setup


def steps(*fns):
    def setup(w, a):
        for f in fns:
            f(w, a)
    return setup


# ------------------------------------------------------------ the library door (a fresh interpreter)
LIBRARY_DOOR = """
import sys
from icgo.core.errors import IcgoError
try:
    import pandas as pd
    from icgo.artifacts.registry import load_model
    from icgo.survey.apply import correct_survey
    model = load_model(sys.argv[1])
    if len(sys.argv) > 2:
        res = correct_survey(model, pd.read_csv(sys.argv[2]))
        col = res.table["azimuth_compensated"]
        print(f"ok: {len(col)} rows, {int(col.isna().sum())} NaN; notices: {res.notices}")
except IcgoError as e:
    print(f"error: {e}", file=sys.stderr)
    raise SystemExit(1)
"""


def library(path: str, survey: bool = True) -> list:
    return ["-c", LIBRARY_DOOR, path] + (["{a}/survey.csv"] if survey else [])


# ------------------------------------------------------------ the battery
KINDS = ("relm_compensation", "msa", "mag_calibration", "gyro_network", "gyro_relm", "gyro_lookup_table",
         "discrepancy_model")
#: One float array and one plain field of each kind, to edit.
KIND_ARRAY = {"relm_compensation": "beta", "msa": "bias", "mag_calibration": "x_mag", "gyro_network": "w1",
              "gyro_relm": "beta", "gyro_lookup_table": "error", "discrepancy_model": "effects.hard_iron"}
KIND_FIELD = {"relm_compensation": "hidden", "msa": "repeat_ids", "mag_calibration": "method",
              "gyro_network": "variant", "gyro_relm": "encoding", "gyro_lookup_table": "toolface",
              "discrepancy_model": "effects"}


def _npy_header_bomb(data: bytes, w: Path) -> bytes:
    """The model's first array member with its .npy header claiming 10^12 elements."""
    import io

    src = io.BytesIO(data)
    out = io.BytesIO()
    with zipfile.ZipFile(src) as z, zipfile.ZipFile(out, "w") as o:
        for i, info in enumerate(z.infolist()):
            body = z.read(info)
            if i == 0:
                hdr = "{'descr': '<f8', 'fortran_order': False, 'shape': (1000000000000,), }"
                hdr = hdr + " " * (118 - len(hdr)) + "\n"
                body = b"\x93NUMPY\x01\x00" + len(hdr).to_bytes(2, "little") + hdr.encode() + b"\0" * 64
            o.writestr(info, body)
    return out.getvalue()


def model_cases() -> list[Case]:
    """Edited model headers and arrays of every kind, through the library door; a third also through apply."""
    import numpy as np

    cases: list[Case] = []

    def add(name, setup, says=("m.",), expect="refuse", fast=False, apply_too=False, model="{w}/m.json", **kw):
        cases.append(Case(f"model/{name}", "icgo.artifacts.registry.load_model", library(model), expect=expect,
                          says=says, setup=setup, fast=fast, **kw))
        if apply_too:
            cases.append(Case(f"apply-model/{name}", "experiments.apply",
                              _mod("experiments.apply") + [f"model={model}", "data={a}/survey.csv", "out={w}/out",
                                                           "hydra.run.dir={w}/hr"],
                              expect=expect, says=says, setup=setup, check=absent("out") if expect == "refuse" else None,
                              **kw))

    for kind in KINDS:
        arr, fld = KIND_ARRAY[kind], KIND_FIELD[kind]
        k = kind
        add(f"{k}/valid", edit_header(k, lambda h: None), expect="ok", fast=kind == "relm_compensation",
            apply_too=kind in ("relm_compensation", "mag_calibration", "msa"))
        # header fields of the wrong type
        for label, value in (("int", 7), ("list", [1, 2]), ("null", None), ("string", "x")):
            add(f"{k}/fields-as-{label}", edit_header(k, lambda h, v=value: h.__setitem__("fields", v)),
                says=("fields",), fast=(kind == "msa" and label == "int"), apply_too=(label == "list"))
        for label, value in (("list", ["relm_compensation"]), ("int", 3), ("unknown", "bogus_kind")):
            add(f"{k}/kind-{label}", edit_header(k, lambda h, v=value: h.__setitem__("kind", v)), says=("kind",))
        for label, value in (("zero", 0), ("string", "1"), ("future", 99), ("bool", True)):
            add(f"{k}/schema-{label}", edit_header(k, lambda h, v=value: h.__setitem__("schema_version", v)),
                says=("schema",))
        for label, value in (("escape", "../../../../etc/passwd"), ("absolute", "/etc/passwd"), ("empty", ""),
                             ("null", None), ("subdir", "sub/m.npz")):
            add(f"{k}/arrays-{label}", edit_header(k, lambda h, v=value: h.__setitem__("arrays", v)),
                says=("arrays",) if label != "subdir" else ("m",), apply_too=label == "escape")
        add(f"{k}/field-missing", edit_header(k, lambda h, f=fld: h["fields"].pop(f)), says=(fld,))
        add(f"{k}/field-wrong-type", edit_header(k, lambda h, f=fld: h["fields"].__setitem__(f, {"x": [1]})),
            says=(fld,))
        add(f"{k}/field-extra", edit_header(k, lambda h: h["fields"].__setitem__("bogus", 1)), says=("bogus",))
        for label, value in (("nan", [float("nan"), 1.0]), ("string", "wide"), ("reversed", [5.0, 1.0]),
                             ("three", [1, 2, 3])):
            def dom(h, v=value):
                key = next(iter(h["fields"]["domain"]))
                h["fields"]["domain"][key] = v
                return Raw(json.dumps(h))  # NaN written as the NaN literal, as Python's json does
            add(f"{k}/domain-{label}", edit_header(k, dom), says=("domain",), fast=(kind == "relm_compensation"
                                                                                     and label == "nan"))
        add(f"{k}/domain-not-object", edit_header(k, lambda h: h["fields"].__setitem__("domain", [0, 1])),
            says=("domain",))
        # arrays
        for label, fn in (("nan", lambda x: np.full_like(x, np.nan)), ("inf", lambda x: np.full_like(x, np.inf)),
                          ("huge", lambda x: np.full_like(x, 1e300)),
                          ("complex", lambda x: x.astype(complex) + 1j),
                          ("string", lambda x: np.full(x.shape, "abc")),
                          ("empty", lambda x: np.zeros((0,) + x.shape[1:])),
                          ("transposed", lambda x: x.T.copy() if x.ndim > 1 and x.shape != x.shape[::-1]
                           else np.concatenate([x.ravel(), [0.0]])),  # a square table: one value too many
                          ("extra-dim", lambda x: x[None]), ("scalar", lambda x: np.float64(1.0))):
            add(f"{k}/array-{label}",
                edit_arrays(k, lambda arrs, a_=arr, f=fn: arrs.__setitem__(a_, np.asarray(f(arrs[a_])))),
                says=(arr,), fast=(kind == "relm_compensation" and label in ("nan", "complex")),
                apply_too=label in ("nan", "huge") and kind in ("relm_compensation", "mag_calibration"))
        add(f"{k}/array-missing", edit_arrays(k, lambda arrs, a_=arr: arrs.pop(a_)), says=(arr,))
        add(f"{k}/array-extra-member", edit_arrays(k, lambda arrs: arrs.__setitem__("extra", np.ones(3))),
            expect="ok")
        add(f"{k}/npz-truncated", edit_npz_bytes(k, lambda b, w: b[: len(b) // 2]), says=("m.npz",),
            fast=kind == "msa")
        add(f"{k}/npz-empty", edit_npz_bytes(k, lambda b, w: b""), says=("m.npz",))
        add(f"{k}/npz-text", edit_npz_bytes(k, lambda b, w: b"not a zip file\n"), says=("m.npz",))
        add(f"{k}/npy-claims-1e12", edit_npz_bytes(k, _npy_header_bomb), says=("m.npz",))
    # kind-specific consistency (silently accepted before: x_std=0, features bogus, ...)
    kind_edits = [
        ("relm_compensation", "x_std-zero", edit_arrays("relm_compensation", lambda a: a.__setitem__(
            "x_std", np.zeros_like(a["x_std"]))), ("x_std",)),
        ("relm_compensation", "features-bogus", edit_header("relm_compensation", lambda h: h["fields"].__setitem__(
            "features", "bogus")), ("features",)),
        ("relm_compensation", "selected-unknown", edit_header("relm_compensation", lambda h: h["fields"].__setitem__(
            "selected", "nope")), ("selected",)),
        ("relm_compensation", "hidden-mismatch", edit_header("relm_compensation", lambda h: h["fields"].__setitem__(
            "hidden", 7)), ("theta",)),
        ("relm_compensation", "lam-1e300", edit_header("relm_compensation", lambda h: h["fields"].__setitem__(
            "lam", 1e300)), ("lam",)),
        ("relm_compensation", "lam-negative", edit_header("relm_compensation", lambda h: h["fields"].__setitem__(
            "lam", -1.0)), ("lam",)),
        ("relm_compensation", "methods-empty", edit_header("relm_compensation", lambda h: h["fields"].__setitem__(
            "methods", [])), ("methods",)),
        ("relm_compensation", "repeat-ids-short", edit_header("relm_compensation", lambda h: h["fields"].__setitem__(
            "repeat_ids", [0])), ("bias",)),
        ("relm_compensation", "interval-level-2", edit_header("relm_compensation", lambda h: h["fields"].__setitem__(
            "interval_level", 2.0)), ("interval_level",)),
        ("msa", "scale-minus-one", edit_arrays("msa", lambda a: a.__setitem__("scale", -np.ones_like(a["scale"]))),
         ("scale",)),
        ("mag_calibration", "singular", edit_arrays("mag_calibration", lambda a: a.__setitem__(
            "x_mag", np.r_[np.zeros(9), a["x_mag"][9:]])), ("x_mag",)),
        ("mag_calibration", "method-bogus", edit_header("mag_calibration", lambda h: h["fields"].__setitem__(
            "method", "bogus")), ("method",)),
        ("mag_calibration", "scale-zero", edit_header("mag_calibration", lambda h: h["fields"].__setitem__(
            "field_scale_nT", 0)), ("field_scale_nT",)),
        ("mag_calibration", "aligned-without-matrix", edit_header("mag_calibration", lambda h: h["fields"].__setitem__(
            "axis_aligned", True)), ("axis_aligned",)),
        ("gyro_network", "net-config-bogus", edit_header("gyro_network", lambda h: h["fields"].__setitem__(
            "net_config", {"bogus": 1})), ("net_config",)),
        ("gyro_network", "hidden-mismatch", edit_header("gyro_network", lambda h: h["fields"]["net_config"].__setitem__(
            "hidden", [4, 4])), ("w1",)),
        ("gyro_network", "y-scale-zero", edit_arrays("gyro_network", lambda a: a.__setitem__(
            "y_scale", np.zeros_like(a["y_scale"]))), ("y_scale",)),
        ("gyro_relm", "std-zero", edit_arrays("gyro_relm", lambda a: a.__setitem__("std", np.zeros_like(a["std"]))),
         ("std",)),
        ("gyro_relm", "encoding-bogus", edit_header("gyro_relm", lambda h: h["fields"].__setitem__(
            "encoding", "bogus")), ("encoding",)),
        ("gyro_lookup_table", "nodes-descending", edit_arrays("gyro_lookup_table", lambda a: a.__setitem__(
            "inc_nodes", a["inc_nodes"][::-1].copy())), ("inc_nodes",)),
        ("discrepancy_model", "effect-unknown", edit_header("discrepancy_model", lambda h: h["fields"].__setitem__(
            "effects", ["bogus"])), ("effects",)),
        ("discrepancy_model", "effect-not-saved", edit_header("discrepancy_model", lambda h: h["fields"].__setitem__(
            "effects", ["hard_iron", "accel_bias"])), ("effects.accel_bias",)),
        ("discrepancy_model", "n-iter-huge", edit_header("discrepancy_model", lambda h: h["fields"].__setitem__(
            "n_iter", 10**9)), ("n_iter",)),
        ("discrepancy_model", "field-negative", edit_arrays("discrepancy_model", lambda a: a.__setitem__(
            "field", np.array([-5.0, 60.0, 0.0]))), ("field",)),
    ]
    for kind, label, setup, says in kind_edits:
        add(f"{kind}/{label}", setup, says=says, fast=label in ("x_std-zero", "features-bogus"),
            apply_too=label in ("x_std-zero", "features-bogus", "lam-1e300"))
    # the header file itself
    for label, setup, says in (
            ("header-not-json", write("m.json", "{not json"), ("m.json",)),
            ("header-empty", write("m.json", ""), ("m.json",)),
            ("header-array", write("m.json", "[1, 2]"), ("m.json",)),
            ("header-deep", write("m.json", "[" * 100_000 + "]" * 100_000), ("m.json",)),
            ("header-binary", write("m.json", bytes(range(256)) * 4), ("m.json",)),
            ("header-fifo", fifo("m.json"), ("m.json",)),
            ("header-directory", mkdir("m.json"), ("m.json",)),
            ("header-huge", write("m.json", lambda w, a: '{"pad": "' + "x" * (8 << 20) + '"}'), ("m.json",)),
            ("header-dev-zero", symlink("/dev/zero", "m.json"), ("m.json",)),
            ("header-missing", None, ("m.json",)),
            ("npz-fifo", steps(edit_header("msa", lambda h: None), lambda w, a: ((w / "m.npz").unlink(),
                                                                                os.mkfifo(w / "m.npz"))), ("m.npz",)),
            ("npz-directory", steps(edit_header("msa", lambda h: None), lambda w, a: ((w / "m.npz").unlink(),
                                                                                     (w / "m.npz").mkdir())),
             ("m.npz",)),
            ("npz-dev-zero", steps(edit_header("msa", lambda h: None), lambda w, a: ((w / "m.npz").unlink(),
                                                                                    os.symlink("/dev/zero",
                                                                                               w / "m.npz"))),
             ("m.npz",)),
            ("npz-missing", steps(edit_header("msa", lambda h: None), lambda w, a: (w / "m.npz").unlink()),
             ("m.npz",)),
            ("header-nan-literal", edit_header("relm_compensation", lambda h: Raw(json.dumps(h).replace(
                '"lam": 0.001', '"lam": NaN'))), ("m.json",)),
            ("zip-bomb-member", lambda w, a: (copy_model(a, w, "relm_compensation"),
                                              shutil.copy(bomb(a), w / "m.npz")), None),
    ):
        add(label, setup, says=says or (), expect="ok" if label == "zip-bomb-member" else "refuse",
            fast=label in ("header-fifo", "header-not-json"), apply_too=label in ("header-fifo", "zip-bomb-member"),
            timeout=60.0)
    # run directories whose run.json points elsewhere
    def run_dir(models, extra=None):
        """Setup: a copy of the fake run directory whose run.json lists ``models`` (``{w}`` is the case folder)."""
        def setup(w, a):
            shutil.copytree(a / "run", w / "run")
            listed = [m.replace("{w}", str(w)) if isinstance(m, str) else m for m in models] \
                if isinstance(models, list) else models
            (w / "run" / "run.json").write_text(json.dumps(_run_record(listed)))
            if extra:
                extra(w, a)
        return setup

    def outside(w, a):
        (w / "elsewhere").mkdir()
        copy_model(a, w / "elsewhere", "msa")
    for label, models, extra, says in (
            ("escape-dotdot", ["../../../../../../etc/passwd"], None, ("models",)),
            ("escape-dotdot-model", ["../elsewhere/m.json"], outside, ("models",)),
            ("escape-absolute", ["{w}/elsewhere/m.json"], outside, ("models",)),
            ("escape-symlink", ["link.json"], lambda w, a: (outside(w, a), os.symlink(
                w / "elsewhere" / "m.json", w / "run" / "link.json")), ("link",)),
            ("models-not-list", "relm_compensation.json", None, ("models",)),
            ("models-empty", [], None, ("models",)),
            ("models-int", [7], None, ("models",)),
            ("run-json-fifo", [], lambda w, a: ((w / "run" / "run.json").unlink(),
                                                os.mkfifo(w / "run" / "run.json")), ("run.json",)),
            ("run-json-not-json", [], lambda w, a: (w / "run" / "run.json").write_text("{"), ("run.json",)),
    ):
        add(f"run/{label}", run_dir(models, extra), says=says, model="{w}/run", fast=label == "escape-dotdot",
            apply_too=label in ("escape-dotdot", "escape-symlink"), timeout=60.0)
    add("run/valid", run_dir(["relm_compensation.json", "msa.json"]), expect="ok", model="{w}/run",
        apply_too=True)
    add("dir/two-models", lambda w, a: (copy_model(a, w, "msa", "one"), copy_model(a, w, "mag_calibration", "two")),
        says=("2 models",), model="{w}")
    add("dir/no-model", lambda w, a: None, says=("no saved model",), model="{w}")
    return cases


# ------------------------------------------------------------ apply
def apply_cases() -> list[Case]:
    cases = []
    base = _mod("experiments.apply") + ["hydra.run.dir={w}/hr"]
    M, S = "model={a}/models/relm_compensation.json", "data={a}/survey.csv"

    def add(name, args, **kw):
        cases.append(Case(f"apply/{name}", "experiments.apply", base + args, **kw))

    add("ok", [M, S, "out={w}/out"], expect="ok", fast=True,
        check=lambda w, a, r: None if (w / "out" / "survey_corrected.csv").exists() else "no output")
    for v in ("maybe", "no", "'false'", "1", "null", "[true]"):
        add(f"require_meta={v}", [M, S, f"require_meta={v}", "out={w}/out"], says=("require_meta",),
            check=absent("out"), fast=v == "maybe")
    for v in ("maybe", "1"):
        add(f"overwrite={v}", [M, S, f"overwrite={v}", "out={w}/out"], says=("overwrite",), check=absent("out"))
    for k, v, says in (("method", "123", "method"), ("method", "bogus", "method"), ("qc.g_tol_g", "-1", "g_tol_g"),
                       ("qc.g_tol_g", "abc", "g_tol_g"), ("qc.dip_tol_deg", "nan", "dip_tol_deg"),
                       ("qc.b_tol_nT", "[1,2]", "b_tol_nT"), ("+bogus", "1", "bogus"), ("+qc.bogus", "1", "bogus"),
                       ("model", "''", "model"), ("data", "null", "data"), ("out", "[1]", "out"),
                       ("model", "{w}/nope.json", "nope.json"), ("data", "{w}/nope.csv", "nope.csv")):
        args = [a_ for a_ in (M, S) if not a_.startswith(k + "=")] + [f"{k}={v}"] + (["out={w}/out"] if k != "out"
                                                                                      else [])
        add(f"{k}={v}".replace("{w}/", ""), args, says=(says,), check=absent("out"))
    add("model-missing", [S, "out={w}/out"], says=("model",))
    add("data-missing", [M, "out={w}/out"], says=("data",))
    add("method-on-one-method-model", ["model={a}/models/msa.json", S, "method=relm", "out={w}/out"],
        says=("method",))
    # hostile surveys
    for label, setup, says in (
            ("dir", mkdir("s.csv"), "s.csv"), ("fifo", fifo("s.csv"), "s.csv"),
            ("dev-zero", symlink("/dev/zero", "s.csv"), "s.csv"), ("empty", write("s.csv", ""), "s.csv"),
            ("binary", write("s.csv", bytes(range(256)) * 8), "s.csv"),
            ("header-only", write("s.csv", "station,gx,gy,gz,bx,by,bz\n"), "s.csv"),
            ("nan", write("s.csv", "station,gx,gy,gz,bx,by,bz\n0,0,0,1,nan,0,40000\n"), "s.csv"),
            ("no-bz", write("s.csv", "station,gx,gy,gz,bx,by\n0,0,0,1,20000,0\n"), "bz"),
            ("uT-units", write("s.csv", "station,gx,gy,gz,bx,by,bz\n0,0,0,1,20,0,40\n1,0.1,0,0.99,21,0,40\n"),
             "s.csv"),
            ("meta-fifo", steps(copy("survey.csv", "s.csv"), lambda w, a: ((w / "s.meta.json").unlink(),
                                                                          os.mkfifo(w / "s.meta.json"))),
             "s.meta.json"),
            ("meta-not-json", steps(copy("survey.csv", "s.csv"), write("s.meta.json", "{")), "s.meta.json"),
            ("meta-nan", steps(copy("survey.csv", "s.csv"), write("s.meta.json", '{"total_field_nT": NaN}')),
             "s.meta.json"),
            ("huge", sparse("s.csv", "station,gx,gy,gz,bx,by,bz\n" + "0,0,0,1,20000,0,40000\n" * 1000, 300 << 20),
             "s.csv"),
    ):
        add(f"survey-{label}", [M, "data={w}/s.csv", "out={w}/out"], says=(says,), setup=setup, check=absent("out"),
            timeout=60.0 if label in ("fifo", "dev-zero", "meta-fifo") else 300.0, fast=label == "fifo")
    # a corrected survey as input: refused, never mixed
    def corrected(w, a):
        subprocess.run([PY, "-m", "experiments.apply", M.format(a=a), S.format(a=a), f"out={w}/first",
                        f"hydra.run.dir={w}/hr0"], cwd=w, env=_env(), capture_output=True, timeout=300)
    add("corrected-survey-again", ["model={a}/models/mag_calibration.json", "data={w}/first/survey_corrected.csv",
                                   "out={w}/out"], setup=corrected, says=("output columns",), check=absent("out"),
        fast=True)
    # output places
    for label, out, setup, says in (
            ("out-is-file", "{w}/f", write("f", "x"), "out"), ("out-under-file", "{w}/f/sub", write("f", "x"), "out"),
            ("out-dev-null", "/dev/null", None, "out"), ("out-under-dev-null", "/dev/null/x", None, "out"),
            ("out-proc", "/proc/icgo-x", None, "out")):
        add(label, [M, S, f"out={out}"], setup=setup, says=(says,))
    add("out-read-only", [M, S, "out={w}/ro/out"], says=("out",), needs="mount")
    add("out-full-disk", [M, S, "out={w}/out"], fsize=2048, says=("out",),
        check=absent_or_complete("out", ("survey_corrected.csv", "survey_corrected.meta.json")), fast=True)
    # a used output directory
    first = lambda w, a: subprocess.run([PY, "-m", "experiments.apply", M.format(a=a), S.format(a=a),  # noqa: E731
                                         f"out={w}/out", f"hydra.run.dir={w}/hr0"], cwd=w, env=_env(),
                                        capture_output=True, timeout=300)
    add("second-into-same-out", [M, S, "out={w}/out"], setup=steps(first, remember("out")), says=("out",),
        check=unchanged("out"), fast=True)
    add("second-other-model-same-out", ["model={a}/models/msa.json", S, "out={w}/out"],
        setup=steps(first, remember("out")), says=("out",), check=unchanged("out"))
    add("overwrite-replaces-whole", ["model={a}/models/msa.json", S, "out={w}/out", "overwrite=true"],
        setup=steps(first, write("out/stale.txt", "old\n")), expect="ok",
        check=lambda w, a, r: ("stale file kept" if (w / "out" / "stale.txt").exists() else None)
        or (None if json.loads((w / "out" / "survey_corrected.meta.json").read_text())["model_kind"] == "msa"
            else "old meta kept"))
    add("overwrite-foreign-dir", [M, S, "out={w}/out", "overwrite=true"], setup=steps(write("out/notes.txt", "mine\n"),
                                                                                     remember("out")),
        says=("out",), check=unchanged("out"))
    add("used-hydra-run-dir", [M, S], setup=steps(first, lambda w, a: shutil.copytree(w / "out", w / "hr",
                                                                                       dirs_exist_ok=True),
                                                  remember("hr")), says=("hydra.run.dir",), check=unchanged("hr"))
    # the domain and the device
    add("far-outside-domain", [M, "data={a}/far_survey.csv", "out={w}/out"], expect="outside",
        check=lambda w, a, r: None if "training domain" in r.stdout else "no notice of the training domain")
    add("reference-in-radians", [M, "data={a}/survey_rad.csv", "out={w}/out"], expect="outside",
        check=lambda w, a, r: None if "looks like radians" in r.stdout and json.loads(
            (w / "out" / "survey_rad_corrected.meta.json").read_text())["verdict"]["status"] == "reference in doubt"
        else "the verdict does not say the reference is in radians")
    add("model-of-another-device", ["model={a}/models/ab_calibration.json", "data={a}/jd_survey.csv", "out={w}/out"],
        expect="outside", check=lambda w, a, r: None if "NOT this model's device" in r.stdout
        else "the verdict does not say the model belongs to another device")
    # size: a limit given, a survey streamed in chunks
    add("streamed", [M, "data={a}/long_survey.csv", "out={w}/out", "stream_mb=1", "chunk_rows=2000"], expect="ok",
        check=lambda w, a, r: None if json.loads((w / "out" / "long_survey_corrected.meta.json").read_text())[
            "chunks"] == 6 else "not streamed in 6 chunks")
    add("max_mb=1", [M, "data={a}/long_survey.csv", "out={w}/out", "max_mb=1"], says=("long_survey.csv", "MiB"),
        check=absent("out"))
    for k in ("max_mb", "stream_mb", "chunk_rows"):
        add(f"{k}=0", [M, S, "out={w}/out", f"{k}=0"], says=(k,), check=absent("out"))
    # interrupted
    for sig, label in ((signal.SIGINT, "ctrl-c"), (signal.SIGTERM, "sigterm")):
        add(label, [M, S, "out={w}/out"], expect="interrupt", signal_after=(sig, 1.5),
            check=absent_or_complete("out", ("survey_corrected.csv", "survey_corrected.meta.json")),
            fast=label == "ctrl-c")
    add("sigkill", [M, S, "out={w}/out"], expect="killed", signal_after=(signal.SIGKILL, 2.5),
        check=absent_or_complete("out", ("survey_corrected.csv", "survey_corrected.meta.json")))
    return cases


# ------------------------------------------------------------ run (the study) and sweeps
def run_cases() -> list[Case]:
    cases = []
    nocache = ["budget=smoke", "split.n_repeats=2", "figures=false", "progress=false"]
    smoke = nocache + ["jax_cache_dir={a}/../jax"]
    base = _mod("experiments.run") + ["hydra.run.dir={w}/run"]

    def add(name, args, **kw):
        cases.append(Case(f"run/{name}", "experiments.run", base + args, **kw))

    for k, v, says in (
            ("figures", "maybe", "figures"), ("overwrite", "maybe", "overwrite"), ("progress", "maybe", "progress"),
            ("model.lam", "1e300", "lam"), ("model.lam", "-1", "lam"), ("model.lam", "nan", "lam"),
            ("model.lam", "abc", "lam"), ("model.hidden", "0", "hidden"), ("model.hidden", "1e9", "hidden"),
            ("model.hidden", "abc", "hidden"), ("split.n_repeats", "0", "n_repeats"),
            ("split.n_repeats", "-3", "n_repeats"), ("split.n_repeats", "abc", "n_repeats"),
            ("split.seed", "abc", "seed"), ("budget.pop_size", "0", "pop_size"), ("budget.iterations", "-1",
                                                                                  "iterations"),
            ("schedule.bounds", "5", "bounds"), ("schedule.bounds", "[0.9,0.1]", "bounds"),
            ("optimizer", "bogus", "optimizer"), ("strategy", "bogus", "strategy"), ("dataset", "bogus", "dataset"),
            ("+bogus", "1", "bogus"), ("bogus", "1", "bogus"), ("msa.model", "bogus", "msa"),
            ("msa.iterations", "-5", "iterations"), ("precision", "bogus", "precision"),
            ("dtype", "float64", "precision"), ("devices", "-1", "devices"),
            ("fitness", "bogus", "fitness"), ("split", "bogus", "split"), ("dataset.seed", "abc", "seed"),
            ("dataset.condition", "9", "condition"), ("label", "[1,2]", "label"), ("split.target", "bogus",
                                                                                  "target"),
            ("optimizer.params.bogus", "1", "bogus"), ("jax_cache_dir", "/dev/null/x", "jax_cache_dir")):
        extra = ["split=transfer"] if k == "split.target" else (["dataset=well_conditions"]
                                                                  if k == "dataset.condition" else [])
        add(f"{k}={v}", smoke + extra + [f"{k}={v}"], says=(says,), check=absent("run"),
            fast=(k, v) in (("model.lam", "1e300"), ("figures", "maybe"), ("split.target", "bogus")))
    for v in ("maybe", "0"):
        add(f"csv-require_meta={v}", smoke + ["dataset=csv", "dataset.path={a}/survey.csv",
                                              f"dataset.require_meta={v}"], says=("require_meta",), check=absent("run"))
    for label, setup, says in (("missing", None, "dataset.path"), ("dir", mkdir("s.csv"), "s.csv"),
                               ("fifo", fifo("s.csv"), "s.csv"), ("empty", write("s.csv", ""), "s.csv")):
        add(f"csv-{label}", smoke + ["dataset=csv", "dataset.path={w}/s.csv"], setup=setup, says=(says,),
            timeout=60.0)
    add("csv-no-path", smoke + ["dataset=csv"], says=("dataset.path",))
    add("hydra-run-dir-is-file", smoke, setup=write("run", "x"), says=("hydra.run.dir",))
    add("used-run-dir", smoke, setup=steps(write("run/notes.txt", "mine\n"), remember("run")), says=("run",),
        check=unchanged("run"))
    add("ok", smoke, expect="ok", fast=True,
        check=lambda w, a, r: None if (w / "run" / "run.json").exists() and (w / "run" / ".hydra").is_dir()
        else "no run.json or .hydra")
    add("ctrl-c", smoke, expect="interrupt", signal_after=(signal.SIGINT, 6.0),
        check=lambda w, a, r: "run.json without a complete run" if (w / "run" / "run.json").exists() and not (
            w / "run" / "summary.csv").exists() else None)
    add("sigkill", smoke, expect="killed", signal_after=(signal.SIGKILL, 6.0),
        check=lambda w, a, r: "half-written run" if (w / "run" / "run.json").exists() and not (
            w / "run" / "summary.csv").exists() else None)
    add("full-disk", nocache + ["jax_cache_dir=null"], fsize=FULL_DISK_BYTES, says=("run",),
        check=lambda w, a, r: "run.json written on a full disk" if (w / "run" / "run.json").exists() else None)
    # sweeps re-run into their directory
    sweep = _mod("experiments.run") + ["-m", "hydra.sweep.dir={w}/sw", "hydra.launcher.workers=1"] + smoke

    def first_sweep(values, extra=()):
        def setup(w, a):
            subprocess.run([PY] + [x.format(w=w, a=a) for x in sweep] + [f"strategy={values}", *extra], cwd=w,
                           env=_env(), capture_output=True, timeout=900)
            (w / ".sw.snapshot").write_text(json.dumps(
                {k: v for k, v in snapshot(w / "sw").items() if k.startswith(("0/", "1/", "2/"))}))
        return setup

    def kept_unchanged(w, a, r):
        before = json.loads((w / ".sw.snapshot").read_text())
        after = snapshot(w / "sw")
        bad = sorted(k for k, v in before.items() if not k.endswith(".log") and after.get(k) != v)
        return f"kept jobs rewritten: {bad[:4]}" if bad else None

    def report_says(statuses):
        def check(w, a, r):
            got = [j["status"] for j in json.loads((w / "sw" / "sweep_report.json").read_text())["jobs"]]
            return None if got == statuses else f"sweep report says {got}, expected {statuses}"
        return check

    cases.append(Case("sweep/reordered-strategies", "experiments.run", sweep + ["strategy=wavelet,chaos"],
                      setup=first_sweep("chaos,gaussian,wavelet"), says=("refused",), report=True,
                      check=chain(kept_unchanged, report_says(["refused", "refused"])), timeout=900, fast=True))
    cases.append(Case("sweep/more-repeats", "experiments.run", sweep + ["strategy=chaos,gaussian", "split.n_repeats=3"],
                      setup=first_sweep("chaos,gaussian"), says=("refused",), report=True,
                      check=chain(kept_unchanged, report_says(["refused", "refused"])), timeout=900))
    cases.append(Case("sweep/same-again", "experiments.run", sweep + ["strategy=chaos,gaussian"],
                      setup=first_sweep("chaos,gaussian"), expect="ok",
                      check=chain(kept_unchanged, report_says(["ok", "ok"])), timeout=900))
    cases.append(Case("sweep/one-more-job", "experiments.run", sweep + ["strategy=chaos,gaussian,wavelet"],
                      setup=first_sweep("chaos,gaussian"), expect="ok",
                      check=chain(kept_unchanged, report_says(["ok", "ok", "ok"])), timeout=900))
    return cases


# ------------------------------------------------------------ calibrate
def calibrate_cases() -> list[Case]:
    cases = []
    base = _mod("experiments.calibrate") + ["hydra.run.dir={w}/cal"]
    quick = ["misma_iter=5", "misma_repeats=1", "misma_pop=6", "peer=false"]

    def add(name, args, **kw):
        kw.setdefault("check", absent("cal") if kw.get("expect", "refuse") == "refuse" else None)
        cases.append(Case(f"calibrate/{name}", "experiments.calibrate", base + args, **kw))

    def j(obj):
        return write("d.json", json.dumps(obj) if not isinstance(obj, str) else obj)

    good_raw = lambda w, a: json.loads((a / "raw.json").read_text())  # noqa: E731
    for label, setup, says in (
            ("not-json", j("{"), "d.json"), ("empty", j(""), "d.json"), ("array", j([1, 2]), "d.json"),
            ("null", j("null"), "d.json"), ("deep", j("[" * 50_000 + "]" * 50_000), "d.json"),
            ("nan", j('{"mag": [[NaN, 1, 2]], "grav": [[0, 0, 1]]}'), "d.json"),
            ("strings", j({"mag": [["a", "b", "c"]], "grav": [[0, 0, 1]]}), "d.json"),
            ("pairs", j({"mag": [[1, 2]], "grav": [[0, 0, 1]]}), "d.json"),
            ("mismatched", write("d.json", lambda w, a: json.dumps({**good_raw(w, a), "grav": good_raw(w, a)["grav"][:5]})),
             "d.json"),

            ("gauss", write("d.json", lambda w, a: json.dumps({"mag": [[c / 100 for c in t] for t in good_raw(w, a)[
                "mag"]], "grav": good_raw(w, a)["grav"]})), "d.json"),
            ("nT", write("d.json", lambda w, a: json.dumps({"mag": [[c * 1000 for c in t] for t in good_raw(w, a)[
                "mag"]], "grav": good_raw(w, a)["grav"]})), "d.json"),
            ("fixture-shots-not-dict", j({"shots": [1, 2, 3]}), "d.json"),
            ("fixture-bad-values", j({"shots": {"mag": ["x"] * 72, "grav": [0.0] * 72}}), "d.json"),
            ("fixture-short", j({"shots": {"mag": [1.0] * 9, "grav": [0.0] * 9}}), "d.json"),
            ("fifo", fifo("d.json"), "d.json"), ("dir", mkdir("d.json"), "d.json"),
            ("dev-zero", symlink("/dev/zero", "d.json"), "d.json"),
            ("huge", write("d.json", lambda w, a: json.dumps({"mag": [[20.0, 0.0, 40.0]] * 240_000,
                                                                "grav": [[0.0, 0.0, 1.0]] * 240_000})), "d.json"),
            ("many-shots", write("d.json", lambda w, a: json.dumps({"mag": good_raw(w, a)["mag"] * 20,
                                                                      "grav": good_raw(w, a)["grav"] * 20})), "d.json"),
            ("binary", write("d.json", bytes(range(256)) * 4), "d.json"),
            ("missing", None, "d.json"),
    ):
        add(f"json-{label}", ["data={w}/d.json"] + quick, setup=setup, says=(says,),
            timeout=60.0 if label in ("fifo", "dev-zero") else 300.0, fast=label in ("fifo", "huge", "not-json"))
    for k, v, says in (("mag_axes", "+x+x+z", "mag_axes"), ("mag_axes", "bogus", "mag_axes"),
                       ("grav_axes", "+q+y+z", "grav_axes"), ("mag_axes", "123", "mag_axes")):
        add(f"raw-{k}={v}", ["data={a}/raw.json", f"{k}={v}"] + quick, says=(says,), fast=v == "+x+x+z")
    add("fixture-with-axes", ["data={a}/fixture.json", "mag_axes=+x+y+z"] + quick, says=("mag_axes",))
    add("csv-with-axes", ["data={a}/device.csv", "mag_axes=+x+y+z"] + quick, says=("mag_axes",))
    add("csv-no-group", ["data={a}/survey.csv"] + quick, says=("group",))
    for k, v, says in (("overwrite", "maybe", "overwrite"), ("peer", "maybe", "peer"), ("misma_iter", "-1",
                                                                                        "misma_iter"),
                       ("misma_iter", "abc", "misma_iter"), ("misma_repeats", "0", "misma_repeats"),
                       ("misma_pop", "1e9", "misma_pop"), ("misma_bounds", "bogus", "misma_bounds"),
                       ("+bogus", "1", "bogus"), ("data", "''", "data"), ("data", "[1]", "data"),
                       ("results_dir", "/dev/null/x", "results_dir")):
        args = ["data={a}/fixture.json"] + quick + [f"{k}={v}"] if k != "data" else quick + [f"{k}={v}"]
        if k == "results_dir":
            args = ["data=bundled"] + quick + [f"{k}={v}"]
        add(f"{k}={v}", args, says=(says,), fast=(k, v) == ("overwrite", "maybe"))
    # shots that were read but cannot be grouped (2 shots: no layout, no roll): the report says why, exit 4
    add("json-two-shots", ["data={w}/d.json"] + quick, setup=write("d.json", lambda w, a: json.dumps(
        {k: v[:2] for k, v in good_raw(w, a).items()})), expect="norecommend", says=("d.json", "no roll"),
        check=lambda w, a, r: None if "no roll" in (w / "cal" / "report.md").read_text() else "no report")
    for label, asset in (("fixture-1e300", "fixture_1e300.json"), ("raw-1e300", "raw_1e300.json")):
        add(f"json-{label}", ["data={w}/d.json"] + quick, setup=copy(asset, "d.json"), says=("d.json", "shot"),
            timeout=60.0)
    for k, v, says in (("site.lat", "100", "site.lat"), ("site.dip", "60", "site.field"),
                       ("site.field", "50", "uT"), ("site.lat", "51", "site.lon"), ("site.dip", "abc", "site.dip"),
                       ("max_shots", "10", "max_shots"), ("max_groups", "0", "max_groups"),
                       ("columns.bogus", "X", "bogus")):
        prefix = "+" if k == "columns.bogus" else ""
        add(f"{k}={v}", ["data={a}/fixture.json"] + quick + [f"{prefix}{k}={v}"], says=(says,))
    add("site.date=1990", ["data={a}/fixture.json"] + quick + ["site.lat=51", "site.lon=0", "site.date=1990-01-01"],
        says=("site.date",))
    add("columns-export", ["data={a}/export.csv", "columns.gx=Gx", "columns.gy=Gy", "columns.gz=Gz", "columns.bx=Bx",
                           "columns.by=By", "columns.bz=Bz", "columns.group=Set"] + quick, expect="ok", timeout=900,
        check=lambda w, a, r: None if (w / "cal" / "report.md").exists() else "no report")
    add("inconsistent-axes-site", ["data={a}/raw_bad_axes.json", "site.dip=66.5", "site.field=49000"] + quick,
        expect="norecommend", says=("no calibration recommended", "inconsistent"), timeout=900,
        check=lambda w, a, r: None if "inconsistent axes or mounting" in (w / "cal" / "report.md").read_text()
        else "the report does not say why")
    first = lambda w, a: (w / "cal").mkdir() or (w / "cal" / "report.md").write_text("old\n")  # noqa: E731
    add("used-run-dir", ["data={a}/fixture.json"] + quick, setup=steps(first, remember("cal")),
        says=("hydra.run.dir",), check=unchanged("cal"), fast=True)
    add("ok-fixture", ["data={a}/fixture.json"] + quick, expect="ok", timeout=900,
        check=lambda w, a, r: None if (w / "cal" / "report.md").exists() and (w / "cal" / "models").is_dir()
        else "incomplete run directory")
    add("full-disk", ["data={a}/fixture.json"] + quick, fsize=FULL_DISK_BYTES, says=("cal",), timeout=900,
        check=absent_or_complete("cal", ("report.md", "calibration.csv", "fixture.png", "models")))
    add("ctrl-c", ["data={a}/fixture.json"] + quick, expect="interrupt", signal_after=(signal.SIGINT, 8.0),
        check=absent_or_complete("cal", ("report.md", "calibration.csv", "fixture.png", "models")))
    return cases


# ------------------------------------------------------------ discrepancy
def discrepancy_cases() -> list[Case]:
    cases = []
    base = _mod("experiments.discrepancy") + ["hydra.run.dir={w}/d"]

    def add(name, args, **kw):
        kw.setdefault("check", absent("d") if kw.get("expect", "refuse") == "refuse" else None)
        cases.append(Case(f"discrepancy/{name}", "experiments.discrepancy", base + args, **kw))

    for k, v, says in (
            ("data", "{w}/nope.csv", "nope.csv"), ("data", "sim:bogus", "bogus"), ("data", "mag_cal:../ok", "../ok"),
            ("data", "mag_cal:bogus", "bogus"), ("data", "[1,2]", "data"), ("design", "bogus", "design"),
            ("study", "bogus", "study"), ("n_stations", "0", "n_stations"), ("n_stations", "-5", "n_stations"),
            ("n_stations", "abc", "n_stations"), ("n_stations", "1000000000", "n_stations"), ("seed", "-1", "seed"),
            ("seed", "abc", "seed"), ("max_effects", "-1", "max_effects"), ("sigma_b_nT", "0", "sigma_b_nT"),
            ("sigma_g", "-1", "sigma_g"), ("k_folds", "1", "k_folds"), ("bucket", "-1", "bucket"),
            ("candidates", "[bogus]", "bogus"), ("candidates", "5", "candidates"), ("min_z", "nan", "min_z"),
            ("n_iter", "0", "n_iter"), ("overwrite", "maybe", "overwrite"), ("+bogus", "1", "bogus"),
            ("noise_tolerance", "abc", "noise_tolerance")):
        add(f"{k}={v}".replace("{w}/", ""), [f"{k}={v}"], says=(says,), fast=(k, v) in (("data", "mag_cal:../ok"),
                                                                                         ("n_stations", "-5")))
    for label, setup, says in (("dir", mkdir("s.csv"), "s.csv"), ("fifo", fifo("s.csv"), "s.csv"),
                               ("empty", write("s.csv", ""), "s.csv"), ("dev-zero", symlink("/dev/zero", "s.csv"),
                                                                         "s.csv")):
        add(f"csv-{label}", ["data={w}/s.csv"], setup=setup, says=(says,), timeout=60.0)
    add("used-run-dir", ["data=sim:hard_iron", "n_stations=40"], setup=steps(write("d/report.md", "old\n"),
                                                                             remember("d")),
        says=("hydra.run.dir",), check=unchanged("d"))
    add("ok", ["data=sim:hard_iron", "n_stations=40", "max_effects=1"], expect="ok", timeout=900,
        check=lambda w, a, r: None if (w / "d" / "report.md").exists() and (w / "d" / "discrepancy_model.json")
        .exists() else "incomplete run directory")
    add("full-disk", ["data=sim:hard_iron", "n_stations=40", "max_effects=1"], fsize=FULL_DISK_BYTES, says=("d",),
        timeout=900, check=absent_or_complete("d", ("report.md", "discrepancy.json", "discrepancy_model.json")))
    return cases


# ------------------------------------------------------------ misma, gyro (their studies are long: settings only)
def study_setting_cases() -> list[Case]:
    cases = []
    for door, items in (
            ("misma", (("simulated.repeats", "0"), ("simulated.repeats", "abc"), ("real.enabled", "maybe"),
                       ("real.peer", "maybe"), ("seed", "abc"), ("+bogus", "1"), ("simulated.enabled", "'yes'"),
                       ("out_dir", "/dev/null/x"))),
            ("gyro", (("seed", "abc"), ("+bogus", "1"), ("out_dir", "/dev/null/x"), ("jax_cache_dir", "/dev/null/x"),
                      ("network.enabled", "maybe"))),
    ):
        for k, v in items:
            says = k.split(".")[-1].lstrip("+")
            cases.append(Case(f"{door}/{k}={v}", f"experiments.{door}",
                              _mod(f"experiments.{door}") + ["hydra.run.dir={w}/r", f"{k}={v}"], says=(says,),
                              timeout=300, fast=(door, k) == ("misma", "real.enabled")))
    return cases


# ------------------------------------------------------------ figures, generalisation, optimizers
def argparse_cases() -> list[Case]:
    cases = []

    def add(door, name, args, **kw):
        cases.append(Case(f"{door.split('.')[-1]}/{name}", door, _mod(door) + args, **kw))

    f = "experiments.figures"
    add(f, "override-bogus", ["--override", "bogus=1", "--out", "{w}/o"], says=("bogus",), check=absent("o"),
        fast=True, timeout=120)
    add(f, "override-bad-group", ["--override", "strategy=bogus", "--out", "{w}/o"], says=("strategy",),
        check=absent("o"))
    add(f, "override-not-kv", ["--override", "bogus", "--out", "{w}/o"], says=("override",), check=absent("o"))
    add(f, "jobs-zero", ["{a}/run", "--jobs", "0", "--out", "{w}/o"], says=("jobs",), check=absent("o"))
    add(f, "jobs-abc", ["{a}/run", "--jobs", "abc", "--out", "{w}/o"], says=("jobs",), check=absent("o"))
    add(f, "out-file", ["{a}/run", "--out", "{w}/f"], setup=write("f", "x"), says=("out",))
    add(f, "out-under-file", ["{a}/run", "--out", "{w}/f/x"], setup=write("f", "x"), says=("out",))
    add(f, "out-dev-null", ["{a}/run", "--out", "/dev/null/x"], says=("out",))
    add(f, "dir-missing", ["{w}/nope", "--out", "{w}/o"], says=("nope",), check=absent("o"))
    add(f, "dir-is-file", ["{w}/f", "--out", "{w}/o"], setup=write("f", "x"), says=("f",), check=absent("o"))
    add(f, "override-with-dirs", ["{a}/run", "--override", "budget=smoke", "--out", "{w}/o"], says=("override",),
        check=absent("o"))
    add(f, "out-used", ["{a}/run", "--out", "{w}/o"], setup=steps(write("o/table1.md", "old\n"), remember("o")),
        says=("out",), check=unchanged("o"))
    add(f, "collect-junk-runs", ["{w}/runs", "--out", "{w}/o"], expect="either",
        setup=steps(write("runs/0/run.json", "{"), write("runs/1/run.json", "[]"), write("runs/2/metrics.csv", "x\n")))
    add(f, "full-disk", ["{a}/run", "--out", "{w}/o"], expect="either", fsize=1024)
    g = "experiments.generalisation"
    for args, says in ((["--n-repeats", "0"], "n-repeats"), (["--n-repeats", "-1"], "n-repeats"),
                       (["--n-repeats", "abc"], "n-repeats"), (["--iterations", "0"], "iterations"),
                       (["--pop-size", "1"], "pop-size"), (["--seed", "abc"], "seed"), (["--bogus"], "bogus")):
        add(g, " ".join(args), args + ["--out", "{w}/o"], says=(says,), check=absent("o"), fast=args[-1] == "0")
    for label, out, setup in (("out-file", "{w}/f", write("f", "x")), ("out-under-file", "{w}/f/x", write("f", "x")),
                              ("out-dev-null", "/dev/null/x", None),
                              ("out-used", "{w}/o", steps(write("o/x.md", "old\n"), remember("o")))):
        add(g, label, ["--n-repeats", "2", "--iterations", "2", "--out", out], setup=setup, says=("out",),
            check=unchanged("o") if label == "out-used" else None, timeout=120)
    o = "experiments.optimizers"
    for args, says in ((["--dims", "0"], "dims"), (["--runs", "0"], "runs"), (["--budget", "-1"], "budget"),
                       (["--functions", "bogus"], "bogus"), (["--methods", "bogus"], "bogus"),
                       (["--alpha", "2"], "alpha"), (["--jobs", "0"], "jobs"), (["--pop-size", "abc"], "pop-size")):
        add(o, " ".join(args), args + ["--out", "{w}/o"], says=(says,), check=absent("o"))
    add(o, "out-file", ["--runs", "2", "--out", "{w}/f"], setup=write("f", "x"), says=("out",))
    add(o, "out-used", ["--runs", "2", "--out", "{w}/o"], setup=steps(write("o/x.md", "old\n"), remember("o")),
        says=("out",), check=unchanged("o"))
    u = "experiments.calibration_unseen"
    for args, says in ((["--variants", "0"], "variants"), (["--variants", "abc"], "variants"),
                       (["--devices", "zz", "--variants", "1"], "zz"), (["--bogus"], "bogus")):
        add(u, " ".join(args), args + ["--out", "{w}/o"], says=(says,), check=absent("o"))
    add(u, "out-file", ["--devices", "ab", "--variants", "1", "--out", "{w}/f"], setup=write("f", "x"), says=("out",))
    for door, args, says in (("experiments.roofline", ["--out", "{w}/d"], "out"),
                             ("experiments.roofline", ["--out", "{w}/f/x"], "out"),
                             ("experiments.roofline", ["--batch", "0"], "batch"),
                             ("experiments.bench", ["--out", "../escape"], "out")):
        setup = mkdir("d") if "{w}/d" in args else (write("f", "x") if "{w}/f/x" in args else None)
        add(door, " ".join(args).replace("{w}/", ""), args, setup=setup, says=(says,), timeout=300)
    return cases


# ------------------------------------------------------------ python -m icgo.io, python -m icgo.datasets
def io_cases() -> list[Case]:
    cases = []

    def add(name, args, **kw):
        cases.append(Case(f"io/{name}", "icgo.io", _mod("icgo.io") + args, **kw))

    hdr = "station,gx,gy,gz,bx,by,bz,azimuth_deg,inclination_deg\n"
    row = "0,0.1,0.2,0.97,20000,1000,40000,10,12\n"
    meta = write("c.meta.json", "{}")
    csvs = {
        "empty": "", "blank-lines": "\n\n\n", "header-only": hdr, "nan": hdr + row.replace("20000", "nan"),
        "inf": hdr + row.replace("20000", "inf"), "text-cell": hdr + row.replace("20000", "abc"),
        "uT": hdr + row.replace("20000,1000,40000", "20,1,40"), "gauss": hdr + row.replace("20000,1000,40000",
                                                                                           "0.2,0.01,0.4"),
        "dup-column": hdr.replace("bz", "bx") + row, "missing-column": hdr.replace(",bz", "") + row.replace(
            ",40000", ""), "short-row": hdr + "0,1,2\n", "long-row": hdr + row.strip() + ",9,9\n",
        "nul": hdr + row.replace("0.1", "0\x001"), "quote": hdr + '"0,0.1' + row[3:],
        "station-float": hdr + row.replace("0,0.1", "0.5,0.1", 1), "station-huge": hdr + "99999999999999999999"
        + row[1:], "inclination-200": hdr + row.replace(",12\n", ",200\n"), "azimuth-1e9": hdr + row.replace(
            ",10,", ",1e9,"), "dup-station": hdr + row + row, "crlf": (hdr + row).replace("\n", "\r\n"),
        "bom": "\ufeff" + hdr + row, "long-line": hdr + "0," + "1" * 200_000 + ",0,1,2,3,4,5,6\n",
        "only-commas": ",,,,,,\n,,,\n", "negative-g": hdr + row.replace("0.97", "-50"),
    }
    valid = ("crlf", "bom", "dup-station")  # odd but within the contract: read
    for label, text in csvs.items():
        add(f"csv-{label}", ["check", "{w}/c.csv"], setup=steps(write("c.csv", text), meta), says=("c.csv",),
            expect="ok" if label in valid else "refuse")
    add("csv-binary", ["check", "{w}/c.csv"], setup=steps(write("c.csv", bytes(range(256)) * 8), meta),
        says=("c.csv",))
    for label, text in (("not-json", "{"), ("array", "[1]"), ("nan", '{"total_field_nT": NaN}'),
                        ("dip-200", '{"dip_deg": 200, "total_field_nT": 50000}'), ("deep", "[" * 100000),
                        ("empty", ""), ("string", '"x"'), ("date-bogus", '{"date": "yesterday", "latitude": 1, '
                                                                         '"longitude": 2}')):
        add(f"meta-{label}", ["check", "{w}/c.csv"], setup=steps(write("c.csv", hdr + row),
                                                                write("c.meta.json", text)), says=("c.meta.json",))
    for label, setup, says in (
            ("csv-fifo", fifo("c.csv"), "c.csv"), ("csv-dir", mkdir("c.csv"), "c.csv"),
            ("csv-dev-zero", symlink("/dev/zero", "c.csv"), "c.csv"), ("csv-missing", None, "c.csv"),
            ("csv-symlink-loop", symlink("c.csv", "c.csv"), "c.csv"),
            ("meta-fifo", steps(write("c.csv", hdr + row), fifo("c.meta.json")), "c.meta.json"),
            ("meta-dir", steps(write("c.csv", hdr + row), mkdir("c.meta.json")), "c.meta.json"),

            ("csv-huge", sparse("c.csv", hdr + row * 1000, 300 << 20), "c.csv")):
        add(label, ["check", "{w}/c.csv"], setup=setup, says=(says,), timeout=60.0 if "fifo" in label else 300.0,
            fast=label == "csv-fifo")
    # the checker takes the doors' options: no .meta.json is read as {} (as apply and calibrate read it) unless
    # require_meta=true; a field export's columns by columns.*= or columns_file=
    add("meta-missing", ["check", "{w}/c.csv"], setup=write("c.csv", hdr + row), expect="ok")
    add("meta-missing-required", ["check", "{w}/c.csv", "require_meta=true"], setup=write("c.csv", hdr + row),
        says=("c.meta.json",))
    export_hdr = "Survey #,Gx (g),Gy (g),Gz (g),Bx (nT),By (nT),Bz (nT),Azi,Inc\n"
    mapped = ["columns.station='Survey #'", "columns.azimuth_deg=Azi", "columns.inclination_deg=Inc"]
    add("export-mapped", ["check", "{w}/c.csv"] + mapped, setup=steps(write("c.csv", export_hdr + row), meta),
        expect="ok")
    add("export-unmapped", ["check", "{w}/c.csv"], setup=steps(write("c.csv", export_hdr + row), meta),
        says=("c.csv", "columns.station='Survey #'", "columns.inclination_deg=Inc"))
    add("export-columns-file", ["check", "{w}/c.csv", "columns_file={w}/map.json"],
        setup=steps(write("c.csv", export_hdr + row), meta, write("map.json", json.dumps(
            {"station": "Survey #", "azimuth_deg": "Azi", "inclination_deg": "Inc"}))), expect="ok")
    add("units-row-uT-on-nT", ["check", "{w}/c.csv"], setup=steps(write("c.csv", hdr + ",g,g,g,uT,uT,uT,deg,deg\n"
                                                                         + row), meta), says=("c.csv", "units row"))
    add("two-failures", ["check", "{w}/c.csv"], setup=steps(write("c.csv", hdr + row.replace("20000", "abc")
                                                                  + row.replace(",12\n", ",200\n")), meta),
        says=("c.csv",), check=lambda w, a, r: None if r.stderr.count("error:") == 2 else
        f"not both failures: {r.stderr[:300]}")
    add("bad-column-setting", ["check", "{w}/c.csv", "columns.bogus=x"], setup=steps(write("c.csv", hdr + row), meta),
        says=("columns.bogus",))
    jsons = {
        "not-json": "{", "empty": "", "array": "[1]", "null": "null", "number": "5", "deep": "[" * 100000,
        "no-layout": '{"a": 1}', "raw-nan": '{"mag": [[NaN, 1, 2]], "grav": [[0, 0, 1]]}',
        "raw-strings": '{"mag": [["a", 1, 2]], "grav": [[0, 0, 1]]}',
        "raw-empty-lists": '{"mag": [], "grav": []}', "raw-mag-dict": '{"mag": {"x": 1}, "grav": [[0, 0, 1]]}',
        "raw-bool": '{"mag": [[true, 1, 2]], "grav": [[0, 0, 1]]}',
        "raw-axes-bogus": '{"mag": [[20, 0, 40]], "grav": [[0, 0, 1]], "mag_axes": "bogus"}',
        "raw-axes-int": '{"mag": [[20, 0, 40]], "grav": [[0, 0, 1]], "mag_axes": 7}',
        "raw-huge-number": '{"mag": [[1e400, 0, 40]], "grav": [[0, 0, 1]]}',
        "fixture-shots-list": '{"shots": [1, 2]}', "fixture-mag-dict": '{"shots": {"mag": {"a": 1}, "grav": []}}',
        "fixture-short": '{"shots": {"mag": [1, 2, 3], "grav": [0, 0, 1]}}',
        "fixture-strings": '{"shots": {"mag": ["x", "y", "z"], "grav": [0, 0, 1]}}',
        "binary": bytes(range(256)) * 4,
    }
    for label, text in jsons.items():
        add(f"json-{label}", ["check", "{w}/j.json"], setup=write("j.json", text), says=("j.json",),
            fast=label in ("not-json", "deep"))
    for label, setup, says in (("json-fifo", fifo("j.json"), "j.json"), ("json-dir", mkdir("j.json"), "j.json"),
                               ("json-dev-zero", symlink("/dev/zero", "j.json"), "j.json"),
                               ("json-huge", write("j.json", lambda w, a: '{"mag": [' + ",".join(
                                   ["[20, 0, 40]"] * 600_000) + '], "grav": []}'), "j.json"),
                               ("json-missing", None, "j.json")):
        add(label, ["check", "{w}/j.json"], setup=setup, says=(says,), timeout=60.0, fast=label == "json-fifo")
    add("check-ok", ["check", "{a}/survey.csv", "{a}/fixture.json", "{a}/raw.json"], expect="ok", fast=True)
    add("no-args", [], says=("io",))
    add("bogus-command", ["bogus", "x"], says=("bogus",))
    add("check-no-files", ["check"], says=("files",))
    # export-mag-cal
    for label, out, setup, says in (("out-file", "{w}/f", write("f", "x"), "f"),
                                    ("out-under-file", "{w}/f/x", write("f", "x"), "f"),
                                    ("out-dev-null", "/dev/null", None, "/dev/null"),
                                    ("out-used", "{w}/o", steps(write("o/mine.txt", "x\n"), remember("o")), "o")):
        add(f"export-{label}", ["export-mag-cal", out], setup=setup, says=(says,),
            check=unchanged("o") if label == "out-used" else None, fast=label == "out-used")
    add("export-ok", ["export-mag-cal", "{w}/o"], expect="ok",
        check=lambda w, a, r: None if len(list((w / "o").glob("*.csv"))) == 9 else "not 9 CSVs")
    add("export-full-disk", ["export-mag-cal", "{w}/o"], fsize=2048, says=("o",),
        check=absent_or_complete("o", tuple(f"mag_cal_{n}.csv" for n in ("ab", "ai", "ar", "gc", "gk", "jd", "jn",
                                                                            "pc", "pd"))))
    add("export-read-only", ["export-mag-cal", "{w}/ro/o"], says=("o",), needs="mount")
    add("export-overwrite", ["export-mag-cal", "{w}/o", "--overwrite"], expect="ok",
        setup=lambda w, a: subprocess.run([PY, "-m", "icgo.io", "export-mag-cal", str(w / "o")], cwd=w, env=_env(),
                                          capture_output=True, timeout=120))
    return cases


def datasets_cases() -> list[Case]:
    cases = []

    def add(name, args, **kw):
        cases.append(Case(f"datasets/{name}", "icgo.datasets", _mod("icgo.datasets") + args, **kw))

    add("bogus-name", ["bogus", "--out", "{w}/o"], says=("bogus",), check=absent("o"))
    add("no-out", ["lab_casing"], says=("out",))
    for v in ("-1", "abc", "1e3", str(2**70)):
        add(f"seed={v}", ["lab_casing", "--out", "{w}/o", "--seed", v], says=("seed",), check=absent("o"),
            fast=v == "-1")
    for label, out, setup, says in (("out-file", "{w}/f", write("f", "x"), "out"),
                                    ("out-under-file", "{w}/f/x", write("f", "x"), "out"),
                                    ("out-dev-null", "/dev/null", None, "out"),
                                    ("out-proc", "/proc/x", None, "out")):
        add(label, ["lab_casing", "--out", out], setup=setup, says=(says,))
    add("out-holds-other-files", ["lab_casing", "--out", "{w}/o"], setup=write("o/mine.csv", "x\n"), expect="ok",
        check=lambda w, a, r: None if (w / "o" / "mine.csv").read_text() == "x\n" and (w / "o" / "lab_casing.csv")
        .exists() else "the other file changed, or the data set is missing")
    add("two-data-sets-one-folder", ["turntable", "--out", "{w}/o"], expect="ok",
        setup=lambda w, a: subprocess.run([PY, "-m", "icgo.datasets", "lab_casing", "--out", str(w / "o")], cwd=w,
                                          env=_env(), capture_output=True, timeout=120),
        check=lambda w, a, r: None if all((w / "o" / f"{n}.csv").exists() for n in ("lab_casing", "turntable"))
        else "one data set is missing")
    add("ok", ["well_conditions", "--out", "{w}/o", "--seed", "1"], expect="ok")
    add("full-disk", ["lab_casing", "--out", "{w}/o"], fsize=FULL_DISK_BYTES, says=("o",),
        check=absent_or_complete("o", ("lab_casing.csv", "lab_casing.meta.json", "lab_casing.truth.json")),
        fast=True)
    add("read-only", ["lab_casing", "--out", "{w}/ro/o"], says=("o",), needs="mount")
    add("second-into-same-out", ["lab_casing", "--out", "{w}/o"], says=("out",),
        setup=steps(lambda w, a: subprocess.run([PY, "-m", "icgo.datasets", "lab_casing", "--out", str(w / "o")],
                                                cwd=w, env=_env(), capture_output=True, timeout=120), remember("o")),
        check=unchanged("o"))
    add("ctrl-c", ["turntable", "--out", "{w}/o"], expect="interrupt", signal_after=(signal.SIGINT, 1.2),
        check=absent_or_complete("o", ("turntable.csv", "turntable.meta.json", "turntable.truth.json")))
    return cases


#: Cases run again through the ``icgo`` console script (``icgo <command> ARGS`` for ``python -m <module> ARGS``):
#: the fast subset, a success, an interruption, a kill, a full disk, a used output directory and a resumed sweep of
#: every door (three of them in the fast subset).
CONSOLE = re.compile(r"/(ok|ok-fixture|ctrl-c|sigkill|full-disk|out-full-disk|used-run-dir|out-used|same-again)$")


def console_cases(cases) -> list[Case]:
    """The cases of :data:`CONSOLE` (and the fast subset) of every door the ``icgo`` script runs, through it: the
    same argv after the command, the same expected verdict (door ``icgo``, names ``icgo/<case>``)."""
    sys.path.insert(0, str(ROOT))
    from experiments.cli import COMMANDS

    command = {module: name for name, (module, _) in COMMANDS.items()}
    return [dataclasses.replace(c, name=f"icgo/{c.name}", door="icgo",
                                argv=["{a}/bin/icgo", command[c.argv[1]], *c.argv[2:]])
            for c in cases if c.argv[:1] == ["-m"] and c.argv[1] in command
            and (CONSOLE.search(c.name) or c.name in FAST_CASES)]


#: The fast subset (``make test``): at least one case of every front door, each a few seconds.
FAST_CASES = (
    "model/relm_compensation/array-nan", "model/run/escape-dotdot", "apply/require_meta=maybe",
    "apply/out-full-disk", "apply/ctrl-c", "run/model.lam=1e300", "calibrate/json-fifo",
    "calibrate/raw-mag_axes=+x+x+z", "calibrate/used-run-dir", "discrepancy/data=mag_cal:../ok",
    "misma/real.enabled=maybe", "gyro/seed=abc", "figures/override-bogus", "generalisation/--n-repeats 0",
    "optimizers/--dims 0", "io/csv-fifo", "datasets/full-disk", "calibrate/json-fixture-1e300",
    "apply/reference-in-radians", "apply/model-of-another-device", "datasets/two-data-sets-one-folder",
    "calibration_unseen/--variants 0", "icgo/calibrate/used-run-dir", "icgo/apply/ctrl-c", "icgo/io/csv-fifo")


def all_cases() -> list[Case]:
    cases = (model_cases() + apply_cases() + run_cases() + calibrate_cases() + discrepancy_cases()
             + study_setting_cases() + argparse_cases() + io_cases() + datasets_cases())
    cases += console_cases(cases)
    names = [c.name for c in cases]
    dup = {n for n in names if names.count(n) > 1}
    assert not dup, f"duplicate case names {sorted(dup)[:5]}"
    missing = set(FAST_CASES) - set(names)
    assert not missing, f"FAST_CASES names no case {sorted(missing)}"
    for c in cases:
        c.fast = c.name in FAST_CASES
    return cases


# ============================================================ running a case
_NOISE = re.compile(r"xla_bridge|libtpu|^\s*warnings\.warn|^\[\d{4}-\d\d-\d\d [\d:,]+\]\[(HYDRA|__main__|icgo)")


#: The checkout under test (``--root``); setups that run a command first use it too.
CURRENT = {"root": ROOT}


def _env(root: Path | None = None) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("HYDRA_", "PYTEST", "ICGO_SCRIPT"))}
    env["PYTHONPATH"] = str(root or CURRENT["root"])
    env["JAX_PLATFORMS"] = "cpu"
    env["HYDRA_FULL_ERROR"] = "0"
    return env


@dataclasses.dataclass
class _Ran:
    rc: int | None
    stdout: str
    stderr: str
    timed_out: bool
    peak_mb: float
    capped: bool
    outcome_hint: str = ""


def _rss_mb(pgid: int) -> float:
    total = 0
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            if os.getpgid(int(d)) != pgid:
                continue
            with open(f"/proc/{d}/status") as fh:
                for line in fh:
                    if line.startswith("VmRSS:"):
                        total += int(line.split()[1])
        except (OSError, ProcessLookupError):
            continue
    return total / 1024


def _execute(case: Case, w: Path, a: Path, root: Path) -> _Ran:
    argv = [PY] + [str(x).replace("{w}", str(w)).replace("{a}", str(a)) for x in case.argv]

    import threading

    t0 = time.monotonic()
    # pipes, not files: a full-disk case's file-size limit must not cut the command's own messages
    p = subprocess.Popen(argv, cwd=w, env=_env(root), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         stdin=subprocess.DEVNULL, start_new_session=True)
    got = {"out": [], "err": []}
    readers = [threading.Thread(target=lambda f=f, k=k: got[k].append(f.read()), daemon=True)
               for f, k in ((p.stdout, "out"), (p.stderr, "err"))]
    for t in readers:
        t.start()
    if case.fsize is not None:  # set on the new process (no preexec_fn: no Python code between fork and exec)
        import resource

        resource.prlimit(p.pid, resource.RLIMIT_FSIZE, (case.fsize, case.fsize))
    peak, capped, timed_out, sent = 0.0, False, False, False
    while p.poll() is None:
        time.sleep(0.1)
        rss = _rss_mb(p.pid)
        peak = max(peak, rss)
        if rss > RSS_CAP_MB:
            capped = True
            os.killpg(p.pid, signal.SIGKILL)
            break
        if case.signal_after and not sent:
            sig, when = case.signal_after
            if (isinstance(when, (int, float)) and time.monotonic() - t0 > when) or (
                    isinstance(when, str) and (w / when).exists()):
                os.kill(p.pid, sig)
                sent = True
        if time.monotonic() - t0 > case.timeout:
            timed_out = True
            os.killpg(p.pid, signal.SIGKILL)
            break
    p.wait()
    with _suppress():
        os.killpg(p.pid, signal.SIGKILL)  # anything the command left running
    for t in readers:
        t.join(timeout=10)
    text = {k: b"".join(v).decode(errors="replace") for k, v in got.items()}
    return _Ran(p.returncode, text["out"], text["err"], timed_out, peak, capped,
                "killed" if case.signal_after and case.signal_after[0] == signal.SIGKILL else "")


class _suppress:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return exc[0] is not None and issubclass(exc[0], (OSError, ProcessLookupError))


def classify(case: Case, ran: _Ran) -> tuple[str, str]:
    """(outcome, detail) of a finished case (see the module docstring)."""
    err = ran.stderr
    lines = [x for x in err.splitlines() if x.strip() and not _NOISE.search(x)]
    if ran.capped:
        return "oom", f"passed {RSS_CAP_MB} MB"
    if ran.timed_out:
        return "hang", f"no end within {case.timeout:.0f} s"
    if "Traceback (most recent call last)" in err or "Traceback (most recent call last)" in ran.stdout:
        tail = [x for x in err.splitlines() if x.strip()][-1:] or ["?"]
        return "traceback", tail[0][:200]
    if case.expect == "killed":
        return ("clean", "") if ran.rc in (0, -signal.SIGKILL) else ("traceback", f"rc {ran.rc} after SIGKILL")
    if ran.rc is not None and ran.rc < 0:
        return "traceback", f"killed by signal {-ran.rc}"
    if case.expect == "outside":  # apply far outside the training domain: its files, the verdict, exit status 3
        return ("clean", "") if ran.rc == 3 else ("unclear", f"rc {ran.rc} (expected 3): {(lines or ['?'])[-1][:160]}")
    if case.expect == "norecommend":  # calibrate: its report and calibrations, one 'error:' line, exit status 4
        if ran.rc != 4:
            return "unclear", f"rc {ran.rc} (expected 4): {(lines or ['?'])[-1][:160]}"
        errs = [x for x in lines if x.startswith("error:")]
        if len(errs) != 1 or not all(x.lower() in errs[0].lower() for x in case.says):
            return "unclear", f"not one 'error:' line naming {list(case.says)}: {' | '.join(lines)[:200]}"
        return "clean", ""
    if ran.rc not in (0, 1, 2, 130):
        return "traceback", f"exit status {ran.rc}: {(lines or ['?'])[-1][:160]}"
    if case.expect == "interrupt":
        if ran.rc == 0:
            return "clean", "finished before the signal"
        if ran.rc != 130 or len(lines) != 1 or "interrupt" not in lines[0].lower():
            return "unclear", f"rc {ran.rc}, {len(lines)} line(s): {' | '.join(lines)[:200]}"
        return "clean", ""
    if case.expect in ("ok", "either"):
        if ran.rc == 0 or case.expect == "either":
            return "clean", ""
        return "unclear", f"refused a valid input: {(lines or ['?'])[0][:200]}"
    if ran.rc == 0:
        return "silent", (ran.stdout.strip().splitlines() or [""])[-1][:200]
    errs = [x for x in lines if x.startswith("error:")] if not case.report else lines
    if not errs or len(errs) != len(lines):
        return "unclear", f"{len(lines)} line(s), not all 'error: ...': {' | '.join(lines)[:240]}"
    text = " ".join(errs).lower()
    missing = [s for s in case.says if s.lower() not in text]
    if missing:
        return "unclear", f"does not name {missing}: {errs[0][:200]}"
    return "clean", ""


def run_case(case: Case, assets: Path, work: Path, root: Path = ROOT) -> Result:
    """Set up, run, check and classify one case in its own folder under ``work``."""
    # no '=' (a path in an override must not hold one); the hash keeps "+bogus=1" and "bogus=1" apart
    w = work / (re.sub(r"[^A-Za-z0-9_.-]+", "_", case.name) + "-" + hashlib.sha1(case.name.encode()).hexdigest()[:6])
    if w.exists():
        shutil.rmtree(w, ignore_errors=True)
    w.mkdir(parents=True)
    if case.needs == "mount":
        if not _mount_read_only(w / "ro"):
            return Result(case.name, case.door, "skipped", "no read-only mount (needs root)", None, 0.0, 0.0)
    t0 = time.monotonic()
    try:
        if case.setup is not None:
            case.setup(w, assets)
        ran = _execute(case, w, assets, root)
        outcome, detail = classify(case, ran)
        if outcome == "clean" and case.check is not None:
            problem = case.check(w, assets, ran)
            if problem:
                outcome, detail = "mixed", problem
    finally:
        if case.needs == "mount":
            subprocess.run(["umount", "-l", str(w / "ro")], capture_output=True)
    return Result(case.name, case.door, outcome, detail, ran.rc, time.monotonic() - t0, ran.peak_mb)


def _mount_read_only(p: Path) -> bool:
    p.mkdir(parents=True, exist_ok=True)
    if os.geteuid() != 0 or not shutil.which("mount"):
        return False
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=64k", "tmpfs", str(p)], capture_output=True)
    return r.returncode == 0


def make_assets(base: Path) -> Path:
    """The assets under ``base`` (built once, in a fresh interpreter: the runner itself never loads JAX, so
    starting the cases' processes never forks a multithreaded runtime)."""
    a = base / "assets"
    if not (a / "ready").exists():
        shutil.rmtree(a, ignore_errors=True)
        base.mkdir(parents=True, exist_ok=True)
        subprocess.run([PY, __file__, "--build-assets", str(a)], check=True, env=_env(ROOT), cwd=base)
    return a


def run_battery(cases, base: Path, root: Path = ROOT, jobs: int = 1, progress=print) -> list[Result]:
    """Run ``cases`` (``jobs`` at a time) with assets and work folders under ``base``."""
    from concurrent.futures import ThreadPoolExecutor

    assets = make_assets(base)
    CURRENT["root"] = root
    work = base / "work"
    results = []
    with ThreadPoolExecutor(jobs) as ex:
        for r in ex.map(lambda c: run_case(c, assets, work, root), cases):
            results.append(r)
            if progress:
                progress(f"{r.outcome:<9} {r.seconds:6.1f} s {r.peak_mb:6.0f} MB  {r.case}"
                         + (f"  -- {r.detail}" if r.detail and r.outcome != "clean" else ""))
    return results


def counts(results) -> dict:
    c = {o: 0 for o in OUTCOMES + ("skipped",)}
    for r in results:
        c[r.outcome] += 1
    return c


def main(argv=None) -> int:
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--fast", action="store_true", help="only the fast subset")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--root", default=str(ROOT), help="checkout of icgo to run (default: this one)")
    ap.add_argument("--base", default=None, help="folder for assets and work (default: a new temporary folder)")
    ap.add_argument("--only", default=None, help="regular expression: run the matching cases")
    ap.add_argument("--json", default=None, help="write every result here")
    ap.add_argument("--build-assets", default=None, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.build_assets:
        build_assets(Path(a.build_assets))
        return 0
    cases = [c for c in all_cases() if (c.fast or not a.fast) and (a.only is None or re.search(a.only, c.name))]
    base = Path(a.base) if a.base else Path(tempfile.mkdtemp(prefix="icgo-hostile-"))
    print(f"{len(cases)} cases; work in {base}", flush=True)
    t0 = time.monotonic()
    res = run_battery(cases, base, Path(a.root), a.jobs, progress=lambda s: print(s, flush=True))
    c = counts(res)
    print(f"\n{len(res)} invocations in {time.monotonic() - t0:.0f} s: " + ", ".join(f"{n} {o}" for o, n in c.items()))
    by_door: dict = {}
    for r in res:
        by_door.setdefault(r.door, {o: 0 for o in OUTCOMES + ("skipped",)})[r.outcome] += 1
    print("\n| front door | cases | " + " | ".join(OUTCOMES) + " |\n|---|---:|" + "---:|" * len(OUTCOMES))
    for door, cc in sorted(by_door.items()):
        print(f"| {door} | {sum(cc.values())} | " + " | ".join(str(cc[o]) for o in OUTCOMES) + " |")
    if a.json:
        Path(a.json).write_text(json.dumps([dataclasses.asdict(r) for r in res], indent=1))
    return 0 if c["clean"] + c["skipped"] == len(res) else 1


if __name__ == "__main__":
    sys.exit(main())
