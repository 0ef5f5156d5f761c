"""Reading a model's files, every check made before a model is built (``docs/reliability.md``).

:func:`header_path` finds the header (``.json``) of a model path, a run directory or a directory with one
model; :func:`read_header` reads it (bounded, a JSON object with a known schema); :func:`read_arrays` reads
the named members of its ``.npz``, each checked from its ``.npy`` header (dtype, size, shape) before any data
is read, nothing unpickled; :func:`field_types`, :func:`plain_ok`, :func:`check_domain` and
:func:`check_array` check the typed JSON fields, the training domain and every array (finite, bounded).
:func:`icgo.artifacts.format.read_model` composes them. Every failure is one :class:`ModelError` line naming the
file.
"""

from __future__ import annotations

import dataclasses
import json
import math
import stat
import zipfile
import zlib
from pathlib import Path

import numpy as np

from icgo.core.errors import DataError, ModelError
from icgo.io.files import read_text_bounded

#: Largest model header (.json) read, bytes.
MAX_HEADER_BYTES = 4 << 20
#: Largest array of a model, bytes (declared in the .npy header; checked before it is read).
MAX_ARRAY_BYTES = 64 << 20
#: Largest total of a model's arrays, bytes.
MAX_ARRAYS_BYTES = 256 << 20
#: Largest magnitude of a fitted parameter: beyond it a parameter is not a fit (1e300 overflows every
#: product to inf); the largest fitted values are fields in nT (~1e5) and RELM output weights (~1e4).
MAX_PARAMETER = 1e12
#: Array dtypes a model may hold: float, signed and unsigned integers (a bool array is refused: no model saves one,
#: and a predictor would do arithmetic on it).
ARRAY_KINDS = "fiu"


def model_files(path) -> list[Path]:
    """The model header files (``*.json`` with a model header) at ``path`` (a file or a run directory)."""
    p = Path(path)
    if p.is_dir():
        return sorted(q for q in p.glob("*.json") if q.is_file() and is_model_header(q))
    if p.suffix == ".npz":
        p = p.with_suffix(".json")
    return [p]


def is_model_header(p: Path) -> bool:
    """Whether ``p`` is a JSON object with the keys of a model header (bounded read, nothing raised)."""
    try:
        head = json.loads(read_text_bounded(p, MAX_HEADER_BYTES, "a model header"))
    except (DataError, ValueError, RecursionError):
        return False
    return isinstance(head, dict) and "schema_version" in head and "kind" in head and "arrays" in head


def local_name(name, where: str, what: str) -> str:
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
    name = local_name(models[0], str(rec), "models[0]")
    path = run_dir / name
    try:
        inside = path.resolve().parent == run_dir.resolve()
    except (OSError, RuntimeError):
        inside = False
    if not inside:
        raise ModelError(f"{rec}: models[0] {name!r} leads out of the run directory (a symbolic link); refused")
    return path


def header_path(path) -> Path:
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


def read_header(p: Path, newest: int) -> dict:
    """The JSON header of a model file: a JSON object with ``schema_version`` (1 to ``newest``), ``kind``,
    ``arrays`` and ``fields`` (a JSON object), and ``array_shapes`` (array name -> list of sizes) if given."""
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
    if ver > newest:
        raise ModelError(f"{p}: written by model schema version {ver}, newer than this icgo's {newest} "
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
    raise e  # from inside json.loads' parse_constant


def read_arrays(npz: Path, names: list[str], shapes: dict | None, where: str) -> dict:
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
    if not stat.S_ISREG(st.st_mode):
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


def field_types(cls) -> dict[str, tuple[str, ...]]:
    """Field name -> the type names of its annotation (``"np.ndarray | None"`` -> ``("np.ndarray", "None")``)."""
    return {f.name: tuple(t.strip() for t in str(f.type).split("|")) for f in dataclasses.fields(cls)}


def plain_ok(v, types: tuple[str, ...]) -> bool:
    """Whether a JSON value ``v`` is one of the type names ``types`` (``int``, ``float`` finite, ``str``,
    ``bool``, ``list``, ``dict``, ``None``)."""
    for t in types:
        if (t == "None" and v is None) or (t == "str" and isinstance(v, str)) \
                or (t == "bool" and isinstance(v, bool)) or (t == "list" and isinstance(v, list)) \
                or (t == "dict" and isinstance(v, dict)) \
                or (t == "int" and isinstance(v, int) and not isinstance(v, bool)) \
                or (t == "float" and isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)):
            return True
    return False


def check_domain(domain, where: str) -> None:
    """A training domain: quantity -> ``[low, high]`` finite numbers with low <= high, or, for a count named
    ``n_*`` (e.g. ``n_points``), an int >= 0 (a quantity compared with a survey's range is always a range)."""
    if not isinstance(domain, dict):
        raise ModelError(f"{where}: 'domain' must be a JSON object, got {type(domain).__name__}")
    for k, v in domain.items():
        if str(k).startswith("n_") and isinstance(v, int) and not isinstance(v, bool) and v >= 0:
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




def one_line(e: BaseException) -> str:
    """The first line of an exception's message (at most 160 characters), or its type's name."""
    text = str(e).strip()
    return text.splitlines()[0][:160] if text else type(e).__name__
