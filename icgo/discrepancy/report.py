"""show: every English sentence of the workflow, the Markdown report, the JSON record and its two figures
(drawn by :mod:`icgo.reporting.plots`).

The library's results are data (:mod:`icgo.discrepancy.search`,
:mod:`~icgo.discrepancy.identifiability`, :mod:`~icgo.discrepancy.compare`);
this module words them. Nothing reads these sentences back.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from icgo.core.settings import config_overrides, config_to_mapping
from icgo.discrepancy.compare import Pattern
from icgo.discrepancy.identifiability import Degeneracy, Separability
from icgo.discrepancy.search import FOLD_SEED, MAX_ROUNDS, Result, Step, gap_table
from icgo.physics import effects as _fx
from icgo.physics.qc import qc_sentence
from icgo.reporting.protocol import protocol_line, settings_line


# ============================================================ sentences
def degeneracy_sentence(d: Degeneracy) -> str:
    """One non-separable or unobservable direction, e.g. ``accel_bias[z] mimics accel_scale[z]``."""
    lhs = " + ".join(d.direction)
    if d.chi2_typical is not None:
        return (f"{lhs} leaves no trace above the noise (a typical {lhs} changes chi2 by "
                f"{d.chi2_typical:.2g}): unobservable with these attitudes")
    if d.unobservable:
        return f"{lhs} leaves no trace in the residual (unobservable with these attitudes)"
    return f"{lhs} mimics {' + '.join(d.mimics)}"


def step_notes(s: Step) -> list[str]:
    """The notes of one step: directions the model can mimic, then what makes equivalent candidates equivalent."""
    notes = [f"given the model: {degeneracy_sentence(d)} (s = {d.s:.1e})" for d in s.degeneracies]
    notes += [f"{degeneracy_sentence(d)} (canonical correlation {d.canonical_correlation:.4f})"
              for d in s.equivalences]
    notes += [f"component not identifiable with these attitudes: {degeneracy_sentence(d)} of an effect not named "
              f"(canonical correlation {d.canonical_correlation:.4f}); the named value may hold it" for d in s.aliases]
    return notes


_HARMONIC = {
    "constant": "the cross-axial field residual is constant in tool coordinates ({:.0%} of it): "
                "the source turns with the tool (tool-fixed)",
    "1st": "the cross-axial field residual follows the 1st toolface harmonic ({:.0%}): "
           "it rotates relative to the tool, as an earth-fixed source or a tilted reference does",
    "2nd": "the cross-axial field residual has a 2nd toolface harmonic ({:.0%}): scale-factor or cross-coupling-like",
}


def pattern_sentences(p: Pattern) -> list[str]:
    """Where a residual concentrates, in words (from :func:`~icgo.discrepancy.compare.find_pattern`)."""
    s = [f"magnetometer residual RMS {p.b_rms_nT:.1f} nT per axis ({p.b_rms_nT / p.noise.sigma_b_nT:.1f}x noise), "
         f"accelerometer {p.g_rms_g * 1e3:.3f} mg ({p.g_rms_g / p.noise.sigma_g:.1f}x noise)"]
    if p.concentrated_on is not None:
        s.append(f"it concentrates on {p.concentrated_on}")
    if p.cross_axial_harmonic is not None:
        s.append(_HARMONIC[p.cross_axial_harmonic].format(p.cross_axial_fraction))
    if p.total_field_offset_nT is not None:
        s.append(f"measured total field is off by {p.total_field_offset_nT:+.0f} nT on average")
    if p.axial_r2 is not None:
        s.append(f"azimuth error grows with sin I sin A (R^2 = {p.axial_r2:.2f}): axial-interference signature")
    if p.azimuth_hotspot is not None:
        w = p.azimuth_hotspot
        s.append(f"azimuth error concentrates at inclination {w.lo:.0f}-{w.hi:.0f} deg "
                 f"(RMS {w.rms_azimuth_deg:.2f} vs {p.rms_azimuth_deg:.2f} deg overall)")
    for c in p.correlated:
        s.append(f"residual {c.component} correlates with {c.column} (|r| = {c.abs_r:.2f}): "
                 "a dependence no vocabulary effect has")
    return s


def _noise_basis(res: Result) -> str:
    """What "noise" means in the verdict: the assumed noise, or the scatter estimated from the shots."""
    est = res.noise_estimate
    if est is None:
        return "noise"
    return (f"the scatter estimated from the shots ({est.noise.sigma_b_nT:.4g} nT, {est.noise.sigma_g * 1e3:.3g} mg "
            f"per axis: {est.ratios[0]:.0f}x and {est.ratios[1]:.0f}x the assumed noise)")


def verdict(res: Result) -> str:
    """The verdict in one line (by ``res.kind``, see :data:`~icgo.discrepancy.search.KINDS`)."""
    pattern = "; ".join(pattern_sentences(res.pattern))
    basis = _noise_basis(res)
    if res.kind == "not_separable":
        text = "not separable: " + "; ".join(
            f"{' / '.join((s.name,) + s.equivalent)} explain the same discrepancy with these attitudes "
            "(no significant margin between them)" for s in res.steps if not s.separable)
        if res.named:
            text += f"; named: {', '.join(res.named)}"
        if res.structure_remains:
            text += "; unexplained structure remains: " + pattern
        return text
    if res.kind == "unexplained":
        text = "unexplained structure remains"
        if res.model:
            text += f" after adding {', '.join(res.model)}"
        est = res.noise_estimate
        if est is not None:
            text += (f" (held-out chi2/residual {res.heldout:.4g}, more than {res.config.noise_tolerance:g}x that of "
                     f"{est.model}, {est.heldout:.4g}: the vocabulary predicts the held-out shots better than the "
                     "effects the search could add one by one with significance)")
        else:
            text += f" (held-out chi2/residual {res.heldout:.2f})"
        return text + ": " + pattern
    if res.kind == "no_missing_effect":
        return (f"no missing effect: the reference model explains the data to {basis} "
                f"(held-out chi2/residual {res.heldout:.4g})")
    return f"explained by {', '.join(res.model)}; the rest is {basis} (held-out chi2/residual {res.heldout:.4g})"


def truth_effects(truth) -> dict:
    """The injected effects of a truth record: name -> parameters (list) or, for a body the vocabulary models
    approximately, a description. Takes either name -> parameters (:func:`icgo.discrepancy.hidden_stations`) or
    a data set's ``truth`` / ``NAME.truth.json`` (``effects`` and ``casing``, :mod:`icgo.datasets`), whose casing
    is what ``magnetic_body`` models (as a point dipole)."""
    if not truth:
        return {}
    out = {k: np.round(np.asarray(v, float), 6).tolist() for k, v in (truth.get("effects") or {}).items()
           if k in _fx.EFFECTS}
    out.update({k: np.round(np.asarray(v, float), 6).tolist() for k, v in truth.items() if k in _fx.EFFECTS})
    cas = truth.get("casing")
    if cas:
        out["magnetic_body"] = (f"a {cas.get('model', '')} casing ({cas.get('length_m', '?')} m, "
                                f"{cas.get('magnetization_A_m', '?')} A/m, from {cas.get('end_ned')} along "
                                f"{cas.get('axis_ned')} m NED)")
    return out


def _pct(a: float, b: float) -> str:
    return f"{100.0 * (b - a) / a:+.0f} %" if np.isfinite(a) and np.isfinite(b) and a > 0 else "n/a"


def outlier_sentence(res: Result) -> str:
    """The robust outliers left out of the fits, named (station, component, residual, robust z)."""
    if not res.outliers:
        return f"no robust outlier (none beyond {res.config.outlier_z:g} robust sigma)"
    unit = lambda c: "nT" if c.startswith("b") else "g"
    return (f"{len(res.outliers)} robust outlier(s) left out of every fit and of these numbers (beyond "
            f"{res.config.outlier_z:g} x 1.4826 MAD): " + "; ".join(
                f"station {o.station} ({o.component} {o.residual:+.4g} {unit(o.component)}, {o.z:.0f} robust sigma)"
                for o in res.outliers))


def answer(res: Result, truth=None) -> list[str]:
    """The report's opening, answer first: the missing effect(s), the held-out gap before -> after (and by how
    much, %), the truth beside them where the data carry one; then separability, what remains, the outliers."""
    g0, g1 = res.gaps[0], res.gaps[-1]
    if res.model:
        named = ", ".join(s.name + ("" if s.separable else f" (or {' / '.join(s.equivalent)}: not separable)")
                          for s in res.steps)
        first = f"missing: **{named}**"
    else:
        first = "**no missing effect** found"
    first += (f"; held-out gap {g0.mag_rms_nT:.1f} -> {g1.mag_rms_nT:.1f} nT per axis ({_pct(g0.mag_rms_nT, g1.mag_rms_nT)})"
              f", azimuth {g0.azimuth_rms_deg:.3f} -> {g1.azimuth_rms_deg:.3f} deg "
              f"({_pct(g0.azimuth_rms_deg, g1.azimuth_rms_deg)})")
    tr = truth_effects(truth)
    if tr:
        hit = [k for k in tr if k in res.model]
        miss = [k for k in tr if k not in res.model]
        extra = [k for k in res.model if k not in tr]
        first += (f"; injected (truth): {', '.join(tr)}: found {', '.join(hit) or 'none'}"
                  + (f", missed {', '.join(miss)}" if miss else "") + (f", not injected {', '.join(extra)}" if extra else ""))
    lines = [f"**Answer:** {first}."]
    sep = [f"{' / '.join((s.name,) + s.equivalent)} not separable with these attitudes" for s in res.steps
           if not s.separable]
    rest = ("what remains is noise" if not res.structure_remains else
            "what remains: " + "; ".join(pattern_sentences(res.pattern)))
    lines.append(f"**Then:** {'; '.join(sep) if sep else 'every named effect separable'}; {rest} (held-out "
                 f"chi2/residual {res.heldout:.3g}, noise floor {res.noise_floor:.3g}); {outlier_sentence(res)}.")
    return lines


def _step_line(s: Step) -> str:
    tag = "named" if s.separable else f"NOT SEPARABLE from {list(s.equivalent)}"
    return (f"  -> {s.name} {tag}: params {np.round(s.params, 6).tolist()} +- {np.round(s.stderr, 6).tolist()} "
            f"{s.units}; margin over {s.runner_up}: z = {s.margin_z:.1f}, dBIC = {s.delta_bic:.1f}")


def _candidate_lines(step_no: int, model, heldout: float, candidates) -> list[str]:
    lines = [f"step {step_no}: model {list(model) or '[reference]'}; held-out chi2/residual {heldout:.3f}"]
    for c in candidates:
        tag = "qualifies" if c.qualifies else ("" if c.converged else "not converged: cannot qualify")
        lines.append(f"    {c.name:20s} held-out {c.heldout:9.3f}  BIC {c.bic:12.1f}  z {c.z:7.1f}  {tag}")
    return lines


def search_log(res: Result) -> list[str]:
    """The search step by step: every candidate's held-out score, BIC and z, each addition and its notes."""
    lines = []
    for i, s in enumerate(res.steps):
        lines += _candidate_lines(i + 1, res.model[:i], s.heldout_before, s.candidates)
        lines.append(_step_line(s))
        lines += [f"     note: {nt}" for nt in step_notes(s)]
    lines += _candidate_lines(len(res.steps) + 1, res.model, res.heldout, res.final_candidates)
    if res.noise_estimate is not None:
        lines.append(res.noise_estimate.sentence())
    return lines + [f"verdict: {verdict(res)}"]


def step_summary(res: Result) -> list[str]:
    """One line per step (the gap before -> after), then the verdict."""
    lines = []
    for i, s in enumerate(res.steps, 1):
        g0, g1 = s.gap_before, s.gap_after
        lines.append(f"step {i}: + {s.name}{'' if s.separable else ' (not separable from ' + ', '.join(s.equivalent) + ')'}: "
                     f"mag gap {g0.mag_rms_nT:.1f} -> {g1.mag_rms_nT:.1f} nT, azimuth gap "
                     f"{g0.azimuth_rms_deg:.3f} -> {g1.azimuth_rms_deg:.3f} deg")
    return lines + [f"verdict: {verdict(res)}"]


# ============================================================ tables, JSON, Markdown
def result_to_json(res: Result) -> dict:
    """Machine-readable result: {"effects": [{name, params, stderr, gap_before, gap_after, ...}], "verdict", ...}."""
    return {
        "effects": [
            {"name": s.name, "params": list(s.params), "stderr": list(s.stderr), "units": s.units,
             "gap_before": s.gap_before._asdict(), "gap_after": s.gap_after._asdict(),
             "heldout_chi2_before": s.heldout_before, "heldout_chi2_after": s.heldout_after,
             "runner_up": s.runner_up, "evidence_margin_z": s.margin_z, "delta_bic_runner_up": s.delta_bic,
             "separable": s.separable, "equivalent": list(s.equivalent), "notes": step_notes(s)}
            for s in res.steps],
        "verdict": verdict(res),
        "kind": res.kind,
        "noise": {"assumed": {"sigma_b_nT": res.config.sigma_b_nT, "sigma_g": res.config.sigma_g},
                  "estimated": None if res.noise_estimate is None else {
                      "sigma_b_nT": res.noise_estimate.noise.sigma_b_nT, "sigma_g": res.noise_estimate.noise.sigma_g,
                      "from_model": res.noise_estimate.model, "heldout_chi2": res.noise_estimate.heldout},
                  "verdict_based_on": "assumed" if res.noise_estimate is None else "estimated"},
        "not_converged": sorted({c.name for s in res.steps for c in s.candidates if not c.converged}
                                | {c.name for c in res.final_candidates if not c.converged}),
        "pattern": pattern_sentences(res.pattern),
        "outliers": [o._asdict() for o in res.outliers],
        "config": config_to_mapping(res.config),
        "seconds": res.seconds,
    }


def report_markdown(res: Result, label: str, truth=None, qc=None, protocol: str | None = None) -> str:
    """The workflow report (steps, gap table, remaining pattern, residual by toolface bin, QC, figures).

    ``qc``: survey-QC counts before and after the fitted model
    (:func:`icgo.artifacts.discrepancy.station_qc`), or None without a reference field. ``protocol``: the report's
    protocol line (:func:`icgo.reporting.protocol.protocol_line`), under the title when given.
    """
    lines = [f"# Discrepancy report: {label}", ""] + ([protocol, ""] if protocol else [])
    lines = lines[:2] + answer(res, truth)[:1] + [""] + answer(res, truth)[1:] + [""] + lines[2:]
    lines += [workflow_settings(res.config, "one workflow run on these data"), ""]
    lines += [f"**Verdict:** {verdict(res)}", "", "## Noise", "",
             "| noise per axis | magnetometer (nT) | accelerometer (mg) |", "|---|---|---|",
             (f"| assumed (`sigma_b_nT`, `sigma_g`; the fits' weights) | {res.config.sigma_b_nT:g} | "
              f"{res.config.sigma_g * 1e3:g} |")]
    if res.noise_estimate is not None:
        est = res.noise_estimate
        lines += [(f"| estimated from the shots (the verdict's basis) | {est.noise.sigma_b_nT:.4g} | "
                   f"{est.noise.sigma_g * 1e3:.3g} |"), "",
                  (f"The estimate is the held-out scatter of the best model evaluated ({est.model}, chi2/residual "
                   f"{est.heldout:.4g}; `icgo.discrepancy.scatter`): sensor noise plus what no vocabulary model "
                   "predicts on shots it did not see.")]
    else:
        lines += ["", "The verdict is based on the assumed noise (a reference attitude, or `noise_from_data=false`)."]
    unconv = sorted({c.name for s in res.steps for c in s.candidates if not c.converged}
                    | {c.name for c in res.final_candidates if not c.converged})
    if unconv:
        never = [u for u in unconv if u not in res.model]
        later = [u for u in unconv if u in res.model]
        lines += ["", ""]
        if never:
            lines[-1] += (f"Not converged within {MAX_ROUNDS} x {res.config.n_iter} LM steps, so never added: "
                          f"{', '.join(never)}.")
        if later:
            lines[-1] += (f"{' ' if never else ''}Not converged at an earlier step (so not added there), added once "
                          f"converged: {', '.join(later)}.")
    lines += ["", "## Where the reference model disagrees (before)", ""]
    lines += [f"- {s}" for s in pattern_sentences(res.pattern_before)]
    lines += ["", "## Steps", ""]
    for i, s in enumerate(res.steps, 1):
        pm = ", ".join(f"{p:.5g} ± {e:.2g}" for p, e in zip(s.params, s.stderr))
        tag = "named" if s.separable else f"NOT SEPARABLE from {', '.join(s.equivalent)}"
        lines.append(f"{i}. **{s.name}** ({tag}): [{pm}] {s.units}; held-out chi2/residual "
                     f"{s.heldout_before:.3g} -> {s.heldout_after:.3g} (z = {s.z_improvement:.1f}); "
                     f"margin over {s.runner_up}: z = {s.margin_z:.1f}, ΔBIC = {s.delta_bic:.1f}")
        lines += [f"   - {nt}" for nt in step_notes(s)]
    if truth_effects(truth):
        lines += ["", "Injected (truth): " + "; ".join(f"{k} = {v}" for k, v in truth_effects(truth).items())]
    lines += ["", "## Gap on held-out stations", "", gap_table(res).to_markdown(index=False, floatfmt=".4g"),
              "", "## Remaining pattern (after)", ""]
    lines += [f"- {s}" for s in pattern_sentences(res.pattern)]
    lines += ["", "## Residual by toolface bin (after)", "",
              "| toolface (deg) | n | RMS abs(dB) (nT) | RMS azimuth error (deg) |", "|---|---|---|---|"]
    for b in res.compare_after.bins["toolface"]:
        lines.append(f"| {b.lo:.0f}-{b.hi:.0f} | {b.n} | {b.rms_b_nT:.3g} | {b.rms_azimuth_deg:.3g} |")
    lines += ["", "## Survey QC", "",
              qc_sentence(qc) if qc else "No reference field given: survey QC against a reference does not apply."]
    lines += ["", "![residual vs toolface](residual_vs_toolface.png)", "", "![gap per step](gap_per_step.png)",
              "", f"Wall time {res.seconds:.1f} s (including JIT compilation)."]
    return "\n".join(lines) + "\n"


def write_report(res: Result, label: str, out_dir, truth=None, qc=None, protocol: str | None = None) -> Path:
    """report.md + discrepancy.json + the two figures into ``out_dir``; returns the report path.

    ``qc``, ``protocol``: as in :func:`report_markdown` (``qc`` also written to discrepancy.json).
    """
    from icgo.reporting import plots

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "discrepancy.json").write_text(json.dumps({**result_to_json(res), "qc": qc}, indent=2, default=float))
    panels = [(name, c.toolface[c.valid], c.resid[c.valid, 3:6])
              for c, name in ((res.compare_before, "before"), (res.compare_after, "after"))]
    plots.save_figure(plots.residual_vs_toolface(panels), out_dir / "residual_vs_toolface.png", None, dpi=110)
    plots.save_figure(plots.gap_per_step(gap_table(res)), out_dir / "gap_per_step.png", None, dpi=110)
    path = out_dir / "report.md"
    path.write_text(report_markdown(res, label, truth, qc, protocol))
    return path


# ============================================================ studies
def separability_cells(sep: Separability) -> tuple[str, str]:
    """(pairs not separable, unobservable directions) of a design, as two table cells."""
    pairs = "; ".join(f"{p.a} / {p.b}: {degeneracy_sentence(p.degeneracy)}" for p in sep.pairs) or "none"
    unobs = "; ".join(degeneracy_sentence(u) for u in sep.unobservable) or "none"
    return pairs, unobs


def _sci(x: float) -> str:
    """Short scientific notation: 0.0003 -> ``3e-4``."""
    m, e = f"{x:e}".split("e")
    return f"{float(m):g}e{int(e)}"


def _noise_words(config) -> str:
    return f"noise {config.sigma_b_nT:g} nT / {_sci(config.sigma_g)} g"


def study_command(study: str, config, **entry) -> str:
    """The command that rewrites ``results/discrepancy_<study>.md`` with these settings (a Markdown code span):
    ``study=``, the entry settings given (``seed=0``) and every workflow option that is not its default."""
    args = [f"study={study}"] + [f"{k}={v}" for k, v in entry.items()] + config_overrides(config)
    return f"`python -m experiments.discrepancy {' '.join(args)}`"


def _selection_test(config, rig: str | None = None) -> str:
    """The protocol's ``test``: the search's decision rules are no reported test (``rig``: the data's rig, which
    sets the candidates, :func:`icgo.physics.effects.names_for_rig`)."""
    n = len(_fx.names_for_rig(rig, config.candidates or _fx.ORDER))
    return (f"none: no p-value is reported. An effect is added when it lowers the held-out chi2 by >= "
            f"{config.min_rel_improvement:.0%} with a paired per-station z >= {config.min_z:g}, and a step is not "
            f"separable when another qualifying candidate is within z < {config.ambiguity_z:g} (docs/discrepancy.md): "
            f"decision rules of a greedy search over {n} candidates per step, not tests of a family, and not adjusted "
            "for their number")


def workflow_settings(config, runs: str, search: str = "") -> str:
    """The stamp line of a workflow table (:func:`icgo.reporting.protocol.settings_line`): the fits' budget, the runs
    each number comes from, the dtype; no source gives a protocol for this workflow."""
    added = ("effects added until the held-out rule stops" if config.max_effects is None
             else f"up to {config.max_effects} effects added")
    return settings_line(f"{search}Levenberg-Marquardt {config.n_iter} iterations per fit, {added}, "
                         f"{config.k_folds} folds", runs, "float64 fits",
                         "No published protocol: the workflow is this project's (docs/discrepancy.md).")


def _folds(config) -> str:
    return (f"{config.k_folds}-fold held-out score (each station held out once, the model fitted on the other "
            f"folds; fold permutation PRNGKey({FOLD_SEED}))")


def hidden_protocol(study) -> str:
    """The protocol line of ``results/discrepancy_hidden.md`` (:func:`hidden_study_markdown`)."""
    c, seed, n = study.config, study.seed, study.n_stations
    return protocol_line(
        study_command("hidden", c, seed=seed, n_stations=n),
        f"one simulated data set and one workflow run per row ({n} stations; no repeat pooled); the design table: "
        "one set of attitudes per design, no fit",
        f"rows: {_folds(c)} over the {n} stations; before -> after: the reference and the final model's held-out "
        "gaps. Design table: none held out (canonical correlations of the noise-weighted Jacobian at the design's "
        "attitudes)",
        f"data seed {seed}: attitudes and noise fold_in(PRNGKey({seed}), 1), the same in every row; "
        f"the i-th hidden effect's magnitudes fold_in(PRNGKey({seed}), 100 + i); designs PRNGKey({seed}). The "
        "workflow's options: `WorkflowConfig` (docs/discrepancy.md, Choices), overridden only as the command says",
        _selection_test(c))


def devices_protocol(runs, config) -> str:
    """The protocol line of ``results/discrepancy_devices.md`` (:func:`devices_study_markdown`)."""
    return protocol_line(
        study_command("devices", config),
        f"one workflow run per device ({len(runs)} devices; no repeat pooled)",
        f"{_folds(config)} over each device's shots, each group's shots spread over the folds; a held-out shot's "
        "group direction is refitted with the fold's global parameters fixed; before -> after: the reference and "
        "the final model's held-out residual and azimuth spread; the noise estimate: the held-out scatter of the "
        "best model evaluated",
        f"no data seed (real recordings); folds PRNGKey({FOLD_SEED}). No device is kept back: the held-out "
        "field/azimuth guard (`search.GAP_TOLERANCE`), one score per model and the scatter estimate "
        "(`noise_from_data`) were added after runs on these devices (docs/discrepancy.md)",
        _selection_test(config))


def _lab_casing_split(study) -> str:
    """The ICGO study's split the lab_casing study reuses, in words."""
    c = study.icgo_config.split
    kept = "every row" if c.sigma_filter is None else f"the rows its {c.sigma_filter:g}-sigma filter keeps"
    return (f"the ICGO study's {c.protocol} split ({c.train_fraction:.0%} of the rows for training) of {kept} of "
            f"lab_casing(seed={study.seed}), repeat 0")


def _lab_casing_seeds(study) -> str:
    s = study.seed
    return (f"data: lab_casing(seed={s}); ICGO study PRNGKey({s}), repeat 0's key fold_in(PRNGKey({s}), 0) (its "
            f"split and search); the workflow's folds PRNGKey({FOLD_SEED})")


def lab_casing_protocol(study) -> str:
    """The protocol line of ``results/discrepancy_lab_casing.md`` (:func:`lab_casing_study_markdown`)."""
    c, res = study.icgo_config, study.result
    return protocol_line(
        study_command("lab_casing", res.config, seed=study.seed),
        f"one split, one CGO search (repeat 0 of the ICGO study); each MAE and RMSE pools the {len(study.error_raw)} "
        "test rows",
        f"{_lab_casing_split(study)}: MSA, ICGO-RELM and the workflow fit its training rows only (the workflow "
        f"chooses its effects by a {_folds(res.config)} inside them); every method is scored on the same test rows",
        f"{_lab_casing_seeds(study)}. ICGO-RELM: `StudyConfig`'s defaults (L = {c.model.hidden}, "
        f"lambda = {c.model.lam:g}, population {c.budget.pop_size}, {c.budget.iterations} iterations); the default "
        "lambda was chosen on lab_casing(seed=1), "
        "study seed 100 (docs/reporting.md)",
        "none: one split, no significance test (the table compares MAE and RMSE only); the workflow's own z are "
        "decision rules (`results/discrepancy_lab_casing_report/report.md`)")


def lab_casing_report_protocol(study) -> str:
    """The protocol line of the lab_casing study's full report (``results/discrepancy_lab_casing_report``)."""
    res = study.result
    return protocol_line(
        study_command("lab_casing", res.config, seed=study.seed),
        f"one workflow run on repeat 0's training rows; each held-out number pools its {res.config.k_folds} folds",
        f"the search and the gap table: {_folds(res.config)} inside the training rows of "
        f"{_lab_casing_split(study)}; the survey QC: the model fitted on every training row, applied to the "
        f"{len(study.error_raw)} test rows",
        _lab_casing_seeds(study),
        _selection_test(res.config, "turntable"))


def hidden_study_markdown(study) -> str:
    """``results/discrepancy_hidden.md`` from :func:`~icgo.studies.discrepancy.results.hidden_study`."""
    rows = ["| hidden | named (in order) | verdict | mag gap nT before -> after | azimuth gap deg before -> after | excess over noise before -> after | s |",
            "|---|---|---|---|---|---|---|"]
    for run in study.runs:
        res = run.result
        g0, g1 = res.gaps[0], res.gaps[-1]
        rows.append(f"| {' + '.join(run.hidden) or 'nothing'} | {', '.join(res.model) or '-'} | {res.kind} | "
                    f"{g0.mag_rms_nT:.1f} -> {g1.mag_rms_nT:.1f} | {g0.azimuth_rms_deg:.3f} -> {g1.azimuth_rms_deg:.3f} | "
                    f"{g0.excess_over_noise:.2f} -> {g1.excess_over_noise:.2f} | {res.seconds:.1f} |")
    designs = ["| design | pairs not separable (first direction) | unobservable |", "|---|---|---|"]
    for dz, sep in study.designs:
        pairs, unobs = separability_cells(sep)
        designs.append(f"| {dz} | {pairs} | {unobs} |")
    return "\n".join(["# Discrepancy workflow: hidden-effect study", "", hidden_protocol(study), "",
                      workflow_settings(study.config, f"one workflow run per row ({study.n_stations} stations)"), "",
                      f"Simulated: seed {study.seed}, {study.n_stations} stations, random attitudes, "
                      f"{_noise_words(study.config)}, magnitudes typical x U(0.5, 1.5).", ""] + rows +
                     ["", "## Which effects a design cannot separate (Jacobian canonical correlations)", ""] + designs)


def devices_study_markdown(runs, config) -> str:
    """``results/discrepancy_devices.md`` from :func:`~icgo.studies.discrepancy.results.devices_study`."""
    rows = [("| device | named (in order) | verdict kind | mag residual nT before -> after | azimuth spread deg before "
             "-> after | noise estimated nT / mg (x assumed) | estimate from |"),
            "|---|---|---|---|---|---|---|"]
    for run in runs:
        res = run.result
        g0, g1 = res.gaps[0], res.gaps[-1]
        est = res.noise_estimate
        cell = "-" if est is None else (f"{est.noise.sigma_b_nT:.0f} / {est.noise.sigma_g * 1e3:.1f} "
                                        f"({est.ratios[0]:.0f}x / {est.ratios[1]:.0f}x)")
        rows.append(f"| {run.device} | {', '.join(res.model) or '-'} | {res.kind} | {g0.mag_rms_nT:.0f} -> {g1.mag_rms_nT:.0f} | "
                    f"{g0.azimuth_rms_deg:.2f} -> {g1.azimuth_rms_deg:.2f} | {cell} | {'-' if est is None else est.model} |")
    return "\n".join([f"# Discrepancy workflow on the {len(runs)} real circuitpython-mag-cal devices", "",
                      devices_protocol(runs, config), "",
                      workflow_settings(config, f"one workflow run per device ({len(runs)} devices)"), "",
                      ("No reference attitude: each group's "
                       "direction and the field magnitude/dip are nuisances; the azimuth spread is the held-out RMS "
                       f"deviation from the group's fitted direction. Noise assumed {config.sigma_b_nT} nT / "
                       f"{config.sigma_g} g (the fits' weights); the verdict is based on the scatter estimated from the "
                       "shots: the held-out scatter of the best model evaluated (`icgo.discrepancy.scatter`). Every "
                       "candidate is fitted to convergence or said not to have converged (and never added)."), ""]
                     + rows)


def lab_casing_study_markdown(study) -> str:
    """``results/discrepancy_lab_casing.md`` from :func:`~icgo.studies.discrepancy.results.lab_casing_study`."""
    res = study.result
    table = [("raw (eq. 1 on raw data)", study.error_raw),
             (f"physics model + {', '.join(res.model)} (discrepancy workflow)", study.error_model)]
    table += [(f"{m} (ICGO study, repeat 0)", e) for m, e in study.error_methods.items()]
    table.append(("msa only", study.error_msa))
    md = ["| method | test azimuth MAE (deg) | test RMSE (deg) | n |", "|---|---|---|---|"]
    for name, e in table:
        md.append(f"| {name} | {np.mean(np.abs(e)):.3f} | {np.sqrt(np.mean(e ** 2)):.3f} | {len(e)} |")
    truth = {"effects": study.truth_effects, "casing": getattr(study, "casing", None)}
    named = "; ".join(f"{s.name} = {np.round(s.params, 5).tolist()} ± {np.round(s.stderr, 5).tolist()} {s.units}"
                      + ("" if s.separable else f" (not separable from {list(s.equivalent)})") for s in res.steps)
    c = study.icgo_config
    return "\n".join(["# Discrepancy workflow on lab_casing vs ICGO-RELM", "", *answer(res, truth), "",
                      lab_casing_protocol(study), "",
                      workflow_settings(study.result.config, "one split (repeat 0), one run of each method",
                                        f"ICGO-RELM: population {c.budget.pop_size} x {c.budget.iterations} "
                                        "iterations ("
                                        + ("the paper's" if (c.budget.pop_size, c.budget.iterations) == (30, 100) else
                                           "NOT the paper's 30 x 100")
                                        + f"), search dtype {c.precision}; workflow: "), "",
                      f"Seed {study.seed}. The workflow is fitted on the ICGO study's training rows of repeat 0 only; "
                      "both are scored on its test rows.", "",
                      f"**Verdict (training rows):** {verdict(res)}", "",
                      "Named: " + named, "",
                      "Injected by the simulation: " + "; ".join(f"{k} = {v}" for k, v in truth_effects(truth).items())
                      + ".", ""]
                     + md + ["", "Full workflow report: `results/discrepancy_lab_casing_report/report.md`."])
