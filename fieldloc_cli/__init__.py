"""The command line of fieldloc: parses options, shows progress, reports errors. No algorithms.

Imported first when ``fieldloc`` starts (the console script, or ``python -m
fieldloc_cli.main``): from here until the command runs (``lazy_group.LazyGroup.invoke`` takes
the signals over), Ctrl-C or SIGTERM end the process in one line. Python's own handling
printed a KeyboardInterrupt traceback from the middle of importing click (a Ctrl-C to `batch
--serial` 0.3 s after its start), or click's "Aborted!" after an empty line."""

from __future__ import annotations

import os
import signal
import sys


def _stopped_at_start(signum, frame) -> None:
    """Ctrl-C or SIGTERM before the command ran: it wrote nothing; one line, exit 128 + the
    signal's number, as a shell says it."""
    what = "terminated" if signum == signal.SIGTERM else "interrupted"
    os.write(2, f"fieldloc: {what} (before it started; nothing was written)\n".encode())
    os._exit(128 + signum)


# the program starting (`fieldloc ...` or `python -m fieldloc_cli.main ...`, whose package is
# imported while sys.argv[0] is still "-m"), not a module imported by a test or a script
if sys.argv and (sys.argv[0] == "-m" or os.path.basename(sys.argv[0]) == "fieldloc"):
    for _signum in (signal.SIGINT, signal.SIGTERM):
        if signal.getsignal(_signum) not in (signal.SIG_IGN, None):  # ignored: left so
            signal.signal(_signum, _stopped_at_start)
