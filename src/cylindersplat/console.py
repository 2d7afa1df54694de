"""The ``cylindersplat`` executable (and ``python -m cylindersplat``): its first code.

Ctrl-C during start-up (the command line's imports take seconds on a busy machine) ends the process at once with
one line (:mod:`cylindersplat.interrupt`); :func:`cylindersplat.cli.main` then takes over.
"""

from .interrupt import exit_at_once

exit_at_once()  # before anything heavier is imported


def main() -> int:
    from .cli import main as run

    return run()
