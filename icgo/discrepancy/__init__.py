"""Discrepancy workflow: find where simulation and measurement disagree, name the
missing physical effect, add it to the model and show the gap shrink.

Six verbs, all usable from a notebook with plain arguments::

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
* **show** — :mod:`.report` (every sentence, Markdown, JSON; its figures drawn by
  :mod:`icgo.reporting.plots`).
* **apply** — :mod:`.inversion`: the fitted physics model as a :class:`PhysicsParams` pytree
  (:func:`physics_params` of a result) and its pure ``predict(params, sensors)``, the attitude that
  best explains each measured station; saved and applied as
  :class:`~icgo.artifacts.discrepancy.PhysicsModel`.

Modules: ``noise`` (the one set of noise constants), ``stations`` (input,
checks, simulation, designs), ``model`` (layout, prepare, predict, residuals),
``fit`` (the fits, and fixed models fitted per member), ``identifiability``, ``compare``, ``config``
(:class:`WorkflowConfig`, every option's one default), ``scatter`` (the noise estimated from grouped
shots), ``search``, ``report``, ``inversion``. The ``results/discrepancy_*`` studies as data are
:mod:`icgo.studies.discrepancy.results`; the workflow as a registered study is :mod:`icgo.studies.discrepancy`.
The workflow's decision statistic is :func:`icgo.maths.stats.paired_z`.
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
    TWELVE_PLUS_FIELD,
    Evaluation,
    evaluate_models,
    fit_members,
    folds,
    lm_fit,
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
from icgo.discrepancy.inversion import Inversion, PhysicsParams, physics_params
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
