"""The study machinery every study shares (the only part of :mod:`icgo.studies` a study imports besides its own
package and, where ``tests/test_layers.py`` allows it, another study's face).

* :mod:`.study`: the interface every study follows (:class:`~icgo.studies.common.study.Study`, ``Invocation``).
* :mod:`.splits`: the train / test protocols (random split and the generalisation protocols).
* :mod:`.timing`: where a study's time goes (wall seconds per stage, the part spent making programs).
* :mod:`.shots`: grouped static shots for the front doors (the file as read, grouped).
* :mod:`.run_log`: the log lines of a long run (durations, rates; a line to the run's log files).
* :mod:`.tracking`: a door's run directory, or a sweep, tracked in MLflow.
* :mod:`.tracking_tables`: the metrics a run directory holds, as MLflow wants them.

It names no study.
"""
