"""The one exception type that the app turns into a single clear line and a non-zero exit."""

import errno
import sys


class PipelineError(Exception):
    """A user-facing error: bad config value, malformed input file, missing artefact."""


def first_line(e: BaseException, limit: int = 200) -> str:
    """The first line of an error's message (its type's name when it has none), cut to
    `limit` characters: a parser's or a library's message can run over many lines."""
    return (str(e).splitlines() or [type(e).__name__])[0][:limit]


def os_error_reason(e: OSError) -> str:
    """Why an OSError happened, in words (disk full said plainly), with the file if known."""
    reason = "the disk is full" if e.errno == errno.ENOSPC else (e.strerror or str(e))
    return reason + (f" ({e.filename})" if e.filename else "")


def report(e: PipelineError | OSError, writing: str) -> int:
    """A command-line tool's error as one line on stderr; returns the exit status, 2. An
    OSError (a read-only dir, a full disk) is said as "cannot write `writing`"."""
    if isinstance(e, OSError):
        print(f"error: cannot write {writing}: {os_error_reason(e)}", file=sys.stderr)
    else:
        print(f"error: {e}", file=sys.stderr)
    return 2
