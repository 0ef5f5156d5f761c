"""Fitted models as artifacts: a header plus arrays (``.json`` + ``.npz``), ``apply(frame)``, ``save``/``load_model``.

``format`` is the file format and the :class:`~icgo.models.format.FittedModel` base; ``relm`` (MSA and
ICGO-RELM compensation), ``calibration`` (magnetometer calibrations), ``network`` (gyro network, its RELM and
lookup table) and ``discrepancy`` (the discrepancy workflow's physics model) are the kinds;
``registry`` lists them and loads any saved one::

    from icgo.models.registry import load_model
    model = load_model("outputs/<date>/<time>/relm_compensation.json")
"""
