"""`python -m aftershock.pipeline` and the `aftershock` command.

Ctrl-C or SIGTERM while the program is still loading its modules (before anything is read or written) ends it
quietly with 130 / 143 instead of an import traceback; from `main` on, the command line handles both, and once
`main` has returned (every output written, only the interpreter's shutdown left) the same quick stop applies again.
"""

import contextlib
import os
import signal
import sys


def _quick_stop(signum: int, _frame: object) -> None:
    for stream in (sys.stdout, sys.stderr):
        # what a finished command printed (its --json) must still reach the reader; a flush the signal cut
        # mid-write can save nothing more
        with contextlib.suppress(Exception):
            stream.flush()
    os.write(2, b"aftershock: interrupted\n")
    os._exit(128 + signum)


def entry() -> None:
    """Console-script entry point."""
    # Left installed: `main` puts its own handlers in and hands back to these when it returns, so a signal during
    # the interpreter's shutdown is the same clean stop, not Python's KeyboardInterrupt (exit -2).
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _quick_stop)
    from aftershock.pipeline.cli import main

    sys.exit(main())


if __name__ == "__main__":
    entry()
