"""The settings of ``python -m experiments.apply`` (conf/apply/apply.yaml, as a plain mapping) checked, then one
survey corrected by one saved model (:func:`icgo.survey.apply_run.apply_survey`).

Every setting is checked before anything is read or written; a bad one is one
:class:`~icgo.core.errors.SettingError` line naming it.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from icgo.core.errors import SettingError
from icgo.core.settings import is_int

#: Every setting of the apply door (conf/apply/apply.yaml).
KEYS = ("model", "data", "method", "require_meta", "out", "qc", "columns", "columns_file", "overwrite", "max_mb",
        "stream_mb", "chunk_rows", "site")


def check_settings(settings: dict) -> None:
    """Every setting checked (unknown keys, the required paths, types, sizes); a mandatory value not given is None.

    Raises:
        SettingError: the first bad setting (one line).
    """
    unknown = sorted(set(settings) - set(KEYS))
    if unknown:
        raise SettingError(f"unknown setting(s) {unknown}; experiments.apply takes {list(KEYS)}")
    for k in ("model", "data"):
        if settings.get(k) in (None, ""):
            raise SettingError(f"{k}= is required: python -m experiments.apply model=<run dir or model .json> "
                               f"data=<survey.csv>")
        if not isinstance(settings[k], str):
            raise SettingError(f"{k}={settings[k]!r}: must be a path")
    if settings.get("method") is not None and not isinstance(settings["method"], str):
        raise SettingError(f"method={settings['method']!r}: must be a method name or null")
    if settings.get("out") is not None and not isinstance(settings["out"], str):
        raise SettingError(f"out={settings['out']!r}: must be a directory path or null")
    for k in ("require_meta", "overwrite"):
        if not isinstance(settings.get(k), bool):
            raise SettingError(f"{k}={settings.get(k)!r}: must be true or false")
    size_settings(settings)
    site_setting(settings)


def site_setting(settings: dict):
    """The ``site.*`` settings' reference field (:func:`icgo.io.site.site_reference`), or None when none is given."""
    from icgo.io.site import site_reference

    site = settings.get("site")
    if site is not None and not isinstance(site, dict):
        raise SettingError(f"site={site!r}: give site.lat= site.lon= site.date=, or site.dip= site.field=")
    return site_reference(site)


def size_settings(settings: dict) -> tuple[int, int, int]:
    """(max bytes, stream above bytes, rows per chunk) from ``max_mb``, ``stream_mb`` and ``chunk_rows``
    (defaults in conf/apply/apply.yaml; docs/data.md)."""
    out = []
    for k, scale in (("max_mb", 1 << 20), ("stream_mb", 1 << 20), ("chunk_rows", 1)):
        v = settings.get(k)
        if not (is_int(v) and v >= 1):
            raise SettingError(f"{k}={v!r}: must be an integer >= 1")
        out.append(int(v) * scale)
    return out[0], out[1], out[2]


def run_apply(settings: dict, out_dir: Path, keep=(),
              write_record: Callable[[Path], None] = lambda stage: None) -> dict:
    """Check the settings, correct the survey, write the two files (all or none); return the meta dict.

    Args:
        settings: the door's settings (a plain mapping). out_dir: the output directory (refused if it holds files,
            unless ``overwrite=true``; :class:`icgo.io.files.Output`). keep: names in it to leave alone (Hydra's
            log). write_record: ``stage -> None``, the door's own record written with the files.
    Raises:
        ValueError (ModelError, DataError, RecordError, SettingError, OutputError): one line.
    """
    from icgo.artifacts.registry import load_model
    from icgo.core.settings import config_from_mapping
    from icgo.io.files import Output
    from icgo.io.recording import column_map
    from icgo.physics.qc import QCBands
    from icgo.survey.apply_run import apply_survey, model_path

    check_settings(settings)
    bands = config_from_mapping(QCBands, settings["qc"], "qc")
    output = Output(out_dir, setting="out" if settings["out"] else "hydra.run.dir", overwrite=settings["overwrite"],
                    keep=keep, writer="experiments.apply").check()
    mpath = model_path(Path(settings["model"]).expanduser())
    model = load_model(mpath)
    data = Path(settings["data"]).expanduser()
    cmap = column_map(settings.get("columns") or None, settings.get("columns_file"))
    max_bytes, stream_above, chunk_rows = size_settings(settings)
    return apply_survey(output, model, mpath, data, settings["data"], columns=cmap, max_bytes=max_bytes,
                        stream_above=stream_above, chunk_rows=chunk_rows, require_meta=settings["require_meta"],
                        method=settings["method"], bands=bands, qc_bands=settings["qc"], write_record=write_record,
                        site=site_setting(settings))
