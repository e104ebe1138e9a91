"""Tools around runs: sweep aggregation, the rerun viewer, metric regression, benchmarks."""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import NoReturn

from pipeline.errors import survive_closed_stdout


def run_tool(main: Callable[[], int | None]) -> NoReturn:
    """A tool's command: exit with what its main returns; Ctrl-C is one line and exit status
    130, as for birlg (each tool writes its files atomically, so a stop leaves none half
    written)."""
    survive_closed_stdout()  # `python -m pipeline.tools.export RUN | head -1`
    try:
        status = main()
    except KeyboardInterrupt:
        print("interrupted by the user", file=sys.stderr)
        sys.exit(130)
    sys.exit(status)
