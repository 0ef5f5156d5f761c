"""Studies behind one interface (:class:`icgo.studies.common.study.Study`) and one registry: the optimizer pattern one
level up.

A study is a :class:`~icgo.studies.common.study.Study`: a frozen config dataclass that validates itself
(``__post_init__``, one-line ``ValueError`` naming the field), a pure-ish
``run(data, config, key) -> result`` and the records the result writes::

    study = get_study("icgo_relm")          # icgo.studies.registry
    cfg = study.config_cls(n_repeats=3)
    result = study.run(data, cfg, jax.random.PRNGKey(0))
    tables = study.records(result)      # {"metrics": DataFrame, ...}
    result.models                        # {"relm_compensation": FittedModel, ...}

``data`` is whatever the study consumes (a data-contract ``DataFrame`` + metadata
for ICGO-RELM; a data set or devices for MISMA); ``key`` is a JAX PRNG key from
which every random draw of the run is split, so ``run`` is deterministic given
``(data, config, key)``. Every result carries its fitted models (dict
name -> :class:`icgo.artifacts.format.FittedModel`) and its records (dict name ->
``DataFrame``, column names from :mod:`icgo.reporting.records`).

A study that a front door runs also names its ``load`` (``(config, **inputs) -> data``), its ``write``
(``(result, data, config, stage, invocation) -> message``: every output file into a staged directory) and
the files it writes ``last``; the one study main (``experiments/_run_study.run_study``) runs any of
them the same way: load -> run -> write.

Hydra never appears here: the front door composes a config, builds the
dataclass (``config_from_mapping``) and calls the study.
"""
