"""Simulation: the sensor models (``instruments``) and the simulated data sets of the papers' experiments
(``protocols``). ``python -m icgo.datasets NAME --out DIR`` writes one as a contract recording.
"""
