"""icgo.io.files: bounded reads of regular files, and the one writer rule (staged, refuse a used directory,
replace whole with overwrite, only an icgo output directory)."""

from __future__ import annotations

import errno
import json
import os

import pytest

from icgo.core.errors import DataError, OutputError, SettingError
from icgo.io.files import MANIFEST, Output, check_output_file, json_text, read_text_bounded


def test_a_regular_file_under_the_limit_is_read(tmp_path):
    p = tmp_path / "a.json"
    p.write_bytes("\ufeff{\"x\": 1}".encode())
    assert read_text_bounded(p, 100, "a JSON") == '{"x": 1}'  # the BOM dropped


@pytest.mark.parametrize("kind", ["fifo", "dir", "device", "missing", "big", "binary"])
def test_what_is_not_a_small_regular_file_is_one_line(tmp_path, kind):
    p = tmp_path / "f.json"
    if kind == "fifo":
        os.mkfifo(p)  # a reader opening it would block for ever
    elif kind == "dir":
        p.mkdir()
    elif kind == "device":
        p.symlink_to("/dev/zero")  # never ends
    elif kind == "big":
        p.write_text("x" * 101)
    elif kind == "binary":
        p.write_bytes(b"\xff\xfe\xfa")
    with pytest.raises(DataError) as e:
        read_text_bounded(p, 100, "a JSON")
    msg = str(e.value)
    assert "\n" not in msg and str(p) in msg
    assert {"fifo": "pipe", "dir": "directory", "device": "device", "missing": "not found", "big": "limit",
            "binary": "UTF-8"}[kind] in msg


def _files(d):
    return sorted(p.name for p in d.iterdir())


def test_a_directory_of_its_own_is_written_whole_with_its_manifest(tmp_path):
    out = tmp_path / "o"
    o = Output(out, writer="t").check()
    assert not out.exists()  # created only when written
    with o.staged(last=("b",)) as stage:
        (stage / "a").write_text("1")
        (stage / "b").write_text("2")
    assert _files(out) == [MANIFEST, "a", "b"]
    assert json.loads((out / MANIFEST).read_text()) == {"writer": "t", "files": ["a", "b"]}


def test_a_used_directory_is_refused_then_replaced_whole_with_overwrite(tmp_path):
    out = tmp_path / "o"
    with Output(out).staged() as stage:
        (stage / "old").write_text("old")
    with pytest.raises(SettingError, match="already holds files .*overwrite=true"):
        Output(out).check()
    keep = out / "job.log"
    keep.write_text("log")
    with Output(out, overwrite=True, keep=("job.log",)).staged() as stage:
        (stage / "new").write_text("new")
    assert _files(out) == [MANIFEST, "job.log", "new"]  # the old file gone, the log kept


def test_overwrite_replaces_only_what_an_icgo_command_wrote(tmp_path):
    (tmp_path / "notes.txt").write_text("mine")
    with pytest.raises(SettingError, match="no icgo command wrote"):
        Output(tmp_path, overwrite=True).check()
    assert _files(tmp_path) == ["notes.txt"]


@pytest.mark.parametrize("where", ["file", "under-file", "dev-null"])
def test_a_place_that_cannot_be_a_directory_is_refused_before_anything(tmp_path, where):
    (tmp_path / "f").write_text("x")
    path = {"file": tmp_path / "f", "under-file": tmp_path / "f" / "sub", "dev-null": "/dev/null/x"}[where]
    with pytest.raises(SettingError, match="not a directory"):
        Output(path, setting="--out").check()


@pytest.mark.parametrize("failure", [OSError(errno.ENOSPC, "No space left on device"), KeyboardInterrupt()])
def test_a_failed_write_changes_nothing(tmp_path, failure):
    out = tmp_path / "o"
    with Output(out).staged() as stage:
        (stage / "old").write_text("old")
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    with pytest.raises(OutputError if isinstance(failure, OSError) else KeyboardInterrupt):
        with Output(out, overwrite=True).staged() as stage:
            (stage / "new").write_text("half")
            raise failure
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    fresh = tmp_path / "fresh"
    with pytest.raises(OutputError):
        with Output(fresh).staged():
            raise OSError(errno.EFBIG, "File too large")
    assert not fresh.exists()  # a failed first write leaves no empty directory


def test_a_shared_folder_keeps_the_other_files(tmp_path):
    (tmp_path / "other.md").write_text("other")
    (tmp_path / "mine.md").write_text("old")
    with Output(tmp_path, shared=True).staged() as stage:
        (stage / "mine.md").write_text("new")
    assert (tmp_path / "other.md").read_text() == "other" and (tmp_path / "mine.md").read_text() == "new"
    assert _files(tmp_path) == ["mine.md", "other.md"]  # no manifest in a shared folder


def test_a_single_output_file(tmp_path):
    f = tmp_path / "r.json"
    assert check_output_file(f) == f
    f.write_text("{}")
    with pytest.raises(SettingError, match="already exists"):
        check_output_file(f)
    assert check_output_file(f, overwrite=True) == f
    with pytest.raises(SettingError, match="is a directory"):
        check_output_file(tmp_path)


def test_json_text_writes_standard_json():
    assert json.loads(json_text({"a": float("nan"), "b": [float("-inf"), 1.5]})) == {"a": None, "b": [None, 1.5]}
