"""The scenes shipped in data/scenes: each loads and validates with the project's loader, and
the warehouse keeps what it promises (size, people in groups, far starts, reachable goal)."""

import json
import math

import numpy as np
import pytest
import yaml
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from pipeline.core.obstacles import ObstacleMap
from pipeline.inputs.scene_file import load_scene_file
from pipeline.tools.make_maps import raster_path_lengths
from tests.conftest import ROOT

SCENES = ROOT / "data" / "scenes"
SHIPPED = sorted(SCENES.glob("*.json"))


@pytest.fixture(scope="module")
def warehouse():
    return load_scene_file(SCENES / "warehouse.json")


def test_the_three_scenes_are_shipped():
    assert {p.stem for p in SHIPPED} >= {"metropolis", "office", "warehouse"}


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.stem)
def test_a_shipped_scene_loads_validates_and_reaches_the_goal(path):
    scene = load_scene_file(path)  # placement and reachability are checked while loading
    assert scene.name == path.stem
    assert scene.free(scene.starts).all() and scene.free(scene.goal[None, :]).all()
    assert scene.unreachable_starts() == []


def test_the_warehouse_map_is_30_by_50_m_at_5_cm_like_the_office():
    maps = ROOT / "data" / "maps"
    office, warehouse = (yaml.safe_load((maps / f"{n}.yaml").read_text())
                         for n in ("office", "warehouse"))
    assert warehouse.pop("image") == "warehouse.pgm" and office.pop("image") == "office.pgm"
    assert warehouse == office  # resolution 0.05, origin 0, negate 0, thresholds, trinary
    assert warehouse["mode"] == "trinary" and warehouse["negate"] == 0
    grid = load_scene_file(SCENES / "warehouse.json").map_grid
    assert grid.shape == (1000, 600) and grid.extent() == pytest.approx((0, 0, 30, 50))


def test_the_warehouse_free_area_is_a_few_hundred_to_1000_m2(warehouse):
    free_cells = (~warehouse.map_grid.occupied).sum() * warehouse.map_grid.resolution ** 2
    assert 300 <= free_cells <= 1000
    robot_free = warehouse.obstacles.free_mask(warehouse.robot_radius).sum() \
        * warehouse.map_grid.resolution ** 2
    assert 300 <= robot_free < free_cells


def test_the_warehouse_has_20_people_in_3_or_more_f_formations(warehouse):
    assert len(warehouse.persons) >= 20
    ids = [p.id for p in warehouse.persons]
    index = {pid: k for k, pid in enumerate(ids)}
    a = [index[i] for i, _ in warehouse.relations]
    b = [index[j] for _, j in warehouse.relations]
    _, label = connected_components(coo_matrix((np.ones(len(a)), (a, b)),
                                               shape=(len(ids), len(ids))), directed=False)
    groups = [np.flatnonzero(label == g) for g in np.unique(label)]
    groups = [g for g in groups if len(g) >= 2]
    assert len(groups) >= 3
    related = {frozenset(r) for r in warehouse.relations}
    for g in groups:
        members = [warehouse.persons[k] for k in g]
        xy = np.array([[p.x, p.y] for p in members])
        centre = xy.mean(axis=0)
        radii = np.linalg.norm(xy - centre, axis=1)
        assert np.ptp(radii) < 0.01  # on a circle (coordinates rounded to 1 mm)
        for p in members:  # each member faces the circle's centre
            towards = math.atan2(centre[1] - p.y, centre[0] - p.x)
            assert abs(math.remainder(p.theta - towards, 2 * math.pi)) < 0.01
        # related pairwise
        assert all(frozenset((p.id, q.id)) in related
                   for i, p in enumerate(members) for q in members[i + 1:])


def test_the_warehouse_starts_are_far_from_the_goal_and_connected(warehouse):
    assert len(warehouse.starts) == 5
    assert (np.linalg.norm(warehouse.starts - warehouse.goal, axis=1) >= 25).all()
    assert warehouse.unreachable_starts() == []
    lengths = raster_path_lengths(warehouse)  # around obstacles and body disks
    assert ((lengths >= 30) & (lengths <= 60)).all(), lengths


def test_the_warehouse_goal_is_behind_doors(warehouse):
    # the doors are at most 1.2 m wide: a robot of 1.3 m cannot leave its start's area
    obstacles = warehouse.obstacles
    assert isinstance(obstacles, ObstacleMap)
    assert not obstacles.reachable(warehouse.goal, warehouse.starts, 0.65).any()
    assert obstacles.reachable(warehouse.goal, warehouse.starts, warehouse.robot_radius).all()


def test_the_warehouse_scene_file_names_its_map_relative_to_itself():
    data = json.loads((SCENES / "warehouse.json").read_text())
    assert data["map"] == "../maps/warehouse.yaml" and "room" not in data
