"""Simulation: the sensor models (``instruments``), the simulated data set (``dataset``) and the papers'
experiments: static stations near a casing (``casing_stations``, ICGO), a gyro inclinometer on a turntable
(``gyro_turntable``, patent CN1888384), a rotating drill string (``drill_string``, MISMA); ``registry`` names
them. ``python -m icgo.datasets NAME --out DIR`` writes one as a contract recording.
"""
