"""The ICGO-RELM tables and figures of ``results/`` from the run directories of ``experiments.run``.

One module per group of outputs: :mod:`.tables` (Tables 1-3), :mod:`.fig9` (Fig. 9, its budgets and the CGO
ablation), :mod:`.figures` (Figs. 10-13), :mod:`.table4` (Table 4 and Fig. 15), :mod:`.sweeps` (schedules and mutation
readings), :mod:`.condition_sweeps` (noise and casing), :mod:`.worlds_tables` (Tables 1, 3 and Fig. 9 over
independent worlds, with its own ``build``); :mod:`.notes` holds what several of them say, and :func:`.build.build`
writes the others. The runs are read by :class:`icgo.reporting.run_collection.Runs`; the statistics
are :mod:`icgo.studies.icgo_relm.results.repeat_tests` and :mod:`icgo.reporting.families`. Here, not in ``icgo.reporting``, because
the builders read the defaults of the optimizers and the study and simulate each data set's noise floor.
"""
