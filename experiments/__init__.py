"""Front doors of icgo: the Hydra entry points (``python -m experiments.run`` ...) and the argparse commands.

Run as ``python -m experiments.<door>``, this package is imported before the door's own modules: a Ctrl-C
while they load ends the command at once with one line (:func:`icgo.core.settings.startup_interrupts`);
the door's ``__main__`` block then hands the signals to :func:`icgo.core.settings.run_cli`.
"""

import sys

if sys.argv[:1] == ["-m"]:  # runpy sets argv[0] to "-m" while it imports the package of the module it runs
    from icgo.core.settings import startup_interrupts

    startup_interrupts()
