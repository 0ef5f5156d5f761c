"""Result values rendered from results/ files (icgo.reporting.render), untraced result numbers found
(icgo.reporting.prose), and ``make docs`` (experiments.docs) on documents and results made here."""

from __future__ import annotations

import json

import pytest

from experiments import docs as D
from icgo.reporting.prose import units, untraced
from icgo.reporting.render import RenderError, evaluate, fields, render_text, stale


@pytest.fixture
def results(tmp_path):
    r = tmp_path / "results"
    r.mkdir()
    (r / "t.csv").write_text("metric,ours,paper\nMAE (deg),0.0404 +/- 0.0041,0.0516\nRMSE (deg),0.0522,0.0731\n")
    (r / "t.md").write_text("# T\n\nReduction: MAE -74.8 %, RMSE -74.7 %.\n\n| method | p | p (Holm) |\n|---|---|---|\n"
                            "| a | 0.002 | **0.0039** |\n| b | 0.1055 | 0.1055 |\n")
    (r / "s.json").write_text(json.dumps({"seconds": {"ours": 81.4, "mealpy": 406.6}, "n": [1, 2, 3]}))
    return r


def test_a_value_renders_from_its_cell_and_a_stale_one_is_named(results):
    doc = ('<!--let T = csv("t.csv", key="metric") -->\nMAE <!--= {T["MAE (deg)"]["ours"]} -->0.0400<!--/--> deg, '
           'mean <!--= {num(T["MAE (deg)"]["ours"]):.3f} -->?<!--/-->, paper <!--= {T["MAE (deg)"]["paper"]} -->'
           '0.0516<!--/-->.\n')
    new, problems = render_text(doc, results)
    assert problems == []
    assert "-->0.0404 +/- 0.0041<!--/--> deg, mean <!---->".replace("<!---->", "") in new.replace(
        '<!--= {num(T["MAE (deg)"]["ours"]):.3f} -->', "")
    assert '-->0.040<!--/-->' in new and render_text(new, results)[0] == new  # rendering is idempotent
    s = stale(doc, results, "d.md")
    assert [str(p) for p in s] == ["d.md:2: stale: '0.0400', the results give '0.0404 +/- 0.0041' (make docs)",
                                   "d.md:2: stale: '?', the results give '0.040' (make docs)"]
    assert stale(new, results, "d.md") == []


def test_sources_json_regex_markdown_tables_and_the_papers_values(results):
    names = {**__import__("icgo.reporting.render", fromlist=["Sources"]).Sources(results).functions()}
    assert evaluate('js("s.json")["seconds"]["ours"]', names) == 81.4
    assert evaluate('text("t.md", r"RMSE -([\\d.]+) %")', names) == 74.7
    assert evaluate('md("t.md", key="method")["a"]["p (Holm)"]', names) == 0.0039  # bold removed, number parsed
    assert evaluate('sum(p < 0.05 for p in col(md("t.md"), "p"))', names) == 1
    assert evaluate('paper("ICGO", "table1", "relm", 0)', names) == 0.5111
    assert evaluate('len(where(md("t.md"), method="b"))', names) == 1
    new, _ = render_text('<!--= {table("t.md")} -->x<!--/-->', results)
    assert new.startswith('<!--= {table("t.md")} -->\n\n| method | p | p (Holm) |') and new.endswith("|\n\n<!--/-->")
    assert render_text(new, results)[0] == new


@pytest.mark.parametrize("expr, why", [
    ('__import__("os")', "not allowed"), ("open('x')", "NameError|name 'open'"), ("T.keys()", "only named functions"),
    ("T.x", "Attribute"), ("lambda: 1", "Lambda"), ('csv("../secret.csv")', "relative to the results"),
    ('csv("none.csv")', "no such file"), ('text("t.md", r"MAE")', "no group"), ('text("t.md", r"(\\d)")', "matches"),
    ('md("t.md", 3)', "no Markdown table 3"), ('csv("t.csv", key="x")', "no column 'x'"),
    ('paper("ICGO", "table9")', "no entry 'table9'"), ("1 +", "not an expr"),
])
def test_a_marker_that_cannot_be_read_is_one_line_naming_it(results, expr, why):
    names = __import__("icgo.reporting.render", fromlist=["Sources"]).Sources(results).functions()
    with pytest.raises(RenderError, match=why):
        evaluate(expr, names)


def test_a_failing_marker_or_a_false_claim_keeps_the_text_and_is_reported(results):
    doc = ("a <!--= {csv(\"t.csv\")[0][\"nope\"]} -->1.0<!--/-->\n<!--? 1 > 2 -->\n"
           "<!--= {js(\"s.json\")[\"n\"][0]--1} -->2<!--/-->\n<!--= {0.0/1e-400} -->z<!--/-->\n")
    new, problems = render_text(doc, results, "d.md")
    assert new == doc
    assert [(p.line, p.message.split(":")[0]) for p in problems] == [
        (1, "'csv(\"t.csv\")[0][\"nope\"]'"), (2, "claim no longer holds"),
        (3, "'--' inside a marker ends the HTML comment early in some Markdown renderers"),
        (4, "'0.0/1e-400'")]


def test_template_fields_split_at_the_format_colon_outside_brackets_and_strings():
    assert fields('{a["x:y"]:.3f} of {{b}} {c} {d[1:2]}') == [
        ("", 'a["x:y"]', ".3f"), (" of {b} ", "c", None), (" ", "d[1:2]", None), ("", None, None)]
    with pytest.raises(RenderError, match="unclosed"):
        fields("{a")
    assert render_text('<!--= {1/3:.1%} and {2:d}x -->?<!--/-->', __import__("pathlib").Path("."))[0].endswith(
        "-->33.3% and 2x<!--/-->")


def test_units_are_paragraphs_items_headings_and_tables():
    text = "# H 1.5\n\npara one\ncontinues\n- item 1\n- item 2\n\n| a |\n|---|\n| 1 |\nafter\n"
    assert [text[a:b].strip().splitlines()[0] for a, b in units(text)] == [
        "# H 1.5", "para one", "- item 1", "- item 2", "| a |", "after"]


def test_untraced_numbers_in_a_unit_that_quotes_results_and_anywhere_a_result_stands(results):
    doc = ("Our MAE is 0.0404 (`results/t.csv`), lower on 7 of 9 splits, 81 s, p = 0.02; see eq. 15 and "
           "section 3.3, `0.5` is a setting.\n\n"
           "Elsewhere 74.8 % and 0.123 and 12.345 (not a result).\n\n"
           "<!--development: timed by hand-->Measured 74.8 once.\n\n"
           "Rendered <!--= {csv(\"t.csv\")[0][\"paper\"]} -->0.0516<!--/--> and 0.0731 beside it.\n")
    found = [(u.line, u.number) for u in untraced(doc, results)]
    assert found == [(1, "0.0404"), (1, "7"), (1, "9"), (1, "81"), (1, "0.02"), (3, "74.8"), (7, "0.0731")]
    bad = untraced("<!--development: x-->quoting results/t.csv\n", results)
    assert len(bad) == 1 and "cites results/" in bad[0].why


def test_make_docs_renders_in_place_all_or_nothing(results, tmp_path, capsys):
    good, bad = tmp_path / "good.md", tmp_path / "bad.md"
    good.write_text('x <!--= {js("s.json")["seconds"]["ours"]:.0f} -->80<!--/--> s\n')
    bad.write_text('y <!--= {js("s.json")["missing"]} -->1<!--/-->\n')
    assert D.main([str(good), str(bad), "--results", str(results)]) == 1
    assert "80<!--/-->" in good.read_text()  # nothing written while any marker fails
    assert "bad.md:1: 'js(\"s.json\")[\"missing\"]': KeyError" in capsys.readouterr().err
    assert D.main([str(good), "--results", str(results)]) == 0
    assert good.read_text() == 'x <!--= {js("s.json")["seconds"]["ours"]:.0f} -->81<!--/--> s\n'
    assert D.main([str(good), "--results", str(results), "--check"]) == 0
    good.write_text(good.read_text() + "\nAlso 406.6 s.\n")
    assert D.main([str(good), "--results", str(results), "--check"]) == 1
    assert "good.md:3: '406.6' equals a value in results/" in capsys.readouterr().out


def test_markers_in_code_are_examples_and_tables_are_found_by_their_columns(results):
    doc = ("Example: `<!--= {csv(\"t.csv\")[0][\"ours\"]} -->x<!--/-->` and `<!--? 1 > 2 -->`.\n\n"
           "```\n<!--= {js(\"s.json\")[\"nope\"]} -->y<!--/-->\n```\n\n"
           "Real: <!--= {md(\"t.md\", key=\"method\", having=\"p (Holm)\")[\"b\"][\"p\"]} -->?<!--/-->.\n")
    new, problems = render_text(doc, results)
    assert problems == [] and new == doc.replace("-->?<!--/-->", "-->0.1055<!--/-->")
    assert untraced(new, results) == []


def test_a_development_region_is_not_checked_but_may_not_cite_results(results):
    doc = ("<!--development-begin: timed by hand-->\nIt took 74.8 s.\n\nAnd 0.0731 once.\n<!--development-end-->\n\n"
           "Then 0.0731 again.\n")
    assert [(u.line, u.number) for u in untraced(doc, results)] == [(7, "0.0731")]
    bad = "<!--development-begin: x-->\nsee results/t.csv\n<!--development-end-->\n"
    assert [u.line for u in untraced(bad, results)] == [1]


def test_a_table_after_a_paragraph_that_quotes_results_is_a_result_unit(results):
    doc = ("The means (`results/t.csv`):\n\n| method | MAE |\n|---|---|\n| ours | 0.04 |\n\n"
           "A figure (`results/t.png`):\n\n| setting | value |\n|---|---|\n| step | 0.5 |\n")
    assert [(u.line, u.number) for u in untraced(doc, results)] == [(5, "0.04")]


def test_lock_reads_the_version_the_lock_beside_results_pins(tmp_path):
    """``lock(name)`` renders the tested-versions table from requirements/dev.lock (names normalised as pip does)."""
    results = tmp_path / "results"
    results.mkdir()
    (tmp_path / "requirements").mkdir()
    (tmp_path / "requirements" / "dev.lock").write_text(
        "hydra-core==1.3.8\n    # via icgo\nJAX==0.12.1\ncolorama==0.4.6 ; sys_platform == 'win32'\n")
    new, problems = render_text('<!--= {lock("jax")}, {lock("Hydra_Core")}, {lock("colorama")} -->?<!--/-->', results)
    assert not problems and "-->0.12.1, 1.3.8, 0.4.6<!--/-->" in new
    _, problems = render_text('<!--= {lock("numpy")} -->?<!--/-->', results)
    assert len(problems) == 1 and "'numpy' is not locked" in str(problems[0])
