"""Files in and out: bounded reads of regular files, and the one rule every writer follows.

Reading (:func:`read_bytes_bounded`, :func:`read_text_bounded`): a path is opened without blocking,
then refused in one :class:`~icgo.core.errors.DataError` line unless it is a regular file no larger
than the stated limit (a FIFO would block for ever, ``/dev/zero`` never ends, a 10 GB file would
fill the memory). The limits of each reader are listed in ``docs/data.md``.

Writing (:class:`Output`): every file a command writes is staged in a hidden folder inside the
output directory and moved into place (``os.replace``) only when all are complete; an error, a
full disk or Ctrl-C leaves the directory exactly as it was. Two kinds of output:

* a *directory of its own* (a run directory, ``out=`` of ``experiments.apply``, ``--out`` of
  ``python -m icgo.datasets``, ...): refused when it already holds files, unless ``overwrite`` is
  set, and then replaced whole (the old content is moved aside in one step and deleted once the
  new one is in place). It ends with :data:`MANIFEST`, the list of what the command wrote, and
  only a directory holding such a manifest (or a run record, ``run.json``) is ever replaced: a
  folder no icgo command wrote is refused even with ``overwrite``;
* a *shared folder* (``results/``, a data folder of ``python -m icgo.datasets``): the command's files
  replace their namesakes all at once; other files stay. Given the names it writes (``names``), it
  refuses to replace existing namesakes unless ``overwrite`` is set.

Problems with the place itself (a file where the directory should be, a read-only parent, a used
directory) are :class:`~icgo.core.errors.SettingError` lines raised by :meth:`Output.check`, before
any computation; a failure while writing is one :class:`~icgo.core.errors.OutputError` line.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
import signal
import stat
import tempfile
import threading
from pathlib import Path

from icgo.core.errors import DataError, OutputError, SettingError
from icgo.core.settings import INTERRUPT

#: The list of files a command wrote into a directory of its own, written last.
MANIFEST = ".icgo-output.json"
#: A run directory's record; a directory holding one counts as an icgo output (runs before the manifest).
RUN_RECORD = "run.json"
_STAGING = ".staging-"
_REPLACED = ".replaced-"

MiB = 1 << 20
#: Errors of the place written to, not of the program: reported in one line.
_DISK_ERRORS = (errno.ENOSPC, errno.EROFS, errno.EACCES, errno.EPERM, errno.EDQUOT, errno.EFBIG, errno.EIO,
                errno.ENOTDIR, errno.EISDIR)


# ------------------------------------------------------------------ reading
def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a directory"
    if stat.S_ISFIFO(mode):
        return "a pipe (FIFO)"
    if stat.S_ISSOCK(mode):
        return "a socket"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    return "a special file"


def open_regular(path, limit: int, what: str):
    """A regular file of at most ``limit`` bytes opened for binary reading (the caller closes it), or a one-line
    DataError naming ``path``.

    The file is opened with ``O_NONBLOCK`` (a FIFO then opens at once instead of waiting for a
    writer) and checked with ``fstat`` on the open descriptor, so what is read is what was checked.

    Args:
        path: the file. limit: the largest size accepted, bytes. what: what the file should be
            (e.g. ``"a circuitpython-mag-cal JSON"``), for the message.
    Raises:
        DataError: not found, a directory, a pipe or device, unreadable, or larger than ``limit``.
    """
    src = str(path)
    try:
        fd = os.open(src, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except FileNotFoundError:
        raise DataError(f"{src}: file not found") from None
    except IsADirectoryError:
        raise DataError(f"{src}: is a directory, not a regular file; give {what}") from None
    except OSError as e:
        raise DataError(f"{src}: cannot open ({e.strerror or type(e).__name__})") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise DataError(f"{src}: is {_kind(st.st_mode)}, not a regular file; give {what}")
        if st.st_size > limit:
            raise DataError(f"{src}: {st.st_size / MiB:.1f} MiB, over the {limit / MiB:g} MiB limit for {what} "
                            f"(docs/data.md)")
        return os.fdopen(fd, "rb", buffering=1 << 20)
    except BaseException:
        os.close(fd)
        raise


def read_bytes_bounded(path, limit: int, what: str) -> bytes:
    """The bytes of a regular file of at most ``limit`` bytes (:func:`open_regular`), or a one-line DataError."""
    src = str(path)
    with open_regular(path, limit, what) as f:
        chunks, total = [], 0
        while True:
            try:
                b = f.read(1 << 20)
            except OSError as e:
                raise DataError(f"{src}: cannot read ({e.strerror or type(e).__name__})") from None
            if not b:
                break
            total += len(b)
            if total > limit:  # grew while being read
                raise DataError(f"{src}: over the {limit / MiB:g} MiB limit for {what} (docs/data.md)")
            chunks.append(b)
        return b"".join(chunks)


def read_text_bounded(path, limit: int, what: str, encoding: str = "utf-8") -> str:
    """:func:`read_bytes_bounded` decoded (a leading BOM dropped); undecodable bytes are one DataError line."""
    data = read_bytes_bounded(path, limit, what)
    try:
        return data.decode("utf-8-sig" if encoding.lower().replace("_", "-") == "utf-8" else encoding)
    except UnicodeDecodeError as e:
        raise DataError(f"{path}: not {encoding.upper()} text ({e.reason} at byte {e.start}); give {what}") from None


# ------------------------------------------------------------------ writing
def _internal(name: str) -> bool:
    """Hidden working folders of an interrupted writer (never content; removed by the next commit)."""
    return name.startswith((_STAGING, _REPLACED)) or (name.startswith(".") and name.endswith(".tmp"))


@contextlib.contextmanager
def _uninterrupted():
    """Hold off Ctrl-C and SIGTERM while the staged files move in (a few renames), then deliver them."""
    if threading.current_thread() is not threading.main_thread() or not hasattr(signal, "pthread_sigmask"):
        yield
        return
    sigs = {signal.SIGINT, signal.SIGTERM}
    old = signal.pthread_sigmask(signal.SIG_BLOCK, sigs)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _why(e: OSError) -> str:
    return e.strerror or type(e).__name__


class Output:
    """One command's output place and its staged, all-or-nothing write (see the module docstring).

    Args:
        path: the output directory.
        setting: how the user names it (``"out"``, ``"--out"``, ``"hydra.run.dir"``), for the messages.
        overwrite: replace a used directory of its own (else it is refused).
        shared: a shared results folder (no refusal, no manifest; only the command's files replaced).
        keep: names the command leaves alone (Hydra's job log of this run).
        ignore: names that do not make a directory "used" and are replaced (a failed run's marker).
        writer: the command, recorded in the manifest.
        overwrite_hint: how to ask for a replacement, in the refusal (``overwrite=true``, ``--overwrite``).
        names: for a shared folder, the files the command writes: existing ones are refused unless
            ``overwrite`` (empty: namesakes are replaced, as in ``results/``).
    """

    def __init__(self, path, *, setting: str = "out", overwrite: bool = False, shared: bool = False, keep=(),
                 ignore=(), writer: str = "", overwrite_hint: str = "overwrite=true", names=()):
        self.path = Path(path).expanduser()
        self.setting = setting
        self.overwrite = bool(overwrite)
        self.shared = shared
        self.keep = frozenset(keep)
        self.ignore = frozenset(ignore)
        self.writer = writer
        self.hint = overwrite_hint
        self.names = tuple(names)

    # -------------------------------------------------------------- before computing
    def content(self) -> list[str]:
        """Names in the directory that make it used (its own earlier output, or anything else)."""
        if not self.path.is_dir():
            return []
        return sorted(e.name for e in self.path.iterdir()
                      if e.name not in self.keep and e.name not in self.ignore and not _internal(e.name))

    def is_icgo_output(self) -> bool:
        """Whether an icgo command wrote this directory (its manifest, or a run record)."""
        return (self.path / MANIFEST).is_file() or (self.path / RUN_RECORD).is_file()

    def check(self) -> "Output":
        """Refuse a place that cannot hold the output (one SettingError line); returns self.

        Called before any computation, so a bad ``out=`` costs nothing. The directory is created by
        :meth:`staged`, when the files are written.
        """
        p, name = self.path, f"{self.setting} {str(self.path)!r}"
        for parent in [p, *p.parents]:
            if parent.exists() or parent.is_symlink():
                if not parent.is_dir():
                    where = "is a file" if parent == p else f"is under {str(parent)!r}, which is a file"
                    raise SettingError(f"{name} {where}, not a directory; give a directory")
                break
        used = self.content()
        held = [n for n in self.names if (p / n).exists() or (p / n).is_symlink()] if p.is_dir() else []
        if self.shared and held and not self.overwrite:
            raise SettingError(f"{name} already holds {', '.join(held)} (this command's files); choose another "
                               f"directory, or pass {self.hint} to replace them (its other files stay)")
        if used and not self.shared:
            shown = ", ".join(used[:3]) + (f" and {len(used) - 3} more" if len(used) > 3 else "")
            if not self.overwrite:
                raise SettingError(f"{name} already holds files ({shown}); choose a new directory, or pass "
                                   f"{self.hint} to replace its content whole")
            if not self.is_icgo_output():
                raise SettingError(f"{name} holds files that no icgo command wrote ({shown}; no {MANIFEST}); "
                                   f"{self.hint} replaces only an icgo output directory: choose a new directory")
        # created only when the files are written (a refused or failed command leaves no empty directory):
        # here it is created and removed again, to learn now whether it can be
        missing = [q for q in [p, *p.parents] if not q.exists()]
        try:
            p.mkdir(parents=True, exist_ok=True)
            writable = os.access(p, os.W_OK | os.X_OK)
        except OSError as e:
            raise SettingError(f"{name}: cannot create the directory ({_why(e)})") from None
        finally:
            for q in missing:
                with contextlib.suppress(OSError):
                    q.rmdir()
        if not writable:
            raise SettingError(f"{name}: the directory is not writable (permission denied or a read-only file "
                               f"system)")
        return self

    # -------------------------------------------------------------- writing
    @contextlib.contextmanager
    def staged(self, last=()):
        """Yield a staging directory; move its content into place when the block ends normally.

        Args:
            last: names moved in last, in this order (the record that says the output is complete).
        Raises:
            OutputError: a write failed (full disk, read-only, ...): nothing in the directory changed.
            Whatever the block raised (Ctrl-C included), after removing the staging directory.
        """
        self.check()
        created = not self.path.exists()
        try:
            self.path.mkdir(parents=True, exist_ok=True)
            stage = Path(tempfile.mkdtemp(prefix=_STAGING, dir=self.path))
        except OSError as e:
            raise OutputError(f"{self.setting} {str(self.path)!r}: cannot write ({_why(e)}); nothing was "
                              f"written") from None

        done = {"committed": False}

        def drop() -> str | None:  # on Ctrl-C (icgo.core.settings.on_interrupt): as if the command had not started
            if done["committed"]:  # the signal waited for the commit to finish: the output is complete
                return None
            shutil.rmtree(stage, ignore_errors=True)
            if created:
                with contextlib.suppress(OSError):
                    self.path.rmdir()  # only if empty
            return str(self.path)

        INTERRUPT["cleanups"].append(drop)
        try:
            try:
                yield stage
            except OSError as e:
                if e.errno in _DISK_ERRORS:
                    raise OutputError(f"writing into {self.path} failed ({_why(e)}); nothing in it was "
                                      f"changed") from None
                e.icgo_unchanged = str(self.path)
                raise
            except BaseException as e:  # Ctrl-C, a bug: the entry point says what happened, and this
                e.icgo_unchanged = str(self.path)
                raise
            try:
                with _uninterrupted():  # a signal arriving during the commit is handled after it, then it's done
                    self._commit(stage, tuple(last))
                    done["committed"] = True
            except OSError as e:
                raise OutputError(f"moving the new files into {self.path} failed ({_why(e)}); the previous "
                                  f"content is unchanged") from None
        finally:
            INTERRUPT["cleanups"].remove(drop)
            shutil.rmtree(stage, ignore_errors=True)
            if created and self.path.is_dir() and not any(self.path.iterdir()):
                self.path.rmdir()  # a failed first write leaves no empty directory either

    def _commit(self, stage: Path, last: tuple) -> None:
        """Move the staged files in (``last`` last, the manifest after them); in a directory of its own, first
        move the old content aside (deleted at the end, put back if a move fails). Called with the signals held."""
        names = sorted((e.name for e in stage.iterdir()), key=lambda n: (n in last, last.index(n) if n in last else 0, n))
        if not self.shared:
            body = json.dumps({"writer": self.writer, "files": names}, indent=1) + "\n"
            (stage / MANIFEST).write_text(body)  # a full disk fails here, before anything moves
            names.append(MANIFEST)
        aside = None if self.shared else Path(tempfile.mkdtemp(prefix=_REPLACED, dir=self.path))
        moved_in: list[str] = []
        old: list[str] = []
        keep_aside = False
        try:
            if aside is not None:
                for e in list(self.path.iterdir()):
                    if e.name not in self.keep and not _internal(e.name):
                        os.replace(e, aside / e.name)
                        old.append(e.name)
            for n in names:
                os.replace(stage / n, self.path / n)
                moved_in.append(n)
        except OSError:
            for n in moved_in:  # put the previous content back
                with contextlib.suppress(OSError):
                    os.replace(self.path / n, stage / n)
            for n in old:
                try:
                    os.replace(aside / n, self.path / n)
                except OSError:
                    keep_aside = True  # never delete what could not be put back: it stays in .replaced-*
            raise
        finally:
            if aside is not None and not keep_aside:
                shutil.rmtree(aside, ignore_errors=True)  # the old content, or an empty folder after a put-back
        if not self.shared:  # working folders an interrupted writer left in this directory of its own
            for e in self.path.iterdir():
                if _internal(e.name) and e.name != stage.name:
                    shutil.rmtree(e, ignore_errors=True) if e.is_dir() else e.unlink(missing_ok=True)


def check_output_file(path, *, overwrite: bool = False, setting: str = "--out",
                      overwrite_hint: str = "--overwrite") -> Path:
    """Check, before any computation, that a single output file can be written: its directory exists and is
    writable, the path is not a directory, and an existing file is replaced only with ``overwrite``.
    The file itself is then written atomically (:func:`icgo.io.recording.atomic_write_texts`).

    Raises:
        SettingError: one line naming ``setting`` and what is wrong.
    """
    p = Path(path).expanduser()
    name = f"{setting} {str(p)!r}"
    if p.is_dir():
        raise SettingError(f"{name} is a directory; give a file name")
    if not p.parent.is_dir():
        raise SettingError(f"{name}: the directory {str(p.parent)!r} does not exist (or is a file)")
    if p.exists() and not overwrite:
        raise SettingError(f"{name} already exists; choose another name, or pass {overwrite_hint} to replace it")
    if p.exists() and not p.is_file():
        raise SettingError(f"{name} is not a regular file (a pipe or device)")
    if not os.access(p.parent, os.W_OK | os.X_OK):
        raise SettingError(f"{name}: its directory is not writable")
    return p


def json_text(obj) -> str:
    """Indented standard JSON of ``obj`` with NaN and inf written as null (Python's ``json`` would write the
    non-standard ``NaN`` / ``-Infinity``, which strict readers, icgo's own included, refuse)."""
    import math

    def clean(v):
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [clean(x) for x in v]
        return v

    return json.dumps(clean(obj), indent=2, allow_nan=False) + "\n"


def staged_results(out, last: str | None = None):
    """The files of a study into a shared results folder, all at once or none (:class:`Output`, ``shared``)."""
    return Output(out, setting="--out", shared=True).staged(last=(last,) if last else ())


#: The repository's shared results folder (``results/`` beside ``icgo/``): the commands regenerate their own files
#: in it and leave the others.
RESULTS_DIR = Path(__file__).resolve().parents[2] / "results"


def results_output(out, *, overwrite: bool = False, writer: str = "") -> Output:
    """The :class:`Output` of a command's ``--out``, checked (one SettingError line).

    The repository's ``results/`` (:data:`RESULTS_DIR`) is a shared folder: the command's files replace their
    namesakes, the others stay. Any other directory is the command's own: refused when it already holds
    files, unless ``--overwrite``, which replaces its content whole.
    """
    p = Path(out).expanduser()
    try:
        shared = p.resolve() == RESULTS_DIR.resolve()
    except (OSError, RuntimeError):
        shared = False
    return Output(p, setting="--out", overwrite=overwrite, shared=shared, writer=writer,
                  overwrite_hint="--overwrite").check()
