"""The hostile battery of every front door (tests/hostile_battery.py): each case's outcome must be ``clean``.

The fast subset (``FAST_CASES``: every front door at least once, a few seconds each) runs in ``make test``;
the whole battery (about 716 invocations) under ``-m slow``, or with its own summary table::

    .venv/bin/python tests/hostile_battery.py --jobs 2
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
import hostile_battery as B  # noqa: E402

CASES = B.all_cases()


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    base = tmp_path_factory.mktemp("hostile")
    B.make_assets(base)
    return base


def _run(case, base):
    r = B.run_case(case, B.make_assets(base), base / "work")
    if r.outcome == "skipped":
        pytest.skip(r.detail)
    assert r.outcome == "clean", f"{case.name}: {r.outcome}: {r.detail}"


def test_the_fast_subset_covers_every_front_door():
    doors = {c.door for c in CASES}
    assert {c.door for c in CASES if c.fast} >= doors - {"experiments.roofline", "experiments.bench"}
    assert len(CASES) >= 424  # at least the size of the battery the issue was filed with


@pytest.mark.parametrize("case", [c for c in CASES if c.fast], ids=lambda c: c.name)
def test_hostile_case(case, base):
    _run(case, base)


@pytest.mark.slow
@pytest.mark.parametrize("case", [c for c in CASES if not c.fast], ids=lambda c: c.name)
def test_hostile_case_full(case, base):
    _run(case, base)


def test_classify_reads_each_outcome():
    """The classifier itself, on made-up process results (it must be able to say every outcome)."""
    case = B.Case("x", "d", [], says=("x.csv",))
    ran = lambda rc, err="", out="", **kw: B._Ran(rc, out, err, kw.get("t", False), 0.0, kw.get("cap", False))  # noqa
    assert B.classify(case, ran(1, "error: x.csv: bad\n"))[0] == "clean"
    assert B.classify(case, ran(1, "error: y.csv: bad\n"))[0] == "unclear"
    assert B.classify(case, ran(1, "error: x.csv: bad\nmore\n"))[0] == "unclear"
    assert B.classify(case, ran(0))[0] == "silent"
    assert B.classify(case, ran(1, "Traceback (most recent call last):\n  boom\n"))[0] == "traceback"
    assert B.classify(case, ran(-11))[0] == "traceback"
    assert B.classify(case, ran(None, t=True))[0] == "hang"
    assert B.classify(case, ran(None, cap=True))[0] == "oom"
    stop = B.Case("y", "d", [], expect="interrupt")
    assert B.classify(stop, ran(130, "interrupted: nothing in o was changed\n"))[0] == "clean"
    assert B.classify(stop, ran(1, "KeyboardInterrupt\n"))[0] == "unclear"
