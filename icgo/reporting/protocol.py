"""The reporting rules every table of ``results/`` follows, as code (``docs/reporting.md``).

* :func:`protocol_line`: the one line that says how a table was made: the command that regenerates it,
  the repeats, the split, the seeds and the statistical test (and its family for Holm's adjustment).
  :func:`parse_protocols` reads those lines back (``tests/test_reporting.py`` checks every table has one).
* :func:`settings_line`: the stamp of a table: the budget, repeats and dtype of the runs its numbers come from, and
  whether that is the published protocol (``tests/test_reporting.py`` checks every table has one).
* :func:`comparison`: the only wording a table uses to call one method better than another: Holm-adjusted
  p below :data:`ALPHA` *and* the effect size beside it; otherwise "no significant difference".
"""

from __future__ import annotations

import math
import re

#: Family-wise significance level of every "better" (Holm-adjusted p-values).
ALPHA = 0.05

#: The fields of a protocol line, in order.
PROTOCOL_FIELDS = ("command", "repeats", "split", "seeds", "test")

_PREFIX = "Protocol: "
#: How a table's stamp line starts.
SETTINGS_PREFIX = "Run settings: "
#: How the environment sentence of a stamp starts (the last sentence of its line).
ENVIRONMENT_PREFIX = "Environment: "
_FIELD = re.compile(r"(?:^|; )(" + "|".join(PROTOCOL_FIELDS) + r"): ")


def protocol_line(command: str, repeats: str, split: str, seeds: str, test: str) -> str:
    """``Protocol: command: ...; repeats: ...; split: ...; seeds: ...; test: ...`` (one Markdown line).

    Args:
        command: the command(s) that regenerate the table (Markdown code spans).
        repeats: how many repeats (seeds, splits) each number pools, and whether they are paired.
        split: which rows fit and which rows score (or "none: ..." where nothing is held out).
        seeds: the data and search seeds reported, and the seeds any choice was made on where that applies.
        test: the statistical test and its Holm family, or "none" with the reason.
    """
    values = dict(zip(PROTOCOL_FIELDS, (command, repeats, split, seeds, test)))
    for k, v in values.items():
        if not str(v).strip():
            raise ValueError(f"protocol_line: {k} is empty")
        if re.search(r"; (" + "|".join(PROTOCOL_FIELDS) + r"): ", str(v)):
            raise ValueError(f"protocol_line: {k} contains another field's label: {v!r}")
    return _PREFIX + "; ".join(f"{k}: {str(v).strip()}" for k, v in values.items())


def settings_line(budget: str, repeats: str, dtype: str, paper: str, environment: str | None = None) -> str:
    """``Run settings: <budget>, <repeats>, <dtype>. <paper> Environment: <environment>.`` (one Markdown line): the
    stamp of a table, from the runs its numbers come from.

    Args:
        budget: what each search or fit was given (population x iterations, evaluations, steps, epochs).
        repeats: how many repeats (seeds, runs) each number pools.
        dtype: the floating-point type the search or fit ran in.
        paper: whether these are the published protocol's settings, which ones differ, or that the source gives none.
        environment: the software and hardware the numbers were made with (:func:`icgo.core.environment.describe`
            of the runs' records); None: this process's (a writer that computes its numbers where it writes them).
    """
    for k, v in (("budget", budget), ("repeats", repeats), ("dtype", dtype), ("paper", paper)):
        if not str(v).strip():
            raise ValueError(f"settings_line: {k} is empty")
    if environment is None:
        from icgo.core.environment import here

        environment = here()
    return (f"{SETTINGS_PREFIX}{budget.strip()}, {repeats.strip()}, {dtype.strip()}. {paper.strip()} "
            f"{ENVIRONMENT_PREFIX}{environment.strip().rstrip('.')}.")


def parse_protocols(text: str) -> list[dict]:
    """Every protocol line of a Markdown text as ``{field: value}`` (fields missing from a line are absent)."""
    out = []
    for line in text.splitlines():
        if not line.startswith(_PREFIX):
            continue
        body = line[len(_PREFIX):]
        marks = list(_FIELD.finditer(body))
        fields = {}
        for i, m in enumerate(marks):
            end = marks[i + 1].start() if i + 1 < len(marks) else len(body)
            fields[m.group(1)] = body[m.end():end].strip()
        out.append(fields)
    return out


def fmt_p(p: float) -> str:
    """A p-value for prose: 3 significant digits."""
    return "nan" if not math.isfinite(p) else f"{p:.3g}"


def comparison(a: str, b: str, p_holm: float, effect: float, unit: str = "deg", family: int | None = None) -> str:
    """One sentence comparing ``a`` with ``b``: "better" only at Holm-adjusted p < :data:`ALPHA`, with the effect.

    Args:
        a, b: the two methods' names.
        p_holm: the Holm-adjusted p-value of the paired test of ``a`` against ``b``.
        effect: ``a - b`` in ``unit`` (median of the paired differences, or as the table states); negative means
            ``a`` is lower (better, for an error).
        unit: the effect's unit.
        family: the size of the Holm family (said in the sentence when given).
    """
    fam = f", Holm over {family} tests" if family else ", Holm-adjusted"
    size = f"paired difference {effect:+.4g} {unit}".rstrip()
    if not (math.isfinite(p_holm) and p_holm < ALPHA):
        return f"{a} vs {b}: no significant difference (p = {fmt_p(p_holm)}{fam}; {size})"
    winner, loser = (a, b) if effect < 0 else (b, a)
    return f"{winner} significantly better than {loser} (p = {fmt_p(p_holm)}{fam}; {a} - {b}: {size})"
