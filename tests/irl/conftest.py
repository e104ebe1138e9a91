"""Shared by the IRL tests: the weight box of four features, central differences, and a
graph of three routes whose optimal route is known for every weight."""

import numpy as np

from pipeline.core.graph_mdp import GraphMDP, Path
from tests.conftest import PAPER_MDP

D = 4
BOX = (-np.ones(D), np.zeros(D))


def central_difference(f, w, h=1e-5):
    return np.array([(f(w + h * e) - f(w - h * e)) / (2 * h) for e in np.eye(len(w))])


# ---------------------------------------------------------------- three routes (PolicyWalk, MaxEnt)

ROUTES_BOX = (np.array([-1.0, -1.0]), np.array([0.0, 0.0]))  # the box of its two weights


def three_routes():
    """Start 0 → via node 1 (A), 2 (B) or 3 (C) → goal 4; or into the dead end 5.
    A costs feature 0, B feature 1, C 0.85 of both: with w ≤ 0, A is optimal iff w1 < w0
    (feature 1 costs more), B iff w0 < w1, and C never. Equal durations: equal goal terms."""
    src, dst = [0, 0, 0, 0, 1, 2, 3], [1, 2, 3, 5, 4, 4, 4]
    feats = [[1, 0], [0, 1], [0.85, 0.85], [0, 0], [0, 0], [0, 0], [0, 0]]
    terminal = np.zeros(6, bool)
    terminal[4] = True
    mdp = GraphMDP(src, dst, np.ones(7), feats, terminal, PAPER_MDP)
    routes = {k: Path(np.array([0, via, 4]), np.array([via - 1, via + 3]), True)
              for k, via in zip("ABC", (1, 2, 3), strict=True)}
    return mdp, routes


def greedy_route(mdp, w):
    return list(mdp.follow(mdp.solve(w).policy, 0).edges)
