"""Train / test protocols of the ICGO-RELM study: the paper's random split and three
generalisation protocols.

A protocol turns the rows of a data set (after the 3-sigma filter) into
*members*: one fitted model each, with its own PRNG key and three 0/1 row masks:

* ``train``: rows that fit the model (MSA, standardisation, RELM search, refit);
* ``test``: rows the model is scored on;
* ``heldout``: rows of the *training data set* the model did not fit. They
  calibrate the split-conformal intervals (:mod:`icgo.maths.conformal`); for
  ``transfer`` they exclude the target instrument's rows, which must never
  calibrate anything.

Protocols (:data:`PROTOCOLS`):

* ``random`` (paper, sections 3.1-3.4): per repeat, a random permutation; the
  first ``round(train_fraction N)`` rows train, the rest test. One member per repeat.
* ``leave_azimuth_out``: whole stations held out, one fold per reference azimuth
  (every toolface of that azimuth). Each repeat is a full pass over the folds
  (F members); the repeats differ only in the search's key.
* ``leave_condition_out``: one fold per well condition (the data's ``condition``
  column, e.g. the six of Table 4).
* ``transfer``: the rows of the source instrument train (the same random
  ``train_fraction`` subset as repeat k of ``random``), every row of a second
  draw (another instrument build: :func:`transfer_survey`) tests.

Member keys: repeat k of ``random``/``transfer`` uses ``fold_in(key, k)`` (so
repeat k of ``transfer`` trains on exactly the rows of repeat k of ``random``);
fold f of repeat k uses ``fold_in(fold_in(key, k), f)``.
"""

from __future__ import annotations

import dataclasses
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd

PROTOCOLS = ("random", "leave_azimuth_out", "leave_condition_out", "transfer")
#: Protocols whose members are folds of a cross-validation pass.
FOLD_PROTOCOLS = ("leave_azimuth_out", "leave_condition_out")


class Members(NamedTuple):
    """The members of a protocol (M of them) over N rows.

    Attributes:
        keys: (M, 2) PRNG keys. repeat: (M,) repeat id. fold: (M,) fold index (0 for
            random / transfer). fold_label: the F fold names (``["all"]`` for random /
            transfer). train, test, heldout: (M, N) float 0/1 masks (see the module).
    """

    keys: np.ndarray
    repeat: np.ndarray
    fold: np.ndarray
    fold_label: list
    train: np.ndarray
    test: np.ndarray
    heldout: np.ndarray


@partial(jax.jit, static_argnames=("n_source",))
def _permutations(base_key, repeat_ids, n_source: int):
    """Per repeat id r: its key ``fold_in(base_key, r)`` and a permutation of the source rows drawn with that key's
    first split (one compiled call for every repeat; each row is what the call for its repeat alone gives)."""
    keys = jax.vmap(lambda r: jax.random.fold_in(base_key, r))(repeat_ids)
    return keys, jax.vmap(lambda k: jax.random.permutation(jax.random.split(k, 3)[0], n_source))(keys)


def _random_train(perm, n_rows: int, n_train: int) -> np.ndarray:
    """(R, N) 0/1: per repeat the first n_train rows of its permutation of the source rows."""
    m = np.zeros((perm.shape[0], n_rows))
    np.put_along_axis(m, perm[:, :n_train], 1.0, axis=1)
    return m


def fold_groups(protocol: str, frame: pd.DataFrame) -> tuple[np.ndarray, list]:
    """Fold index per row and fold labels of a fold protocol.

    Args:
        protocol: ``leave_azimuth_out`` (groups of equal ``azimuth_deg``, rounded to
            1e-6 deg) or ``leave_condition_out`` (groups of the ``condition`` column).
        frame: the rows (after filtering).
    Returns:
        ((N,) int fold of each row, F labels such as ``"azimuth 30"`` / ``"condition 2"``).
    Raises:
        ValueError: one line when the column is missing or there are fewer than 2 groups.
    """
    col = {"leave_azimuth_out": "azimuth_deg", "leave_condition_out": "condition"}[protocol]
    if col not in frame.columns:
        raise ValueError(f"split {protocol!r} needs a {col!r} column in the data; it has {list(frame.columns)}")
    v = frame[col].to_numpy()
    if col == "azimuth_deg":
        v = np.round(v.astype(float), 6)
    values, idx = np.unique(v, return_inverse=True)
    if len(values) < 2:
        raise ValueError(f"split {protocol!r}: the data hold {len(values)} distinct {col!r} value(s); "
                         f"need at least 2 to hold one out")
    name = "azimuth" if col == "azimuth_deg" else "condition"
    return idx, [f"{name} {x:g}" if isinstance(x, float) else f"{name} {x}" for x in values.tolist()]


def members(protocol: str, frame: pd.DataFrame, base_key, repeat_ids, train_fraction: float,
            n_source: int | None = None) -> Members:
    """Build the members of a protocol.

    Args:
        protocol: one of :data:`PROTOCOLS`.
        frame: the filtered rows; for ``transfer`` the source rows first, then the target's.
        base_key: the study's PRNG key. repeat_ids: the repeat ids to run.
        train_fraction: training share of the source rows (random, transfer).
        n_source: number of source rows (``transfer``; the rest are the target's).
    Returns:
        :class:`Members`.
    """
    n = len(frame)
    keys, rep, fold, train, test, held = [], [], [], [], [], []
    if protocol in ("random", "transfer"):
        ns = n if protocol == "random" else int(n_source)
        source = np.arange(n) < ns
        labels = ["all"]
        ks, perms = _permutations(base_key, jnp.asarray([int(r) for r in repeat_ids], jnp.uint32), ns)
        trains = _random_train(np.asarray(perms), n, int(round(train_fraction * ns)))
        for r, k, t in zip(repeat_ids, np.asarray(ks), trains):
            keys.append(k), rep.append(r), fold.append(0), train.append(t)
            held.append(source * (1.0 - t))
            test.append(held[-1] if protocol == "random" else (~source).astype(float))
    elif protocol in FOLD_PROTOCOLS:
        idx, labels = fold_groups(protocol, frame)
        for r in repeat_ids:
            kr = jax.random.fold_in(base_key, int(r))
            for f in range(len(labels)):
                out = (idx == f).astype(float)
                keys.append(jax.random.fold_in(kr, f)), rep.append(r), fold.append(f)
                train.append(1.0 - out), test.append(out), held.append(out)
    else:
        raise ValueError(f"split protocol {protocol!r}: choose one of {list(PROTOCOLS)}")
    return Members(np.stack([np.asarray(k) for k in keys]), np.asarray(rep, int), np.asarray(fold, int), labels,
                   np.stack(train), np.stack(test), np.stack(held))


def describe(protocol: str, train_fraction: float) -> str:
    """What a protocol's test rows are, for a table's caption (e.g. ``"test rows: a random 30 % of the rows per
    repeat"``)."""
    test_pct = f"{100 * (1 - train_fraction):.3g} %"
    text = {"random": f"test rows: a random {test_pct} of the rows per repeat",
            "transfer": f"test rows: every row of a second instrument (training: a random "
                        f"{100 * train_fraction:.3g} % of the first instrument's rows)",
            "leave_azimuth_out": "test rows: each reference azimuth's stations in turn (one fold per azimuth, "
                                 "its metrics pooled over the folds)",
            "leave_condition_out": "test rows: each well condition's rows in turn (one fold per condition, "
                                   "its metrics pooled over the folds)"}
    if protocol not in text:
        raise ValueError(f"split protocol {protocol!r}: choose one of {list(PROTOCOLS)}")
    return text[protocol]


# ------------------------------------------------------------- transfer draw
@dataclasses.dataclass(frozen=True)
class TransferDraw:
    """How the target instrument of ``split=transfer`` differs from the source build.

    The changes are what differs between two real runs of the same tool design:
    another noise realisation, the casing at another distance and magnetized
    differently, and a few tenths of a degree of magnetometer misalignment
    (re-mounted sensor board). Values are chosen a priori (docs/generalisation.md),
    never tuned on the results.

    Attributes:
        seed: noise seed of the target draw (the source's is ``dataset.seed``).
        casing_distance_scale: the casing's position (NED, m, from the lab origin at the
            sensor) times this factor (1.1: 10 % farther).
        casing_strength_scale: the casing's magnetization times this factor.
        misalignment_deg: (3,) deg added to the source's ``mag_misalignment`` effect.
    """

    seed: int = 1
    casing_distance_scale: float = 1.1
    casing_strength_scale: float = 0.85
    misalignment_deg: tuple = (0.2, -0.3, 0.2)

    def __post_init__(self):
        from icgo.core.settings import is_int, is_real, need

        if isinstance(self.misalignment_deg, list):
            object.__setattr__(self, "misalignment_deg", tuple(self.misalignment_deg))
        need(is_int(self.seed) and self.seed >= 0, "seed", f"must be an integer >= 0, got {self.seed!r}")
        for name in ("casing_distance_scale", "casing_strength_scale"):
            v = getattr(self, name)
            need(is_real(v) and v > 0, name, f"must be a number > 0 (a factor), got {v!r}")
        m = self.misalignment_deg
        need(isinstance(m, tuple) and len(m) == 3 and all(is_real(x) and abs(x) <= 5.0 for x in m),
             "misalignment_deg", f"must be three angles in deg, each within +/- 5, got {m!r}")


def transfer_survey(name: str, seed: int, kwargs: dict, draw: TransferDraw):
    """The target draw of ``split=transfer``: the simulator ``name`` with the source's
    settings changed as ``draw`` says.

    Args:
        name: ``lab_casing`` or ``well_conditions`` (:mod:`icgo.datasets.casing_stations`).
        seed: the source's noise seed (must differ from ``draw.seed``).
        kwargs: the source's extra keyword arguments.
        draw: :class:`TransferDraw`.
    Returns:
        :class:`icgo.datasets.dataset.Dataset` of the target instrument.
    """
    from icgo.datasets import casing_stations

    cs = casing_stations
    gen = {"lab_casing": (cs.lab_casing, cs.LAB_CASING, cs.LAB_EFFECTS),
           "well_conditions": (cs.well_conditions, cs.WELL_CASING, cs.WELL_EFFECTS)}
    if name not in gen:
        raise ValueError(f"split 'transfer' simulates its target with {sorted(gen)}; dataset {name!r} has no "
                         f"simulator (give split.target.path, a recording of the second instrument)")
    if int(seed) == draw.seed:
        raise ValueError(f"split.target.seed = {draw.seed} equals the source's dataset.seed; the target must be "
                         f"another noise draw")
    fn, casing0, effects0 = gen[name]
    kw = dict(kwargs)
    casing = kw.pop("casing", casing0)
    effects = dict(kw.pop("effects", effects0) or {})
    if casing is not None:
        casing = casing._replace(end_ned=tuple(draw.casing_distance_scale * np.asarray(casing.end_ned, float)),
                                 magnetization_A_m=draw.casing_strength_scale * casing.magnetization_A_m)
    mis = np.asarray(effects.get("mag_misalignment", (0.0, 0.0, 0.0)), float) + np.asarray(draw.misalignment_deg)
    effects["mag_misalignment"] = tuple(float(x) for x in mis)
    return fn(draw.seed, casing=casing, effects=effects, **kw)
