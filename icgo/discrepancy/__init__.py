"""Discrepancy workflow: find where simulation and measurement disagree, name the
missing physical effect, add it to the model and show the gap shrink.

Five verbs (issue #7), all usable from a notebook with plain arguments::

    from icgo import discrepancy as D
    st = D.stations_from_recording(icgo.io.recording.read_recording(path))   # or D.simulate(...)
    res = D.run_workflow(st, D.WorkflowConfig(max_effects=4))
    print(D.verdict(res)); D.write_report(res, "my data", out_dir)

* **simulate** — :func:`predict` (:mod:`.model`): each station's G (g) and B (nT)
  from its reference attitude (or its group's fitted direction), the field and
  the effects in the model; toolface from the *measured* G with the model's
  accelerometer effects removed.
* **compare** — :func:`compare`, :func:`find_pattern` (:mod:`.compare`):
  residuals measured - predicted, binned, toolface harmonics, correlations.
* **name** — :mod:`.fit`: every candidate model fitted by Levenberg-Marquardt
  on k training folds and on all stations in one jitted call; held-out chi2,
  BIC, standard errors; :mod:`.identifiability`: what the attitudes cannot tell apart.
* **add** — :func:`run_workflow` (:mod:`.search`): the greedy forward search
  as ``init`` / ``step`` / ``finish`` over a :class:`SearchState`.
* **show** — :mod:`.report` (every sentence, Markdown, JSON), :mod:`.plots`.

Modules: ``noise`` (the one set of noise constants), ``stations`` (input,
checks, simulation, designs), ``model`` (layout, prepare, predict, residuals),
``stats`` (the paired z), ``fit``, ``identifiability``, ``compare``, ``config``
(:class:`WorkflowConfig`, every option's one default), ``scatter`` (the noise estimated from grouped
shots), ``search``, ``report``,
``plots``, ``result_studies`` (the ``results/discrepancy_*`` studies as data;
the workflow as a registered study is :mod:`icgo.studies.discrepancy`),
``artifact`` (:class:`~icgo.models.discrepancy.PhysicsModel`, the fitted
physics model saved and applied through :mod:`icgo.models.format`).
Sign convention everywhere: residual = measured - predicted.
Units: G in g, B in nT, angles in degrees at every public boundary.
"""

from icgo.discrepancy.compare import (
    COMPONENTS,
    Bin,
    Comparison,
    Correlated,
    Gap,
    Pattern,
    compare,
    find_pattern,
    gap,
)
from icgo.discrepancy.config import WorkflowConfig
from icgo.discrepancy.fit import (
    Evaluation,
    Inversion,
    correct,
    correct_with,
    evaluate_models,
    folds,
    lm_fit,
    model_params,
    standard_errors,
)
from icgo.discrepancy.identifiability import (
    Degeneracy,
    Pair,
    Separability,
    canonical_independence,
    design_jacobian,
    identifiability,
    separability,
)
from icgo.discrepancy.model import (
    FIELD_SCALES,
    GROUP_SCALE_DEG,
    VERTICAL_EXCLUDE_DEG,
    Data,
    Layout,
    Prediction,
    Prepared,
    effect_params,
    make_layout,
    predict,
    prepare,
    remove_accel_effects,
    residuals,
)
from icgo.discrepancy.noise import NOISE, Noise, effective_sigma, noise_floor
from icgo.discrepancy.plots import plot_gap_per_step, plot_residual_vs_toolface
from icgo.discrepancy.report import (
    degeneracy_sentence,
    pattern_sentences,
    report_markdown,
    result_to_json,
    search_log,
    step_notes,
    step_summary,
    verdict,
    write_report,
)
from icgo.discrepancy.scatter import NoiseEstimate
from icgo.discrepancy.search import (
    KINDS,
    Candidate,
    Result,
    SearchState,
    Step,
    finish,
    gap_table,
    init,
    run_workflow,
    step,
)
from icgo.discrepancy.stations import (
    DESIGNS,
    MIN_STATIONS,
    Stations,
    check_stations,
    design_attitudes,
    hidden_stations,
    pad_stations,
    random_effect_params,
    select_stations,
    simulate,
    stations_from_recording,
)
from icgo.discrepancy.stats import paired_z
