"""Shared by the tests of the input files: a refusal as one line."""

import pytest

from pipeline.errors import PipelineError


def refused(match: str, fn, *args, **kwargs) -> str:
    with pytest.raises(PipelineError, match=match) as info:
        fn(*args, **kwargs)
    text = str(info.value)
    assert "\n" not in text and "Traceback" not in text
    return text
