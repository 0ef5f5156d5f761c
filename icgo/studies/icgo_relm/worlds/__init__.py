"""The ICGO-RELM study over independent simulated worlds (``worlds=N`` on the run door): the sharded search of every
world (:mod:`.study`), a worlds run's directory and printed summary (:mod:`.outputs`) and the statistics over worlds
(:mod:`.stats`: per-world and pooled tables, first in k of N, tests over worlds).
"""
