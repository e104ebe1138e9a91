"""The one exception type that the app turns into a single clear line and a non-zero exit."""


class PipelineError(Exception):
    """A user-facing error: bad config value, malformed input file, missing artefact."""
