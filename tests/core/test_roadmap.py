"""The reference roadmap (pipeline/core/roadmap.py) on the metropolis scene."""

import numpy as np

from pipeline.core.roadmap import segments_feasible


def test_roadmap_is_feasible_and_16_connected(metropolis, roadmap):
    assert segments_feasible(metropolis, roadmap.positions[roadmap.src],
                             roadmap.positions[roadmap.dst]).all()
    assert not metropolis.in_body(roadmap.positions).any()
    # An interior lattice node far from people has all 16 neighbours.
    node = int(np.argmin(np.linalg.norm(roadmap.positions - [9.0, 4.0], axis=1)))
    assert (roadmap.src == node).sum() == 16
    # No two nodes at (almost) the same place.
    d = np.linalg.norm(roadmap.positions[:, None] - roadmap.positions[None], axis=2)
    assert (d + np.eye(len(d)) * 9).min() > 0.1
    np.testing.assert_allclose(roadmap.positions[roadmap.start_nodes], metropolis.starts)
