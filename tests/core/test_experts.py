"""Experts (pipeline/core/experts.py, DESIGN §6): optimal and Boltzmann demonstrations on the
metropolis reference roadmap, and several Boltzmann walks per start on a two-route graph."""

import math

import numpy as np
import pytest
from scipy.special import expit

from pipeline.core.experts import BoltzmannParams, boltzmann_demos, optimal_demos
from pipeline.core.features import FeatureModel
from pipeline.core.social import INTIMATE_ZONE, min_distance_to_person, path_metrics
from tests.conftest import POLITE, RUDE, two_routes


@pytest.fixture(scope="module")
def mdp(roadmap):
    return roadmap.mdp()


def demos_under(mdp, roadmap, w):
    return optimal_demos(mdp, roadmap.positions, roadmap.start_nodes, mdp.solve(w))


def test_polite_demos_avoid_links_and_intimate_zones(metropolis, roadmap, mdp):
    demos = demos_under(mdp, roadmap, POLITE)
    assert len(demos) == 7
    for d in demos:
        m = path_metrics(d.points, metropolis, d.durations.sum(), d.reached)
        assert d.reached
        assert m["relation_crossings"] == 0
        assert m["intimate_intrusion_m"] == 0.0
        assert min_distance_to_person(d.points, metropolis.person_xy) >= INTIMATE_ZONE


def test_rude_demos_are_shorter_and_cross_links(metropolis, roadmap, mdp):
    polite = demos_under(mdp, roadmap, POLITE)
    rude = demos_under(mdp, roadmap, RUDE)
    crossings = [path_metrics(d.points, metropolis, 0, True)["relation_crossings"] for d in rude]
    assert sum(crossings) >= 3
    for p, r in zip(polite, rude, strict=True):
        assert r.reached and r.features[3] <= p.features[3] + 1e-9
    assert sum(r.features[3] for r in rude) < sum(p.features[3] for p in polite) - 1.0


def test_demo_features_match_polyline(metropolis, roadmap, mdp):
    fm = FeatureModel.from_scene(metropolis)
    for d in demos_under(mdp, roadmap, POLITE):
        np.testing.assert_allclose(d.features, fm.polyline(d.points), rtol=1e-9, atol=1e-12)


def test_optimal_demo_value_equals_roadmap_value(roadmap, mdp):
    sol = mdp.solve(POLITE)
    for k, d in enumerate(optimal_demos(mdp, roadmap.positions, roadmap.start_nodes, sol)):
        quality = d.stats(mdp.params).quality(POLITE)
        assert quality == pytest.approx(sol.values[roadmap.start_nodes[k]])


def test_boltzmann_demos_are_seeded_noisy_and_worse(roadmap, mdp):
    sol = mdp.solve(POLITE)

    def make(seed):
        return boltzmann_demos(mdp, roadmap.positions, roadmap.start_nodes, POLITE, sol,
                               BoltzmannParams(50.0, 2000, 50), np.random.default_rng(seed))

    a, b, c = make(1), make(1), make(2)
    assert all(np.array_equal(x.points, y.points) for x, y in zip(a, b, strict=True))
    assert any(not np.array_equal(x.points, y.points) for x, y in zip(a, c, strict=True))
    assert all(d.reached for d in a)
    for k, d in enumerate(a):
        assert d.stats(mdp.params).quality(POLITE) <= sol.values[roadmap.start_nodes[k]] + 1e-9


def test_several_boltzmann_demos_per_start():
    """k walks per start, in start order; the first walk is the one k = 1 draws."""
    mdp, _, _ = two_routes()
    positions = np.array([[0, 0], [1, 1], [2, 2], [3, 0]], float)
    w = np.array([-0.5])
    sol = mdp.solve(w)
    one = boltzmann_demos(mdp, positions, np.array([0, 1]), w, sol,
                          BoltzmannParams(beta=1.0), np.random.default_rng(5))
    three = boltzmann_demos(mdp, positions, np.array([0, 1]), w, sol,
                            BoltzmannParams(beta=1.0, demos_per_start=3),
                            np.random.default_rng(5))
    assert [d.start_index for d in three] == [0, 0, 0, 1, 1, 1]
    np.testing.assert_array_equal(three[0].points, one[0].points)
    assert all(d.reached for d in three)
    # β = 1 on a 2-route choice with ΔQ small: both routes appear among many walks
    many = boltzmann_demos(mdp, positions, np.array([0]), w, sol,
                           BoltzmannParams(beta=1.0, demos_per_start=200),
                           np.random.default_rng(0))
    share_a = np.mean([len(d.points) == 2 for d in many])
    q = mdp.q_values(w, sol.values)[mdp.indptr[0]:mdp.indptr[1]]
    direct = int(np.flatnonzero(mdp.dst[mdp.indptr[0]:mdp.indptr[1]] == 3)[0])
    p_direct = expit(q[direct] - q[1 - direct])
    assert abs(share_a - p_direct) < 4 * math.sqrt(p_direct * (1 - p_direct) / 200)


def test_demonstrations_from_polylines_are_each_polylines_own(metropolis, monkeypatch):
    """`Demonstration.from_polylines` (all polylines' segments in one feature call) gives
    each demonstration what its own polyline gives alone, to the bit: the features of its
    segments, their durations at `speed`, its start, reached, subject and source, in arrays
    of its own (no views into the others'). Chunks of 7 sub-steps: the segments' features
    depend on where chunks fall."""
    import pipeline.core.features as features
    from pipeline.core.experts import Demonstration

    monkeypatch.setattr(features, "_CHUNK_POINTS", 7)
    fm = FeatureModel.from_scene(metropolis)
    rng = np.random.default_rng(5)
    polylines = [np.cumsum(rng.normal(0, 0.4, (n, 2)), axis=0) + [5.0, 5.0]
                 for n in (2, 9, 3, 30, 4, 17)]
    demos = Demonstration.from_polylines(list(range(6)), polylines, fm, 1.25,
                                         [k % 2 == 0 for k in range(6)],
                                         [f"s{k}" for k in range(6)], [f"w{k}" for k in range(6)])
    assert len(demos) == len(polylines)
    for k, (demo, p) in enumerate(zip(demos, polylines, strict=True)):
        assert (demo.start_index, demo.reached, demo.subject, demo.source) == \
            (k, k % 2 == 0, f"s{k}", f"w{k}")
        assert demo.points.tobytes() == p.tobytes()
        assert demo.edge_features.tobytes() == fm.segments(p[:-1], p[1:]).tobytes()
        assert demo.durations.tobytes() == \
            (np.linalg.norm(p[1:] - p[:-1], axis=1) / 1.25).tobytes()
        assert demo.edge_features.flags.owndata and demo.durations.flags.owndata
    assert Demonstration.from_polylines([], [], fm, 1.0, []) == []
