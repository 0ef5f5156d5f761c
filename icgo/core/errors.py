"""One error hierarchy: every problem a user can cause is an :class:`IcgoError` with a one-line message.

Front doors print ``str(err)`` and exit 2 for a :class:`SettingError` (a bad setting or
argument), 1 for any other :class:`IcgoError` (bad data, a bad model file, a run record that
does not follow the schema). Each subclass is a ``ValueError``, so library callers that catch
``ValueError`` keep working.
"""

from __future__ import annotations


class IcgoError(ValueError):
    """Base of every user-facing problem; ``str(err)`` is the line to print."""


class SettingError(IcgoError):
    """A bad setting: a config field, a command-line key or an entry-point argument (exit status 2).

    ``SettingError(field, problem)`` reads ``"<field> <problem>"``; entry points rename ``field``
    to their own key (``n_repeats`` -> ``split.n_repeats``). ``SettingError(message)`` is a whole
    line that names its setting itself (``field`` and ``problem`` are then None).

    Attributes:
        field: the dataclass field or key, or None.
        problem: the rest of the message, or None.
        problems: every line of the message (one per bad value when several are reported at once).
    """

    def __init__(self, field: str, problem: str | None = None):
        message = field if problem is None else f"{field} {problem}"
        super().__init__(message)
        self.field = None if problem is None else field
        self.problem = problem
        self.problems = (message,)


class SettingsError(SettingError):
    """Several bad settings reported at once, one line each (``problems``)."""

    def __init__(self, problems):
        problems = tuple(problems)
        super().__init__("\n".join(problems))
        self.problems = problems


class DataError(IcgoError):
    """Bad input data (a recording, a JSON layout): one line naming the file, row and column."""


class GroupingError(DataError):
    """Shots that were read, but whose groups cannot be made (no roll found, too noisy to find one, rolls about
    another axis than the pointing axis): the calibrate door writes its report with the reason (one line)."""


class ModelError(IcgoError):
    """A bad model file, or a model that does not fit the survey it is applied to (one line)."""


class RecordError(IcgoError):
    """A run directory or table that does not follow the run-record schema (one line naming the file)."""


class OutputError(IcgoError):
    """An output that could not be written (a full or read-only disk, a path under a file): one line naming the
    place; nothing that was there before is changed (exit status 1)."""
