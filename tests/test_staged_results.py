"""icgo.io.files.staged_results (Output, shared): a study's files land in a shared results folder
all at once or not at all."""

from __future__ import annotations

import errno

import pytest

from icgo.core.errors import OutputError
from icgo.io.files import staged_results


def _previous(out):
    out.mkdir()
    (out / "misma_summary.md").write_text("old summary\n")
    (out / "misma_summary.json").write_text("{\"old\": 1}\n")
    (out / "other_study.csv").write_text("untouched\n")
    return {f.name: f.read_text() for f in out.iterdir()}


@pytest.mark.parametrize("failure", [KeyboardInterrupt, OSError(errno.ENOSPC, "No space left on device"), ValueError])
def test_a_failed_write_leaves_the_folder_as_it_was(tmp_path, failure):
    """The folder is unchanged; a full disk is one OutputError line saying so, anything else is re-raised carrying
    the folder (the entry point's line names it: icgo.core.settings.interrupted)."""
    out = tmp_path / "results"
    before = _previous(out)
    disk = isinstance(failure, OSError)
    with pytest.raises(OutputError if disk else failure) as e:
        with staged_results(out, last="misma_summary.json") as stage:
            (stage / "misma_summary.md").write_text("new, complete\n")
            (stage / "misma_fair_curving.csv").write_text("a,b\n1,")  # cut off mid-write
            raise failure
    assert {f.name: f.read_text() for f in out.iterdir()} == before  # no staging directory left either
    if disk:
        assert f"into {out} failed (No space left on device); nothing in it was changed" in str(e.value)
    else:
        assert e.value.icgo_unchanged == str(out)


def test_a_complete_write_replaces_only_its_files_record_last(tmp_path, monkeypatch):
    out = tmp_path / "results"
    _previous(out)
    import os

    order = []
    real = os.replace
    monkeypatch.setattr(os, "replace", lambda a, b: (order.append(os.path.basename(b)), real(a, b)))
    with staged_results(out, last="misma_summary.json") as stage:
        for name in ("misma_summary.json", "misma_summary.md", "misma_fair_curving.csv"):
            (stage / name).write_text(f"new {name}\n")
    assert order[-1] == "misma_summary.json" and len(order) == 3
    assert (out / "misma_summary.md").read_text() == "new misma_summary.md\n"
    assert (out / "other_study.csv").read_text() == "untouched\n"
    assert sorted(f.name for f in out.iterdir()) == ["misma_fair_curving.csv", "misma_summary.json",
                                                     "misma_summary.md", "other_study.csv"]


def test_figures_entry_writes_through_the_staging(tmp_path, monkeypatch):
    """experiments.figures moves its tables in only when the build finished (a failing builder changes nothing)."""
    from experiments import figures
    from icgo.io import files
    from icgo.studies.icgo_relm.results import build as results_build

    out = tmp_path / "results"
    monkeypatch.setattr(files, "RESULTS_DIR", out)  # the shared results folder
    before = _previous(out)

    def boom(dirs, stage, report_file=None):
        (stage / "table1.md").write_text("half")
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(results_build, "build", boom)
    (tmp_path / "runs").mkdir()
    with pytest.raises(OutputError):
        figures.main([str(tmp_path / "runs"), "--out", str(out)])
    assert {f.name: f.read_text() for f in out.iterdir()} == before
