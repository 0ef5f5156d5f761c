"""``python -m experiments.run --help``: the ICGO-RELM door's usage, read from ``conf/`` (so it never lists an
option that does not exist). Nothing here imports JAX."""

from __future__ import annotations

from hydra_plugins.icgo_launcher.door import CONF_DIR, STUDY_GROUPS, group_options


def run_help() -> str:
    """Usage, the config groups with their options and defaults, the main keys, and where to read more."""
    import yaml

    cfg = yaml.safe_load((CONF_DIR / "config.yaml").read_text())
    defaults = {k: v for d in cfg.get("defaults", []) if isinstance(d, dict) for k, v in d.items()}
    lines = ["ICGO-RELM study: MSA, then a RELM whose hidden layer an optimizer searches; writes a run directory",
             "(metrics, models, figures, summary.md with the verdict) and prints the summary and the verdict.", "",
             "usage: python -m experiments.run [-m] [GROUP=OPTION ...] [KEY=VALUE ...]", "",
             "config groups (GROUP=OPTION; default in brackets):"]
    for g in STUDY_GROUPS:
        lines.append(f"  {g:<11} {', '.join(group_options(g))}  [{defaults.get(g) or 'none'}]")
    lines += ["", "other settings (KEY=VALUE): " + ", ".join(k for k in cfg if k not in ("defaults", "hydra")),
              "  e.g. split.n_repeats=3 budget.iterations=50 precision=float64 devices=2 progress=false overwrite=true",
              "  your own recording: dataset=csv dataset.path=FILE.csv [dataset.columns.gx=Gx ...] (docs/data.md)", "",
              "examples:",
              "  python -m experiments.run strategy=three_stage           # make run",
              "  python -m experiments.run experiment=table3              # a paper preset",
              "  python -m experiments.run -m strategy=chaos,wavelet      # a sweep (one process per job)",
              "  python -m experiments.apply model=outputs/<date>/<time> data=survey.csv   # then apply the model", "",
              "docs: docs/experiments.md (groups, presets, launchers), README.md; Hydra's own flags: --hydra-help"]
    return "\n".join(lines)
