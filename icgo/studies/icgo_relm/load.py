"""The data of one ICGO-RELM run, from its typed config (:class:`icgo.studies.icgo_relm.run_config.RunConfig`): the
configured data set (a simulation of :data:`icgo.datasets.registry.DATASETS` or a recording), the second
instrument's survey of ``split=transfer``, and the worlds of ``worlds=N`` (:mod:`icgo.studies.icgo_relm.worlds.study`).

Every failure is one line (:class:`icgo.core.errors.SettingError` naming the YAML key, or
:class:`icgo.core.errors.DataError`).
"""

from __future__ import annotations

import sys
from pathlib import Path

from icgo.core.errors import SettingError


def load_data(run):
    """(frame, metadata, description) of ``run.dataset``.

    Raises:
        SettingError / icgo.core.errors.DataError: one line (missing file, bad CSV, unknown data set).
    """
    ds = run.dataset
    if ds.name == "csv":
        from icgo.io.recording import column_map, read_recording

        cmap = column_map(ds.columns or None, ds.columns_file, "dataset.columns")
        rec = read_recording(Path(str(ds.path)).expanduser(), require_meta=ds.require_meta, columns=cmap,
                             column_setting="dataset.columns")
        for line in rec.notices:  # what the reader noticed but accepted (icgo.io.recording check prints the same)
            print(f"notice: {line}", file=sys.stderr)
        return rec.frame, dict(rec.meta), f"csv:{ds.path}"
    from icgo.datasets.registry import DATASETS

    fn = DATASETS.get(ds.name)
    if fn is None:
        raise SettingError(f"dataset {ds.name!r}: icgo.datasets.registry.DATASETS has no such data set")
    try:
        data = fn(int(ds.seed), **ds.kwargs)
    except TypeError as e:
        raise SettingError(f"dataset.kwargs for {ds.name}: {str(e).splitlines()[0]}") from None
    frame, meta, desc = data.frame, dict(data.meta), ds.name
    if ds.condition is not None:
        frame, desc = select_condition(frame, int(ds.condition)), f"{ds.name}[{ds.condition}]"
    return frame, meta, desc


def load_target(run):
    """The second instrument's survey of ``split=transfer`` (a DataFrame), or None for other protocols.

    ``split.target.path`` reads a recording; otherwise the data set's simulator draws the target with the changes
    of ``split.target`` (:func:`icgo.studies.common.splits.transfer_survey`).

    Raises:
        SettingError / icgo.core.errors.DataError: one line.
    """
    target = run.split.target
    if run.split.protocol != "transfer" or target is None:
        return None
    if target.path is not None:
        from icgo.io.recording import read_recording

        return read_recording(Path(str(target.path)).expanduser(), require_meta=False).frame
    from icgo.studies.common.splits import TransferDraw, transfer_survey

    ds = run.dataset
    if ds.name == "csv":
        raise SettingError("split=transfer on dataset=csv needs split.target.path (a recording of the second "
                           "instrument); only the simulated data sets can draw one")
    try:
        return transfer_survey(ds.name, int(ds.seed), dict(ds.kwargs), TransferDraw(**target.draw())).frame
    except SettingError as e:
        raise (SettingError(f"split.target.{e.field}", e.problem) if e.field else e) from None


def select_condition(frame, condition: int):
    """Rows of one Table 4 condition of a well_conditions frame (column ``condition``)."""
    if "condition" not in frame.columns:
        raise SettingError("dataset.condition is set but the data set has no 'condition' column")
    sub = frame[frame["condition"] == condition].reset_index(drop=True)
    if len(sub) == 0:
        raise SettingError(f"dataset.condition {condition}: no rows with that condition")
    return sub


def load_worlds(run):
    """(the :class:`icgo.studies.icgo_relm.worlds.study.World` s, description) of ``run.worlds`` data seeds from ``dataset.seed``."""
    from icgo.studies.icgo_relm.worlds.study import World, simulate, world_seeds

    ds = run.dataset
    try:
        worlds = simulate(ds.name, world_seeds(int(ds.seed), int(run.worlds)), **ds.kwargs)
    except TypeError as e:
        raise SettingError(f"dataset.kwargs for {ds.name}: {str(e).splitlines()[0]}") from None
    cond = ds.condition
    if cond is not None:
        worlds = [World(w.seed, select_condition(w.frame, int(cond)), w.meta) for w in worlds]
    first, last = worlds[0].seed, worlds[-1].seed
    return worlds, f"{ds.name}{f'[{cond}]' if cond is not None else ''} worlds {first}-{last}"
