"""The benchmark: what ``python -m experiments.bench`` and ``python -m experiments.roofline`` measure.

The top layer of the library: it times the studies (:mod:`icgo.studies`) and the front doors in child processes.
Modules: ``cli`` (the benchmark's options, their checks and modes), ``cpu`` (every CPU measurement), ``backend``
(the ``--gpu-check`` on whatever backend it finds), ``rows`` (``--rows``: the commands on large CSVs),
``front_door`` (Table 3 and the calibrate door through their commands, the core curve, the like-for-like run),
``process`` (a command's wall time and peak memory), ``peers`` (evosax beside icgo on the same fitness),
``kernels`` (the study's data, the numpy reference fitness, timing helpers, mealpy's runs) and ``roofline`` (the
CPU kernel's per-stage roofline).
"""
