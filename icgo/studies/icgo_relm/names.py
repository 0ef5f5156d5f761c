"""The names every output gives the study's methods and CGO's 4th-seed strategies (one set, so a table, a
figure, a sweep and the printed summary of a run name a method the same way).

Method ids are the study's (``relm``, ``pso``, ``cgo-<strategy>``, ...; :meth:`icgo.studies.icgo_relm.config.StudyConfig.method_names`);
strategy ids and their names are the registry's (:data:`icgo.optim.mutation.MUTATIONS`: each entry's ``label``).
"""

from __future__ import annotations

from icgo.optim.mutation import MUTATIONS, STRATEGIES
from icgo.optim.mutation import label as strategy_label

#: Built-in strategy id -> its name in tables and legends (the registry's labels; a strategy a user registers
#: later is named by :func:`method_name` through the registry).
STRATEGY_NAMES = {s: MUTATIONS[s].label for s in STRATEGIES}

#: Method id -> its name (the ICGO paper's where it gives one). CGO with the original 4th seed is the paper's
#: CGO-RELM; with a mutated seed, ICGO-RELM with that strategy.
METHOD_NAMES = {"raw": "raw (eq. 1)", "msa": "MSA only", "relm": "RELM", "relm-tuned": "RELM (tuned)",
                "pso": "PSO-RELM", "ga": "GA-RELM", "sma": "SMA-RELM", "cgo-original": "CGO-RELM",
                **{f"cgo-{s}": f"ICGO-RELM ({n})" for s, n in STRATEGY_NAMES.items() if s != "original"}}


def method_name(method: str) -> str:
    """:data:`METHOD_NAMES`, else ``ICGO-RELM (<label>)`` for ``cgo-<strategy>`` (the registry's label, or the
    name of a strategy not registered in this process), else ``<ALG>-RELM (<variant>)`` from an id
    ``<alg>-<variant>`` (``<ALG>-RELM`` alone)."""
    if method in METHOD_NAMES:
        return METHOD_NAMES[method]
    name, _, value = method.partition("-")
    if name == "cgo" and value:  # a strategy registered after import (a user's own): ICGO-RELM with its label
        return f"ICGO-RELM ({strategy_label(value)})"
    return f"{name.upper()}-RELM" + (f" ({strategy_label(value)})" if value else "")
