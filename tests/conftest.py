"""Test-session set-up shared by every test file.

JAX's persistent compilation cache (ENGINEERING-NOTES: a scan's compile fell
from 955 ms to 27 ms in a second process) is turned on for the test session, so
the two xdist workers and later runs reuse what the other compiled. The cache
lives in ``.jax_cache/`` at the repository root (git-ignored); results do not
depend on it.
"""

import os
from pathlib import Path

# Entry points called in-process (calibrate, run) turn on the cache their config names, by default under
# $XDG_CACHE_HOME: point it into the repository's cache folder, so the test session never shares a cache
# with the user's own runs going on beside it (a program read while another process wrote it crashed a worker).
os.environ["XDG_CACHE_HOME"] = str(Path(__file__).resolve().parents[1] / ".jax_cache" / "xdg")
# MLflow tracking (tracking=auto) off for every door a test runs; tests/test_tracking.py turns it on where it tests it
os.environ["ICGO_TRACKING"] = "false"

import pytest  # noqa: E402

import icgo  # noqa: F401, E402  (enables float64 before any test builds arrays)
from icgo.core.devices import enable_jax_cache, use_host_devices  # noqa: E402

#: Host devices of every test process: the studies' searches are sharded over them (one sharded program), so the
#: fast suite runs the multi-device path; tests that compare against one device take ``jax.devices()[:1]``.
HOST_DEVICES = use_host_devices(2)

#: Programs that took at least this long to compile are kept in the cache. Measured over the fast suite (two
#: workers, cold cache): ~7,300 programs compiled, 920 s of compiling; the ~260 over 0.5 s took 620 s, the ~460 between
#: 0.1 and 0.5 s took 115 s, which a threshold of 0.5 s compiled again on every warm run; the ~6,600 under 0.1 s (most
#: under 50 ms, eager operations) are compiled each time: a cache entry would save little of each, and JAX's bounded
#: cache scans the whole folder on every write, so thousands of tiny entries would slow the cold run.
CACHE_MIN_COMPILE_SECS = 0.1

# the two workers share one cache, locked (icgo.core.devices.CACHE_MAX_BYTES): a worker crashed in CI in a test that
# passes alone, with the unlocked cache fresh and both workers writing to it; a torn entry is the suspected cause
SESSION_CACHE_DIR = str(Path(__file__).resolve().parents[1] / ".jax_cache")
enable_jax_cache(SESSION_CACHE_DIR, min_compile_secs=CACHE_MIN_COMPILE_SECS)


def relm_train_data(n=60, hidden=5, seed=0, scale=1.0):
    """Small random RELM problem: (X (n, 6), T (n,), 0/1 mask, population (8, 7 hidden), train-mode FitData)."""
    import jax.numpy as jnp
    import numpy as np

    from icgo.models import relm

    rng = np.random.default_rng(seed)
    X = rng.standard_normal((n, 6))
    T = np.sin(X[:, 0]) + 0.3 * X[:, 1] * X[:, 2] + 0.01 * rng.standard_normal(n)
    mask = (rng.random(n) < 0.7).astype(float)
    pop = scale * rng.uniform(-1, 1, (8, relm.n_params(hidden)))
    fit = relm.FitData(jnp.asarray(X), jnp.asarray(T), jnp.asarray(mask)[None], jnp.asarray(mask)[None])
    return X, T, mask, jnp.asarray(pop), fit


@pytest.fixture(autouse=True)
def _hydra_config_cleared_after_each_test():
    """A test that sets Hydra's job config (as a front door's task function sees it) leaves it set for the next
    test in the process; a front door called in-process then writes a Hydra record into its outputs. Clear it."""
    yield
    from hydra.core.hydra_config import HydraConfig

    HydraConfig.instance().cfg = None


@pytest.fixture(autouse=True)
def _session_compilation_cache_kept():
    """A door's body called in-process turns on the cache its config names (``jax_cache_dir``, by default under
    XDG_CACHE_HOME, every program kept): give the session's cache set-up back after the test, or every later test
    of that worker writes each program it compiles, however small, into the cache (the fast suite ran ~10 % slower)."""
    yield
    import jax

    if (jax.config.jax_compilation_cache_dir != SESSION_CACHE_DIR
            or jax.config.jax_persistent_cache_min_compile_time_secs != CACHE_MIN_COMPILE_SECS):
        enable_jax_cache(SESSION_CACHE_DIR, min_compile_secs=CACHE_MIN_COMPILE_SECS)


def _memory_map_count() -> int:
    """Memory mappings this process holds now (lines of /proc/self/maps; 0 where there is no /proc)."""
    try:
        with open("/proc/self/maps", "rb") as maps:
            return maps.read().count(b"\n")
    except OSError:
        return 0


def _memory_map_limit() -> int:
    """The kernel's limit on one process's memory mappings (vm.max_map_count; Linux's default 65530)."""
    try:
        return int(Path("/proc/sys/vm/max_map_count").read_text())
    except (OSError, ValueError):
        return 65530


#: Compiled programs are released once a test process holds this many memory mappings. XLA's CPU backend maps
#: several regions per compiled program and keeps every program a cache still holds; one xdist worker passes
#: ~1,500 distinct programs and crossed vm.max_map_count (65530) near the end of the suite: CI failed with "LLVM
#: compilation error: Cannot allocate memory", and a worker died here at 64,760 mappings. Half the limit leaves
#: room for the largest jump measured in one test (~2,000 mappings); counting costs ~0.7 us a mapping.
MAP_COUNT_RELEASE = _memory_map_limit() // 2


@pytest.fixture(autouse=True)
def _compiled_programs_released_near_the_mapping_limit():
    """After a test, drop JAX's in-memory compiled programs when the process nears the kernel's mapping limit
    (the persistent cache in .jax_cache/ still holds the slow ones, so the next use reloads rather than recompiles)."""
    yield
    if _memory_map_count() > MAP_COUNT_RELEASE:
        release_compiled_programs()


def release_compiled_programs() -> None:
    """Drop every compiled program JAX holds in memory, with the memory mappings XLA made for them."""
    import gc

    import jax

    jax.clear_caches()
    gc.collect()
