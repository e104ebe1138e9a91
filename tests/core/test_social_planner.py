"""The people-aware planner expert (pipeline.core.social_planner): properties its paths must
have on the metropolis scene and on small hand-made scenes, its cost against hand
computations, and its optimality against an independent Dijkstra."""

import dataclasses
import heapq
import json
import math

import numpy as np
import pytest
from scipy.integrate import quad

from pipeline.core.evaluation import discrete_frechet
from pipeline.core.experts import optimal_demos
from pipeline.core.features import FeatureModel
from pipeline.core.params import ParameterError
from pipeline.core.roadmap import segments_feasible
from pipeline.core.social import min_distance_to_person, relation_crossings
from pipeline.core.social_planner import (
    SUBJECT_FIELDS,
    SocialCost,
    SocialPlannerParams,
    _drop_collinear,
    _string_pull,
    edge_costs,
    groups,
    lattice_spacing,
    plan,
    planner_demos,
    planner_graph,
    subjects,
)
from pipeline.core.world import Person, Room, Scene, scene_from_dict
from pipeline.errors import PipelineError
from pipeline.inputs.scene_file import load_scene_file
from tests.conftest import METROPOLIS, POLITE, moved_scene, write_json

INTIMATE = 0.45  # m


@pytest.fixture(scope="module")
def metropolis_paths(metropolis):
    return plan(metropolis, SocialPlannerParams())


@pytest.fixture(scope="module")
def metropolis_subjects(metropolis):
    """Five subjects from every start (seed 0)."""
    return planner_demos(metropolis, FeatureModel.from_scene(metropolis),
                         SocialPlannerParams(n_subjects=5), np.random.default_rng(0), 1.0)


def corridor(theta: float) -> Scene:
    """A 10 m × 4 m corridor with one person in the middle facing across it (theta), the
    goal straight along it: the person can be passed in front or behind."""
    return scene_from_dict({
        "name": "corridor", "room": {"x_min": 0, "y_min": 0, "x_max": 10, "y_max": 4},
        "persons": [{"id": 1, "x": 5.0, "y": 2.0, "theta": theta}], "relations": [],
        "starts": [[0.5, 2.0]], "goal": [9.5, 2.0]})


GROUP_CENTRE = np.array([5.0, 3.0])


def group_scene() -> Scene:
    """Three persons 0.9 m around GROUP_CENTRE facing it (an F-formation), 1.56 m apart:
    wide enough gaps to walk through; start and goal on a line through the centre."""
    persons = []
    for k, angle in enumerate(np.radians([90.0, 210.0, 330.0])):
        persons.append({"id": k + 1, "x": GROUP_CENTRE[0] + 0.9 * math.cos(angle),
                        "y": GROUP_CENTRE[1] + 0.9 * math.sin(angle), "theta": angle + math.pi})
    return scene_from_dict({
        "name": "group", "room": {"x_min": 0, "y_min": 0, "x_max": 10, "y_max": 6},
        "persons": persons, "relations": [[1, 2], [2, 3], [1, 3]],
        "starts": [[0.5, 3.0]], "goal": [9.5, 3.0]})


def y_at(points: np.ndarray, x: float) -> float:
    """y of a polyline that runs left to right where it passes x."""
    assert np.all(np.diff(points[:, 0]) > 0)
    return float(np.interp(x, points[:, 0], points[:, 1]))


# -- the paths -----------------------------------------------------------------------------


def test_every_path_runs_from_its_start_exactly_to_the_goal(metropolis, metropolis_paths):
    assert [p.start_index for p in metropolis_paths] == list(range(len(metropolis.starts)))
    for p in metropolis_paths:
        assert np.array_equal(p.points[0], metropolis.starts[p.start_index])
        assert np.array_equal(p.points[-1], metropolis.goal)
        # DESIGN §3's goal-disk rule: no point within goal_tolerance before the end
        before_end = np.linalg.norm(p.points[:-1] - metropolis.goal, axis=1)
        assert before_end.min() > metropolis.goal_tolerance


def test_paths_are_collision_free_polite_and_out_of_the_intimate_zone(metropolis,
                                                                      metropolis_paths,
                                                                      metropolis_subjects):
    link_a, link_b = metropolis.links
    paths = [p.points for p in metropolis_paths] + [d.points for d in metropolis_subjects]
    for points in paths:
        assert segments_feasible(metropolis, points[:-1], points[1:]).all()
        assert relation_crossings(points, link_a, link_b) == 0
        assert min_distance_to_person(points, metropolis.person_xy) > INTIMATE


def test_smoothing_leaves_few_vertices_and_no_collinear_ones(metropolis_paths):
    for p in metropolis_paths:
        assert len(p.points) < len(p.lattice_nodes) / 3
        d_in, d_out = np.diff(p.points, axis=0)[:-1], np.diff(p.points, axis=0)[1:]
        cross = d_in[:, 0] * d_out[:, 1] - d_in[:, 1] * d_out[:, 0]
        assert np.all(np.abs(cross) > 1e-9)


def test_smoothing_never_raises_the_cost_of_the_cheapest_lattice_path(metropolis_paths):
    for p in metropolis_paths:
        assert p.cost <= p.lattice_cost * (1 + 1e-9)
        assert p.lattice_cost - p.cost < 0.01 * p.lattice_cost  # the same path, straightened


def test_string_pulling_jumps_to_the_farthest_vertex_it_may():
    """In an empty 10 m room, far from its walls (whose cost is e^-22 of its peak 2 m
    away), the density is 1: a staircase from (3, 3) to (7, 5) costs its length, the
    straight segment less, so pulling leaves its two ends. A vertex the segment may not
    reach (a person in the way) is kept, and the pull goes on from it."""
    room = Room(0.0, 0.0, 10.0, 10.0)
    steps = np.array([[3.0, 3.0], [4.0, 3.0], [4.0, 4.0], [5.0, 4.0], [6.0, 4.0], [6.0, 5.0],
                      [7.0, 5.0]])
    along = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(steps, axis=0), axis=1))])
    empty = Scene("empty", room, (), (), steps[:1], steps[-1])
    pulled = _string_pull(empty, SocialCost(empty, SocialPlannerParams()), steps, along)
    assert np.array_equal(pulled, steps[[0, -1]])
    # a person 0.13 m off the straight line (clear of the staircase), the cost made flat by
    # zero amplitudes: from (3, 3) the farthest vertex in sight is (6, 4), then the goal
    flat = SocialPlannerParams(amplitude_person=0.0, amplitude_intimate=0.0,
                               amplitude_group=0.0, amplitude_wall=0.0)
    blocked = Scene("blocked", room, (Person(1, 5.3, 4.3),), (), steps[:1], steps[-1])
    assert segments_feasible(blocked, steps[:-1], steps[1:]).all()
    pulled = _string_pull(blocked, SocialCost(blocked, flat), steps, along)
    assert pulled.tolist() == [[3.0, 3.0], [6.0, 4.0], [7.0, 5.0]]


def test_the_planners_lattice_ends_a_path_where_it_enters_the_goal_disk(metropolis):
    """No edge leaves or enters a lattice node within goal_tolerance of the goal: an edge
    into the disk goes to the goal itself instead. A start is a path's first point, never
    cut away, even within the disk (a Scene made directly: a file refuses it)."""
    graph = planner_graph(metropolis, SocialPlannerParams())
    in_disk = metropolis.at_goal(graph.positions)
    in_disk[graph.goal_node] = False
    assert not in_disk[graph.src].any() and not in_disk[graph.dst].any()
    into_goal = graph.src[graph.dst == graph.goal_node]
    assert len(into_goal) and (np.linalg.norm(graph.positions[into_goal] - metropolis.goal,
                                              axis=1) > metropolis.goal_tolerance).all()
    near = dataclasses.replace(metropolis, starts=np.array([[5.5, 8.8], [0.5, 0.5]]))
    graph = planner_graph(near, SocialPlannerParams())
    assert (graph.src == graph.start_nodes[0]).any()


def test_paths_keep_clear_of_obstacles_and_go_through_the_door():
    # A wall across the room at y = 5 with a 1.2 m door at x in [6, 7.2].
    wall = [[[0, 4.9], [6, 4.9], [6, 5.1], [0, 5.1]], [[7.2, 4.9], [10, 4.9], [10, 5.1],
                                                       [7.2, 5.1]]]
    scene = scene_from_dict({
        "name": "door", "room": {"x_min": 0, "y_min": 0, "x_max": 10, "y_max": 10},
        "obstacles": wall, "persons": [{"id": 1, "x": 3.0, "y": 7.0, "theta": 0.0}],
        "relations": [], "starts": [[2.0, 2.0], [8.0, 1.0]], "goal": [2.0, 8.5]})
    for p in plan(scene, SocialPlannerParams()):
        assert segments_feasible(scene, p.points[:-1], p.points[1:]).all()
        assert scene.obstacles.min_clearance_along(p.points) >= scene.robot_radius
        crossing = np.flatnonzero(np.diff(np.sign(p.points[:, 1] - 5.0)))[0]
        a, b = p.points[crossing], p.points[crossing + 1]
        x_at_wall = a[0] + (5.0 - a[1]) / (b[1] - a[1]) * (b[0] - a[0])
        assert 6.0 < x_at_wall < 7.2


@pytest.mark.parametrize("theta", [math.pi / 2, -math.pi / 2])
def test_passes_behind_a_person_rather_than_in_front(theta):
    scene = corridor(theta)
    (path,) = plan(scene, SocialPlannerParams())
    facing = math.sin(theta)  # +1: the person faces +y, so behind is y < 2
    offset = y_at(path.points, 5.0) - 2.0
    assert offset * facing < -0.5  # passed behind, well clear
    assert min_distance_to_person(path.points, scene.person_xy) > INTIMATE
    # the side follows the asymmetry: with the larger space behind, it passes in front
    (reversed_,) = plan(scene, SocialPlannerParams(sigma_front=0.5, sigma_back=1.2))
    assert (y_at(reversed_.points, 5.0) - 2.0) * facing > 0.5


def test_takes_a_detour_around_a_group_rather_than_through_its_o_space():
    scene = group_scene()
    centre, radius = groups(scene)
    assert np.allclose(centre, [GROUP_CENTRE]) and np.allclose(radius, [0.9])
    link_a, link_b = scene.links
    (path,) = plan(scene, SocialPlannerParams())
    assert relation_crossings(path.points, link_a, link_b) == 0
    assert min_distance_to_person(path.points, GROUP_CENTRE[None]) > 0.9
    # The scene lets a path through: with little regard for persons and none for the group
    # the planner walks through the o-space; the group term alone keeps it out.
    careless = SocialPlannerParams(amplitude_person=0.2, sigma_front=0.4)
    (through,) = plan(scene, dataclasses.replace(careless, amplitude_group=0.0))
    assert relation_crossings(through.points, link_a, link_b) > 0
    (around,) = plan(scene, careless)
    assert relation_crossings(around.points, link_a, link_b) == 0
    assert min_distance_to_person(around.points, GROUP_CENTRE[None]) > 0.9


def test_unreachable_start_is_refused_naming_it():
    ring = tuple(Person(k, 2 + 0.45 * math.cos(a), 2 + 0.45 * math.sin(a))
                 for k, a in enumerate(np.linspace(0, 2 * math.pi, 9)[:-1]))
    scene = Scene("ring", Room(0, 0, 6, 6), ring, (), np.array([[5.0, 5.0], [2.0, 2.0]]),
                  np.array([5.0, 1.0]))
    with pytest.raises(PipelineError, match=r"no path from start 1 \(2, 2\)"):
        plan(scene, SocialPlannerParams())


# -- the cost ------------------------------------------------------------------------------


def test_density_matches_the_formula_at_hand_computed_points():
    q = SocialPlannerParams(room_walls=False)
    scene = scene_from_dict({
        "name": "one", "room": {"x_min": 0, "y_min": 0, "x_max": 10, "y_max": 10},
        "persons": [{"id": 1, "x": 5, "y": 5, "theta": math.pi / 2}], "relations": [],
        "starts": [[1, 1]], "goal": [9, 9]})
    cost = SocialCost(scene, q)
    front, behind, side = [5.0, 6.0], [5.0, 4.0], [4.0, 5.0]  # 1 m in front, behind, right
    intimate = q.amplitude_intimate * math.exp(-1 / (2 * q.sigma_intimate ** 2))
    expected = [1 + q.amplitude_person * math.exp(-1 / (2 * q.sigma_front ** 2)) + intimate,
                1 + q.amplitude_person * math.exp(-1 / (2 * q.sigma_back ** 2)) + intimate,
                1 + q.amplitude_person * math.exp(-1 / (2 * q.sigma_side ** 2)) + intimate]
    assert np.allclose(cost.density(np.array([front, behind, side])), expected, rtol=1e-12)
    # far away only the 1 is left; the room border is a wall when room_walls is on
    assert cost.density(np.array([[0.0, 9.0]]))[0] == 1.0
    walled = SocialCost(scene, SocialPlannerParams())
    assert walled.density(np.array([[0.0, 9.0]]))[0] == pytest.approx(1 + q.amplitude_wall)


def test_group_o_spaces_of_metropolis(metropolis):
    centres, radii = groups(metropolis)
    xy = {p.id: np.array([p.x, p.y]) for p in metropolis.persons}
    expected = [[1, 2, 3, 4], [5, 6], [7, 8], [9, 10], [11, 12]]  # its relation components
    assert len(centres) == len(expected)
    for members in expected:
        pts = np.array([xy[i] for i in members])
        c = pts.mean(axis=0)
        k = int(np.argmin(np.linalg.norm(centres - c, axis=1)))
        assert np.allclose(centres[k], c)
        assert radii[k] == pytest.approx(np.linalg.norm(pts - c, axis=1).mean())


def test_segment_cost_is_the_integral_of_the_density(metropolis):
    cost = SocialCost(metropolis, SocialPlannerParams())
    a, b = np.array([0.5, 0.5]), np.array([5.5, 9.0])  # passes close to several persons
    length = float(np.linalg.norm(b - a))
    exact = quad(lambda t: cost.density((a + t * (b - a))[None])[0] * length, 0, 1,
                 limit=500, epsabs=1e-10)[0]
    assert cost.segments(a[None], b[None])[0] == pytest.approx(exact, rel=1e-3)


def test_cheapest_lattice_paths_match_an_independent_dijkstra(metropolis):
    params = SocialPlannerParams(spacing=0.2)
    graph = planner_graph(metropolis, params)
    costs = edge_costs(graph, SocialCost(metropolis, params))
    lengths = np.linalg.norm(graph.positions[graph.dst] - graph.positions[graph.src], axis=1)
    out: list[list[tuple[int, int]]] = [[] for _ in graph.positions]
    for e, (u, v) in enumerate(zip(graph.src, graph.dst, strict=True)):
        out[u].append((int(v), e))

    def dijkstra(source: int, weight: np.ndarray) -> tuple[float, list[int]]:
        """Forward Dijkstra from source to the goal (heapq): cost and edges."""
        best, via = {source: 0.0}, {}
        heap = [(0.0, source)]
        while heap:
            d, u = heapq.heappop(heap)
            if u == graph.goal_node:
                break
            if d > best[u]:
                continue
            for v, e in out[u]:
                if d + weight[e] < best.get(v, math.inf):
                    best[v], via[v] = d + weight[e], e
                    heapq.heappush(heap, (best[v], v))
        edges, node = [], graph.goal_node
        while node != source:
            edges.append(via[node])
            node = int(graph.src[via[node]])
        return best[graph.goal_node], edges[::-1]

    cost = SocialCost(metropolis, params)
    edge_of = {(int(u), int(v)): e for e, (u, v) in enumerate(zip(graph.src, graph.dst,
                                                                   strict=True))}
    for path in plan(metropolis, params, graph):
        s = int(graph.start_nodes[path.start_index])
        optimum, _ = dijkstra(s, costs)
        assert path.lattice_cost == pytest.approx(optimum, rel=1e-12)
        # its edges add up to that cost
        nodes = path.lattice_nodes
        steps = zip(nodes[:-1], nodes[1:], strict=True)
        assert sum(costs[edge_of[u, v]] for u, v in steps) == pytest.approx(optimum, rel=1e-12)
        # smoothing never raises the cost (up to the quadrature of merged collinear runs)
        assert path.cost <= path.lattice_cost * (1 + 1e-5)
        # no cheaper than the shortest lattice path, nor the straight line, under its cost
        _, shortest = dijkstra(s, lengths)
        assert path.cost <= costs[shortest].sum() * (1 + 1e-5)
        start, goal = metropolis.starts[path.start_index], metropolis.goal
        if segments_feasible(metropolis, start[None], goal[None])[0]:
            assert path.cost <= cost.polyline(np.array([start, goal])) * (1 + 1e-5)


def test_lattice_is_capped_for_large_rooms(metropolis):
    assert lattice_spacing(metropolis, SocialPlannerParams()) == 0.1
    big = dataclasses.replace(metropolis, room=Room(0, 0, 40, 40))
    assert lattice_spacing(big, SocialPlannerParams()) == pytest.approx(0.2)


def test_demonstrations_are_the_same_wherever_the_scene_lies(tmp_path, metropolis,
                                                              metropolis_subjects):
    """Five subjects on metropolis moved to UTM magnitudes give the same paths, moved: lattice
    points there carry 1e-9 m of rounding, which used to keep straight runs as turns and
    string-pull 6 of the 35 paths another way."""
    shift = np.array([500_000.0, 5_600_000.0])
    data = moved_scene(json.loads(METROPOLIS.read_text()), tuple(shift))
    moved = load_scene_file(write_json(tmp_path / "utm.json", data))
    there = planner_demos(moved, FeatureModel.from_scene(moved),
                          SocialPlannerParams(n_subjects=5), np.random.default_rng(0), 1.0)
    assert len(there) == len(metropolis_subjects) == 35
    for here, utm in zip(metropolis_subjects, there, strict=True):
        assert here.points.shape == utm.points.shape
        np.testing.assert_allclose(utm.points - shift, here.points, rtol=0, atol=1e-6)
        np.testing.assert_allclose(utm.edge_features, here.edge_features, rtol=0, atol=1e-6)


def test_straight_runs_with_rounding_are_not_turns():
    """A straight lattice run at UTM magnitudes, its points rounded there, keeps only its
    ends; a 1 mm kink is kept."""
    x = 500_000.0 + 0.1 * np.arange(6)
    run = np.column_stack([x, np.full(6, 5_600_000.0) + 1e-9 * np.array([0, 1, -1, 1, 0, 1])])
    points, _ = _drop_collinear(run, np.arange(6.0))
    assert np.array_equal(points, run[[0, -1]])
    run[3, 1] += 1e-3
    assert np.array_equal(_drop_collinear(run, np.arange(6.0))[0], run[[0, 2, 3, 4, 5]])


# -- subjects ------------------------------------------------------------------------------


def test_same_seed_gives_identical_demonstrations(metropolis):
    features = FeatureModel.from_scene(metropolis)
    params = SocialPlannerParams(n_subjects=2)
    a = planner_demos(metropolis, features, params, np.random.default_rng(7), 1.0)
    b = planner_demos(metropolis, features, params, np.random.default_rng(7), 1.0)
    assert len(a) == len(b) == 2 * len(metropolis.starts)
    for x, y in zip(a, b, strict=True):
        assert (x.subject, x.start_index) == (y.subject, y.start_index)
        assert np.array_equal(x.points, y.points)
        assert np.array_equal(x.edge_features, y.edge_features)
        assert np.array_equal(x.durations, y.durations)


def test_subjects_differ_unless_the_spread_is_zero(metropolis, metropolis_paths,
                                                   metropolis_subjects):
    n = len(metropolis.starts)
    assert [d.subject for d in metropolis_subjects] == [f"s{k}" for k in range(5) for _ in
                                                        range(n)]
    by_subject = [metropolis_subjects[k * n:(k + 1) * n] for k in range(5)]
    for k in range(1, 5):
        differs = [not np.array_equal(a.points, b.points)
                   for a, b in zip(by_subject[0], by_subject[k], strict=True)]
        assert any(differs)
    # spread 0: every subject walks like the configured one
    features = FeatureModel.from_scene(metropolis)
    same = planner_demos(metropolis, features, SocialPlannerParams(n_subjects=3,
                                                                   subject_spread=0.0),
                         np.random.default_rng(0), 1.0)
    for d in same:
        assert np.array_equal(d.points, metropolis_paths[d.start_index].points)


def test_one_subject_draws_nothing_and_subjects_keep_their_draws_as_n_grows():
    rng = np.random.default_rng(3)
    state = rng.bit_generator.state
    assert subjects(SocialPlannerParams(), rng) == [SocialPlannerParams()]
    assert rng.bit_generator.state == state
    three = subjects(SocialPlannerParams(n_subjects=3), np.random.default_rng(3))
    five = subjects(SocialPlannerParams(n_subjects=5), np.random.default_rng(3))
    assert [[getattr(s, f) for f in SUBJECT_FIELDS] for s in five[:3]] == \
        [[getattr(s, f) for f in SUBJECT_FIELDS] for s in three]
    for s in five:  # only the personal-space parameters vary, log-normally around the base
        base = SocialPlannerParams(n_subjects=5)
        for f in dataclasses.fields(SocialPlannerParams):
            ratio = getattr(s, f.name) / getattr(base, f.name) if f.name in SUBJECT_FIELDS \
                else None
            if ratio is None:  # all else as configured
                assert getattr(s, f.name) == getattr(base, f.name)
            else:
                assert ratio != 1.0 and abs(math.log(ratio)) < 5 * base.subject_spread


def test_demonstrations_carry_the_learners_features_and_durations(metropolis):
    features = FeatureModel.from_scene(metropolis)
    for d in planner_demos(metropolis, features, SocialPlannerParams(), None, speed=0.5):
        assert d.subject == "s0" and d.reached
        assert np.allclose(d.features, features.polyline(d.points))
        length = np.linalg.norm(np.diff(d.points, axis=0), axis=1)
        assert np.allclose(d.durations, length / 0.5)


def test_paths_are_not_the_optimum_of_the_learners_default_reward(metropolis, roadmap):
    """The planner is a demonstrator the learner cannot express exactly: under the polite
    preset on the learner's own features it is worse than the optimal expert from every
    start, and it passes people closer (no hinge at 1.2 m) where the polite expert keeps
    out of the personal zone."""
    features = FeatureModel.from_scene(metropolis)
    mdp = roadmap.mdp()
    solution = mdp.solve(POLITE)
    optimal = optimal_demos(mdp, roadmap.positions, roadmap.start_nodes, solution)
    demos = planner_demos(metropolis, features, SocialPlannerParams(), None, 1.0)
    gap, closer, far = [], [], []
    for o, d in zip(optimal, demos, strict=True):
        gap.append(solution.values[roadmap.start_nodes[d.start_index]]
                   - d.stats(mdp.params).quality(POLITE))
        closer.append(min_distance_to_person(o.points, metropolis.person_xy)
                      - min_distance_to_person(d.points, metropolis.person_xy))
        far.append(discrete_frechet(o.points, d.points))
    assert min(gap) > 0.05
    assert np.mean(closer) > 0.15
    assert np.median(far) > 0.5


def test_parameters_are_range_checked():
    for bad in [{"sigma_front": 0.0}, {"amplitude_person": -1.0}, {"connectivity": 12},
                {"n_subjects": 0}, {"subject_spread": -0.1}, {"smooth": "yes"},
                {"spacing": float("nan")}]:
        with pytest.raises(ParameterError, match=next(iter(bad))):
            SocialPlannerParams(**bad)


def test_a_spread_that_draws_out_of_range_subjects_is_named():
    """A log-normal spread of 20 draws personal spaces of kilometres: one line naming the
    setting and the subject, not the range check of a parameter nobody set."""
    with pytest.raises(PipelineError, match=r"expert\.subject_spread=20 drew subject s\d+'s "
                                            r"\w+=.*lower expert\.subject_spread"):
        subjects(SocialPlannerParams(n_subjects=3, subject_spread=20.0),
                 np.random.default_rng(0))
    assert len(subjects(SocialPlannerParams(n_subjects=3, subject_spread=1.0),
                        np.random.default_rng(0))) == 3


def test_groups_are_relation_components_of_two_members_or_more():
    """Persons 1 and 2 related, 2 m apart; person 3 alone: one o-space, centred between the
    pair, radius 1 m (the lone person is no group)."""
    scene = Scene("pair", Room(0.0, 0.0, 10.0, 10.0),
                  (Person(1, 1.0, 2.0), Person(2, 3.0, 2.0), Person(3, 7.0, 7.0)), ((1, 2),),
                  np.array([[0.5, 0.5]]), np.array([9.5, 9.5]))
    centres, radii = groups(scene)
    assert centres.tolist() == [[2.0, 2.0]] and radii.tolist() == [1.0]


def test_the_personal_space_reaches_five_sigma_front_ahead():
    """A person facing +x, room walls off: 3.5 to 5.5 m ahead (beyond five σ_side or σ_back,
    within five σ_front) the density is the formula's; 6.5 m ahead (beyond 5 σ_front = 6 m)
    the term is dropped and only the 1 is left."""
    q = SocialPlannerParams(room_walls=False)
    scene = Scene("ahead", Room(0.0, 0.0, 20.0, 10.0), (Person(1, 5.0, 5.0, 0.0),), (),
                  np.array([[0.5, 0.5]]), np.array([19.5, 9.5]))
    d = np.array([3.5, 4.5, 5.5])
    expected = 1 + q.amplitude_person * np.exp(-d ** 2 / (2 * q.sigma_front ** 2)) \
        + q.amplitude_intimate * np.exp(-d ** 2 / (2 * q.sigma_intimate ** 2))
    cost = SocialCost(scene, q)
    np.testing.assert_allclose(cost.density(np.c_[5.0 + d, np.full(3, 5.0)]), expected,
                               rtol=1e-12)
    assert cost.density(np.array([[11.5, 5.0]]))[0] == 1.0


def test_the_wall_cost_by_hand_from_the_room_border_and_from_obstacles():
    """c = 1 + A_w·exp(-clearance² / 2σ_w²): 0.3 m from the room's border (σ_w = 0.3 m)
    1 + e^-0.5. Obstacles count with room_walls off too: beside a box, its clearance."""
    q = SocialPlannerParams()
    room = Room(0.0, 0.0, 10.0, 10.0)
    empty = Scene("empty", room, (), (), np.array([[5.0, 5.0]]), np.array([9.0, 9.0]))
    assert SocialCost(empty, q).density(np.array([[0.3, 5.0]]))[0] == \
        pytest.approx(1 + math.exp(-0.5), rel=1e-12)
    box = np.array([[4.0, 4.0], [6.0, 4.0], [6.0, 6.0], [4.0, 6.0]])
    boxed = Scene("boxed", room, (), (), np.array([[1.0, 1.0]]), np.array([9.0, 9.0]),
                  polygons=(box,))
    no_room = SocialPlannerParams(room_walls=False)
    p = np.array([[3.8, 5.0], [2.0, 5.0]])
    clearance = boxed.obstacles.clearance_at(p)
    assert 0.1 < clearance[0] < 0.3
    np.testing.assert_allclose(SocialCost(boxed, no_room).density(p),
                               1 + np.exp(-0.5 * (clearance / 0.3) ** 2), rtol=1e-12)


def test_no_edge_leads_into_the_goal_through_an_obstacle():
    """A shelf (y 5.3..5.4) across the goal disk (1 m round the goal (5, 5)): lattice edges
    entering the disk above the shelf would lead to the goal through it; only those that
    reach the goal collision-free are kept."""
    shelf = np.array([[3.5, 5.3], [6.5, 5.3], [6.5, 5.4], [3.5, 5.4]])
    scene = Scene("shelf", Room(0.0, 0.0, 10.0, 10.0), (), (), np.array([[5.0, 1.0]]),
                  np.array([5.0, 5.0]), goal_tolerance=1.0, polygons=(shelf,))
    params = SocialPlannerParams(spacing=0.2, connectivity=8)
    graph = planner_graph(scene, params)
    into = graph.src[graph.dst == graph.goal_node]
    assert len(into) > 0
    assert (graph.positions[into, 1] < 5.0).any()
    assert segments_feasible(scene, graph.positions[into],
                             np.repeat(scene.goal[None], len(into), axis=0)).all()
    assert not (graph.positions[into, 1] > 5.4).any()


def test_an_edge_costs_the_same_bits_both_ways(metropolis):
    graph = planner_graph(metropolis, SocialPlannerParams())
    costs = edge_costs(graph, SocialCost(metropolis, SocialPlannerParams()))
    n = len(graph.positions)
    key = {(int(s), int(d)): c for s, d, c in zip(graph.src, graph.dst, costs, strict=True)}
    both = [(s, d) for s, d in key if s < d and (d, s) in key]
    assert len(both) > 1000 and n > 0
    assert all(key[s, d] == key[d, s] for s, d in both)


def test_a_u_turn_is_a_turn_and_a_straight_run_is_not():
    points = np.array([[0.0, 0.0], [1.0, 0.0], [0.5, 0.0], [0.5, 1.0], [0.5, 2.0]])
    kept, cumulative = _drop_collinear(points, np.arange(5.0))
    assert kept.tolist() == [[0.0, 0.0], [1.0, 0.0], [0.5, 0.0], [0.5, 2.0]]
    assert cumulative.tolist() == [0.0, 1.0, 2.0, 4.0]


def test_string_pulling_takes_a_shortcut_that_costs_exactly_the_path():
    """Density 1 (no persons, walls off) and integration steps of 0.25 m (exact in binary):
    the straight run (0, 0) → (2, 0) costs exactly what its two halves cost, so it is
    taken ("costs no more")."""
    room = Room(-5.0, -5.0, 5.0, 5.0)
    empty = Scene("empty", room, (), (), np.array([[0.0, 0.0]]), np.array([2.0, 0.0]))
    q = SocialPlannerParams(room_walls=False, resolution=0.25)
    cost = SocialCost(empty, q)
    points = np.array([[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    cumulative = np.array([0.0, 1.0, 2.0])
    assert cost.segments(points[:1], points[2:])[0] == 2.0
    assert cost.polyline(points) == 2.0
    assert _string_pull(empty, cost, points, cumulative).tolist() == [[0.0, 0.0], [2.0, 0.0]]


def test_planner_demos_report_progress_after_subjects():
    scene = Scene("small", Room(0.0, 0.0, 4.0, 4.0), (Person(1, 2.0, 2.0),), (),
                  np.array([[0.5, 0.5]]), np.array([3.5, 3.5]))
    calls = []
    demos = planner_demos(scene, FeatureModel.from_scene(scene),
                          SocialPlannerParams(n_subjects=3, spacing=0.2),
                          np.random.default_rng(0), 1.0, lambda done, n: calls.append((done, n)))
    assert len(demos) == 3 and calls
    assert all(1 <= done < 3 and n == 3 for done, n in calls)
    assert [done for done, _ in calls] == sorted({done for done, _ in calls})


def test_a_turn_is_measured_as_the_next_vertexs_distance_from_the_incoming_line():
    """Within TIE (1e-6 m) of the incoming line is no turn, whatever the incoming edge's
    length: 1e-7 m off after a 100 m edge is straight on; 5e-6 m off after a 1 cm edge
    turns."""
    long_in = np.array([[0.0, 0.0], [100.0, 0.0], [200.0, 1e-7]])
    assert _drop_collinear(long_in, np.arange(3.0))[0].tolist() == [[0.0, 0.0], [200.0, 1e-7]]
    short_in = np.array([[0.0, 0.0], [0.01, 0.0], [0.02, 5e-6]])
    assert len(_drop_collinear(short_in, np.arange(3.0))[0]) == 3


def test_the_planner_graph_records_the_spacing_it_used():
    """A 4 m x 4 m room capped at 100 lattice nodes: the spacing is raised to √(16/100) =
    0.4 m, and the graph says so (its error messages name it)."""
    scene = Scene("small", Room(0.0, 0.0, 4.0, 4.0), (), (), np.array([[0.5, 0.5]]),
                  np.array([3.5, 3.5]))
    params = SocialPlannerParams(spacing=0.1, max_lattice_nodes=100)
    graph = planner_graph(scene, params)
    assert graph.spacing == pytest.approx(0.4) == lattice_spacing(scene, params)
    lattice = graph.positions[:-2]  # less the start and the goal
    gaps = np.linalg.norm(lattice[:, None] - lattice[None], axis=2) + np.eye(len(lattice)) * 9
    assert gaps.min() == pytest.approx(0.4)
