"""The names every output gives the study's methods and CGO's 4th-seed strategies (one set, so a table, a
figure, a sweep and the printed summary of a run name a method the same way).

Method ids are the study's (``relm``, ``pso``, ``cgo-<strategy>``, ...; :meth:`icgo.studies.icgo_relm_config.StudyConfig.method_names`);
strategy ids are :data:`icgo.optim.STRATEGIES`.
"""

from __future__ import annotations

#: Strategy id -> its name in tables and legends.
STRATEGY_NAMES = {"original": "original", "chaos": "chaotic", "gaussian": "Gaussian", "wavelet": "wavelet",
                  "three_stage": "three-stage"}

#: Method id -> its name (the ICGO paper's where it gives one). CGO with the original 4th seed is the paper's
#: CGO-RELM; with a mutated seed, ICGO-RELM with that strategy.
METHOD_NAMES = {"raw": "raw (eq. 1)", "msa": "MSA only", "relm": "RELM", "relm-tuned": "RELM (tuned)",
                "pso": "PSO-RELM", "ga": "GA-RELM", "sma": "SMA-RELM", "cgo-original": "CGO-RELM",
                **{f"cgo-{s}": f"ICGO-RELM ({n})" for s, n in STRATEGY_NAMES.items() if s != "original"}}


def method_name(method: str) -> str:
    """:data:`METHOD_NAMES`, else ``<ALG>-RELM (<variant>)`` from an id ``<alg>-<variant>`` (``<ALG>-RELM`` alone)."""
    if method in METHOD_NAMES:
        return METHOD_NAMES[method]
    name, _, value = method.partition("-")
    return f"{name.upper()}-RELM" + (f" ({STRATEGY_NAMES.get(value, value)})" if value else "")
