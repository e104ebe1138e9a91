"""The command leaves scipy's docstrings as written (pipeline.app.scipy_docs): each check in
a fresh interpreter, since this one has scipy imported already."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

from scipy._lib import _array_api

from pipeline.app.scipy_docs import keep_scipy_docstrings

ROOT = Path(__file__).resolve().parents[2]

# scipy.linalg.block_diag is marked with xp_capabilities and imported with scipy.spatial.
# Its docstring as written is read from its source; the capability records and the
# function's use must not change.
DOCSTRING = textwrap.dedent("""
    import ast, inspect, json, sys
    {setup}
    import scipy.spatial
    from scipy._lib._array_api import FunctionDoc, xp_capabilities_table
    from scipy.linalg import block_diag
    source = inspect.getsource(sys.modules[block_diag.__module__])
    written = next(ast.get_docstring(node, clean=False) for node in ast.walk(ast.parse(source))
                   if isinstance(node, ast.FunctionDef) and node.name == "block_diag")
    print(json.dumps({{"as_written": block_diag.__doc__ == written.lstrip(" \\n"),
                      "note": "Array API Standard Support" in block_diag.__doc__,
                      "recorded": block_diag in xp_capabilities_table,
                      "stand_in": FunctionDoc.__name__,
                      "works": block_diag([[1]], [[2]]).tolist()}}))
""")


def _run(setup: str) -> dict:
    out = subprocess.run([sys.executable, "-c", DOCSTRING.format(setup=setup)],
                         capture_output=True, text=True, check=True, cwd=ROOT).stdout
    return json.loads(out.strip().splitlines()[-1])


def test_scipy_appends_its_capability_note_and_keep_scipy_docstrings_leaves_it_out():
    """Without the call scipy rewrites the docstring (if a scipy release stops doing so, the
    stand-in is no longer needed); with it the docstring is the source's, and scipy's own
    records and the function are unchanged."""
    assert _run("") == {"as_written": False, "note": True, "recorded": True,
                        "stand_in": "FunctionDoc", "works": [[1, 0], [0, 2]]}
    assert _run("from pipeline.app.scipy_docs import keep_scipy_docstrings\n"
                "assert keep_scipy_docstrings()") == {
        "as_written": True, "note": False, "recorded": True,
        "stand_in": "DocstringAsWritten", "works": [[1, 0], [0, 2]]}


def test_the_command_keeps_scipy_docstrings_and_the_python_api_does_not():
    """`python -m pipeline` (its module's imports) applies it before importing scipy; a user
    importing pipeline.api gets scipy's docstrings as scipy makes them."""
    assert _run("import pipeline.__main__")["note"] is False
    assert _run("import pipeline.api")["note"] is True


def test_unexpected_scipy_internals_are_left_alone(monkeypatch):
    """Another scipy whose decorator does not use the numpydoc parser: nothing changes."""
    other = object()
    monkeypatch.setattr(_array_api, "FunctionDoc", other)
    assert keep_scipy_docstrings() is False
    assert _array_api.FunctionDoc is other
