"""Fitted models as artifacts: one pattern, one file format, one generic save/load.

Every fitted model is a **params pytree** and one pure ``predict(params, x)`` (jit- and vmap-able) of its
family: the study scores through that ``predict`` and the saved model applies through it, so applying a
saved model reproduces the study. :class:`FittedModel` is the artifact around it: the params (field
``params``, a pytree of the family's class :attr:`FittedModel.PARAMS`), and the meta: the fit's settings,
its training data's hash and domain and the family's own labels (JSON values) and records (arrays that
``predict`` does not use, such as loss curves). A subclass sets ``KIND``, ``UNITS``, ``PARAMS``,
``PREDICT``, ``INPUTS`` (the frame columns that make ``x``) and implements ``apply(frame) -> DataFrame`` on
a data-contract frame (``gx, gy, gz`` in g, ``bx, by, bz`` in nT, ...).

Optional parts: a family whose models may lack a part (a calibration without an accelerometer fit) has None
in that leaf's place, so the params' structure says which parts a model has. The kind lists such leaves in
:attr:`FittedModel.OPTIONAL_LEAVES` (top-level fields of its params); an absent one is written in the
header's ``fields`` as ``null`` (the header says which parts the model has, readable without icgo), and
:meth:`FittedModel.params_like` reads it back from there: ``null`` gives None in the skeleton, anything else
a leaf to read.

File format (open, readable without icgo): ``<stem>.npz`` holds the arrays (float64/int, exact): each leaf
of the params under its path in the pytree (``w1``; ``effects.hard_iron`` for a dict entry), then the meta's
arrays under their field names; ``<stem>.json`` holds the header::

    {"schema_version": 2, "package_version": "0.1.0", "kind": "gyro_network",
     "units": {...}, "fields": {...meta JSON values...}, "arrays": "<stem>.npz",
     "array_names": [...], "array_shapes": {...}}

Loading (:func:`read_model`) is the equinox way: the kind rebuilds the params' skeleton from the meta
(:meth:`FittedModel.params_like`: its leaves' paths and the static settings ``predict`` needs), and
exactly those leaves are read into it, every one checked (:mod:`icgo.artifacts.reading`). The JSON file is
written last (both atomically, temp file + rename), so a header on disk always names a complete array
file. ``save -> load -> apply`` is bitwise ``apply`` (tested): arrays are stored exactly, the skeleton
rebuilt from the meta is the saved params' own (checked on save) and ``predict`` is deterministic.

Errors (a file that is not a model, a newer schema, a frame lacking the columns a model needs) are
:class:`ModelError`, one line naming the file or the columns.
"""

from __future__ import annotations

import abc
import dataclasses
import hashlib
import json
import os
import re
import tempfile
from pathlib import Path
from typing import Any, Callable, ClassVar

import jax
import numpy as np
import pandas as pd

from icgo.core.errors import ModelError
from icgo.artifacts.reading import (
    check_array,
    check_domain,
    field_types,
    header_path,
    local_name,
    one_line,
    plain_ok,
    read_arrays,
    read_header,
    run_model_path,  # noqa: F401  (a run directory's main model; experiments.apply finds it here)
)

#: Version of the header/array layout written by :meth:`FittedModel.save`. Schema 2 stores a discrepancy
#: model's effects one array each (``effects.<name>``); every other kind's layout is schema 1's, and those
#: files are read as they are (a kind's :attr:`FittedModel.OLDEST_SCHEMA`).
SCHEMA_VERSION = 2

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


#: A leaf name of a params pytree: letters, digits, ``_``, with ``.`` between the parts of its path.
_LEAF_NAME = re.compile(r"[A-Za-z0-9_]+(\.[A-Za-z0-9_]+)*")


def _leaf_name(path) -> str:
    """The name of a pytree leaf from its key path: the keys joined by ``.`` (``w1``, ``effects.hard_iron``)."""
    return ".".join(str(getattr(k, "name", getattr(k, "key", getattr(k, "idx", k)))) for k in path)


def param_arrays(params) -> dict[str, np.ndarray]:
    """A params pytree's leaves as ``{leaf name: array}`` (:func:`_leaf_name`), in the pytree's order."""
    return {_leaf_name(path): np.asarray(leaf) for path, leaf in jax.tree_util.tree_flatten_with_path(params)[0]}


@dataclasses.dataclass(frozen=True, eq=False)
class FittedModel(abc.ABC):
    """Base of every fitted model: the params pytree of its family and the meta of its fit.

    Attributes:
        config: the settings the fit used (JSON-able dict).
        data_hash: :func:`data_hash` of the training data.
        domain: training-domain ranges (:func:`sensor_domain` plus method-specific ones).

    A kind adds ``params: <PARAMS>`` (the pytree its ``PREDICT`` takes) and its meta fields: JSON values
    (``str``, ``int``, ``float``, ``bool``, ``list``, ``dict``, ``None``) saved in the header, ``np.ndarray``
    records saved in the ``.npz``. Class settings:

    * ``KIND``, ``UNITS``: its name in the header and the units it states.
    * ``CORRECTS_FIELD``: its output corrects the magnetic field itself (what survey QC then checks).
    * ``PARAMS``: the params pytree class (a ``NamedTuple`` of arrays, or a dataclass registered with
      ``jax.tree_util.register_dataclass`` whose static fields are settings of ``predict``).
    * ``PREDICT``: the family's pure ``predict(params, x)``, batched as the kind's params are (over a leading
      member axis where the params have one); :meth:`predict` applies it.
    * ``INPUTS``: the frame columns that make ``x`` (:meth:`inputs`).
    * ``MAY_BE_EMPTY``, ``NAN_OK``: arrays (leaf or field names) that may be empty or hold NaN.
    * ``OPTIONAL_LEAVES``: params leaves (top-level fields of ``PARAMS``) a model may lack (None); an absent
      one is ``null`` in the header's ``fields`` (see the module doc).
    * ``OLDEST_SCHEMA``, ``REFIT``: the oldest schema of this kind's files that is read, and what to do
      with an older one (one line, e.g. the command that refits it).
    """

    KIND: ClassVar[str] = ""
    UNITS: ClassVar[dict] = {}
    CORRECTS_FIELD: ClassVar[bool] = False
    PARAMS: ClassVar[type]
    PREDICT: ClassVar[Callable | None] = None
    INPUTS: ClassVar[tuple] = ()
    MAY_BE_EMPTY: ClassVar[tuple] = ()
    NAN_OK: ClassVar[tuple] = ()
    OPTIONAL_LEAVES: ClassVar[tuple] = ()
    #: Meta fields a kind gained after files of it were written (each defaults to None): left out of the header while
    #: None, so such a file loads and saves back as it was, and an older icgo reads what this one writes.
    LATER_FIELDS: ClassVar[tuple] = ()
    OLDEST_SCHEMA: ClassVar[int] = 1
    REFIT: ClassVar[str] = "refit it"

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

    @classmethod
    def params_like(cls, fields: dict) -> Any:
        """The skeleton of this kind's params from its meta (``fields``: the header's JSON values): a
        ``PARAMS`` pytree whose leaves are placeholders (their paths name the arrays to read) and whose static
        fields are the meta's settings. The default suits a ``NamedTuple`` of arrays; a kind with static
        settings or dict-valued leaves builds its own, raising :class:`ModelError` (one line) where the meta
        cannot make one."""
        return cls.PARAMS(*[0] * len(cls.PARAMS._fields))

    def inputs(self, frame: pd.DataFrame) -> np.ndarray:
        """``x``: the frame's :attr:`INPUTS` columns, (N, len(INPUTS)) float64, checked present and finite."""
        return frame_values(frame, self.INPUTS, f"{self.KIND} model")

    def predict(self, x):
        """``PREDICT(params, x)``: the family's forward pass with this model's params (what the study scored)."""
        return type(self).PREDICT(self.params, x)

    # ---------------------------------------------------------------- files
    def _split_fields(self) -> tuple[dict, dict]:
        """``(arrays, plain)``: the arrays to save (params leaves, then array fields) and the JSON fields."""
        arrays = param_arrays(self.params)
        plain = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            if f.name == "params":
                plain.update({n: None for n in self.OPTIONAL_LEAVES if getattr(v, n) is None})
                continue
            if f.name in self.OPTIONAL_LEAVES:
                raise ValueError(f"{self.KIND}: field {f.name!r} has the name of an optional params leaf")
            if isinstance(v, np.ndarray):
                if f.name in arrays:
                    raise ValueError(f"{self.KIND}: field {f.name!r} has the name of a params leaf")
                arrays[f.name] = v
            elif not (v is None and f.name in self.LATER_FIELDS):
                plain[f.name] = v
        like = self.params_like(json.loads(json.dumps(plain, default=_json_default)))
        if jax.tree_util.tree_structure(like) != jax.tree_util.tree_structure(self.params):
            raise ValueError(f"{self.KIND}: the params' structure or settings differ from those its meta "
                             f"describes ({jax.tree_util.tree_structure(self.params)} vs "
                             f"{jax.tree_util.tree_structure(like)}); a saved model would not load as it is")
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


def need_shape(a, shape: tuple, name: str) -> None:
    """ModelError unless ``a`` has ``shape`` (None in ``shape`` matches any size)."""
    got = np.shape(a)
    if len(got) != len(shape) or any(w is not None and g != w for g, w in zip(got, shape)):
        want = "(" + ", ".join("n" if w is None else str(w) for w in shape) + ("," if len(shape) == 1 else "") + ")"
        raise ModelError(f"array {name!r} has shape {got}, expected {want}")


def read_model(path, kinds: dict) -> FittedModel:
    """Load a model saved by :meth:`FittedModel.save`, every part checked.

    Checks, each a one-line :class:`ModelError` naming the file: the header (a JSON object of at
    most :data:`~icgo.artifacts.reading.MAX_HEADER_BYTES`, a known schema and kind, a schema the kind still
    reads, meta ``fields`` of the kind's types (an absent optional leaf: null), a training domain of finite
    ranges), the params' skeleton rebuilt from the meta (:meth:`FittedModel.params_like`), the array file
    (a zip archive; only the skeleton's leaves and the kind's array fields are read, each checked from its
    .npy header for dtype, size (:data:`~icgo.artifacts.reading.MAX_ARRAY_BYTES`) and shape before it is
    read, then for NaN/inf and magnitude; nothing is unpickled), and the kind's own consistency
    (:meth:`FittedModel.validate`: shapes that agree, scales > 0, names it knows).

    Args:
        path: the ``.json`` header, the ``.npz``, the stem, a run directory (its ``run.json``'s first
            model) or a directory holding exactly one model.
        kinds: KIND -> model class (:data:`icgo.artifacts.registry.MODEL_KINDS`).
    """
    p = header_path(path)
    head = read_header(p, SCHEMA_VERSION)
    kind = head["kind"]
    cls = kinds.get(kind) if isinstance(kind, str) else None
    if cls is None:
        raise ModelError(f"{p}: unknown model kind {str(kind)[:60]!r}; known: {sorted(kinds)}")
    if head["schema_version"] < cls.OLDEST_SCHEMA:
        raise ModelError(f"{p}: a {kind} file of model schema {head['schema_version']}, a layout this icgo no longer "
                         f"reads (it reads schema {cls.OLDEST_SCHEMA} on); {cls.REFIT}")
    npz = p.with_name(local_name(head["arrays"], str(p), "'arrays'"))
    types = field_types(cls)
    types.pop("params")
    fields = head["fields"]
    unknown = sorted(set(fields) - set(types) - set(cls.OPTIONAL_LEAVES))
    if unknown:
        raise ModelError(f"{p}: model of kind {kind!r} has unknown field(s) {unknown[:5]}")
    for name in cls.OPTIONAL_LEAVES:  # in the header only as null: the model lacks that part
        if fields.get(name) is not None:
            raise ModelError(f"{p}: {name!r} must be an array in {npz.name} or null, got {str(fields[name])[:40]!r}")
    defaults = {f.name for f in dataclasses.fields(cls)
                if f.default is not dataclasses.MISSING or f.default_factory is not dataclasses.MISSING}
    kwargs = {}
    for name, t in types.items():  # the JSON values; arrays below
        if "np.ndarray" in t:
            continue
        if name not in fields:
            if name in defaults:
                continue
            raise ModelError(f"{p}: model of kind {kind!r} lacks field {name!r}")
        if not plain_ok(fields[name], t):
            raise ModelError(f"{p}: field {name!r} must be {' or '.join(t)}, got {str(fields[name])[:60]!r}")
        kwargs[name] = fields[name]
    check_domain(kwargs["domain"], str(p))
    try:
        leaves, skeleton = jax.tree_util.tree_flatten_with_path(cls.params_like(fields))
    except ModelError as e:
        raise ModelError(f"{p}: {e}") from None
    except (TypeError, ValueError, IndexError, KeyError, AttributeError) as e:
        raise ModelError(f"{p}: the meta of this {kind} model describes no params ({type(e).__name__}: "
                         f"{one_line(e)})") from None
    leaf_names = [_leaf_name(path) for path, _ in leaves]
    bad = [n for n in leaf_names if not _LEAF_NAME.fullmatch(n)]
    if bad:
        raise ModelError(f"{p}: params leaf name {bad[0][:60]!r} is not a plain name (letters, digits, _ and .)")
    field_arrays = [n for n, t in types.items() if "np.ndarray" in t]
    arrays = read_arrays(npz, leaf_names + field_arrays, head.get("array_shapes"), str(p))
    for name in leaf_names + field_arrays:
        if name in arrays:
            check_array(arrays[name], name, str(npz), may_be_empty=name in cls.MAY_BE_EMPTY,
                        nan_ok=name in cls.NAN_OK)
    missing = [n for n in leaf_names if n not in arrays]
    if missing:
        raise ModelError(f"{p}: model of kind {kind!r} lacks array {missing[0]!r} in {npz.name}")
    kwargs["params"] = jax.tree_util.tree_unflatten(skeleton, [arrays[n] for n in leaf_names])
    for name in field_arrays:
        t = types[name]
        if name in arrays:
            kwargs[name] = arrays[name]
        elif name in fields:
            if fields[name] is not None or "None" not in t:
                raise ModelError(f"{p}: {name!r} must be an array in {npz.name}"
                                 + (" or null" if "None" in t else "") + f", got {str(fields[name])[:40]!r}")
            kwargs[name] = None
        elif name not in defaults:
            raise ModelError(f"{p}: model of kind {kind!r} lacks array {name!r} in {npz.name}")
    try:
        model = cls(**kwargs)
        model.validate()
    except ModelError as e:
        raise ModelError(f"{p}: {e}") from None
    except (TypeError, ValueError, IndexError, KeyError) as e:
        raise ModelError(f"{p}: inconsistent model of kind {kind!r} ({type(e).__name__}: {one_line(e)})") from None
    return model


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
