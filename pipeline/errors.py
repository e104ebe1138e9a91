"""The one exception type that the app turns into a single clear line and a non-zero exit."""

import errno


class PipelineError(Exception):
    """A user-facing error: bad config value, malformed input file, missing artefact."""


def os_error_reason(e: OSError) -> str:
    """Why an OSError happened, in words (disk full said plainly), with the file if known."""
    reason = "the disk is full" if e.errno == errno.ENOSPC else (e.strerror or str(e))
    return reason + (f" ({e.filename})" if e.filename else "")
