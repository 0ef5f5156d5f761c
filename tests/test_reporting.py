"""The mechanical reporting rules of docs/reporting.md, checked over results/, README.md and docs/.

* every table of results/ states its protocol (command, repeats, split, seeds, test);
* every p-value column has its Holm-adjusted column, and every p quoted in a table's notes is adjusted;
* the papers' values stand beside ours in the tables that report the same quantity;
* every table carries its stamp (``Run settings: ...``) from its own runs;
* every result number of README.md and docs/ is rendered from its results cell (``make docs``);
* the MISMA study reports a seed its choices were not made on.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import pytest

from icgo.reporting import documents as D
from icgo.reporting.protocol import ALPHA, PROTOCOL_FIELDS, SETTINGS_PREFIX, comparison, parse_protocols, protocol_line

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"

#: Markdown files of results/ that are not study tables (the protocol line does not apply), and why.
EXEMPT = {
    "performance.md": "a benchmark (one run, ratios within it: docs/performance.md), not a method comparison",
    "bench_cpu.md": "a benchmark (one run, ratios within it: docs/performance.md), not a method comparison",
    "bench_gpu_check_cpu.md": "a benchmark (the per-backend check, one run: docs/performance.md), not a method "
                              "comparison",
    "bench_cpu_quiet.md": "a benchmark (Table 3's front door against mealpy in one run: results/performance.md), not a "
                          "method comparison",
    "bench_cpu_untracked.md": "a benchmark (the same, its front-door runs untracked: results/performance.md), not a "
                              "method comparison",
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


@pytest.mark.parametrize("path", _result_tables(), ids=lambda p: str(p.relative_to(RESULTS)))
def test_every_result_table_carries_the_stamp_of_its_runs(path):
    rel = str(path.relative_to(RESULTS))
    stamped = any(line.startswith(SETTINGS_PREFIX) for line in path.read_text().splitlines())
    assert stamped, f"results/{rel}: no '{SETTINGS_PREFIX}...' line (icgo.reporting.protocol.settings_line)"


@pytest.mark.parametrize("path", _result_tables(), ids=lambda p: str(p.relative_to(RESULTS)))
def test_every_stamp_names_the_environment_its_numbers_were_made_in(path):
    """Python, JAX/jaxlib, numpy, scipy, the CPU, the backend and device count (icgo.core.environment), or "not
    recorded" for runs from before run.json recorded them."""
    from icgo.reporting.protocol import ENVIRONMENT_PREFIX

    for line in path.read_text().splitlines():
        if line.startswith(SETTINGS_PREFIX):
            env = line.split(ENVIRONMENT_PREFIX, 1)[1] if ENVIRONMENT_PREFIX in line else ""
            assert env.startswith(("not recorded", "Python ")), f"results/{path.relative_to(RESULTS)}: {line[:120]}"


def test_the_environment_stamp_from_a_run_record_and_from_this_process(tmp_path):
    import json
    import platform

    from icgo.core import environment as E
    from icgo.reporting import stamp
    from icgo.reporting.protocol import settings_line

    env = {"python": "3.12.1", "jax": "0.12.1", "jaxlib": "0.12.1", "numpy": "2.4.6", "scipy": "1.18.1",
           "cpu": "Some CPU", "backend": "gpu", "device": "NVIDIA H100", "device_count": 2}
    assert E.describe(env) == ("Python 3.12.1, jax 0.12.1, jaxlib 0.12.1, numpy 2.4.6, scipy 1.18.1, CPU Some CPU, "
                               "gpu NVIDIA H100 x 2 device(s)")
    assert E.describe(None) == "not recorded"
    (tmp_path / "run.json").write_text(json.dumps({"environment": env}))
    assert stamp.run_settings(tmp_path)["environment"] == E.describe(env)
    assert stamp.run_settings(tmp_path / "none")["environment"] == "not recorded"
    text = stamp.describe([{"pop_size": 30, "iterations": 100, "n_repeats": 10, "dtype": "float32",
                            "environment": E.describe(env)}])["text"]
    assert text.endswith(f"Environment: {E.describe(env)}.")
    here = E.environment()
    assert here["python"] == platform.python_version() and here["device_count"] >= 1
    assert settings_line("b", "r", "d", "p.").endswith(f"p. Environment: {E.here()}.")


def test_the_writers_stamp_their_tables():
    """The stamp lines of the MISMA, gyro and discrepancy writers, from their default configs."""
    from icgo.discrepancy.config import WorkflowConfig
    from icgo.discrepancy.report import workflow_settings
    from icgo.studies.gyro import report as gyro_report
    from icgo.studies.misma import report as misma_report
    from icgo.studies.gyro.study import GyroConfig
    from icgo.studies.misma.config import MismaConfig

    assert misma_report.settings(MismaConfig()).startswith(
        "Run settings: population 30 x 2051 iterations per simulated search; real devices: 300 iterations per MISMA "
        "run, 10 search repeats per row, 4 MISMA runs per real-device fit, float64 searches. The paper's population "
        "and iterations (its Table 3); the box around U")
    assert gyro_report.settings(GyroConfig()).startswith("Run settings: networks 8-8: adam, up to 2000 epochs")
    assert "No published protocol" in gyro_report.settings(GyroConfig())
    assert workflow_settings(WorkflowConfig(), "one run").startswith(
        "Run settings: Levenberg-Marquardt 12 iterations per fit, effects added until the held-out rule stops, "
        "5 folds, one run, float64 fits.")
    assert "up to 4 effects added" in workflow_settings(WorkflowConfig(max_effects=4), "one run")


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
    from icgo.datasets.casing_stations import TABLE4_ORIGINAL
    from icgo.studies.icgo_relm.results.outputs import PAPER
    from icgo.reporting.published import ICGO

    assert PAPER is ICGO
    assert [tuple(r[2:4]) for r in ICGO["table4"]] == [tuple(r) for r in TABLE4_ORIGINAL]


# ---------------------------------------------------------------------------------------------- seeds
def test_misma_reports_a_seed_its_choices_were_not_made_on():
    from icgo.studies.misma.config import DEVELOPMENT_SEEDS, MismaConfig

    assert MismaConfig().seed not in DEVELOPMENT_SEEDS
    reported = json.loads((RESULTS / "misma_summary.json").read_text())["config"]["seed"]
    assert reported not in DEVELOPMENT_SEEDS, f"results/misma_* report development seed {reported}"


# ---------------------------------------------------------------------------------------------- prose: rendered
@pytest.mark.parametrize("doc", D.documents(), ids=lambda p: str(p.relative_to(ROOT)))
def test_every_result_number_in_the_prose_is_rendered_from_its_cell(doc):
    """docs/reporting.md, rule 6: no value stale against its results file, no marker that cannot be read, no
    false claim, no citation of a missing results file, and no unmarked result number (`make docs` renders them;
    icgo.reporting.documents.PENDING names a document whose numbers are not yet marked: only the first four apply)."""
    problems = D.check([doc], RESULTS)
    assert not problems, "\n".join(problems)


def test_only_the_named_documents_are_pending():
    assert set(D.PENDING) <= {p.name for p in D.documents()}
    assert set(D.NOT_CHECKED) == {"design.md", "engineering-notes.md"}


# ---------------------------------------------------------------------------------------------- derived claims
def _paragraph(doc: Path, marker: str) -> str:
    text = doc.read_text()
    i = text.index(marker)
    j = text.find("\n- ", i)
    return text[i:j if j > 0 else None]


def test_calibrate_held_out_comparison():
    """docs/calibrate.md's held-out comparison of twelve+axis+relm, recomputed from results/calibration_devices.csv:
    per device, the mean over its held-out splits where both fits are sound (a device's splits share its data: the
    device is the independent unit), paired Wilcoxon over devices, Holm over the 5 comparisons. The means and counts
    are rendered from the CSV (their markers read as the text they render); the p-values, which no results file
    holds, are typed and checked here."""
    import pandas as pd

    from icgo.maths.stats import holm, wilcoxon_paired

    d = pd.read_csv(RESULTS / "calibration_devices.csv")
    d = d[d.outer.isna()] if "outer" in d.columns else d  # the in-sample and held-out splits, not the inner ones
    d = d[(d.split != "in-sample") & ~d.degenerate.astype(bool)]
    h = d.pivot_table(index=["recording", "split"], columns="method", values="score_deg")
    others = ["peer_fit_non_linear", "twelve+axis", "joint", "misma+axis", "peer_fit_to_axis"]
    rows = []
    for o in others:
        w = h[["twelve+axis+relm", o]].dropna().groupby(level="recording").mean()  # one pair per device
        assert w.index.is_unique and len(w) <= d.recording.nunique()
        rows.append((o, len(w), w.mean().to_numpy(), int((w["twelve+axis+relm"] < w[o]).sum()),
                     wilcoxon_paired(w["twelve+axis+relm"], w[o]).p_value))
    p_holm = holm([r[4] for r in rows])
    item = _paragraph(ROOT / "docs" / "calibrate.md", "checked by tests/test_reporting.py::"
                                                      "test_calibrate_held_out_comparison")
    text = " ".join(re.sub(r"<!--.*?-->", "", item, flags=re.S).split())
    for (o, n, means, lower, p), ph in zip(rows, p_holm):
        assert f"({n} devices) {means[0]:.3f} vs {means[1]:.3f}, lower on {lower} of {n}" in text, o
        assert f"`{o.removeprefix('peer_')}` p = {p:.2g}, Holm {ph:.2g}" in text, o
    assert min(p_holm) >= ALPHA and "None is below 0.05 after Holm" in text
