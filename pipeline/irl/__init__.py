"""IRL methods behind one interface (base.py): BIRL-G MAP and MCMC, PolicyWalk, MaxEnt IRL.

Every module of this package is imported by `methods()`, so a new method registers itself.
"""

from __future__ import annotations

import importlib
import pkgutil

from pipeline.irl.base import REGISTRY, Method


def methods() -> dict[str, Method]:
    """Every registered IRL method by name (imports each module of this package once)."""
    for info in pkgutil.iter_modules(__path__):
        importlib.import_module(f"{__name__}.{info.name}")
    return dict(sorted(REGISTRY.items()))
