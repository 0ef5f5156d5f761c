"""The command a door prints for the user to run next (a verdict's ``next:`` line), runnable as printed.

Started by the ``icgo`` console script (:mod:`experiments.cli`, which sets :data:`SCRIPT_ENV` to its own path), a
door names ``icgo <door>`` when that script is the ``icgo`` on the ``PATH``, else the script's full path; started as
``python -m experiments.<door>``, it names this interpreter by its full path (``sys.executable``), so the command
works without the virtual environment active. Nothing here imports more than the standard library.
"""

from __future__ import annotations

import os
import shlex
import shutil
import sys

#: Environment variable the ``icgo`` console script sets to its own path.
SCRIPT_ENV = "ICGO_SCRIPT"


def door_command(door: str) -> str:
    """The shell command that runs the front door ``door`` (``apply``, ``run``, ``calibrate`` ...), without its
    arguments: ``icgo apply``, ``/path/to/icgo apply`` or ``/path/to/python -m experiments.apply``."""
    script = os.environ.get(SCRIPT_ENV)
    if script:
        on_path = shutil.which("icgo")
        if on_path and os.path.realpath(on_path) == os.path.realpath(script):
            return f"icgo {door}"
        return f"{shlex.quote(script)} {door}"
    return f"{shlex.quote(sys.executable)} -m experiments.{door}"
