"""Optimizer study report: optimizers.md (protocol and stamp lines, compilation, summary, CGO against mealpy,
one table per dimension) and the CSV tables of :func:`icgo.studies.optimizers.study.run` (:func:`write_results`).
"""

from __future__ import annotations

from pathlib import Path

import pandas as pd


def write_results(res, argv, stage: Path) -> None:
    """optimizers_table.csv (the cell table), optimizers_runs.csv (the run table) and optimizers.md into ``stage``."""
    rec = res.records
    rec["cells"].to_csv(stage / "optimizers_table.csv", index=False)
    rec["runs"].drop(columns="evals").to_csv(stage / "optimizers_runs.csv", index=False)
    (stage / "optimizers.md").write_text("\n".join(markdown(res, argv)) + "\n")


def write(result, data, config, stage: Path, invocation) -> str:
    """The study's outputs (:class:`icgo.studies.common.study.Study` ``.write``): :func:`write_results` (the command line
    named in optimizers.md); returns the summary table."""
    write_results(result, list(invocation.argv), stage)
    return result.records["summary"].to_string(index=False)


def markdown(res, argv) -> list[str]:
    """The lines of optimizers.md for a :class:`icgo.studies.optimizers.study.OptimizerStudyResult`; ``argv``: the
    command line's arguments (named in the report's command)."""
    from icgo.optim import iterations_for_budget
    from icgo.optim.cgo import CGO
    from icgo.optim.pso import PSO

    cfg, names, df, summary = res.config, res.functions, res.records["cells"], res.records["summary"]
    n_cgo, n_pso = (iterations_for_budget(a, cfg.pop_size, cfg.budget) for a in (CGO, PSO))
    fmt = lambda v: f"{v:.3g}"  # noqa: E731
    n_cells = len(names) * len(cfg.dims)
    from icgo.reporting.protocol import protocol_line, settings_line

    command = f"`.venv/bin/python -m experiments.optimizers {' '.join(argv) if argv else ''}`".replace(" `", "`")
    lines = ["# Optimizer study: icgo.optim vs mealpy 3.x at equal evaluation budget", "",
             f"Command: {command}", "",
             protocol_line(f"{command} (`make optimizers`)",
                           f"{cfg.runs} runs per (algorithm, function, dimension); ours and mealpy's are independent "
                           "samples (unpaired)",
                           "none: a benchmark function has no held-out data; each run's best error f(x) - f* is "
                           "the score",
                           f"ours: PRNGKey({cfg.seed}) split per run; mealpy: seeds 0..{cfg.runs - 1}. The defaults "
                           "compared here were set from the papers' readings, not from these runs (docs/optimizers.md)",
                           f"Wilcoxon rank-sum (two-sided), Holm over each row's {n_cells} cells (one family per "
                           f"algorithm); `+`/`-` only at Holm p < {cfg.alpha:g}"),
             "",
             settings_line(f"population {cfg.pop_size}, {cfg.budget} fitness evaluations per run", f"{cfg.runs} runs "
                           "per cell", "float64 (ours and mealpy's numpy)", "No published protocol: the study compares "
                           "implementations at one budget, not the papers' results."),
             "",
             f"Functions: {', '.join(names)} (shifted + rotated with the CEC 2017 data, `icgo.optim.benchmarks`), "
             f"box [-100, 100]^D, D in {list(cfg.dims)}; {cfg.runs} runs per cell; population {cfg.pop_size}; "
             f"budget {cfg.budget} fitness evaluations per run for every algorithm (CGO: "
             f"{n_cgo} iterations x 4 evaluations per seed; "
             f"PSO/GA/SMA: {n_pso} iterations). Values are errors "
             "f(x) - f* of the best point. The evaluation columns are the measured maxima over runs "
             "(mealpy: a call counter on the objective). mealpy runs use seeds 0..runs-1; its fitness is "
             "opfunu's numpy operator on the same shift/rotation data (an independent implementation).",
             "",
             f"Wilcoxon rank-sum, two-sided, Holm-adjusted over the family of one row ({len(names)} functions x all "
             f"dimensions): `+` ours significantly lower error (Holm p < {cfg.alpha:g}), `-` significantly higher, "
             "`=` no significant difference. The Holm columns are the decisions; the uncorrected columns are shown "
             "for reference only and claim nothing: without the adjustment an algorithm identical to its reference "
             f"shows at least one `-` in {n_cells} cells with probability {1 - (1 - cfg.alpha / 2) ** n_cells:.2f}.",
             "",
             f"Wall time on this 2-core machine (shared): ours {res.wall_s['ours']:.0f} s including compilation, "
             f"mealpy {res.wall_s['peer']:.0f} s (jobs={cfg.jobs}); total {res.wall_s['total']:.0f} s.", ""]
    if not cfg.peer:
        lines += ["mealpy was not run (`--no-peer`): the mealpy columns are empty and there are no decisions.", ""]
    lines += ["## Compilation", "",
              "Each (algorithm, dimension) is one jitted call over all functions x runs; the CGO call also vmaps "
              "over the strategies (original, three_stage). New compiled programs per call "
              "(`icgo.optim.compiled_runners()` difference) and wall time:", ""]
    comp = res.compilation
    for dim in cfg.dims:
        c = comp[comp.dim == dim]
        lines += [f"- D={dim}: " + ", ".join(f"{r.job}: {r.compiles} compile(s), {r.seconds:.1f} s"
                                             for r in c.itertuples())]
    lines += ["", f"## Summary (+/=/- over the {len(names)} functions)", "", summary.to_markdown(index=False), ""]
    lines += ["## CGO against mealpy OriginalCGO, function by function", "",
              "`mealpy` rows: our `variant=mealpy`, the same algorithm as OriginalCGO (the side-by-side check); "
              "`paper` rows: the ICGO paper's text (the library default); `matlab`: the original MATLAB code.", ""]
    for m in res.methods:
        if m.algorithm != CGO.name:
            continue
        sel = df[df.ours == m.label]
        for sign, word in (("+", "better"), ("-", "worse")):
            cells = [f"{r.function} D{r.dim} (median {fmt(r.ours_median)} vs {fmt(r.mealpy_median)}, Holm p = "
                     f"{r.p_holm:.2g})" for r in sel.itertuples() if r.result_holm == sign]
            n_raw = int((sel.result == sign).sum())
            lines += [f"- {m.label}: significantly {word} (Holm) in {len(cells)} of {len(sel)} cells "
                      f"({n_raw} uncorrected)" + (": " + ", ".join(cells) if cells else "")]
    lines += [""]
    for dim in cfg.dims:
        d = df[df.dim == dim]
        lines += [f"## D = {dim}", ""]
        tab = pd.DataFrame({
            "function": d.function, "ours": d.ours,
            "median [IQR]": [f"{fmt(m)} [{fmt(i)}]" for m, i in zip(d.ours_median, d.ours_iqr)],
            "evals": d.ours_evals, "mealpy": d.mealpy,
            "mealpy median [IQR]": [f"{fmt(m)} [{fmt(i)}]" for m, i in zip(d.mealpy_median, d.mealpy_iqr)],
            "mealpy evals": d.mealpy_evals, "p": [f"{p:.2g}" for p in d.p_value], "": d.result,
            "p (Holm)": [f"{p:.2g}" for p in d.p_holm], "Holm": d.result_holm})
        lines += [tab.sort_values(["ours", "function"], kind="stable").to_markdown(index=False), ""]
    return lines
