"""The ``stscam`` command installed with the package: the same command line as the binary
(the parser and every job run in the extension; ``stscam --help``)."""
from __future__ import annotations

import signal
import sys

from . import _native


def main() -> None:
    """Runs ``stscam`` with ``sys.argv`` and exits with its code (0, 1 or 2)."""
    # Ctrl-C ends the command at once, as it ends the binary (Python's own handler would only
    # run once the native job returns).
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    # A closed pipe (`stscam info --json | head`) ends it quietly too (Python ignores SIGPIPE,
    # which would turn the write into an error).
    if hasattr(signal, "SIGPIPE"):
        signal.signal(signal.SIGPIPE, signal.SIG_DFL)
    sys.exit(_native.cli(["stscam", *sys.argv[1:]]))


if __name__ == "__main__":
    main()
