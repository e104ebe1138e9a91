"""The reference roadmap (pipeline/core/roadmap.py) on the metropolis scene."""

import numpy as np
import pytest

import pipeline.core.roadmap as roadmap_module
import pipeline.core.world as world_module
from pipeline.core.adaptive_graph import voronoi_centroids
from pipeline.core.features import FeatureModel, FeatureParams
from pipeline.core.nearby import PAIR_BUDGET, points_in_disks, segments_clear_of_disks
from pipeline.core.roadmap import RoadmapParams, build_roadmap, lattice_graph, segments_feasible
from pipeline.core.social import min_distance_to_person
from tests.conftest import moved_metropolis


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


# -- the person tests against every person (the code before the k-d tree cut-off) ---------
# Kept here only as the oracle: the package tests the persons near each segment or point.


def dense_segments_clear(a, b, persons, radius):
    seg = b - a
    len2 = np.maximum(np.einsum("nk,nk->n", seg, seg), 1e-18)
    ap = persons[None, :, :] - a[:, None, :]  # (n, P, 2)
    t = np.clip(np.einsum("npk,nk->np", ap, seg) / len2[:, None], 0.0, 1.0)
    closest = a[:, None, :] + t[..., None] * seg[:, None, :]
    d = np.linalg.norm(closest - persons[None, :, :], axis=2)
    return (d >= radius).all(axis=1)


def dense_points_in_disks(points, persons, radius):
    d = np.linalg.norm(points[:, None, :] - persons[None, :, :], axis=2)
    return (d < radius).any(axis=1)


def dense_lattice_graph(scene, spacing, connectivity):
    """lattice_graph with the dense person tests (monkeypatched into the package)."""
    import pipeline.core.nearby as nearby
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(nearby, "segments_clear_of_disks", dense_segments_clear)
        mp.setattr(roadmap_module, "segments_clear_of_disks", dense_segments_clear)
        mp.setattr(world_module, "points_in_disks", dense_points_in_disks)
        return lattice_graph(scene, spacing, connectivity)


def random_segments(rng, n, persons, radius):
    """Random segments in a 6 m square with, mixed in, segments touching body disks
    (an end at exactly `radius` from a person, along an axis so the distance is exact),
    segments grazing them, zero-length segments and long ones."""
    a = rng.uniform(0, 6, (n, 2))
    b = a + rng.normal(0, 0.4, (n, 2))
    k = n // 6
    who = persons[rng.integers(len(persons), size=k)]
    a[:k] = who + [radius, 0.0]  # on the disk's rim
    b[:k] = a[:k] + [rng.uniform(0, 1), 0.0]  # leaving it radially
    a[k:2 * k] = who + [0.0, -1.0]  # tangent to the disk: passes at exactly `radius`
    a[k:2 * k, 0] += radius
    b[k:2 * k] = a[k:2 * k] + [0.0, 2.0]
    b[2 * k:3 * k] = a[2 * k:3 * k]  # zero length
    a[3 * k:3 * k + 5] = who[:5] + [radius, 0.0]  # zero length on the rim
    b[3 * k:3 * k + 5] = a[3 * k:3 * k + 5]
    b[4 * k:4 * k + 10] = a[4 * k:4 * k + 10] + rng.normal(0, 8, (10, 2))  # long
    return a, b


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("budget", [PAIR_BUDGET, 40])  # one chunk / many chunks and trees
def test_segment_and_point_tests_equal_the_dense_ones(seed, budget, monkeypatch):
    import pipeline.core.nearby as nearby
    monkeypatch.setattr(nearby, "PAIR_BUDGET", budget)
    monkeypatch.setattr(nearby, "DENSE_PAIRS", 0)  # always the tree path
    rng = np.random.default_rng(seed)
    radius = 0.25
    persons = rng.uniform(0.5, 5.5, (rng.integers(5, 40), 2))
    a, b = random_segments(rng, 3000, persons, radius)
    dense = dense_segments_clear(a, b, persons, radius)
    # every kind of case is there: blocked, free, and free exactly at the rim
    assert dense.sum() > 100 and (~dense).sum() > 100
    np.testing.assert_array_equal(segments_clear_of_disks(a, b, persons, radius), dense)
    points = np.vstack([a, persons + [radius, 0.0], persons + [0.0, radius - 1e-12]])
    for r in (radius, radius + 0.1):
        np.testing.assert_array_equal(points_in_disks(points, persons, r),
                                      dense_points_in_disks(points, persons, r))


def test_segment_test_catches_one_blocked_pair(monkeypatch):
    """A pair the k-d tree would leave out is caught: a segment through a person far from
    its midpoint (the midpoint lies half the length away)."""
    import pipeline.core.nearby as nearby
    monkeypatch.setattr(nearby, "DENSE_PAIRS", 0)
    persons = np.array([[0.0, 0.0], [50.0, 50.0]])
    a = np.array([[-10.0, 0.0], [-10.0, 0.3], [0.25, 0.0], [0.0, 0.2499]])
    b = np.array([[0.0, 0.0], [10.0, 0.3], [0.25, 0.0], [0.0, 0.2499]])
    np.testing.assert_array_equal(segments_clear_of_disks(a, b, persons, 0.25),
                                  [False, True, True, False])


@pytest.mark.parametrize("connectivity", [8, 16])
def test_lattice_edges_equal_the_dense_computation(metropolis, connectivity, monkeypatch):
    import pipeline.core.nearby as nearby
    monkeypatch.setattr(nearby, "DENSE_PAIRS", 0)
    monkeypatch.setattr(nearby, "PAIR_BUDGET", 5000)
    dense = dense_lattice_graph(metropolis, 0.25, connectivity)
    new = lattice_graph(metropolis, 0.25, connectivity)
    assert len(dense[1]) > 1000
    for x, y in zip(new, dense, strict=True):
        np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("shift", [(10.0, 20.0), (-51.225, -51.225), (500_000.0, 5_600_000.0)])
@pytest.mark.parametrize("spacing", [0.2, 0.25])
def test_a_lattice_is_the_same_wherever_the_room_lies(spacing, shift):
    """The lattices (the reference roadmap, 0.25 m; the alternatives, 0.2 m) of metropolis
    moved by (10, 20) m, a ROS map's origin and a UTM offset: the same nodes and edges. Its
    round numbers put lattice points exactly 0.1 m from the goal and exactly on body disks'
    edges, ties that the moved coordinates' rounding decided differently (a node kept here,
    its neighbour there)."""
    data = moved_metropolis((0.0, 0.0))
    moved = moved_metropolis(shift)
    here = lattice_graph(world_module.scene_from_dict(data), spacing)
    there = lattice_graph(world_module.scene_from_dict(moved), spacing)
    assert len(here[0]) == len(there[0]) and len(here[1]) == len(there[1])
    np.testing.assert_allclose(there[0] - np.array(shift), here[0], atol=1e-6)
    np.testing.assert_array_equal(np.sort(here[1] * len(here[0]) + here[2]),
                                  np.sort(there[1] * len(there[0]) + there[2]))


# every kind of the library that a scene without a map has
EVERY_KIND = ["relation", "crossing", "social", "social@0.8", "social_squared", "intimate",
              "gaussian", "front", "group_space", "wall", "goal_deviation", "length"]


@pytest.mark.parametrize("shift", [(10.0, 20.0), (500_000.0, 5_600_000.0)])
def test_lattice_edge_features_are_the_same_wherever_the_room_lies(shift):
    """Every feature of every edge of the 0.2 m lattice (the alternatives) of metropolis
    moved by `shift`: the same integrals to 1e-6. Before ties were decided with a tolerance,
    at the UTM offset `relation` differed by up to 0.05 on edges along the perpendicular
    through a link's end (counted inside here, outside there), and `social` by 5e-4 on edges
    that got a midpoint sub-step more (length 0.2 + 1e-9 m: five sub-steps, not four)."""
    built = []
    for moved in (moved_metropolis((0.0, 0.0)), moved_metropolis(shift)):
        scene = world_module.scene_from_dict(moved)
        roadmap = build_roadmap(scene, FeatureModel.from_scene(scene, FeatureParams(EVERY_KIND)),
                                RoadmapParams(spacing=0.2))
        order = np.lexsort((roadmap.dst, roadmap.src))
        built.append((roadmap.src[order], roadmap.dst[order], roadmap.features[order]))
    (src, dst, here), (src_there, dst_there, there) = built
    np.testing.assert_array_equal(src, src_there)
    np.testing.assert_array_equal(dst, dst_there)
    assert (here[:, EVERY_KIND.index("relation")] > 0).sum() > 100  # links are crossed
    np.testing.assert_allclose(there, here, rtol=0, atol=1e-6)


def test_voronoi_centroids_are_the_same_wherever_the_room_lies():
    """The adaptive graph's first nodes: in UTM coordinates Qhull put them 100 m off (all
    outside the room, so none was added)."""
    here = world_module.scene_from_dict(moved_metropolis((0.0, 0.0)))
    shift = np.array([500_000.0, 5_600_000.0])
    there = world_module.scene_from_dict(moved_metropolis(tuple(shift)))
    expected = voronoi_centroids(here.person_xy, here.room)
    assert len(expected) == len(here.person_xy) and here.room.contains(expected).all()
    np.testing.assert_allclose(voronoi_centroids(there.person_xy, there.room) - shift,
                               expected, rtol=0, atol=1e-6)


# -- a tiny room worked by hand -------------------------------------------------------------


def tiny_scene(persons=(), polygons=(), robot_radius=0.25):
    """A 1.5 m x 1 m room: the lattice of 0.5 m has 4 x 3 nodes; the start and the goal lie
    in the middle of a cell, 0.354 m (> spacing/2) from its four corners, so none is dropped."""
    return world_module.Scene("tiny", world_module.Room(0.0, 0.0, 1.5, 1.0), tuple(persons), (),
                              np.array([[0.25, 0.25]]), np.array([1.25, 0.75]),
                              robot_radius=robot_radius, polygons=tuple(polygons))


def test_tiny_lattice_has_the_hand_counted_nodes_and_edges():
    """8-connected: 3·3 + 4·2 horizontal and vertical pairs and 2·3·2 diagonal ones, each
    both ways (58), plus start and goal both ways to the 4 corners of their cell (16).
    16-connected: 28 knight moves more, and start and goal reach the 9 nodes within
    0.5·√5 m (36)."""
    scene = tiny_scene()
    for connectivity, n_edges in [(8, 58 + 16), (16, 58 + 28 + 36)]:
        positions, src, dst = lattice_graph(scene, 0.5, connectivity)
        assert len(positions) == 12 + 2
        np.testing.assert_allclose(positions[-2:], [[0.25, 0.25], [1.25, 0.75]])
        lattice = {(round(x / 0.5), round(y / 0.5)) for x, y in positions[:-2]}
        assert lattice == {(i, j) for i in range(4) for j in range(3)}
        assert len(src) == n_edges
        pairs = set(zip(src.tolist(), dst.tolist(), strict=True))
        assert len(pairs) == n_edges  # no edge twice
        assert pairs == {(b, a) for a, b in pairs}  # every edge both ways
        length = np.linalg.norm(positions[dst] - positions[src], axis=1)
        steps = np.sqrt([1.0, 2.0, 5.0][:2 if connectivity == 8 else 3]) * 0.5
        inner = (src < 12) & (dst < 12)
        assert np.isclose(length[inner, None], steps[None, :]).any(axis=1).all()
        assert (length[~inner] <= steps[-1] + 1e-9).all()


def test_interior_node_has_exactly_the_king_and_knight_moves():
    """In a 2 m x 1.5 m room (not square: rows and columns cannot be swapped unseen), the
    node at (1, 0.75) links to exactly the 8 king and 8 knight offsets of 0.25 m."""
    scene = world_module.Scene("tiny", world_module.Room(0.0, 0.0, 2.0, 1.5), (), (),
                               np.array([[0.1, 0.1]]), np.array([1.9, 1.4]))
    positions, src, dst = lattice_graph(scene, 0.25, 16)
    node = int(np.argmin(np.linalg.norm(positions - [1.0, 0.75], axis=1)))
    offsets = {tuple(np.round((positions[d] - positions[node]) / 0.25).astype(int))
               for d in dst[src == node]}
    king = {(i, j) for i in (-1, 0, 1) for j in (-1, 0, 1)} - {(0, 0)}
    knight = {(i, j) for i in (-2, -1, 1, 2) for j in (-2, -1, 1, 2) if abs(i) != abs(j)}
    assert offsets == king | knight
    assert (src == node).sum() == 16


def test_lattice_node_near_a_start_is_dropped_only_within_half_a_spacing():
    """A start 0.2 m (< 0.25) from a lattice node replaces it; one 0.28 m and more from the
    corners of its cell does not."""
    scene = world_module.Scene("tiny", world_module.Room(0.0, 0.0, 1.5, 1.0), (), (),
                               np.array([[0.5, 0.2], [1.2, 0.7]]), np.array([1.5, 0.0]))
    positions, src, dst = lattice_graph(scene, 0.5, 8)
    lattice = {(round(x / 0.5), round(y / 0.5)) for x, y in positions[:-3]}
    assert src.min() >= 0 and dst.min() >= 0  # a dropped node starts or ends no edge
    # (1, 0) is 0.2 m from start 0, the goal sits on (3, 0); start 1 is 0.28 m from (2, 1)
    assert lattice == {(i, j) for i in range(4) for j in range(3)} - {(1, 0), (3, 0)}


def test_segments_feasible_keeps_out_of_bodies_room_and_obstacles():
    """Hand-placed segments: through a body disk, 0.22 m from a person (inside the 0.25 m
    disk), 0.3 m from it; leaving the room; 0.1 m from a wall with robot_radius 0.25 m
    and 0.4 m from it."""
    person = world_module.Person(1, 0.75, 0.5)
    scene = tiny_scene(persons=[person])
    a = np.array([[0.1, 0.5], [0.1, 0.72], [0.1, 0.8], [1.2, 0.2], [1.2, 0.8]])
    b = np.array([[1.4, 0.5], [1.4, 0.72], [1.4, 0.8], [1.7, 0.2], [1.2, 1.2]])
    np.testing.assert_array_equal(segments_feasible(scene, a, b),
                                  [False, False, True, False, False])
    wall = np.array([[0.0, 0.9], [1.5, 0.9], [1.5, 1.0], [0.0, 1.0]])  # 0.1 m thick
    walled = tiny_scene(polygons=[wall])
    a = np.array([[0.2, 0.8], [0.2, 0.5]])
    b = np.array([[1.3, 0.8], [1.3, 0.5]])
    np.testing.assert_array_equal(segments_feasible(walled, a, b), [False, True])


def test_roadmap_durations_are_lengths_over_the_speed():
    scene = tiny_scene()
    roadmap = build_roadmap(scene, FeatureModel.from_scene(scene),
                            RoadmapParams(spacing=0.5, connectivity=8), speed=2.0)
    length = np.linalg.norm(roadmap.positions[roadmap.dst] - roadmap.positions[roadmap.src],
                            axis=1)
    np.testing.assert_allclose(roadmap.duration, length / 2.0)
    assert roadmap.goal_node == 13 and roadmap.start_nodes.tolist() == [12]


def test_starts_without_path_follow_the_edges_direction():
    """Edges 0 → 1 → 2 (goal) → 3: start 0 reaches the goal, start 3 only leaves it."""
    positions = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0]])
    src, dst = np.array([0, 1, 2]), np.array([1, 2, 3])
    roadmap = roadmap_module.Roadmap(positions, src, dst, np.ones(3), np.zeros((3, 1)),
                                     np.array([False, False, True, False]),
                                     start_nodes=np.array([0, 3]), goal_node=2)
    assert roadmap.starts_without_path_to_goal() == [1]


def _staircase(a, b, step=0.25):
    """A lattice staircase from a to b: first along x as far as the x gap exceeds the y
    gap, then diagonally (the shape a lattice's shortest path takes)."""
    (x0, y0), (x1, y1) = a, b
    flat = (x1 - x0) - (y1 - y0)
    n_flat, n_diag = round(flat / step), round((y1 - y0) / step)
    pts = [[x0 + k * step, y0] for k in range(n_flat + 1)]
    pts += [[x0 + flat + k * step, y0 + k * step] for k in range(1, n_diag + 1)]
    return np.array(pts)


def test_a_staircase_pulled_taut_by_length_is_the_straight_line():
    """In an empty room, under length alone (the shortest path's reward), a staircase from
    (0.5, 0.5) to (4.5, 2.5) pulls taut to the straight segment between its ends."""
    scene = world_module.Scene("open", world_module.Room(0.0, 0.0, 5.0, 3.0), (), (),
                               np.array([[0.5, 0.5]]), np.array([4.5, 2.5]))
    stairs = _staircase([0.5, 0.5], [4.5, 2.5])
    np.testing.assert_allclose(stairs[-1], [4.5, 2.5])
    cost = roadmap_module.segment_cost(FeatureModel.from_scene(scene),
                                       roadmap_module.MDPParams(), np.zeros(4))
    np.testing.assert_allclose(roadmap_module.pulled_taut(scene, stairs, cost),
                               [[0.5, 0.5], [4.5, 2.5]])


def test_pulled_taut_keeps_round_a_person_and_never_costs_more():
    """A person in the way: pulled taut by length, the path still keeps out of the body disk
    (every segment feasible), keeps its ends and gets no longer; under a reward that costs
    passing near people, it costs no more than before under that reward, and passes the
    person no closer than the straight line by length does."""
    person = world_module.Person(1, 2.5, 1.5, 0.0)
    scene = world_module.Scene("open", world_module.Room(0.0, 0.0, 5.0, 3.0), (person,), (),
                               np.array([[0.5, 0.5]]), np.array([4.5, 2.5]))
    fm = FeatureModel.from_scene(scene)
    detour = np.array([[0.5, 0.5], [1.5, 0.25], [2.5, 0.25], [3.5, 0.25], [4.25, 1.0],
                       [4.5, 1.75], [4.5, 2.5]])
    assert segments_feasible(scene, detour[:-1], detour[1:]).all()
    length = roadmap_module.segment_cost(fm, roadmap_module.MDPParams(), np.zeros(4))
    social = roadmap_module.segment_cost(fm, roadmap_module.MDPParams(), [0.0, -5.0, 0.0, 0.0])
    by_length = roadmap_module.pulled_taut(scene, detour, length)
    by_social = roadmap_module.pulled_taut(scene, detour, social)
    for taut, cost in ((by_length, length), (by_social, social)):
        np.testing.assert_array_equal(taut[[0, -1]], detour[[0, -1]])
        assert segments_feasible(scene, taut[:-1], taut[1:]).all()
        assert cost(taut[:-1], taut[1:]).sum() <= cost(detour[:-1], detour[1:]).sum() + 1e-12
        assert len(taut) < len(detour)  # something was pulled
    assert length(by_length[:-1], by_length[1:]).sum() < length(detour[:-1], detour[1:]).sum()
    near = [min_distance_to_person(t, scene.person_xy) for t in (by_length, by_social)]
    assert near[0] < 1.2 <= near[1]  # the social hinge (1.2 m) keeps the detour wide
