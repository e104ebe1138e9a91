"""The alternatives lattice's size (birl.alternatives=lattice): as set on a small floor,
coarsened to at most ALTERNATIVES_MAX_NODES nodes on a large one, with the reason."""

import math

import pytest

from pipeline.app import limits


def test_a_small_floor_keeps_the_spacing_as_set():
    assert limits.alternatives_spacing(100.0, 0.2, "metropolis") == (0.2, "")


@pytest.mark.parametrize("area", [1600.0, 1.0e4])
def test_a_large_floor_gets_a_coarser_lattice_and_says_why(area):
    spacing, why = limits.alternatives_spacing(area, 0.2, "big")
    assert spacing > 0.2
    assert area / spacing**2 == pytest.approx(limits.ALTERNATIVES_MAX_NODES)
    assert math.isclose(spacing, math.sqrt(area / limits.ALTERNATIVES_MAX_NODES))
    assert "birl.alternatives_spacing" in why and "'big'" in why
