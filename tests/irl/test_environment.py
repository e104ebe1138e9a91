"""The growing environment (birl.grow_nodes): the adaptive graph grows under each weight
vector once, however often the method rolls that vector out again."""

import numpy as np

from pipeline.core.graph_mdp import MDPParams
from pipeline.irl.environment import GrowingGraphEnvironment
from pipeline.tools.bench import _grow


def test_the_graph_grows_once_per_weight_vector():
    adaptive, w_a = _grow(80, seed=0)
    w_b = np.array([-1.0, -0.2, -0.5, 0.0])
    env = GrowingGraphEnvironment(adaptive, MDPParams(), grow_nodes=4)
    sizes = []
    for w in (w_a, w_b, w_b, w_a, w_a, w_b.copy()):
        rolled = env.rollout(np.asarray(w, float))
        sizes.append(rolled.graph.mdp.n_nodes)
        assert rolled.graph is env.graph  # the rollout lives in the graph as it is now
    # the first rollout scores the stored graph; then w_b grows it, w_b again does not,
    # w_a (not grown under yet) does, and repeats of either (equal values) do not
    assert sizes[0] == 80
    assert sizes[1] > sizes[0] and sizes[2] == sizes[1]
    assert sizes[3] > sizes[2] and sizes[4] == sizes[3] and sizes[5] == sizes[4]
