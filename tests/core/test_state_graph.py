"""The state graph's spatial index (pipeline/core/state_graph.py) against brute force."""

import numpy as np

from pipeline.core.state_graph import SpatialIndex


def test_spatial_index_matches_brute_force_across_rebuilds():
    """Inserted one by one (the k-d tree is rebuilt now and then, the points since its last
    build scanned directly): every query equals a brute-force scan of all points."""
    rng = np.random.default_rng(3)
    index = SpatialIndex()
    points = rng.uniform(0, 20, (3000, 2))
    for n, p in enumerate(points, start=1):
        index.add(p)
        if n % 250 == 0 or n in (1, 33, 700):
            recent = points[max(0, n - 3):n] + rng.normal(0, 0.2, (min(n, 3), 2))
            for q in np.vstack([rng.uniform(-1, 21, (5, 2)), recent]):
                dist = np.linalg.norm(points[:n] - q, axis=1)
                for r in (0.3, 1.5):
                    inside = np.flatnonzero(dist <= r)
                    assert set(index.within(q, r).tolist()) == set(inside.tolist())
                    assert index.count_within(q, r) == len(inside)
                    near = index.nearest(q, 4, r)
                    assert np.allclose(np.sort(dist[near]), np.sort(dist[inside])[:4])
                assert list(index.within(q, 1.5)) == sorted(
                    index.within(q, 1.5), key=lambda i: (round(dist[i], 12), i))


def test_batched_queries_equal_the_single_point_queries():
    """any_within_many, count_within_many and nearest_many (one query for a batch of
    candidates) answer exactly as nearest(p, k, r) and count_within(p, r) do point by
    point, before and after the k-d tree's first build and with points since its last
    build."""
    rng = np.random.default_rng(5)
    index = SpatialIndex()
    points = rng.uniform(0, 10, (1500, 2))
    for n, p in enumerate(points, start=1):
        index.add(p)
        if n in (1, 20, 40, 300, 1111, 1500):
            queries = np.vstack([rng.uniform(-1, 11, (8, 2)), points[:n][-3:] + 0.05])
            poses = np.column_stack([queries, rng.uniform(-3, 3, len(queries))])
            for r in (0.1, 0.4, 1.2):
                assert index.any_within_many(poses, r).tolist() == \
                    [len(index.nearest(q, 1, r)) > 0 for q in queries]
                assert index.count_within_many(poses, r).tolist() == \
                    [index.count_within(q, r) for q in queries]
                for k in (1, 2, 5):  # nearest_many: the same nodes, with their distances
                    nodes, dists = index.nearest_many(poses, k, r)
                    assert nodes.shape == dists.shape == (len(queries), k)
                    for q, row, dist in zip(queries, nodes, dists, strict=True):
                        near = row[row >= 0]
                        assert near.tolist() == index.nearest(q, k, r).tolist()
                        assert dist[:len(near)].tolist() == \
                            np.linalg.norm(points[near] - q, axis=1).tolist()
                        assert (row[len(near):] == -1).all() and np.isinf(dist[len(near):]).all()


def test_a_point_exactly_a_radius_away_is_within_it_wherever_the_points_lie():
    """Nodes on a 0.5 m grid (medial-axis points, gridded drawings) lie exactly a radius of
    0.5 m (or √2·0.5) apart: counted within it at the origin, moved by a ROS map's origin
    and by a UTM offset alike, before and after the k-d tree's first build. A warehouse
    moved to a UTM offset counted such neighbours differently and grew another graph."""
    centre = np.array([2.5, 2.5])
    grid = np.array([[i * 0.5, j * 0.5] for i in range(12) for j in range(12)])
    grid = grid[np.argsort(np.linalg.norm(grid - centre, axis=1), kind="stable")]
    counts = []
    for shift in ([0.0, 0.0], [-51.225, -51.225], [500_000.0, 5_600_000.0]):
        for n in (30, len(grid)):  # recent points only; then most in the tree
            index = SpatialIndex()
            for p in grid[:n] + shift:
                index.add(p)
            q = centre + shift
            counts.append((n, index.count_within(q, 0.5), index.count_within(q, np.hypot(
                0.5, 0.5)), len(index.within(q, 0.5)), len(index.nearest(q, 20, 0.5)),
                int(index.count_within_many(q[None], 0.5)[0]),
                bool(index.any_within_many((q + [0.5, 0.0])[None], 0.0)[0])))
    # the point and its 4 (8) neighbours, in the scan of recent points and in the tree
    assert counts[0] == (30, 5, 9, 5, 5, 5, True)
    assert counts[1] == (len(grid), 5, 9, 5, 5, 5, True)
    assert counts[2:] == counts[:2] * 2, counts


def test_a_point_within_tie_beyond_the_radius_is_within():
    """0.4 − 0.1 is 0.30000000000000004 in floating point: at radius 0.3 the point counts."""
    index = SpatialIndex()
    index.add(np.array([0.4, 0.0]))
    q = np.array([0.1, 0.0])
    assert index.within(q, 0.3).tolist() == [0]
    assert index.within(q, 0.3, ordered=False).tolist() == [0]
    assert index.count_within(q, 0.3) == 1


def tiny_graph(max_edges=2):
    from pipeline.core.controllers import LinearController
    from pipeline.core.features import FeatureModel
    from pipeline.core.graph_mdp import MDPParams
    from pipeline.core.state_graph import SAMPLED, START, StateGraph
    from pipeline.core.world import Room, Scene
    scene = Scene("tiny", Room(0.0, 0.0, 5.0, 1.0), (), (), np.array([[0.5, 0.5]]),
                  np.array([4.5, 0.5]))
    fm = FeatureModel.from_scene(scene)
    graph = StateGraph(scene, fm, LinearController(), np.zeros(fm.dim), radius=3.0,
                       max_edges=max_edges, min_separation=0.1, mdp=MDPParams())
    for k, x in enumerate([0.5, 1.0, 1.5, 2.0, 2.5]):
        graph.add_node((x, 0.5, 0.0), START if k == 0 else SAMPLED)
    return graph


def test_connect_links_each_node_to_its_max_edges_nearest_both_ways():
    graph = tiny_graph(max_edges=2)
    graph.connect([0])
    pairs = sorted(zip(graph.src.tolist(), graph.dst.tolist(), strict=True))
    assert pairs == [(0, 1), (0, 2), (1, 0), (2, 0)]
    np.testing.assert_allclose(graph.duration[np.lexsort((graph.dst, graph.src))],
                               [0.5, 1.0, 0.5, 1.0])


def test_add_edges_skips_self_loops_and_repeats():
    graph = tiny_graph()
    w = [np.zeros((2, 2))] * 3
    graph.add_edges([0, 1, 0], [0, 2, 1], [1.0, 1.0, 1.0], np.zeros((3, graph.fm.dim)), w)
    graph.add_edges([1], [2], [1.0], np.zeros((1, graph.fm.dim)), w[:1])
    assert list(zip(graph.src.tolist(), graph.dst.tolist(), strict=True)) == [(1, 2), (0, 1)]


def test_reachable_from_follows_edges_forward_only():
    """Edges 0 → 1 → 2 and 3 → 2: from 1, nodes 1 and 2; never 0 or 3."""
    graph = tiny_graph()
    w = [np.zeros((2, 2))] * 3
    graph.add_edges([0, 1, 3], [1, 2, 2], [1.0, 1.0, 1.0], np.zeros((3, graph.fm.dim)), w)
    assert graph.reachable_from(np.array([1])).tolist() == [False, True, True, False, False]
