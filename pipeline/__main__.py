"""`python -m aftershock.pipeline` and the `aftershock` command.

Ctrl-C or SIGTERM while the program is still loading its modules (before anything is read or written) ends it
quietly with 130 / 143 instead of an import traceback; from `main` on, the command line handles both.
"""

import os
import signal
import sys


def _early(signum: int, _frame: object) -> None:
    os.write(2, b"aftershock: interrupted\n")
    os._exit(128 + signum)


def entry() -> None:
    """Console-script entry point."""
    previous = {sig: signal.signal(sig, _early) for sig in (signal.SIGINT, signal.SIGTERM)}
    from aftershock.pipeline.cli import main

    for sig, handler in previous.items():
        signal.signal(sig, handler)
    sys.exit(main())


if __name__ == "__main__":
    entry()
