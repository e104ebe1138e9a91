"""Shared by the tests of pipeline/core: the metropolis reference roadmap and random graphs."""

import numpy as np
import pytest

from pipeline.core.features import FeatureModel
from pipeline.core.graph_mdp import GraphMDP, MDPParams
from pipeline.core.roadmap import build_roadmap


@pytest.fixture(scope="module")
def roadmap(metropolis):
    """The reference roadmap of metropolis, built once per module."""
    return build_roadmap(metropolis, FeatureModel.from_scene(metropolis))


# The two formulations of the graph MDP: the paper's discounted one and goal reaching.
DISCOUNTED = MDPParams(gamma=0.9, time_cost=0.0, r_goal=1.0, v_max=5.0)
GOAL = MDPParams(time_cost=0.05, r_goal=1.0, v_max=5.0)


def random_graph(rng, n=40, p=0.12, d=3, n_terminal=2, params=DISCOUNTED):
    """A random directed graph MDP: n nodes, each edge present with probability p, d features."""
    pairs = [(i, j) for i in range(n) for j in range(n) if i != j and rng.random() < p]
    src, dst = np.array(pairs).T
    terminal = np.zeros(n, bool)
    terminal[rng.choice(n, n_terminal, replace=False)] = True
    return GraphMDP(src, dst, rng.uniform(0.2, 2.0, len(src)), rng.uniform(0, 1, (len(src), d)),
                    terminal, params)
