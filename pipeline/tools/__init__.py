"""Tools around runs: sweep aggregation, the rerun viewer, metric regression, benchmarks."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path
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


def output_directory(parser: argparse.ArgumentParser, out: Path) -> Path:
    """A benchmark's --out directory, created before any run (a path that is a file is
    refused with one line then, not after minutes of runs)."""
    if out.exists() and not out.is_dir():
        parser.error(f"--out {out} is a file, not a directory")
    out.mkdir(parents=True, exist_ok=True)
    return out
