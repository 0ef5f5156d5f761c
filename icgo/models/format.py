"""Fitted models as artifacts: one header format, one file format, one registry.

Every method in icgo hands back what it fitted as a :class:`FittedModel`: a
frozen dataclass whose array fields are the fitted parameters and whose other
fields are plain JSON values (settings, labels). Subclasses implement
``apply(frame) -> DataFrame`` on a data-contract frame (columns ``gx, gy, gz``
in g, ``bx, by, bz`` in nT, ...) and register themselves with
:func:`register_model` under a ``KIND`` name.

File format (open, readable without icgo): ``<stem>.npz`` holds the arrays
(float64/int, exact), ``<stem>.json`` the header::

    {"schema_version": 1, "package_version": "0.1.0", "kind": "relm_compensation",
     "units": {...}, "fields": {...JSON fields...}, "arrays": "<stem>.npz",
     "array_names": [...]}

The JSON file is written last (both atomically, temp file + rename), so a
header on disk always names a complete array file. ``save -> load -> apply``
is bitwise ``apply`` (tested): arrays are stored exactly and ``apply`` is
deterministic.

Errors (a file that is not a model, a newer schema, a frame lacking the
columns a model needs) are :class:`ModelError`, one line naming the file or
the columns.
"""

from __future__ import annotations

import abc
import dataclasses
import hashlib
import json
import os
import tempfile
from pathlib import Path
from typing import ClassVar

import numpy as np
import pandas as pd

from icgo.core.errors import ModelError

#: Version of the header/array layout written by :meth:`FittedModel.save`.
SCHEMA_VERSION = 1

#: Output columns of a model that corrects the field itself (nT); survey QC after the model checks them.
CORRECTED_B = ("bx_corrected", "by_corrected", "bz_corrected")




def data_hash(*arrays) -> str:
    """SHA-256 (hex, first 16 characters) of arrays' float64 bytes and shapes: the training data's identity."""
    h = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(np.asarray(a, dtype=np.float64))
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()[:16]


def sensor_domain(G, B) -> dict:
    """Training-domain ranges of a set of shots: inclination, toolface-free quantities and field.

    Args:
        G: (N, 3) gravity, g. B: (N, 3) field, nT.
    Returns:
        ``{"inclination_deg": [lo, hi], "g_norm_g": [...], "b_norm_nT": [...], "dip_deg": [...]}``,
        plain floats (JSON).
    """
    from icgo.physics.qc import measured_dip_deg

    G = np.asarray(G, float)
    B = np.asarray(B, float)
    gn = np.linalg.norm(G, axis=1)
    bn = np.linalg.norm(B, axis=1)
    inc = np.degrees(np.arctan2(np.hypot(G[:, 0], G[:, 1]), G[:, 2]))
    dip = measured_dip_deg(G, B)

    def rng(x):
        return [float(np.min(x)), float(np.max(x))]

    return {"inclination_deg": rng(inc), "g_norm_g": rng(gn), "b_norm_nT": rng(bn), "dip_deg": rng(dip)}


def require_columns(frame: pd.DataFrame, columns, what: str) -> None:
    """ModelError naming the missing columns (and the model that needs them), else nothing."""
    if not isinstance(frame, pd.DataFrame):
        raise ModelError(f"{what}: expected a data-contract DataFrame, got {type(frame).__name__}")
    missing = [c for c in columns if c not in frame.columns]
    if missing:
        raise ModelError(f"{what} needs column(s) {missing}, which the survey lacks "
                         f"(it has {list(frame.columns)})")


def frame_values(frame: pd.DataFrame, columns, what: str) -> np.ndarray:
    """(N, len(columns)) float64 values of ``columns``, checked present and finite (one-line ModelError)."""
    require_columns(frame, columns, what)
    try:
        v = frame[list(columns)].to_numpy(dtype=np.float64)
    except (TypeError, ValueError):
        raise ModelError(f"{what}: non-numeric value in columns {list(columns)}") from None
    bad = np.argwhere(~np.isfinite(v))
    if bad.size:
        r, c = bad[0]
        raise ModelError(f"{what}: NaN/inf in row {r}, column {list(columns)[c]!r}")
    return v


def _atomic_write(path: Path, write) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


@dataclasses.dataclass(frozen=True, eq=False)
class FittedModel(abc.ABC):
    """Base of every fitted model (abstract: a subclass implements :meth:`apply`).

    Attributes:
        config: the settings the fit used (JSON-able dict).
        data_hash: :func:`data_hash` of the training data.
        domain: training-domain ranges (:func:`sensor_domain` plus method-specific ones).

    Subclasses add their parameters as ``np.ndarray`` fields (saved to the
    ``.npz``) and labels as JSON fields, set ``KIND`` and ``UNITS`` and
    implement :meth:`apply`.
    """

    KIND: ClassVar[str] = ""
    UNITS: ClassVar[dict] = {}

    config: dict
    data_hash: str
    domain: dict

    @abc.abstractmethod
    def apply(self, frame: pd.DataFrame) -> pd.DataFrame:
        """Corrected values and/or attitude per row of a data-contract frame."""

    # ---------------------------------------------------------------- files
    def _split_fields(self) -> tuple[dict, dict]:
        arrays, plain = {}, {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if isinstance(v, np.ndarray):
                arrays[f.name] = v
            else:
                plain[f.name] = v
        return arrays, plain

    def header(self) -> dict:
        """The JSON header (without the array file name)."""
        from icgo import __version__

        arrays, plain = self._split_fields()
        return {"schema_version": SCHEMA_VERSION, "package_version": __version__, "kind": self.KIND,
                "units": dict(self.UNITS), "fields": plain, "array_names": sorted(arrays)}

    def save(self, path) -> Path:
        """Write ``<stem>.npz`` then ``<stem>.json`` (atomic each); return the JSON path.

        Args:
            path: target path; its suffix (if any) is replaced.
        """
        stem = Path(path)
        if stem.suffix in (".json", ".npz"):
            stem = stem.with_suffix("")
        stem.parent.mkdir(parents=True, exist_ok=True)
        arrays, _ = self._split_fields()
        npz, js = stem.with_name(stem.name + ".npz"), stem.with_name(stem.name + ".json")

        def write_npz(tmp):
            with open(tmp, "wb") as fh:
                np.savez(fh, **arrays)

        _atomic_write(npz, write_npz)
        head = {**self.header(), "arrays": npz.name}
        _atomic_write(js, lambda tmp: Path(tmp).write_text(json.dumps(head, indent=2, default=_json_default) + "\n"))
        return js


def _json_default(v):
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (np.floating,)):
        return float(v)
    if isinstance(v, np.bool_):
        return bool(v)
    if isinstance(v, np.ndarray) and v.ndim <= 1 and v.size <= 64:
        return v.tolist()
    if isinstance(v, (tuple, set)):
        return list(v)
    raise TypeError(f"not JSON-serialisable: {type(v).__name__}")


def model_files(path) -> list[Path]:
    """The model header files (``*.json`` with a model header) at ``path`` (a file or a run directory)."""
    p = Path(path)
    if p.is_dir():
        return sorted(q for q in p.glob("*.json") if _is_model_header(q))
    if p.suffix == ".npz":
        p = p.with_suffix(".json")
    return [p]


def _is_model_header(p: Path) -> bool:
    try:
        head = json.loads(p.read_text())
    except (OSError, ValueError, RecursionError):
        return False
    return isinstance(head, dict) and "schema_version" in head and "kind" in head and "arrays" in head


def read_model(path, kinds: dict) -> FittedModel:
    """Load a model saved by :meth:`FittedModel.save`.

    Args:
        path: the ``.json`` header, the ``.npz``, the stem, or a run directory
            holding exactly one model.
        kinds: KIND -> model class (:data:`icgo.models.registry.MODEL_KINDS`).
    Raises:
        ModelError: one line: not found, not a model, newer schema, unknown kind,
            missing arrays, several models in a directory.
    """
    p = Path(path)
    if p.is_dir():
        found = model_files(p)
        if not found:
            raise ModelError(f"{p}: no saved model (*.json model header) in this directory")
        if len(found) > 1:
            raise ModelError(f"{p}: {len(found)} models in this directory ({', '.join(q.name for q in found)}); "
                             f"name one file")
        p = found[0]
    elif p.suffix != ".json":
        p = p.with_suffix(".json") if p.suffix == ".npz" else p.with_name(p.name + ".json")
    if not p.is_file():
        raise ModelError(f"{p}: model file not found")
    try:
        head = json.loads(p.read_text())
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as e:
        raise ModelError(f"{p}: not a model file (not a JSON header: {type(e).__name__})") from None
    if not isinstance(head, dict) or not {"schema_version", "kind", "arrays", "fields"} <= set(head):
        raise ModelError(f"{p}: not a model file (no schema_version/kind/arrays/fields header)")
    ver = head["schema_version"]
    if not isinstance(ver, int) or isinstance(ver, bool) or ver < 1:
        raise ModelError(f"{p}: not a model file (schema_version {ver!r})")
    if ver > SCHEMA_VERSION:
        raise ModelError(f"{p}: written by model schema version {ver}, newer than this icgo's {SCHEMA_VERSION} "
                         f"(package {head.get('package_version', '?')}); upgrade icgo")
    cls = kinds.get(head["kind"]) if isinstance(head["kind"], str) else None
    if cls is None:
        raise ModelError(f"{p}: unknown model kind {head['kind']!r}; known: {sorted(kinds)}")
    npz = p.with_name(str(head["arrays"]))
    try:
        with np.load(npz, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError) as e:
        raise ModelError(f"{npz}: model arrays unreadable ({type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''})") from None
    names = {f.name for f in dataclasses.fields(cls)}
    fields = dict(head["fields"])
    missing = [n for n in names if n not in fields and n not in arrays]
    if missing:
        raise ModelError(f"{p}: model of kind {head['kind']!r} lacks {sorted(missing)}")
    kwargs = {n: (arrays[n] if n in arrays else fields[n]) for n in names}
    return cls(**kwargs)


#: Overshoots of the training range smaller than these are not reported (units of each quantity):
#: about the sensor noise of a new draw of the same stations, and the QC bands of icgo.physics.qc.
DOMAIN_TOLERANCE = {"inclination_deg": 0.5, "azimuth_deg": 1.0, "dip_deg": 0.25, "b_norm_nT": 300.0,
                    "g_norm_g": 0.0025}


def domain_overshoots(trained: dict, survey: dict, margin: float = 0.05) -> dict[str, dict]:
    """Quantities whose survey range leaves the training range by more than noise, and by how much.

    Args:
        trained: the model's ``domain`` (name -> [low, high]). survey: the same quantities of the survey.
        margin: overshoots up to this fraction of the training range's width, or up to
            :data:`DOMAIN_TOLERANCE` of the quantity, are not counted (a new draw of the same stations
            differs by noise alone).
    Returns:
        ``{name: {"below": ..., "above": ...}}`` (units of the quantity, >= 0); quantities missing from either
        side are not compared.
    """
    out = {}
    for name, (lo, hi) in survey.items():
        if name not in trained:
            continue
        tlo, thi = (float(x) for x in trained[name])
        below, above = max(tlo - lo, 0.0), max(hi - thi, 0.0)
        if max(below, above) > max(margin * (thi - tlo), DOMAIN_TOLERANCE.get(name, 0.0)):
            out[name] = {"below": below, "above": above}
    return out


def domain_notices(trained: dict, survey: dict, margin: float = 0.05) -> list[str]:
    """One line per quantity whose survey range leaves the training range, saying how far.

    Args:
        trained: the model's ``domain`` (name -> [low, high]).
        survey: the same quantities of the survey (e.g. :func:`sensor_domain`).
        margin: overshoots up to this fraction of the training range's width, or up to
            :data:`DOMAIN_TOLERANCE` of the quantity, are not reported (a new draw of the
            same stations differs by noise alone).
    Returns:
        Lines such as ``"inclination_deg: survey 2 to 95, trained on 10 to 90 (5 below, 5 above)"``;
        quantities missing from either side are not compared.
    """
    lines = []
    for name, o in domain_overshoots(trained, survey, margin).items():
        (lo, hi), (tlo, thi) = survey[name], (float(x) for x in trained[name])
        lines.append(f"{name}: survey {lo:.6g} to {hi:.6g}, trained on {tlo:.6g} to {thi:.6g} "
                     f"({o['below']:.4g} below, {o['above']:.4g} above the training range)")
    return lines
