"""circuitpython-mag-cal's recordings: its fixture layout and device frame, and the nine bundled devices.

:func:`fixture_shots` converts mag_cal's fixture layout (``{"shots": {"mag", "grav"}}``, device frame, g and uT)
to the tool frame (:data:`MAG_CAL_DEVICE_TO_TOOL`, nT); :func:`load_mag_cal_device` reads one of the nine
devices vendored in ``icgo/data/mag_cal/`` (:func:`mag_cal_devices`) as a contract
:class:`icgo.io.recording.Recording`. A user's own mag_cal JSON file: :mod:`icgo.io.mag_cal_json`.
"""

from __future__ import annotations

import json
import math
from importlib import resources

import numpy as np
import pandas as pd

from icgo.io.recording import Recording, validate
from icgo.io.schema import fail, is_number

MAG_CAL_VERSION = "1.4.1"
MAG_CAL_LICENSE = "MIT, Copyright (c) 2022 Phil Underwood for Underwood Underground"
#: Device frame of the mag_cal fixtures: X right, Y the pointing axis, Z up
#: (mag_cal docs/howto.rst). Tool frame: z = device Y (pointing axis), x = device
#: Z (up, so a level upright device has toolface 0), y = device X; right-handed
#: since Z x X = Y.
MAG_CAL_DEVICE_TO_TOOL = (2, 0, 1)  # tool[i] = device[MAG_CAL_DEVICE_TO_TOOL[i]]
#: nT per uT (circuitpython-mag-cal reports the field in uT).
UT_TO_NT = 1000.0
#: Shots rolled about the pointing axis in one direction (mag_cal read_fixture: mag[8:16], mag[16:24]).
MAG_CAL_RUNS = ((8, 16), (16, 24))
MAG_CAL_SHOTS = 24


def _mag_cal_dir():
    return resources.files("icgo").joinpath("data").joinpath("mag_cal")


def mag_cal_devices() -> list[str]:
    """Names of the 9 vendored circuitpython-mag-cal devices (``['ab', 'ai', ...]``)."""
    return sorted(p.name[:-5] for p in _mag_cal_dir().iterdir() if p.name.endswith(".json"))


def _fixture_triples(values, src: str, key: str) -> np.ndarray:
    """mag_cal's read_fixture: drop None/NaN padding, reshape to (n, 3)."""
    if not isinstance(values, list):
        fail(src, f"'shots.{key}' is not a list")
    kept = [v for v in values if v is not None and not (isinstance(v, float) and math.isnan(v))]
    bad = next((i for i, v in enumerate(kept) if not is_number(v) or not math.isfinite(v)), None)
    if bad is not None:
        fail(src, f"'shots.{key}' value {bad} is not a finite number: {str(kept[bad])[:40]!r}")
    if len(kept) % 3:
        fail(src, f"'shots.{key}' has {len(kept)} values, not a multiple of 3")
    return np.asarray(kept, np.float64).reshape(-1, 3)


def device_to_tool(v) -> np.ndarray:
    """mag_cal device frame (X right, Y pointing, Z up) -> tool frame, (N, 3) (:data:`MAG_CAL_DEVICE_TO_TOOL`)."""
    return np.asarray(v, np.float64)[:, list(MAG_CAL_DEVICE_TO_TOOL)]


def fixture_shots(d, src: str) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """mag_cal's fixture layout (``{"shots": {"mag", "grav"}}``, device frame, g and uT) -> tool frame.

    Returns:
        (G (n, 3) g, B (n, 3) nT, group): for the peer's 24 shots, shot k < 8 is its own group k and
        shots 8-15 and 16-23 are groups 8 and 9 (rolled about the pointing axis, mag_cal ``read_fixture``);
        for any other count None (the rolls are then found from the data, :mod:`icgo.io.mag_cal_json`).
    Raises:
        DataError: one line naming ``src``.
    """
    shots = d.get("shots") if isinstance(d, dict) else None
    if not isinstance(shots, dict) or "mag" not in shots or "grav" not in shots:
        fail(src, "no 'shots' with 'mag' and 'grav'")
    mag = _fixture_triples(shots["mag"], src, "mag")
    grav = _fixture_triples(shots["grav"], src, "grav")
    if len(mag) != len(grav) or not len(mag):
        fail(src, f"'shots.mag' has {len(mag)} readings and 'shots.grav' {len(grav)}: one of each per shot")
    group = None
    if len(mag) == MAG_CAL_SHOTS:
        group = np.arange(MAG_CAL_SHOTS)
        for gid, (a, b) in zip((8, 9), MAG_CAL_RUNS):
            group[a:b] = gid
    # fixtures are in g already (median |G| ~ 1.00), gravity pointing down; uT -> nT
    return device_to_tool(grav), device_to_tool(mag) * UT_TO_NT, group


def load_mag_cal_device(name: str) -> Recording:
    """One real device of circuitpython-mag-cal 1.4.1 as a contract Recording.

    24 static shots of raw accelerometer (g) and magnetometer (uT -> nT, x1000)
    readings, axes permuted from the device frame to the tool frame
    (``MAG_CAL_DEVICE_TO_TOOL``). Groups: shot k < 8 is its own group k (eight
    distinct orientations); shots 8-15 are group 8 and shots 16-23 group 9 (rolled
    about the pointing axis, one true direction each). ``station`` = shot index
    0-23. No reference attitude, no field metadata. An unknown name raises DataError.

    Args:
        name: one of :func:`mag_cal_devices`.
    Returns:
        Recording (24 rows).
    """
    names = mag_cal_devices()
    if name not in names:
        fail("mag_cal", f"unknown device {name!r}; choose one of {', '.join(names)}")
    res = _mag_cal_dir().joinpath(f"{name}.json")
    src = f"icgo/data/mag_cal/{name}.json"
    d = json.loads(res.read_text(encoding="utf-8"))
    G, B, group = fixture_shots(d, src)
    frame = pd.DataFrame({
        "station": np.arange(MAG_CAL_SHOTS),
        "gx": G[:, 0], "gy": G[:, 1], "gz": G[:, 2],
        "bx": B[:, 0], "by": B[:, 1], "bz": B[:, 2],
        "group": group,
    })
    meta = {
        "name": str(d.get("name", name)),
        "source": f"circuitpython-mag-cal {MAG_CAL_VERSION} sdist, tests/fixtures/cal_data/{name}.json",
        "license": MAG_CAL_LICENSE,
        "description": "raw (uncalibrated) static shots; device axes (X right, Y pointing, Z up) "
                       "mapped to tool (x, y, z) = (Z, X, Y); mag uT x1000 -> nT; shots 8-15 "
                       "(group 8) and 16-23 (group 9) rolled about the pointing axis",
    }
    return validate(frame, meta, source=src)
