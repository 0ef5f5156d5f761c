"""Hydra launcher ``icgo_local``: one spawned process per sweep job (see :mod:`._core`)."""
