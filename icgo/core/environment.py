"""The software and hardware a run executed on: recorded in every run.json (``environment``) and stamped on every
table made from runs (:mod:`icgo.reporting.stamp`).

Reproducibility (DESIGN.md, Batching): a run repeated in the *same* environment (these fields equal) gives bitwise
the same numbers; across environments (another JAX/jaxlib or numpy, another CPU's vector units, another device
count) the arithmetic may differ in the last place, and a chaotic search amplifies such one-ulp differences into a
different search path, so per-world or per-repeat rows differ while the pooled claims over worlds hold. A table's
stamp says which environment made it, so a reader knows which of the two to expect.
"""

from __future__ import annotations

import platform
import sys
from pathlib import Path

#: The fields of an environment, in the order the stamp lists them.
FIELDS = ("python", "jax", "jaxlib", "numpy", "scipy", "cpu", "backend", "device", "device_count")


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo`` on Linux, else :func:`platform.processor`), or the machine type."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                return " ".join(line.split(":", 1)[1].split())
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown"


def _version(module: str) -> str:
    try:
        from importlib.metadata import version

        return version(module)
    except Exception:  # noqa: BLE001  (a missing distribution is recorded as such)
        return "not installed"


def environment() -> dict:
    """This process's environment: {python, jax, jaxlib, numpy, scipy: versions; cpu: model name; backend: JAX's
    default backend; device: its first device's kind; device_count: devices of that backend}."""
    import jax

    devices = jax.devices()
    return {"python": platform.python_version(), "jax": _version("jax"), "jaxlib": _version("jaxlib"),
            "numpy": _version("numpy"), "scipy": _version("scipy"), "cpu": cpu_model(),
            "backend": jax.default_backend(), "device": str(getattr(devices[0], "device_kind", "unknown")),
            "device_count": len(devices)}


def describe(env: dict | None) -> str:
    """One line naming an environment (``"not recorded"`` for None or an empty record). Two environments are the
    same for reproducibility when these lines are equal."""
    if not env:
        return "not recorded"
    g = {k: env.get(k, "?") for k in FIELDS}
    device = ("" if g["backend"] == "cpu" else f" {g['device']}")
    return (f"Python {g['python']}, jax {g['jax']}, jaxlib {g['jaxlib']}, numpy {g['numpy']}, scipy {g['scipy']}, "
            f"CPU {g['cpu']}, {g['backend']}{device} x {g['device_count']} device(s)")


def here() -> str:
    """:func:`describe` of this process's environment."""
    return describe(environment())


if __name__ == "__main__":  # pragma: no cover  (a quick look: python -m icgo.core.environment)
    sys.stdout.write(here() + "\n")
