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
import zipfile
import zlib
from pathlib import Path
from typing import ClassVar

import numpy as np
import pandas as pd

from icgo.core.errors import DataError, ModelError
from icgo.io.files import read_text_bounded

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
    #: Arrays that may legitimately be empty (e.g. the parameters of a model with no effect).
    MAY_BE_EMPTY: ClassVar[tuple] = ()
    #: Arrays that may hold NaN (e.g. an interval no row could calibrate).
    NAN_OK: ClassVar[tuple] = ()

    config: dict
    data_hash: str
    domain: dict

    @abc.abstractmethod
    def apply(self, frame: pd.DataFrame) -> pd.DataFrame:
        """Corrected values and/or attitude per row of a data-contract frame."""

    def validate(self) -> None:
        """The kind's own consistency checks of a loaded model (shapes that agree, scales > 0, names it
        knows); a :class:`ModelError` line each. :func:`read_model` has already checked every field's type,
        every array (numeric, finite, bounded) and the domain. The base has nothing more to check."""

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
                "units": dict(self.UNITS), "fields": plain, "array_names": sorted(arrays),
                "array_shapes": {k: list(np.shape(v)) for k, v in sorted(arrays.items())}}

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
        return sorted(q for q in p.glob("*.json") if q.is_file() and _is_model_header(q))
    if p.suffix == ".npz":
        p = p.with_suffix(".json")
    return [p]


def _is_model_header(p: Path) -> bool:
    try:
        head = json.loads(read_text_bounded(p, MAX_HEADER_BYTES, "a model header"))
    except (DataError, ValueError, RecursionError):
        return False
    return isinstance(head, dict) and "schema_version" in head and "kind" in head and "arrays" in head


# ------------------------------------------------------------------ reading a model, checked
#: Largest model header (.json) read, bytes.
MAX_HEADER_BYTES = 4 << 20
#: Largest array of a model, bytes (declared in the .npy header; checked before it is read).
MAX_ARRAY_BYTES = 64 << 20
#: Largest total of a model's arrays, bytes.
MAX_ARRAYS_BYTES = 256 << 20
#: Largest magnitude of a fitted parameter: beyond it a parameter is not a fit (1e300 overflows every
#: product to inf); the largest fitted values are fields in nT (~1e5) and RELM output weights (~1e4).
MAX_PARAMETER = 1e12
#: Array dtypes a model may hold: float, signed and unsigned integers, bool.
ARRAY_KINDS = "fiub"


def _local_name(name, where: str, what: str) -> str:
    """A file name inside the model's (or run's) own directory: no directory part, no ``..``."""
    if not isinstance(name, str) or not name or name in (".", "..") or "/" in name or "\\" in name \
            or "\x00" in name or Path(name).is_absolute():
        raise ModelError(f"{where}: {what} must be a file name in the same directory, got {str(name)[:80]!r}")
    return name


def run_model_path(run_dir) -> Path:
    """The main model of a run directory: the first of its ``run.json``'s ``models``, which must name a
    file in that directory (no path, no ``..``, no symbolic link out of it)."""
    run_dir = Path(run_dir)
    rec = run_dir / "run.json"
    try:
        run = json.loads(read_text_bounded(rec, MAX_HEADER_BYTES, "a run record (run.json)"))
    except DataError as e:
        raise ModelError(str(e)) from None
    except (ValueError, RecursionError) as e:
        raise ModelError(f"{rec}: not a run record (invalid JSON: {type(e).__name__})") from None
    models = run.get("models") if isinstance(run, dict) else None
    if not isinstance(models, list) or not models:
        raise ModelError(f"{rec}: 'models' must be a non-empty list of the run's model files")
    name = _local_name(models[0], str(rec), "models[0]")
    path = run_dir / name
    try:
        inside = path.resolve().parent == run_dir.resolve()
    except (OSError, RuntimeError):
        inside = False
    if not inside:
        raise ModelError(f"{rec}: models[0] {name!r} leads out of the run directory (a symbolic link); refused")
    return path


def _resolve(path) -> Path:
    """The header path of ``path`` (a header, an .npz, a stem, a run directory or a directory with one model)."""
    p = Path(path)
    if p.is_dir():
        if (p / "run.json").exists() or (p / "run.json").is_symlink():  # a pipe or a directory there is refused
            return run_model_path(p)
        found = model_files(p)
        if not found:
            raise ModelError(f"{p}: a directory with no saved model (*.json model header); name a model file")
        if len(found) > 1:
            raise ModelError(f"{p}: {len(found)} models in this directory ({', '.join(q.name for q in found)}); "
                             f"name one file")
        return found[0]
    if p.suffix != ".json":
        p = p.with_suffix(".json") if p.suffix == ".npz" else p.with_name(p.name + ".json")
    return p


def _read_header(p: Path) -> dict:
    try:
        text = read_text_bounded(p, MAX_HEADER_BYTES, "a model header (.json)")
    except DataError as e:
        raise ModelError(str(e) if p.exists() or p.is_symlink() else f"{p}: model file not found") from None
    try:
        head = json.loads(text, parse_constant=lambda c: _raise(ModelError(f"{p}: {c} in the model header")))
    except (ValueError, RecursionError) as e:
        if isinstance(e, ModelError):
            raise
        raise ModelError(f"{p}: not a model file (not a JSON header: {type(e).__name__})") from None
    if not isinstance(head, dict) or not {"schema_version", "kind", "arrays", "fields"} <= set(head):
        raise ModelError(f"{p}: not a model file (no schema_version/kind/arrays/fields header)")
    ver = head["schema_version"]
    if not isinstance(ver, int) or isinstance(ver, bool) or ver < 1:
        raise ModelError(f"{p}: not a model file (schema_version {ver!r})")
    if ver > SCHEMA_VERSION:
        raise ModelError(f"{p}: written by model schema version {ver}, newer than this icgo's {SCHEMA_VERSION} "
                         f"(package {str(head.get('package_version', '?'))[:40]}); upgrade icgo")
    if not isinstance(head["fields"], dict):
        raise ModelError(f"{p}: 'fields' must be a JSON object, got {type(head['fields']).__name__}")
    shapes = head.get("array_shapes")
    if shapes is not None and not (isinstance(shapes, dict) and all(
            isinstance(v, list) and all(isinstance(d, int) and not isinstance(d, bool) and d >= 0 for d in v)
            for v in shapes.values())):
        raise ModelError(f"{p}: 'array_shapes' must map array names to lists of sizes")
    return head


def _raise(e):
    raise e


def _read_arrays(npz: Path, names: list[str], shapes: dict | None, where: str) -> dict:
    """The arrays ``names`` of a model's ``.npz``, each checked from its .npy header before it is read.

    Only the model's own members are opened; any other member of the archive (a huge one included)
    is never read. A member's dtype must be numeric (:data:`ARRAY_KINDS`), its size under
    :data:`MAX_ARRAY_BYTES` and consistent with the archive's size for it, its shape the header's.
    """
    if not npz.exists() and not npz.is_symlink():
        raise ModelError(f"{npz}: the model's array file is missing (named by {where})")
    try:
        st = npz.stat()
    except OSError as e:
        raise ModelError(f"{npz}: cannot read the model's arrays ({e.strerror})") from None
    import stat as _stat

    if not _stat.S_ISREG(st.st_mode):
        raise ModelError(f"{npz}: the model's array file is not a regular file")
    arrays, total = {}, 0
    try:
        with zipfile.ZipFile(npz) as z:
            members = {i.filename: i for i in z.infolist()}
            for name in names:
                info = members.get(f"{name}.npy")
                if info is None:
                    continue
                with z.open(info) as fh:
                    version = np.lib.format.read_magic(fh)
                    read_header = {(1, 0): np.lib.format.read_array_header_1_0,
                                   (2, 0): np.lib.format.read_array_header_2_0}.get(version)
                    if read_header is None:
                        raise ValueError(f"npy format version {version}")
                    shape, fortran, dtype = read_header(fh)
                    if dtype.kind not in ARRAY_KINDS or dtype.hasobject or dtype.fields is not None:
                        raise ModelError(f"{npz}: array {name!r} has dtype {dtype}; a model's arrays are real "
                                         f"numbers or integers")
                    count = int(np.prod(shape, dtype=object))
                    nbytes = count * dtype.itemsize
                    if nbytes > MAX_ARRAY_BYTES or total + nbytes > MAX_ARRAYS_BYTES:
                        raise ModelError(f"{npz}: array {name!r} declares shape {tuple(shape)} "
                                         f"({nbytes / 2**20:.0f} MiB), over the {MAX_ARRAY_BYTES >> 20} MiB limit of "
                                         f"a model array")
                    if info.file_size < nbytes:
                        raise ModelError(f"{npz}: array {name!r} declares shape {tuple(shape)} but holds only "
                                         f"{info.file_size} bytes (a truncated or edited file)")
                    if shapes is not None and name in shapes and list(shape) != list(shapes[name]):
                        raise ModelError(f"{npz}: array {name!r} has shape {tuple(shape)}, the header says "
                                         f"{tuple(shapes[name])}")
                    data = fh.read(nbytes)
                    if len(data) != nbytes:
                        raise ModelError(f"{npz}: array {name!r} is cut short (a truncated file)")
                    a = np.frombuffer(data, dtype=dtype).reshape(shape, order="F" if fortran else "C")
                    arrays[name] = a.astype(dtype.newbyteorder("="))  # a writable copy in native byte order
                    total += nbytes
    except ModelError:
        raise
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, OSError, ValueError, KeyError, TypeError,
            NotImplementedError, RuntimeError, zlib.error) as e:
        why = str(e).splitlines()[0][:100] if str(e) else ""
        raise ModelError(f"{npz}: model arrays unreadable ({type(e).__name__}{': ' + why if why else ''})") from None
    return arrays


def _field_types(cls) -> dict[str, tuple[str, ...]]:
    """Field name -> the type names of its annotation (``"np.ndarray | None"`` -> ``("np.ndarray", "None")``)."""
    return {f.name: tuple(t.strip() for t in str(f.type).split("|")) for f in dataclasses.fields(cls)}


def _plain_ok(v, types: tuple[str, ...]) -> bool:
    import math

    for t in types:
        if (t == "None" and v is None) or (t == "str" and isinstance(v, str)) \
                or (t == "bool" and isinstance(v, bool)) or (t == "list" and isinstance(v, list)) \
                or (t == "dict" and isinstance(v, dict)) \
                or (t == "int" and isinstance(v, int) and not isinstance(v, bool)) \
                or (t == "float" and isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)):
            return True
    return False


def need_shape(a, shape: tuple, name: str) -> None:
    """ModelError unless ``a`` has ``shape`` (None in ``shape`` matches any size)."""
    got = np.shape(a)
    if len(got) != len(shape) or any(w is not None and g != w for g, w in zip(got, shape)):
        want = "(" + ", ".join("n" if w is None else str(w) for w in shape) + ("," if len(shape) == 1 else "") + ")"
        raise ModelError(f"array {name!r} has shape {got}, expected {want}")


def need(cond: bool, message: str) -> None:
    """ModelError ``message`` unless ``cond`` (a kind's :meth:`FittedModel.validate`)."""
    if not cond:
        raise ModelError(message)


def check_domain(domain, where: str) -> None:
    """A training domain: quantity -> ``[low, high]`` finite numbers with low <= high, or a count (int >= 0)."""
    import math

    if not isinstance(domain, dict):
        raise ModelError(f"{where}: 'domain' must be a JSON object, got {type(domain).__name__}")
    for k, v in domain.items():
        if isinstance(v, int) and not isinstance(v, bool) and v >= 0:
            continue
        ok = (isinstance(v, list) and len(v) == 2
              and all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)
              and v[0] <= v[1])
        if not ok:
            raise ModelError(f"{where}: training domain {k!r} must be [low, high] (finite numbers, low <= high), "
                             f"got {str(v)[:60]}")


def check_array(a: np.ndarray, name: str, where: str, *, may_be_empty: bool = False, nan_ok: bool = False) -> None:
    """A model array: real numbers (no NaN/inf unless ``nan_ok``), at most :data:`MAX_PARAMETER` in magnitude."""
    if a.size == 0 and not may_be_empty:
        raise ModelError(f"{where}: array {name!r} is empty")
    if a.dtype.kind == "f":
        finite = np.isfinite(a)
        if not nan_ok and not finite.all():
            raise ModelError(f"{where}: array {name!r} holds NaN or inf ({int((~finite).sum())} of {a.size} values)")
        mag = np.abs(a[finite].astype(np.float64))
        if np.any(mag > MAX_PARAMETER):
            raise ModelError(f"{where}: array {name!r} holds values beyond +/-{MAX_PARAMETER:g} (largest "
                             f"{mag.max():.3g}); not a fitted model")
    elif a.dtype.kind in "iu" and a.size and np.abs(a.astype(np.float64)).max() > MAX_PARAMETER:
        raise ModelError(f"{where}: array {name!r} holds integers beyond +/-{MAX_PARAMETER:g}")


def read_model(path, kinds: dict) -> FittedModel:
    """Load a model saved by :meth:`FittedModel.save`, every part checked.

    Checks, each a one-line :class:`ModelError` naming the file: the header (a JSON object of at
    most :data:`MAX_HEADER_BYTES`, a known schema and kind, ``fields`` of the kind's types, a training
    domain of finite ranges), the array file (a zip archive; only the kind's arrays are read, each
    checked from its .npy header for dtype, size (:data:`MAX_ARRAY_BYTES`) and shape before it is
    read, then for NaN/inf and magnitude), and the kind's own consistency (:meth:`FittedModel.validate`:
    shapes that agree, scales > 0, names it knows).

    Args:
        path: the ``.json`` header, the ``.npz``, the stem, a run directory (its ``run.json``'s first
            model) or a directory holding exactly one model.
        kinds: KIND -> model class (:data:`icgo.models.registry.MODEL_KINDS`).
    """
    p = _resolve(path)
    head = _read_header(p)
    kind = head["kind"]
    cls = kinds.get(kind) if isinstance(kind, str) else None
    if cls is None:
        raise ModelError(f"{p}: unknown model kind {str(kind)[:60]!r}; known: {sorted(kinds)}")
    npz = p.with_name(_local_name(head["arrays"], str(p), "'arrays'"))
    types = _field_types(cls)
    fields = head["fields"]
    array_names = [n for n, t in types.items() if "np.ndarray" in t]
    unknown = sorted(set(fields) - set(types))
    if unknown:
        raise ModelError(f"{p}: model of kind {kind!r} has unknown field(s) {unknown[:5]}")
    defaults = {f.name for f in dataclasses.fields(cls)
                if f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING}
    arrays = _read_arrays(npz, array_names, head.get("array_shapes"), str(p))
    kwargs = {}
    for name, t in types.items():
        if name in array_names:
            if name in arrays:
                check_array(arrays[name], name, str(npz), may_be_empty=name in cls.MAY_BE_EMPTY,
                            nan_ok=name in cls.NAN_OK)
                kwargs[name] = arrays[name]
            elif name in fields:
                if fields[name] is not None or "None" not in t:
                    raise ModelError(f"{p}: {name!r} must be an array in {npz.name}"
                                     + (" or null" if "None" in t else "") + f", got {str(fields[name])[:40]!r}")
                kwargs[name] = None
            elif name not in defaults:
                raise ModelError(f"{p}: model of kind {kind!r} lacks array {name!r} in {npz.name}")
            continue
        if name not in fields:
            if name in defaults:
                continue
            raise ModelError(f"{p}: model of kind {kind!r} lacks field {name!r}")
        if not _plain_ok(fields[name], t):
            raise ModelError(f"{p}: field {name!r} must be {' or '.join(t)}, got {str(fields[name])[:60]!r}")
        kwargs[name] = fields[name]
    check_domain(kwargs["domain"], str(p))
    try:
        model = cls(**kwargs)
        model.validate()
    except ModelError as e:
        raise ModelError(f"{p}: {e}") from None
    except (TypeError, ValueError, IndexError, KeyError) as e:
        raise ModelError(f"{p}: inconsistent model of kind {kind!r} ({type(e).__name__}: {one_line(e)})") from None
    return model


def one_line(e: BaseException) -> str:
    text = str(e).strip()
    return text.splitlines()[0][:160] if text else type(e).__name__


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
