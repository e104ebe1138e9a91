"""Tools around runs: sweep aggregation, the rerun viewer, metric regression, benchmarks."""

from __future__ import annotations

import argparse
import re
import signal
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import NoReturn

from pipeline.errors import (
    Interrupted,
    PipelineError,
    os_error_reason,
    restore_handlers,
    stop_quietly_while_starting,
    survive_closed_stdout,
)

# `python -m pipeline.tools.X` (argv[0] is "-m" while Python finds the module): a Ctrl-C
# during the tool's imports, most of a second, is one line, not a traceback from inside
# them; `run_tool` puts the handlers back. Imported by tests or a notebook: nothing changes.
# (This module imports nothing heavy before it: under load, a Ctrl-C landed in mcap's.)
_HANDLERS_BEFORE_IMPORTS = stop_quietly_while_starting() if sys.argv[:1] == ["-m"] else {}


# What pandas and the plotting raise on a committed table that is damaged (a column gone, a
# text where numbers were, an empty file): said as one line naming the table
DAMAGED_TABLE = (ValueError, KeyError, AttributeError, TypeError)


def run_tool(main: Callable[[], int | None]) -> NoReturn:
    """A tool's command: exit with what its main returns; Ctrl-C is one line and exit status
    130, as for birlg (each tool writes its files atomically, so a stop leaves none half
    written)."""
    restore_handlers(_HANDLERS_BEFORE_IMPORTS)
    survive_closed_stdout()  # `python -m pipeline.tools.export RUN | head -1`
    try:
        status = main()
    except KeyboardInterrupt:
        print("interrupted by the user", file=sys.stderr)
        sys.exit(130)
    except Interrupted as e:  # a tool that runs the pipeline in-process (benchmarks, docs)
        print(e.describe(), file=sys.stderr)
        sys.exit(e.exit_code)
    # Its work is done and said: a Ctrl-C in the interpreter's teardown would turn its exit
    # status into 130 without a word.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    sys.exit(status)


def output_directory(parser: argparse.ArgumentParser, out: Path) -> Path:
    """A benchmark's --out directory, created before any run (a path that is a file is
    refused with one line then, not after minutes of runs)."""
    if out.exists() and not out.is_dir():
        parser.error(f"--out {out} is a file, not a directory")
    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out):  # writable: the tables come after the runs
            pass
    except OSError as e:
        parser.error(f"--out {out} cannot be written: {os_error_reason(e)}")
    return out


def check_out_places(root: Path, files: list[Path], writer: str) -> None:
    """Before anything is made under the --out dir `root`: the dirs the `files` (relative to
    root) go in are dirs where they exist, and no file's place is taken by a dir."""
    for place in (root, *sorted({(root / f).parent for f in files} - {root})):
        if place.exists() and not place.is_dir():
            raise PipelineError(f"{place} is a file; --out needs a directory there")
    for f in files:
        if (root / f).is_dir():
            raise PipelineError(f"{root / f} is a directory; {writer} writes a file there")


def dir_override(key: str, path: Path | str) -> str:
    """`key=path` (hydra.run.dir, hydra.sweep.dir) as a Hydra override, whatever the path
    holds: quoted, its quotes escaped and the backslashes before them or at its end doubled
    (unquoted, a path with `=`, quotes, spaces or non-ASCII letters is refused)."""
    text = re.sub(r"(\\*)('|$)", lambda m: m.group(1) * 2 + ("\\'" if m.group(2) else ""),
                  str(path))
    return f"{key}='{text}'"
