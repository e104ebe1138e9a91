"""The seeded random scene generator (pipeline/core/scenegen.py): valid F-formation groups,
reproducible from the seed, and a clear error when no scene fits."""

import numpy as np
import pytest

from pipeline.core.obstacles import ObstacleMap, OccupancyGrid
from pipeline.core.scenegen import (
    RandomSceneSpec,
    all_starts_reach_goal,
    check_fits,
    most_points_apart,
    person_margin,
    random_scene,
)
from pipeline.core.world import Room, Scene, scene_from_dict
from pipeline.errors import PipelineError


@pytest.mark.parametrize("seed", range(4))
def test_random_scene_is_valid_and_seeded(seed):
    spec = RandomSceneSpec(n_groups=3, n_singles=3)
    scene = random_scene(spec, np.random.default_rng(seed))
    again = random_scene(spec, np.random.default_rng(seed))
    assert scene.to_dict() == again.to_dict()
    scene_from_dict(scene.to_dict())  # passes the same validation as a file
    assert all_starts_reach_goal(scene)
    assert len(scene.starts) == spec.n_starts
    # Groups: related persons are F-formation members facing the group's centre, and every
    # pair within a group is related.
    pos = {p.id: np.array([p.x, p.y]) for p in scene.persons}
    groups = {}  # keyed by each group's lowest id, which never appears second in a relation
    for a, b in scene.relations:
        if a not in {q for _, q in scene.relations}:
            groups.setdefault(a, {a}).add(b)
    for members in groups.values():
        centre = np.mean([pos[m] for m in members], axis=0)
        assert 2 <= len(members) <= 4
        n_links = len([r for r in scene.relations if r[0] in members])
        assert n_links == len(members) * (len(members) - 1) // 2
        for m in members:
            p = next(q for q in scene.persons if q.id == m)
            facing = np.array([np.cos(p.theta), np.sin(p.theta)])
            to_centre = (centre - pos[m]) / np.linalg.norm(centre - pos[m])
            assert facing @ to_centre > 0.999
    # Starts near one wall, goal near the opposite one.
    assert np.linalg.norm(scene.starts.mean(axis=0) - scene.goal) > 0.6 * 10


def test_random_scene_that_cannot_fit_fails_clearly():
    # 9 singles 0.7 m apart fit in the 1.5 m square left inside the walls (a 0.75 m grid),
    # but random draws rarely find it
    spec = RandomSceneSpec(width=3.0, height=3.0, n_singles=9, n_groups=0, max_tries=3)
    with pytest.raises(PipelineError, match="no valid scene in scene.max_tries=3"):
        random_scene(spec, np.random.default_rng(0))


def test_persons_that_can_never_fit_are_refused_before_drawing():
    # the 0.5 m square inside the walls holds at most 3 points 0.7 m apart (the bound's 3:
    # (0.5 + 0.7)² / (√3/2 · 0.7²) = 3.39)
    spec = RandomSceneSpec(width=2.0, height=2.0, n_singles=20, n_groups=0, max_tries=3)
    with pytest.raises(PipelineError, match="20 singles and groups do not fit .* at most 3 "):
        random_scene(spec, np.random.default_rng(0))


def test_groups_count_towards_what_can_fit_and_a_goal_disk_across_the_room_is_refused():
    """Each group keeps one member min_person_gap from the others, as a single does: 2
    singles and 2 groups are 4 where at most 3 fit. A goal disk as wide as the distance
    between the starts' wall and the goal's reaches the starts: refused, also at equality
    (the room's 4 m less twice the 0.3 m margin: 3.4 m)."""
    spec = RandomSceneSpec(width=2.0, height=2.0, n_singles=2, n_groups=2, max_tries=3)
    with pytest.raises(PipelineError, match="4 singles and groups do not fit .* at most 3 "):
        random_scene(spec, np.random.default_rng(0))
    spec = RandomSceneSpec(width=4.0, height=4.0, n_singles=0, n_groups=0, goal_tolerance=3.4)
    with pytest.raises(PipelineError, match="goal_tolerance=3.4 m reaches across"):
        random_scene(spec, np.random.default_rng(0))


def test_a_formation_radius_below_the_body_radius_is_refused():
    """Members of a pair closer than a body radius to their centre overlap bodies."""
    from pipeline.core.params import ParameterError

    with pytest.raises(ParameterError, match="formation_radius=0.2 is not allowed"):
        RandomSceneSpec(formation_radius=0.2, body_radius=0.25)
    assert RandomSceneSpec(formation_radius=0.25, body_radius=0.25).formation_radius == 0.25


def test_the_packing_bound_is_exact_on_a_unit_square_and_never_below_a_hexagonal_packing():
    assert most_points_apart(1.0, 1.0, 1.0) == 4  # the corners; a fifth point is < 1 apart
    for width, height, gap in [(10, 10, 0.7), (3, 17, 1.0), (0.0, 5.0, 0.5), (40, 2.5, 0.3)]:
        rows = np.arange(0.0, height + 1e-9, gap * np.sqrt(3) / 2)
        hexagonal = sum(len(np.arange(gap / 2 * (k % 2), width + 1e-9, gap))
                        for k in range(len(rows)))
        assert hexagonal <= most_points_apart(width, height, gap)


def test_a_random_scene_on_a_slam_map_lands_in_its_building():
    """A 60 m × 60 m SLAM map that is unknown but for a 12 m × 8 m room (2.7 % of it): draws
    over the whole extent would land in the room 2.7 % of the time and the scene fail; drawn
    within the free cells' bounds, persons, starts and goal all stand in the room."""
    occupied = np.ones((600, 600), dtype=bool)  # 0.1 m cells
    occupied[300:380, 200:320] = False  # the room: x 20..32 m, y 30..38 m
    grid = OccupancyGrid(occupied, (0.0, 0.0), 0.1)
    spec = RandomSceneSpec(n_groups=2, n_singles=2, n_starts=3)
    scene = random_scene(spec, np.random.default_rng(0), map_grid=grid, map_source="slam")
    points = np.vstack([[[p.x, p.y] for p in scene.persons], scene.starts, scene.goal[None]])
    assert ((points >= [20, 30]) & (points <= [32, 38])).all()
    assert len(scene.persons) >= 6 and len(scene.starts) == 3


@pytest.mark.parametrize("speck", [
    np.s_[100:104, 500:504],  # 0.4 m of free cells 20 m away (laser through a window)
    np.s_[50:110, 450:540],  # a 9 m × 6 m room no door leads to, smaller than the building
])
def test_a_random_scene_on_a_slam_map_ignores_free_space_outside_its_building(speck):
    """Free cells outside the building stretched the box the starts are drawn in, and its
    diagonal sets how far from the goal a start must be: every draw failed ("use fewer
    persons"). Positions are drawn in the largest free region."""
    occupied = np.ones((600, 600), dtype=bool)
    occupied[300:380, 200:320] = False  # the building: x 20..32 m, y 30..38 m
    occupied[speck] = False
    grid = OccupancyGrid(occupied, (0.0, 0.0), 0.1)
    spec = RandomSceneSpec(n_groups=2, n_singles=2, n_starts=3)
    scene = random_scene(spec, np.random.default_rng(0), map_grid=grid, map_source="slam")
    points = np.vstack([[[p.x, p.y] for p in scene.persons], scene.starts, scene.goal[None]])
    assert ((points >= [20, 30]) & (points <= [32, 38])).all()


def test_persons_on_a_map_stand_where_the_robot_can_go():
    """A 12 m x 8 m building with a locked 4 m x 3 m room in it (walls 0.3 m, no door):
    persons were drawn anywhere in the free region's bounding box, the locked room too (5 of
    12 in a user's run); they now stand only in the region the starts and goal are in."""
    occupied = np.ones((100, 140), dtype=bool)  # 0.1 m cells
    occupied[10:90, 10:130] = False  # the building: x 1..13 m, y 1..9 m
    occupied[50:83, 85:128] = True  # the locked room's walls: x 8.5..12.8 m, y 5..8.3 m
    occupied[53:80, 88:125] = False  # its floor: x 8.8..12.5 m, y 5.3..8 m
    grid = OccupancyGrid(occupied, (0.0, 0.0), 0.1)
    spec = RandomSceneSpec(n_groups=2, n_singles=6, n_starts=3)
    locked = 0
    for seed in range(6):
        scene = random_scene(spec, np.random.default_rng(seed), map_grid=grid, map_source="m")
        xy = np.array([[p.x, p.y] for p in scene.persons])
        inside = (xy[:, 0] > 8.5) & (xy[:, 0] < 12.8) & (xy[:, 1] > 5.0) & (xy[:, 1] < 8.3)
        locked += int(inside.sum())
        assert len(xy) >= 8
    assert locked == 0


def test_the_largest_free_region_by_hand():
    from pipeline.core.obstacles import ObstacleMap
    occupied = np.ones((6, 8), dtype=bool)
    occupied[1:3, 1:4] = False  # 6 cells
    occupied[3, 4] = False  # touches the first by a corner: 8-connected, 7 cells in all
    occupied[4:5, 6:8] = False  # 2 cells apart
    region = ObstacleMap(OccupancyGrid(occupied, (0.0, 0.0), 1.0)).largest_free_region()
    expected = np.zeros_like(occupied)
    expected[1:3, 1:4] = expected[3, 4] = True
    assert (region == expected).all()


def test_starts_spread_along_one_wall_and_the_goal_at_the_opposite_one():
    """In a 12 x 8 m room (not square: x and y cannot be swapped unseen), every start is
    border_margin from one wall, one per equal bin along it, and the goal border_margin from
    the opposite wall, within the middle 40 % of it; over eight seeds the walls differ
    (starts along the long walls and along the short ones)."""
    spec = RandomSceneSpec(width=12.0, height=8.0, n_singles=0, n_groups=0, n_starts=4)
    m, shared = spec.border_margin, set()
    for seed in range(8):
        scene = random_scene(spec, np.random.default_rng(seed))
        across = 1 if np.ptp(scene.starts[:, 1]) == 0 else 0  # the coordinate they share
        shared.add(across)
        assert np.ptp(scene.starts[:, across]) == 0
        side = (spec.width, spec.height)[across]
        along_len = (spec.width, spec.height)[1 - across]
        assert scene.starts[0, across] in (m, side - m)
        assert scene.starts[0, across] + scene.goal[across] == pytest.approx(side)
        bins = np.linspace(m, along_len - m, spec.n_starts + 1)
        assert ((scene.starts[:, 1 - across] >= bins[:-1])
                & (scene.starts[:, 1 - across] <= bins[1:])).all()
        assert 0.3 * along_len <= scene.goal[1 - across] <= 0.7 * along_len
    assert shared == {0, 1}


def test_a_start_walled_off_from_the_goal_fails_the_reachability_check():
    """Start 0 or start 1 walled into the room's corner (two walls meeting), the other free:
    not every start reaches the goal, whichever start it is (a scene file with it is
    refused; here the check is called on a Scene made directly)."""
    corner = (np.array([[0.0, 2.0], [2.6, 2.0], [2.6, 2.3], [0.0, 2.3]]),
              np.array([[2.3, 0.0], [2.6, 0.0], [2.6, 2.3], [2.3, 2.3]]))
    room, goal = Room(0.0, 0.0, 10.0, 10.0), np.array([6.0, 9.0])
    for starts in ([[1.0, 1.0], [6.0, 1.0]], [[6.0, 1.0], [1.0, 1.0]]):
        walled = Scene("corner", room, (), (), np.array(starts), goal, polygons=corner)
        assert not all_starts_reach_goal(walled), starts
        assert all_starts_reach_goal(Scene("free", room, (), (), np.array(starts), goal))


def test_spec_bounds_on_group_sizes_and_the_rooms_size():
    """Groups have two members or more; a room must be wider and higher than twice the
    walls' margin, max(border_margin, 0.5 m + body_radius) = 0.75 m: 1.5 m is refused (at
    equality too), 1.51 m is not."""
    from pipeline.core.params import ParameterError

    with pytest.raises(ParameterError, match="group_size_min"):
        RandomSceneSpec(group_size_min=1)
    for width, height in [(1.5, 10.0), (10.0, 1.5), (1.0, 10.0)]:
        with pytest.raises(ParameterError, match="width and height above 1.5 m"):
            RandomSceneSpec(width=width, height=height)
    assert RandomSceneSpec(width=1.51, height=1.51).width == 1.51


def test_what_fits_is_refused_above_the_bound_and_allowed_at_it():
    """check_fits by hand. A 10 x 2 m room: persons keep 0.75 m from the walls, an 8.5 x
    0.5 m box, (8.5 + 0.7)(0.5 + 0.7) / (√3/2 · 0.7²) = 26.02: 26 singles and groups pass,
    27 do not (a bound from 8.5 x 8.5 would pass 199). A 2 x 2 m room with a 0.25 m border
    margin: starts along 1.5 m, one per 0.2 m: 7 pass, 8 do not. A 1.6 m room with a
    0.75 m margin leaves 0.1 m: still one start."""
    room = Room(0.0, 0.0, 10.0, 2.0)
    check_fits(RandomSceneSpec(width=10.0, height=2.0, n_singles=20, n_groups=6), room, False)
    with pytest.raises(PipelineError, match="27 singles and groups .* at most 26 singles"):
        check_fits(RandomSceneSpec(width=10.0, height=2.0, n_singles=21, n_groups=6), room,
                   False)
    square = Room(0.0, 0.0, 2.0, 2.0)
    check_fits(RandomSceneSpec(width=2.0, height=2.0, n_singles=3, n_groups=0, n_starts=7,
                               border_margin=0.25), square, False)
    with pytest.raises(PipelineError, match="8 starts do not fit .* at most 7;"):
        check_fits(RandomSceneSpec(width=2.0, height=2.0, n_singles=0, n_groups=0, n_starts=8,
                                   border_margin=0.25), square, False)
    narrow = RandomSceneSpec(width=1.6, height=1.6, n_singles=0, n_groups=0, n_starts=1,
                             border_margin=0.75, goal_tolerance=0.05)
    check_fits(narrow, Room(0.0, 0.0, 1.6, 1.6), False)
    # on a 20 x 2 m map starts keep 1 m apart: (20 + 1)(2 + 1) / (√3/2) = 72.7, so 72
    spec = RandomSceneSpec(n_singles=0, n_groups=0, n_starts=72)
    check_fits(spec, Room(0.0, 0.0, 20.0, 2.0), True)
    with pytest.raises(PipelineError, match="73 starts do not fit .* at most 72;"):
        check_fits(RandomSceneSpec(n_singles=0, n_groups=0, n_starts=73),
                   Room(0.0, 0.0, 20.0, 2.0), True)


@pytest.mark.parametrize("seed", range(3))
def test_persons_stand_inside_the_walls_margin_and_pairs_face_each_other(seed):
    """Every person, group members included, at least person_margin (0.75 m) from the
    walls; groups of exactly two (group_size_min = group_size_max = 2) stand on opposite
    sides of their centre, about 2 · formation_radius apart (each member's angle jitters by
    0.15 rad: their distance is 1.4 m · cos(δ/2), above 1.2 m for |δ| up to 1.1 rad, five
    standard deviations); each pair is related once, lower id first."""
    spec = RandomSceneSpec(width=6.0, height=6.0, n_singles=1, n_groups=5, group_size_min=2,
                           group_size_max=2)
    scene = random_scene(spec, np.random.default_rng(seed))
    m = person_margin(spec)
    xy = scene.person_xy
    assert ((xy >= m - 1e-9) & (xy <= 6.0 - m + 1e-9)).all()
    assert len(scene.persons) == 11 and len(scene.relations) == 5
    assert len(set(scene.relations)) == 5 and all(a < b for a, b in scene.relations)
    pos = {p.id: np.array([p.x, p.y]) for p in scene.persons}
    for a, b in scene.relations:
        assert np.linalg.norm(pos[a] - pos[b]) > 1.2


def test_groups_of_the_largest_size_are_drawn():
    spec = RandomSceneSpec(width=8.0, height=8.0, n_singles=0, n_groups=2, group_size_min=4,
                           group_size_max=4)
    scene = random_scene(spec, np.random.default_rng(0))
    assert len(scene.persons) == 8 and len(scene.relations) == 2 * 6


def test_persons_on_a_map_keep_person_margin_from_its_walls():
    """On a map persons stand clear of obstacles by person_margin (0.75 m), not merely by
    robot_radius: the building's walls are inside the box they are drawn in."""
    occupied = np.ones((200, 200), dtype=bool)  # 0.1 m cells
    occupied[50:130, 40:160] = False  # a 12 m x 8 m room
    grid = OccupancyGrid(occupied, (0.0, 0.0), 0.1)
    spec = RandomSceneSpec(n_groups=2, n_singles=4, n_starts=2)
    for seed in range(3):
        scene = random_scene(spec, np.random.default_rng(seed), map_grid=grid, map_source="m")
        clearance = scene.obstacles.clearance_at(scene.person_xy)
        assert (clearance >= person_margin(spec)).all(), clearance.min()


@pytest.mark.parametrize(("goal_tolerance", "n_starts"), [(0.3, 5), (5.5, 3)])
def test_starts_on_a_map_keep_away_from_the_goal_and_from_each_other(goal_tolerance, n_starts):
    """On a map the starts lie at least a third of the draw box's diagonal (here the 12 m x
    8 m building less robot_radius at each wall: about 4.7 m) from the goal and outside its
    goal disk (a 5.5 m tolerance reaches farther than that third), and MAP_START_GAP (1 m)
    from each other."""
    from pipeline.core.scenegen import MAP_START_GAP

    occupied = np.ones((200, 200), dtype=bool)  # 0.1 m cells
    occupied[50:130, 40:160] = False  # x 4..16 m, y 5..13 m
    grid = OccupancyGrid(occupied, (0.0, 0.0), 0.1)
    spec = RandomSceneSpec(n_groups=0, n_singles=1, n_starts=n_starts,
                           goal_tolerance=goal_tolerance)
    obstacles = ObstacleMap(grid)
    x0, y0, x1, y1 = obstacles.free_bounds(obstacles.largest_free_region(spec.robot_radius))
    inset = spec.robot_radius  # the box: where the robot can stand, to within a cell
    np.testing.assert_allclose([x0, y0, x1, y1], [4 + inset, 5 + inset, 16 - inset, 13 - inset],
                               atol=0.1 + 1e-9)
    third = np.hypot(x1 - x0, y1 - y0) / 3
    for seed in range(3):
        scene = random_scene(spec, np.random.default_rng(seed), map_grid=grid, map_source="m")
        to_goal = np.linalg.norm(scene.starts - scene.goal, axis=1)
        assert (to_goal >= third).all() and (to_goal > goal_tolerance).all()
        apart = np.linalg.norm(scene.starts[:, None] - scene.starts[None], axis=2)
        assert (apart + np.eye(n_starts) * 1e9 >= MAP_START_GAP).all()


def test_a_map_too_small_or_without_free_space_is_refused():
    """A map 1.5 m high, exactly twice person_margin: refused (at equality too); a 3 m map
    with every cell occupied has no free cell for the robot."""
    thin = OccupancyGrid(np.zeros((15, 100), dtype=bool), (0.0, 0.0), 0.1)
    with pytest.raises(PipelineError, match="both sides must be longer than 1.5 m"):
        random_scene(RandomSceneSpec(), np.random.default_rng(0), map_grid=thin,
                     map_source="thin")
    full = OccupancyGrid(np.ones((30, 30), dtype=bool), (0.0, 0.0), 0.1)
    with pytest.raises(PipelineError, match="has no free cell"):
        random_scene(RandomSceneSpec(), np.random.default_rng(0), map_grid=full,
                     map_source="full")


def test_on_a_map_a_goal_disk_may_reach_across_the_room():
    """The opposite-walls rule of a plain room does not apply on a map: a 3.5 m goal disk
    in a 4 m x 4 m map is fine, the start drawn beyond it (towards a far corner)."""
    grid = OccupancyGrid(np.zeros((40, 40), dtype=bool), (0.0, 0.0), 0.1)
    spec = RandomSceneSpec(n_singles=0, n_groups=0, n_starts=1, goal_tolerance=3.5)
    scene = random_scene(spec, np.random.default_rng(0), map_grid=grid, map_source="m")
    assert np.linalg.norm(scene.starts[0] - scene.goal) > 3.5


@pytest.mark.parametrize("seed", range(3))
def test_starts_and_goal_keep_a_tenth_of_a_metre_more_than_a_body_from_persons(seed):
    """With a border margin of 0.7 m starts and goal may stand next to persons (who keep
    0.75 m from the walls): they are kept body_radius + 0.1 m from each of them."""
    spec = RandomSceneSpec(width=5.0, height=5.0, n_singles=8, n_groups=0, border_margin=0.7)
    scene = random_scene(spec, np.random.default_rng(seed))
    ends = np.vstack([scene.starts, scene.goal[None]])
    gap = np.linalg.norm(ends[:, None] - scene.person_xy[None], axis=2)
    assert gap.min() >= spec.body_radius + 0.1 - 1e-6


def test_random_scene_returns_only_scenes_its_accept_test_passes():
    spec = RandomSceneSpec(n_singles=1, n_groups=1)
    for seed in range(3):
        scene = random_scene(spec, np.random.default_rng(seed),
                             accept=lambda s: s.goal[1] > 9.0)  # the goal at the top wall
        assert scene.goal[1] == pytest.approx(10.0 - spec.border_margin)
    with pytest.raises(PipelineError, match="no valid scene in scene.max_tries=5"):
        random_scene(RandomSceneSpec(max_tries=5), np.random.default_rng(0),
                     accept=lambda s: False)
