"""The mechanical reporting rules of docs/reporting.md, checked over results/, README.md and docs/.

* every table of results/ states its protocol (command, repeats, split, seeds, test);
* every p-value column has its Holm-adjusted column, and every p quoted in a table's notes is adjusted;
* the papers' values stand beside ours in the tables that report the same quantity;
* a README / docs paragraph that names a results/ file quotes its decimal numbers from that file;
* the MISMA study reports a seed its choices were not made on.
"""

from __future__ import annotations

import glob
import json
import math
import re
from pathlib import Path

import pytest

from icgo.reporting.protocol import ALPHA, PROTOCOL_FIELDS, comparison, parse_protocols, protocol_line

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"

#: Markdown files of results/ that are not study tables (the protocol line does not apply), and why.
EXEMPT = {
    "performance.md": "a benchmark (one run, ratios within it: docs/performance.md), not a method comparison",
    "bench_cpu.md": "a benchmark (one run, ratios within it: docs/performance.md), not a method comparison",
    "bench_gpu_check_cpu.md": "a benchmark (the per-backend check, one run: docs/performance.md), not a method "
                              "comparison",
}


def _result_tables() -> list[Path]:
    return sorted(p for p in RESULTS.rglob("*.md") if str(p.relative_to(RESULTS)) not in EXEMPT)


def test_the_exemptions_name_existing_files():
    for name in EXEMPT:
        assert (RESULTS / name).exists(), f"results/{name} is exempt but does not exist: drop it from EXEMPT"


# ---------------------------------------------------------------------------------------------- protocol line
def test_protocol_line_round_trip_and_refusals():
    line = protocol_line("`make x`", "10 (paired)", "random 7:3", "data 0; keys fold_in(0, k)", "Wilcoxon; Holm")
    assert parse_protocols(f"# t\n\n{line}\n") == [dict(zip(PROTOCOL_FIELDS, ("`make x`", "10 (paired)", "random 7:3",
                                                                            "data 0; keys fold_in(0, k)",
                                                                            "Wilcoxon; Holm")))]
    with pytest.raises(ValueError, match="test is empty"):
        protocol_line("c", "r", "s", "d", " ")
    with pytest.raises(ValueError, match="another field"):
        protocol_line("c", "r; seeds: 3", "s", "d", "t")


def test_comparison_says_better_only_below_alpha_and_gives_the_effect():
    assert comparison("A", "B", 0.01, -0.004, family=3) == (
        "A significantly better than B (p = 0.01, Holm over 3 tests; A - B: paired difference -0.004 deg)")
    assert comparison("A", "B", 0.01, +0.004).startswith("B significantly better than A")
    assert comparison("A", "B", ALPHA, -0.004).startswith("A vs B: no significant difference (p = 0.05")
    assert "no significant difference" in comparison("A", "B", math.nan, -1.0)


@pytest.mark.parametrize("path", _result_tables(), ids=lambda p: str(p.relative_to(RESULTS)))
def test_every_result_table_states_its_protocol(path):
    lines = parse_protocols(path.read_text())
    assert lines, f"{path.relative_to(ROOT)}: no 'Protocol: command: ...; repeats: ...; split: ...; seeds: ...; " \
                  "test: ...' line (icgo.reporting.protocol.protocol_line)"
    for fields in lines:
        missing = [f for f in PROTOCOL_FIELDS if not fields.get(f)]
        assert not missing, f"{path.relative_to(ROOT)}: protocol line without {missing}"
        assert "`" in fields["command"], f"{path.relative_to(ROOT)}: the command is not a code span"


# ---------------------------------------------------------------------------------------------- Holm
_P_HEADER = re.compile(r"(?i)(?<![a-z^])p(?![a-z])|p-value")
_P_PROSE = re.compile(r"(?<![\w.])p\s*(=|<|>|<=|>=)\s*\d")


def _tables(text: str) -> list[list[str]]:
    """The header cells of every Markdown table of ``text``."""
    out, prev = [], ""
    for line in text.splitlines():
        if line.startswith("|") and not prev.startswith("|"):
            out.append([c.strip() for c in re.split(r"(?<!\\)\|", line.strip())[1:-1]])
        prev = line
    return out


def _holm_files() -> list[Path]:
    return [p for p in _result_tables() if p.name not in ("performance.md", "bench_cpu.md", "bench_gpu_check_cpu.md")]


@pytest.mark.parametrize("path", _holm_files(), ids=lambda p: str(p.relative_to(RESULTS)))
def test_every_p_value_is_holm_adjusted(path):
    text = path.read_text()
    for header in _tables(text):
        p_cols = [h for h in header if _P_HEADER.search(h)]
        if p_cols:
            assert any("holm" in h.lower() for h in header), (
                f"{path.relative_to(ROOT)}: p-value column(s) {p_cols} without a Holm-adjusted column")
    for line in text.splitlines():
        if line.startswith("|") or line.startswith("Protocol: ") or not _P_PROSE.search(line):
            continue
        assert re.search(r"(?i)holm|family of one", line), (
            f"{path.relative_to(ROOT)}: a p-value in the notes that is not said to be Holm-adjusted: {line[:160]}")


def test_the_holm_check_catches_a_raw_p_column():
    assert _tables("x\n\n| method | p |\n|---|---|\n| a | 0.01 |\n") == [["method", "p"]]
    assert _P_HEADER.search("p_value") and _P_HEADER.search("Friedman p (Holm)") and not _P_HEADER.search("pop_size")
    assert not _P_HEADER.search("R^2 paper") and not _P_HEADER.search("params_within_median")


# ---------------------------------------------------------------------------------------------- papers' values
def _paper_values() -> dict:
    from icgo.reporting.published import ICGO, ICGO_LAB_MAE, MISMA

    t4 = [v for row in ICGO["table4"] for v in row[2:]]
    return {
        "table1.md": [v for r in ICGO["table1"].values() for v in r],
        "table2.md": [v for r in ICGO["table2"].values() for v in r],
        "table3.md": [v for r in ICGO["table3"].values() for pair in r for v in pair],
        "table4.md": t4,
        "fig9.md": list(ICGO["fig9"]["cgo-original"]),
        "generalisation.md": [v for v, _ in ICGO_LAB_MAE.values()],
        "misma_summary.md": [MISMA["fig10"]["sma"], MISMA["fig10"]["misma"], *MISMA["fig11_first2"].values(),
                             *MISMA["fig11_rest"].values(), MISMA["fig7_faster_pct"]],
    }


@pytest.mark.parametrize("name", sorted(_paper_values()))
def test_the_papers_values_stand_beside_ours(name):
    text = (RESULTS / name).read_text()
    numbers = {float(x) for x in re.findall(r"\d+\.\d+", text)}
    missing = [v for v in _paper_values()[name] if not any(abs(v - x) < 1e-9 for x in numbers)]
    assert not missing, f"results/{name} lacks the paper's {missing} (icgo.reporting.published)"


def test_one_copy_of_the_published_values():
    from experiments import figures
    from icgo.datasets.protocols import TABLE4_ORIGINAL
    from icgo.reporting.published import ICGO

    assert figures.PAPER is ICGO
    assert [tuple(r[2:4]) for r in ICGO["table4"]] == [tuple(r) for r in TABLE4_ORIGINAL]


# ---------------------------------------------------------------------------------------------- seeds
def test_misma_reports_a_seed_its_choices_were_not_made_on():
    from icgo.studies.misma import DEVELOPMENT_SEEDS, MismaConfig

    assert MismaConfig().seed not in DEVELOPMENT_SEEDS
    reported = json.loads((RESULTS / "misma_summary.json").read_text())["config"]["seed"]
    assert reported not in DEVELOPMENT_SEEDS, f"results/misma_* report development seed {reported}"


# ---------------------------------------------------------------------------------------------- prose quotes
#: Notes whose prose is not checked here, and why (design.md and engineering-notes.md are copies of the project's
#: source documents; the rest is pending).
DOCS_NOT_CHECKED = {
    "design.md": "a copy of the project's design document",
    "engineering-notes.md": "a copy of the project's engineering notes",
}
DOCS = [ROOT / "README.md"] + sorted(p for p in (ROOT / "docs").glob("*.md") if p.name not in DOCS_NOT_CHECKED)
_CITE = re.compile(r"results/([\w./<>*{},-]+)")
_DECIMAL = re.compile(r"(?<![\w.^/])[-+]?\d+\.\d+(?:e[-+]?\d+)?(?![\w.]*\d)")
_ANY_NUMBER = re.compile(r"[-+]?\d+\.?\d*(?:[eE][-+]?\d+)?")


def _units(text: str):
    """(text, cited result files) per paragraph or list item; a table inherits the citations of the paragraph
    before it."""
    blocks, cur = [], []
    for line in text.splitlines():
        starts_item = re.match(r"\s*([-*] |\d+\. )", line) and cur and not cur[-1].lstrip().startswith("|")
        if not line.strip() or line.startswith("#") or starts_item or (
                cur and line.lstrip().startswith("|") != cur[-1].lstrip().startswith("|")):
            if cur:
                blocks.append(cur)
            cur = [] if (not line.strip() or line.startswith("#")) else [line]
        else:
            cur.append(line)
    if cur:
        blocks.append(cur)
    def cited(t):
        return {m.group(1).rstrip(".,)`") for m in _CITE.finditer(t)}

    prev = set()
    for b in blocks:
        t = "\n".join(b)
        if not all(x.lstrip().startswith("|") for x in b):
            prev = cited(t)
            yield t, prev
        elif cited(t):  # a table whose rows cite files: each row quotes its own
            yield from ((row, cited(row)) for row in b)
        else:  # a table of numbers introduced by the paragraph before it
            yield t, prev


#: Files of results/ that exist only when something is missing or excluded (a citation of one names no number).
CONDITIONAL = ("tables_missing.txt", "excluded_repeats.txt")


def _resolve(cite: str, numbers_only: bool = True) -> list[Path]:
    """The result files a citation names: a file, ``X.{md,csv}``, ``X.*``, ``X_<variant>.csv``, a directory; only
    the Markdown, CSV and JSON files unless ``numbers_only`` is False."""
    pattern = re.sub(r"<[^>]*>", "*", cite)
    pattern = re.sub(r"\{[^}]*\}", "*", pattern)
    hits = [Path(p) for p in glob.glob(str(RESULTS / pattern))]
    files = []
    for h in hits:
        files += [q for q in h.rglob("*") if q.is_file()] if h.is_dir() else [h]
    return [f for f in files if f.suffix in (".md", ".csv", ".json") or not numbers_only]


def _numbers(files) -> list[float]:
    out = []
    for f in files:
        for x in _ANY_NUMBER.findall(f.read_text()):
            try:
                out.append(abs(float(x)))
            except ValueError:
                pass
    return sorted(set(out))


def _quoted(q: str, values) -> bool:
    v = abs(float(q))
    mantissa = q.lower().split("e")[0]
    digits = len(mantissa.split(".")[1]) if "." in mantissa else 0
    scale = 10 ** int(q.lower().split("e")[1]) if "e" in q.lower() else 1.0
    tol = 0.5 * 10 ** -digits * scale * (1 + 1e-9) + 1e-12
    return any(abs(v - x) <= tol for x in values)


def _unquoted(text: str, cites) -> list[str]:
    """The decimal numbers of ``text`` (outside code spans) that are not in the cited files; a number followed by
    ``%`` may quote a fraction (0.0027 -> 0.27 %)."""
    files = [f for c in cites for f in _resolve(c)]
    values = _numbers(files)
    percent = [100 * v for v in values]
    body = re.sub(r"`[^`]*`", "", text)
    body = re.sub(r"\]\([^)]*\)", "]", body)  # link targets
    out = []
    for m in _DECIMAL.finditer(body):
        q = m.group(0)
        is_pct = body[m.end():m.end() + 2].lstrip().startswith("%")
        if not (_quoted(q, values) or (is_pct and _quoted(q, percent))):
            out.append(q)
    return out


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(ROOT)))
def test_prose_numbers_come_from_the_results_they_cite(doc):
    bad = []
    for text, cites in _units(doc.read_text()):
        if not cites or "<!-- checked by" in text:
            continue
        missing = [c for c in cites if c not in CONDITIONAL and not _resolve(c, numbers_only=False)]
        if missing:
            bad.append(f"cites {missing}, which do(es) not exist: {text[:100]!r}")
            continue
        if not any(_resolve(c) for c in cites):  # only figures cited: their numbers are in no table
            continue
        wrong = _unquoted(text, cites)
        if wrong:
            bad.append(f"{wrong} not in {sorted(cites)}: {text[:120]!r}")
    assert not bad, f"{doc.relative_to(ROOT)}:\n" + "\n".join(bad)


def test_the_quote_check_finds_a_stale_number(tmp_path):
    assert _quoted("0.0118", [0.01185]) and _quoted("1.9e-6", [1.9e-06]) and not _quoted("0.0361", [0.0360])
    units = list(_units("Intro citing results/table3.md.\n\n| a | b |\n|---|---|\n| x | 0.0360 |\n\nNo cite 0.5.\n"))
    assert [u[1] for u in units] == [{"table3.md"}, {"table3.md"}, set()]
    assert _unquoted("wavelet 0.0295 and `0.123` settings", {"table3.md"}) == []
    assert _unquoted("three-stage 0.0361 +/- 0.0044", {"table3.md"}) == ["0.0361", "0.0044"]


# ---------------------------------------------------------------------------------------------- derived claims
def _paragraph(doc: Path, marker: str) -> str:
    text = doc.read_text()
    i = text.index(marker)
    j = text.find("\n- ", i)
    return text[i:j if j > 0 else None]


def test_calibrate_held_out_comparison():
    """docs/calibrate.md's held-out comparison of twelve+axis+relm, recomputed from results/calibration_devices.csv:
    paired Wilcoxon over the splits where both fits are sound, Holm over the 5 comparisons."""
    import pandas as pd

    from icgo.maths.stats import holm, wilcoxon_paired

    d = pd.read_csv(RESULTS / "calibration_devices.csv")
    d = d[d.outer.isna()] if "outer" in d.columns else d  # the in-sample and held-out splits, not the inner ones
    h = d[d.split != "in-sample"].pivot_table(index=["recording", "split"], columns="method", values="score_deg")
    others = ["peer_fit_non_linear", "twelve+axis", "joint", "misma+axis", "peer_fit_to_axis"]
    rows = []
    for o in others:
        w = h[["twelve+axis+relm", o]].dropna()
        rows.append((o, len(w), w.mean().to_numpy(), int((w["twelve+axis+relm"] < w[o]).sum()),
                     wilcoxon_paired(w["twelve+axis+relm"], w[o]).p_value))
    p_holm = holm([r[4] for r in rows])
    text = " ".join(_paragraph(ROOT / "docs" / "calibrate.md", "checked by tests/test_reporting.py::"
                                                                  "test_calibrate_held_out_comparison").split())
    (o, n, means, lower, p), ph = rows[0], p_holm[0]
    assert f"({n} splits) {means[0]:.3f} vs {means[1]:.3f} deg, lower on {lower} of {n}, p = {p:.2f}, Holm {ph:.2f}" \
        in text
    (o, n, means, lower, p), ph = rows[1], p_holm[1]
    assert f"({n} splits) {means[0]:.3f} vs {means[1]:.3f}, lower on {lower} of {n}, p = {p:.2g}, Holm {ph:.2g}" in text
    for (o, n, means, lower, p), ph in list(zip(rows, p_holm))[2:]:
        assert f"p = {p:.2g}, Holm {ph:.2g}" in text, o
    assert min(p_holm) >= ALPHA and "None is below 0.05 after Holm" in text
