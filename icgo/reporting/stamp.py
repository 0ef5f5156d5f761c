"""What a table or figure of ``results/`` was made from: budget, repeats, search dtype, and whether that is the paper's
protocol, stamped on every Markdown table and every figure title by the builders of
:mod:`icgo.studies.icgo_relm.results`; and the table's protocol line (command, repeats, split, seeds, test:
:func:`icgo.reporting.protocol.protocol_line`) from the same runs.

The runs of the output being built are held in a context variable set by :func:`stamping` around each builder: the
runs it was started with, and every run whose rows the builder then reads (:func:`use`, called by
:class:`icgo.reporting.run_collection.Runs` when it hands out a run's rows). So each table's stamp and protocol line
describe the runs its numbers come from, not every run collected, and the builders'
:func:`icgo.reporting.table_writer.write_table` and :func:`save` calls stamp without passing it along. A run's
settings are read from the resolved ``config.yaml`` of its run directory (every run of ``experiments.run`` writes
one).
"""

from __future__ import annotations

import contextlib
import contextvars
from pathlib import Path

#: The ICGO paper's protocol: population 30, 100 iterations, repeats of a random 7:3 split.
PAPER_POP, PAPER_ITERATIONS = 30, 100

_CURRENT: contextvars.ContextVar[list | None] = contextvars.ContextVar("stamp", default=None)


def run_settings(run_dir: Path) -> dict:
    """Budget, repeats, dtype and split of one run from its ``config.yaml`` (empty values when it has none)."""
    import yaml

    try:
        cfg = yaml.safe_load((Path(run_dir) / "config.yaml").read_text()) or {}
    except (OSError, ValueError, yaml.YAMLError):
        cfg = {}
    b, s, d = cfg.get("budget") or {}, cfg.get("split") or {}, cfg.get("dataset") or {}
    precision = cfg.get("precision", cfg.get("dtype"))  # a run directory written before the key was ``precision``
    return {"pop_size": b.get("pop_size"), "iterations": b.get("iterations"), "max_evals": b.get("max_evals"),
            "dtype": precision, "n_repeats": s.get("n_repeats"), "protocol": s.get("protocol"),
            "train_fraction": s.get("train_fraction"), "split_seed": s.get("seed"), "dataset": d.get("name"),
            "data_seed": d.get("seed"), "environment": run_environment(run_dir)}


def run_environment(run_dir: Path) -> str:
    """The environment one run recorded (run.json's ``environment``, :func:`icgo.core.environment.describe`), or
    ``"not recorded"`` (a run from before runs recorded it, or no run.json)."""
    import json

    from icgo.core.environment import describe as describe_env

    try:
        env = json.loads((Path(run_dir) / "run.json").read_text()).get("environment")
    except (OSError, ValueError, AttributeError):
        env = None
    return describe_env(env)


def environments(settings: list[dict]) -> str:
    """Each distinct environment of the runs, joined by ``"; "`` (the stamp's environment sentence). Rows reproduce
    bitwise only in the same environment; across environments the pooled claims hold (docs/relm_study.md)."""
    envs = list(dict.fromkeys(s.get("environment") or "not recorded" for s in settings)) or ["not recorded"]
    return "; ".join(envs)


def describe(settings: list[dict]) -> dict:
    """The stamp of an output made from runs with these settings: ``{"text", "short", "paper", "repeats", "split",
    "seeds"}`` (the last three: the fields of its protocol line).

    ``paper`` is True when every run used the paper's population and iterations (or its equal-evaluation
    variant) on the random 7:3 protocol; the text then says so, else it says which budget it was and
    that the numbers are not the paper's protocol.
    """
    seen = []
    for s in settings:
        key = (s.get("pop_size"), s.get("iterations"), s.get("max_evals"), s.get("dtype"), s.get("n_repeats"))
        if key not in seen:
            seen.append(key)
    if not seen:
        return {"text": "", "short": "", "paper": False, **_split_and_seeds(settings)}
    paper = all(p == PAPER_POP and (it == PAPER_ITERATIONS or ev is not None) for p, it, ev, _, _ in seen) and all(
        s.get("protocol") in (None, "random") for s in settings)
    from icgo.reporting.protocol import settings_line

    parts = []
    for p, it, ev, dt, n in seen:
        budget = f"population {p} x {it} iterations" if ev is None else f"population {p}, {ev} fitness evaluations"
        parts.append((budget, f"{n} repeat(s) per run", f"search dtype {dt}"))
    text = settings_line("; ".join(", ".join(x) for x in parts[:-1]) + ("; " if len(parts) > 1 else "")
                         + parts[-1][0], parts[-1][1], parts[-1][2],
                         "The paper's protocol (population 30 x 100 iterations)." if paper else
                         "NOT the paper's protocol (population 30 x 100 iterations): compare with the paper's numbers "
                         "only as a smoke check.", environments(settings))
    p, it, ev, _, n = seen[0]
    short = (f"{p} x {it if ev is None else str(ev) + ' evals'}, {n} repeat(s)" + ("" if len(seen) == 1 else ", mixed")
             + ("" if paper else ": NOT the paper's protocol"))
    return {"text": text, "short": short, "paper": paper, **_split_and_seeds(settings)}


def _values(settings: list[dict], key: str) -> list:
    """The distinct values of ``key`` over the runs, in first-seen order (None left out)."""
    out = []
    for s in settings:
        v = s.get(key)
        if v is not None and v not in out:
            out.append(v)
    return out


def _split_and_seeds(settings: list[dict]) -> dict:
    """The protocol line's repeats, split and seeds fields for runs with these settings."""
    def listed(key, unknown="not recorded"):
        v = _values(settings, key)
        return ", ".join(str(x) for x in v) if v else unknown

    repeats = listed("n_repeats")
    fractions = _values(settings, "train_fraction")
    parts = []
    for protocol in _values(settings, "protocol") or ["random"]:
        if protocol == "random":
            share = " / ".join(f"{round(10 * f):g}:{round(10 * (1 - f)):g}" for f in fractions) or "7:3"
            parts.append(f"random {share} of the 3-sigma-filtered rows, a new permutation per repeat; fitted (search "
                         "fitness, MSA, ridge) on the training rows only, scored on the test rows")
        else:
            parts.append(f"{protocol} (docs/generalisation.md)")
    seeds = (f"data: {listed('dataset', 'the data set')} with noise seed {listed('data_seed')}; repeat k: split and "
             f"search key fold_in(PRNGKey({listed('split_seed')}), k), the same for every method (paired repeats). "
             + seeds_choices([(s.get("dataset"), s.get("data_seed")) for s in settings]))
    return {"repeats": f"{repeats} per run (paired: the same splits and keys for every method)",
            "split": "; ".join(parts), "seeds": seeds}


def seeds_choices(data) -> str:
    """What was chosen on data, for the seeds field of a one-draw table made from ``data`` ((dataset, seed) pairs):
    the ridge and the tuned RELM's grid, and, on a development seed, that the table is one draw and not a claim."""
    from icgo.reporting.choices import LAMBDA, development_note

    notes = [n for n in dict.fromkeys(development_note(d, s) for d, s in data) if n]
    return (f"Settings chosen on data: {LAMBDA.sentence()}; the tuned RELM chooses on validation rows inside each "
            "training set" + "".join(f"; {n}" for n in notes))


@contextlib.contextmanager
def stamping(settings: list[dict]):
    """Within the block, :func:`note`, :func:`protocol` and :func:`title` give the stamp of runs with these settings
    and of every run :func:`use` adds."""
    token = _CURRENT.set(list(settings))
    try:
        yield
    finally:
        _CURRENT.reset(token)


def use(settings: list[dict]) -> None:
    """Add runs the output being built reads (no effect outside :func:`stamping`; a run already there counts once)."""
    runs = _CURRENT.get()
    if runs is not None:
        runs.extend(s for s in settings if s not in runs)


def _current() -> dict | None:
    runs = _CURRENT.get()
    return describe(runs) if runs is not None else None


def note() -> str:
    """The stamp line for a Markdown table (empty outside :func:`stamping`)."""
    s = _current()
    return s["text"] if s else ""


def protocol(command: str, test: str, repeats: str | None = None, split: str | None = None,
             seeds: str | None = None) -> str:
    """The protocol line of the table being built (:func:`icgo.reporting.protocol.protocol_line`): repeats, split and
    seeds from the runs it is made from (within :func:`stamping`), unless given."""
    from icgo.reporting.protocol import protocol_line

    s = _current() or _split_and_seeds([])
    return protocol_line(command, repeats or s["repeats"], split or s["split"], seeds or s["seeds"], test)


def title(text: str) -> str:
    """A figure title with the stamp's short form on a second line."""
    s = _current()
    return f"{text}\n[{s['short']}]" if s and s["short"] else text


def save(fig, path, text: str, dpi: int = 120) -> None:
    """:func:`icgo.reporting.plots.save_figure` with the stamped title."""
    from icgo.reporting.plots import save_figure

    save_figure(fig, path, title(text), dpi=dpi)
