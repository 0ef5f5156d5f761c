"""The simulated data set every simulator of this package returns, and what the simulators share.

A :class:`Dataset` is a DataFrame in the data contract (DESIGN.md), its metadata and the ground truth that was
injected; :func:`contract_frame` builds the frame from stations, G, B and the attitude, :func:`spawn_rngs` the
independent noise streams of one seed, :func:`jsonable` the truth as plain JSON, and :func:`write_dataset`
writes a data set as contract files (CSV + meta) and its truth beside them.
"""

from __future__ import annotations

from typing import Any, Mapping, NamedTuple

import jax.numpy as jnp
import numpy as np
import pandas as pd


class Dataset(NamedTuple):
    """A simulated recording.

    Attributes:
        frame: DataFrame with the data-contract columns (station, gx, gy, gz,
            bx, by, bz, azimuth_deg, inclination_deg, toolface_deg, ...).
        meta: data-contract metadata (total_field_nT, dip_deg,
            declination_deg, gravity_g, ...) plus ``name`` and ``seed``.
        truth: every injected parameter (effects, geometry, noise, dropped rows).
    """

    frame: pd.DataFrame
    meta: dict
    truth: dict


def as_float64(x) -> np.ndarray:
    """``x`` as a float64 numpy array (host side)."""
    return np.asarray(x, dtype=np.float64)


def jsonable(x: Any):
    """Convert arrays / tuples / NamedTuples in a truth dict to plain JSON types."""
    if isinstance(x, Mapping):
        return {str(k): jsonable(v) for k, v in x.items()}
    if hasattr(x, "_asdict"):
        return {k: jsonable(v) for k, v in x._asdict().items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, (np.ndarray, jnp.ndarray)):
        return jsonable(np.asarray(x).tolist())
    if isinstance(x, (np.floating, np.integer, np.bool_)):
        return x.item()
    return x


def contract_frame(station, G, B, A, I, T, extra: Mapping[str, Any] | None = None) -> pd.DataFrame:
    """The contract columns from stations (N,), G (N, 3) g, B (N, 3) nT and the attitude A, I, T (N,) deg;
    ``extra`` columns (name -> (N,)) after them."""
    G, B = as_float64(G), as_float64(B)
    cols = {
        "station": np.asarray(station, dtype=np.int64),
        "gx": G[:, 0], "gy": G[:, 1], "gz": G[:, 2],
        "bx": B[:, 0], "by": B[:, 1], "bz": B[:, 2],
        "azimuth_deg": as_float64(A), "inclination_deg": as_float64(I), "toolface_deg": as_float64(T),
    }
    for k, v in (extra or {}).items():
        cols[k] = np.asarray(v)
    return pd.DataFrame(cols)


def spawn_rngs(seed, n):
    """``n`` independent numpy generators from one seed (SeedSequence.spawn: streams never overlap)."""
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed {seed!r}: must be a non-negative integer")
    return [np.random.default_rng(s) for s in np.random.SeedSequence(int(seed)).spawn(n)]


def write_dataset(ds: Dataset, out_dir, name: str | None = None):
    """Write ``DIR/NAME.csv`` + ``DIR/NAME.meta.json`` (via :func:`icgo.io.recording.write_recording`) and ``DIR/NAME.truth.json``.

    Returns the path of the CSV.
    """
    import json
    from pathlib import Path

    from icgo.io import recording as io

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    name = name or ds.meta["name"]
    path = out / f"{name}.csv"
    io.write_recording(path, ds.frame, ds.meta)
    (out / f"{name}.truth.json").write_text(json.dumps(jsonable(ds.truth), indent=1) + "\n")
    return path
