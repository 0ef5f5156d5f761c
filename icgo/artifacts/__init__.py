"""Fitted models as artifacts: a family's params pytree, its pure ``predict(params, x)`` and the fit's meta.

``format`` is the pattern and the one generic save/load (:class:`~icgo.artifacts.format.FittedModel`; header
``.json`` + arrays ``.npz``), ``reading`` every check of a model file; ``relm`` (MSA and ICGO-RELM
compensation), ``calibration`` (magnetometer calibrations), ``network`` (gyro network, its RELM and lookup
table) and ``discrepancy`` (the discrepancy workflow's physics model) are the kinds; ``registry`` lists them
and loads any saved one::

    from icgo.artifacts.registry import load_model
    model = load_model("outputs/run/<date>/<time>/relm_compensation.json")
"""
