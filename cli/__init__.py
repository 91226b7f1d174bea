"""The twincd command line: a thin typer layer over the ``twincd`` library."""

import signal
import sys
import threading


def _exit_terminated(signum: int, frame: object) -> None:
    # SIGTERM before a command runs (while modules load): nothing is written yet, so leave at
    # once with 143, saying so as a running command does (it raises ``Terminated`` instead and
    # cleans up first)
    sys.stderr.write("twincd: terminated\n")
    sys.exit(128 + signum)


if threading.current_thread() is threading.main_thread():
    signal.signal(signal.SIGTERM, _exit_terminated)
