"""Start-up of the command: scipy's docstrings left as written.

scipy (1.16 and later) appends a table of array-API backend support to the docstring of each
function it marks with `xp_capabilities`, parsing and re-rendering that docstring with its
numpydoc copy as the module is imported: 416 docstrings for the modules a run imports, a
sixth of the time the libraries a run uses take to import. A run never reads a docstring, so the
command (`python -m pipeline`, `birlg`) lets scipy keep them as written, without the table;
every function and scipy's own capability records are unchanged. The Python API
(`pipeline.api`) does not: a notebook that imports it shows scipy's help as usual.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any


class DocstringAsWritten:
    """Stands in for the numpydoc parser (`FunctionDoc`) inside `xp_capabilities`, which
    appends its note to `doc["Notes"]`, renders `str(doc)` and drops that text's first line
    (the signature): here the note goes to a list nobody keeps, and the text is an empty
    first line and the docstring."""

    def __init__(self, function: Callable[..., Any]) -> None:
        self.docstring = function.__doc__ or ""

    def __getitem__(self, section: str) -> list[str]:
        return []

    def __str__(self) -> str:
        return "\n" + self.docstring


def keep_scipy_docstrings() -> bool:
    """Make scipy's `xp_capabilities` leave docstrings as written (for the modules imported
    from now on); True if it will. Nothing changes where scipy's internals are not as
    expected (another version) or scipy is missing."""
    try:
        from scipy._lib import _array_api, _docscrape
    except ImportError:
        return False
    if getattr(_array_api, "FunctionDoc", None) is not _docscrape.FunctionDoc \
            or not callable(getattr(_array_api, "xp_capabilities", None)):
        return False
    _array_api.FunctionDoc = DocstringAsWritten
    return True
