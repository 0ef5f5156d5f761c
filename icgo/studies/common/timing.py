"""Where a study's time goes: wall seconds per stage, and the part of it JAX spent making programs.

JAX reports through :mod:`jax.monitoring` how long it traced a function, lowered it to MLIR and
compiled it or loaded it from the persistent compilation cache (the backend-compile event wraps
both). :func:`compile_seconds` sums those events over the process's life; :class:`Stages` records,
per named stage, its wall time and that sum's growth during it, so a stage's time splits into
"making programs" (compile or cache load) and "running them".
"""

from __future__ import annotations

import time
from contextlib import contextmanager

#: The :mod:`jax.monitoring` duration events counted as making programs (tracing, lowering, compiling or
#: loading from the persistent cache).
COMPILE_EVENTS = ("/jax/core/compile/jaxpr_trace_duration", "/jax/core/compile/jaxpr_to_mlir_module_duration",
                  "/jax/core/compile/backend_compile_duration")
_total = [0.0]
_listening = [False]


def _on_duration(event: str, duration: float, **_) -> None:
    if event in COMPILE_EVENTS:
        _total[0] += duration


def compile_seconds() -> float:
    """Seconds this process has spent tracing, lowering and compiling (or cache-loading) JAX programs
    since the first call (which starts listening)."""
    if not _listening[0]:
        import jax

        jax.monitoring.register_event_duration_secs_listener(_on_duration)
        _listening[0] = True
    return _total[0]


class Stages:
    """Wall seconds per stage (``<name>_s``) and the compile or cache-load seconds within it (``<name>_compile_s``)."""

    def __init__(self):
        self.times: dict[str, float] = {}

    @contextmanager
    def __call__(self, name: str):
        c0, t0 = compile_seconds(), time.perf_counter()
        try:
            yield
        finally:
            wall = time.perf_counter() - t0
        self.add(name, wall, min(wall, compile_seconds() - c0))  # JAX times its events on its own clock

    def add(self, name: str, wall: float, compile_s: float = 0.0) -> None:
        """Add ``wall`` seconds (``compile_s`` of them making programs) to stage ``name``."""
        self.times[f"{name}_s"] = self.times.get(f"{name}_s", 0.0) + wall
        self.times[f"{name}_compile_s"] = self.times.get(f"{name}_compile_s", 0.0) + compile_s
