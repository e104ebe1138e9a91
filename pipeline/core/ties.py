"""How geometry decides exact ties: the same way wherever the room lies.

Round numbers make ties common (a lattice point 0.1 m from a goal at x.5, a lattice edge
exactly four sub-steps long), and coordinates far from 0 carry their rounding (1e-9 m at UTM
magnitudes): before these tolerances, metropolis moved by (10, 20) m learned other weights.
Plain numpy; no scipy, so that light modules (the metric names) may use it.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

TIE = 1e-6  # m: distances this close count as equal


def within(distance: ArrayLike, radius: float) -> np.ndarray:
    """Mask: `distance` ≤ `radius`, a distance less than TIE beyond it counted as within
    (a lattice point exactly goal_tolerance from the goal is in the goal disk)."""
    return np.asarray(distance) <= radius + TIE


def substeps(length: ArrayLike, step: float) -> np.ndarray:
    """ceil(length / step), at least 1 (int64, shaped like `length`): how many equal
    sub-steps of at most `step` a segment of `length` needs, a length within TIE of a
    multiple of `step` counted as that multiple. Lattice edges are such multiples; a rounding
    of 1e-9 m gave them a sub-step more, so other midpoints and other feature integrals."""
    return np.maximum(1, np.ceil((np.asarray(length, float) - TIE) / step)).astype(np.int64)
