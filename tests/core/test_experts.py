"""Reference roadmap and experts on the metropolis scene (DESIGN §4, §6)."""

import json

import numpy as np
import pytest

from pipeline.core.experts import BoltzmannParams, boltzmann_demos, optimal_demos
from pipeline.core.features import FeatureModel
from pipeline.core.graph_mdp import discounted_counts
from pipeline.core.roadmap import build_roadmap, segments_feasible
from pipeline.core.social import INTIMATE_ZONE, min_distance_to_person, path_metrics
from pipeline.errors import PipelineError
from pipeline.inputs.demo_file import load_demo_file
from tests.conftest import POLITE, RUDE


@pytest.fixture(scope="module")
def roadmap(metropolis):
    return build_roadmap(metropolis, FeatureModel.from_scene(metropolis))


@pytest.fixture(scope="module")
def mdp(roadmap):
    return roadmap.mdp()


def demos_under(mdp, roadmap, w):
    return optimal_demos(mdp, roadmap.positions, roadmap.start_nodes, mdp.solve(w))


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
        phi, end = discounted_counts(d.edge_features, d.durations, mdp.gamma)
        assert POLITE @ phi + end * mdp.r_goal == pytest.approx(sol.values[roadmap.start_nodes[k]])


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
        phi, end = discounted_counts(d.edge_features, d.durations, mdp.gamma)
        assert POLITE @ phi + end <= sol.values[roadmap.start_nodes[k]] + 1e-9


def test_demo_file_loading(tmp_path, metropolis):
    fm = FeatureModel.from_scene(metropolis)
    path = tmp_path / "demos.json"
    path.write_text(json.dumps({"scene": "metropolis", "trajectories": [
        [[0.5, 0.5], [0.5, 0.5], [3.0, 8.8], [5.5, 9.0]]]}))
    [d] = load_demo_file(path, metropolis, fm, speed=1.0)
    assert d.start_index == 0 and len(d.points) == 3  # repeated point dropped
    path.write_text(json.dumps({"trajectories": [[[0.5, 0.5], [3.0, 3.0]]]}))
    with pytest.raises(PipelineError, match="trajectory 0 ends .* from the goal"):
        load_demo_file(path, metropolis, fm, speed=1.0)
    path.write_text(json.dumps({"trajectories": [[[0.5, 0.5], [15.0, 9.0]]]}))
    with pytest.raises(PipelineError, match="trajectory 0 leaves the room"):
        load_demo_file(path, metropolis, fm, speed=1.0)


def test_demos_stage_writes_k_noisy_demos_per_start(tmp_path):
    from pipeline.artefacts import read_artefact
    from tests.conftest import run_in_process

    run_in_process(tmp_path, "stages=[scene,demos]", "expert=boltzmann", "expert.beta=20",
                   "expert.demos_per_start=3", "expert.n_demos=2")
    demos = read_artefact(tmp_path / "demos.mcap").all("/demos")
    assert [d["start_index"] for d in demos] == [0, 0, 0, 1, 1, 1]
    assert len({len(d["points"]) for d in demos[:3]}) > 1  # three different walks
