"""The test session's own set-up (tests/conftest.py): compiled programs are released near the mapping limit."""

from functools import partial

import jax
import jax.numpy as jnp
import pytest
from conftest import _memory_map_count, release_compiled_programs

needs_proc = pytest.mark.skipif(_memory_map_count() == 0, reason="no /proc/self/maps here")


def _scan(k, x):
    def body(c, _):
        c = jnp.sin(c) * k + jnp.cumsum(c) / (1 + jnp.abs(c).sum())
        return c, c.max()

    return jax.lax.scan(body, x, None, length=3)


@needs_proc
def test_releasing_compiled_programs_gives_back_their_memory_mappings():
    """40 small scan programs map ~10 regions each (measured 417 for 40); releasing them gives those back."""
    programs = [jax.jit(partial(_scan, k + 0.5)) for k in range(40)]
    before = _memory_map_count()
    for k, program in enumerate(programs):
        jax.block_until_ready(program(jnp.ones(3 + k)))
    compiled = _memory_map_count()
    assert compiled - before >= 80
    release_compiled_programs()
    assert _memory_map_count() <= before + (compiled - before) // 5

