"""Messages decoded back into core objects (pipeline/artefacts/codec.py), through real MCAP
files: the occupancy grid, the demonstrations' statistics and MDP settings, and a graph
written in several messages. (The graph's columns: tests/artefacts/test_graph_columns.py.)"""

import numpy as np
import pytest

from pipeline.artefacts import ArtefactError, codec, read_artefact, topics
from pipeline.artefacts.store import ArtefactWriter
from pipeline.core.graph_mdp import MDPParams, Polylines
from pipeline.core.obstacles import OccupancyGrid
from pipeline.core.state_graph import EdgeTable, NodeTable


def _write(path, messages):
    """An artefact of (topic, type, payload, log_time)."""
    with ArtefactWriter(path, config_yaml="", metadata={}) as w:
        for topic, type_name, payload, log_time in messages:
            w.add(topic, type_name, payload, log_time=log_time)
    return path


def _nodes(n: int, first: int = 0, terminal: bool = True) -> NodeTable:
    k = np.arange(first, first + n)
    return NodeTable(np.stack([k * 1.0, k * 2.0, np.zeros(n)], axis=1),
                     np.array(["sampled"] * n), k - 1, k // 2, k * 0.5, k * 0.25, -k * 1.0,
                     (k % 2).astype(bool) if terminal else None)


def _edges(n_features: int) -> EdgeTable:
    return EdgeTable(np.array([0, 1]), np.array([1, 0]), np.array([1.0, 2.0]),
                     np.arange(2.0 * n_features).reshape(2, n_features),
                     Polylines.from_list([[[0, 0], [1, 1]], [[1, 1], [0, 0]]]),
                     np.array([True, False]), np.array([0, 1]))


def test_an_occupancy_grid_round_trips_with_its_origin_and_rows(tmp_path):
    """A 2 × 3 grid (row 0 the lowest y) at origin (-1.5, 2.5): cell (0, 2) and (1, 0)
    occupied; the message keeps x, y of the origin and height, width of the raster apart."""
    occupied = np.array([[False, False, True], [True, False, False]])
    grid = OccupancyGrid(occupied, (-1.5, 2.5), 0.25)
    path = _write(tmp_path / "scene.mcap", [(topics.SCENE_MAP, "OccupancyGrid",
                                             codec.grid_record(grid), 0)])
    msg = read_artefact(path).one(topics.SCENE_MAP)
    assert (msg["origin"], msg["width"], msg["height"]) == ([-1.5, 2.5], 3, 2)
    back = codec.decode_grid(msg)
    assert back.origin == (-1.5, 2.5) and back.resolution == 0.25
    assert np.array_equal(back.occupied, occupied)
    assert back.extent() == (-1.5, 2.5, -0.75, 3.0)


def test_the_demonstrations_statistics_and_mdp_settings_are_read_field_by_field(tmp_path):
    """Values chosen all different, so that no two fields can be confused."""
    demo = {"start_index": 2, "discounted_features": [0.5, -1.5], "offset": -0.75,
            "end_discount": 0.125, "reached": False, "heldout": False}
    expert = {"gamma": 0.95, "time_cost": 0.02, "r_goal": 3.0, "speed": 1.5}
    path = _write(tmp_path / "demos.mcap", [(topics.DEMOS_EXPERT, "Expert", expert, 0),
                                            (topics.DEMOS, "Demonstration", demo, 0)])
    art = read_artefact(path)
    [stats] = codec.decode_expert_stats(codec.training_demos(art))
    assert (stats.start, stats.offset, stats.end_discount, stats.reached) == \
        (2, -0.75, 0.125, False)
    assert np.array_equal(stats.phi, [0.5, -1.5])
    assert codec.decode_mdp_params(art.one(topics.DEMOS_EXPERT)) == \
        MDPParams(gamma=0.95, time_cost=0.02, r_goal=3.0, speed=1.5)


def test_last_iteration_is_the_largest_growth_iteration_of_the_rows():
    nodes = _nodes(5)  # added at iterations 0, 0, 1, 1, 2
    assert codec.last_iteration(nodes) == 2
    later = _nodes(3, first=5)  # 2, 3, 3
    assert codec.last_iteration(later) == 3
    assert codec.last_iteration(_nodes(0)) == 0


def test_terminal_flags_are_read_only_when_every_message_has_them(tmp_path):
    path = _write(tmp_path / "nodes.mcap", [
        ("/all", "GraphNodes", codec.nodes_message(_nodes(3), 0, with_terminal=True), 0),
        ("/all", "GraphNodes", codec.nodes_message(_nodes(2, 3), 3, with_terminal=True), 1),
        ("/some", "GraphNodes", codec.nodes_message(_nodes(3), 0, with_terminal=True), 0),
        ("/some", "GraphNodes", codec.nodes_message(_nodes(2, 3, terminal=False), 3), 1)])
    art = read_artefact(path)
    assert np.array_equal(codec.decode_nodes(art, "/all").terminal,
                          [False, True, False, True, False])
    assert codec.decode_nodes(art, "/some").terminal is None


def test_edge_messages_of_different_feature_counts_are_one_line_errors(tmp_path):
    with pytest.raises(ValueError, match="2 feature names for 3 feature columns"):
        codec.edges_message(_edges(3), 0, ["a", "b"])
    path = _write(tmp_path / "edges.mcap", [
        ("/e", "GraphEdges", codec.edges_message(_edges(3), 0, ["a", "b", "c"]), 0),
        ("/e", "GraphEdges", codec.edges_message(_edges(2), 2, ["a", "b"]), 1)])
    with pytest.raises(ArtefactError, match=r"topic '/e' with another 'n_features' than the "
                                            r"others \(\[2, 3\]\)"):
        codec.decode_edges(read_artefact(path), "/e")


def test_decoded_columns_of_edges_without_features(tmp_path):
    """n_features 0 (a run learning no feature): the features column is empty, not an error,
    with a row per edge (it had shape (0, 1)); the other columns decode as they are."""
    edges = _edges(0)
    path = _write(tmp_path / "edges.mcap", [
        (topics.GRAPH_EDGES, "GraphEdges", codec.edges_message(edges, 0, []), 0)])
    art = read_artefact(path)
    out = codec.decoded_columns(art, topics.GRAPH_EDGES, art.one(topics.GRAPH_EDGES))
    assert out["features"].shape == (2, 0)
    assert np.array_equal(out["duration"], [1.0, 2.0])
    assert np.array_equal(out["waypoints"], [[0, 0], [1, 1], [1, 1], [0, 0]])
