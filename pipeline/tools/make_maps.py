"""Generate the shipped maps and their scenes: data/maps/NAME.{pgm,yaml}, data/scenes/NAME.json.

    python -m pipeline.tools.make_maps office              # or: warehouse, all
    python -m pipeline.tools.make_maps all --out DIR       # into DIR/maps and DIR/scenes

Deterministic (no randomness): the same command writes the same bytes. Each map is a ROS
map_server map (trinary, negate 0, 0.05 m/cell) drawn from axis-aligned boxes: 0.15 m walls
(the outer wall centred 0.5 m inside the map edge, unknown grey outside it), door openings
cut through them, furniture and shelving as occupied boxes. Each scene puts social groups in
F-formations (members evenly on a circle, facing its centre, related pairwise) and a few
singles on the map. Before anything is replaced, the files are written to a temporary
directory and checked: the scene loads with the project's loader (placement, goal reachable
from every start), starts, goal and persons have clearance >= 0.3 m, and every start reaches
the goal around the persons' body disks grown by the robot radius.

office: 20 m × 14 m (400 × 280 pixels): a 2.4 m corridor along the middle (y 5.8..8.2),
three rooms on each side, 1 m doors into the corridor, one door between the two south-east
rooms, desks and tables. Four groups in the corridor and rooms, three singles; starts in five
rooms, the goal in the sixth.

warehouse: 30 m × 50 m (600 × 1000 pixels), about 1000 m² of free cells (810 m² where the
robot fits). An office block along the south wall (four rooms off a 2.35 m office corridor,
1 m doors) opens through two 1.2 m doors onto the warehouse floor: a 4 m main corridor
running north, racks up to 2.6 m deep (west: rows running east-west, aisles 2.4 m ending at
the west wall; east: three columns running north-south, aisles 2.6 and 2.4 m between them
and 1.5 m along the east wall), a cross aisle halfway, a packing area along the north wall
and a supervisor's room in the north-west corner. Seven groups and six singles (pickers in
the aisles, one walking in the main corridor); five starts in the north half, the goal in
the meeting room; raster paths of 30-60 m (checked here).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image
from scipy import sparse
from scipy.sparse import csgraph

from pipeline.app.context import PACKAGE_ROOT
from pipeline.core.world import Scene
from pipeline.errors import PipelineError, report
from pipeline.inputs.scene_file import load_scene_file
from pipeline.tools import check_out_places, run_tool

RES = 0.05
WALL = 0.15
FREE, OCCUPIED, UNKNOWN = 254, 0, 205  # map_saver's grey values
CLEARANCE = 0.3  # m, the least clearance of starts, goal and persons from obstacles

Box = tuple[float, float, float, float]  # (x0, y0, x1, y1)
Group = tuple[list[int], tuple[float, float], float, float]  # ids, centre, radius, first angle


@dataclass(frozen=True)
class FloorPlan:
    """A map drawn from boxes and the scene on it."""

    name: str
    width: float  # m
    height: float
    walls: list[Box]  # centre lines, drawn WALL thick
    doors: dict[str, Box]  # openings cut through the walls (on a wall's centre line)
    furniture: list[Box]
    groups: list[Group]
    singles: list[dict[str, float]]
    starts: list[list[float]]
    goal: list[float]
    robot_radius: float
    path_range: tuple[float, float] | None = None  # (min, max) m of every start's raster path
    outline: Box = field(init=False)  # the outer walls' centre lines: free inside

    def __post_init__(self) -> None:
        object.__setattr__(self, "outline", (0.5, 0.5, self.width - 0.5, self.height - 0.5))


def draw_map(plan: FloorPlan) -> np.ndarray:
    """(H, W) uint8 grey image in map orientation (row 0 = lowest y)."""
    h, w = round(plan.height / RES), round(plan.width / RES)
    xs = (np.arange(w) + 0.5) * RES
    ys = (np.arange(h) + 0.5) * RES
    grid = np.full((h, w), UNKNOWN, dtype=np.uint8)

    def box(x0: float, y0: float, x1: float, y1: float, value: int) -> None:
        cols = (xs >= min(x0, x1)) & (xs <= max(x0, x1))
        rows = (ys >= min(y0, y1)) & (ys <= max(y0, y1))
        grid[np.ix_(rows, cols)] = value

    box(*plan.outline, FREE)
    half = WALL / 2
    for x0, y0, x1, y1 in plan.walls:
        box(x0 - half, y0 - half, x1 + half, y1 + half, OCCUPIED)
    for x0, y0, x1, y1 in plan.doors.values():
        box(x0 - half * (x0 == x1), y0 - half * (y0 == y1),
            x1 + half * (x0 == x1), y1 + half * (y0 == y1), FREE)
    for rect in plan.furniture:
        box(*rect, OCCUPIED)
    return grid


def map_yaml(name: str) -> str:
    return (f"image: {name}.pgm\nresolution: {RES}\norigin: [0.0, 0.0, 0.0]\nnegate: 0\n"
            "occupied_thresh: 0.65\nfree_thresh: 0.196\nmode: trinary\n")


def f_formation(ids: list[int], centre: tuple[float, float], radius: float,
                first_angle: float) -> list[dict[str, float]]:
    """Persons evenly on a circle around `centre`, each facing it."""
    persons = []
    for k, pid in enumerate(ids):
        a = first_angle + 2 * math.pi * k / len(ids)
        x, y = centre[0] + radius * math.cos(a), centre[1] + radius * math.sin(a)
        persons.append({"id": pid, "x": round(x, 3), "y": round(y, 3),
                        "theta": round(math.atan2(centre[1] - y, centre[0] - x), 6)})
    return persons


def scene_dict(plan: FloorPlan) -> dict[str, Any]:
    persons: list[dict[str, float]] = []
    relations: list[list[int]] = []
    for ids, centre, radius, angle in plan.groups:
        persons += f_formation(ids, centre, radius, angle)
        relations += [[a, b] for i, a in enumerate(ids) for b in ids[i + 1:]]
    return {"name": plan.name, "map": f"../maps/{plan.name}.yaml",
            "robot_radius": plan.robot_radius, "persons": persons + plan.singles,
            "relations": relations, "starts": plan.starts, "goal": plan.goal}


def raster_path_lengths(scene: Scene) -> np.ndarray:
    """(n_starts,) m: the shortest 8-connected path from each start to the goal through cells
    with clearance >= robot_radius outside the body disks (inf where none); up to ~8 % longer
    than the true shortest path (the 8 directions)."""
    obstacles = scene.obstacles
    assert obstacles is not None, "a scene on a map"
    free = obstacles.free_mask(scene.robot_radius,
                               obstacles.blocked_disks(scene.person_xy, scene.body_radius))
    h, w = free.shape
    index = np.arange(h * w).reshape(h, w)
    padded_free = np.pad(free, 1, constant_values=False)  # no neighbours beyond the edge
    padded_index = np.pad(index, 1)
    src, dst, cost = [], [], []
    for dr, dc in [(0, 1), (1, 0), (1, 1), (1, -1)]:  # each undirected neighbour pair once
        both = free & padded_free[1 + dr:h + 1 + dr, 1 + dc:w + 1 + dc]
        src.append(index[both])
        dst.append(padded_index[1 + dr:h + 1 + dr, 1 + dc:w + 1 + dc][both])
        cost.append(np.full(int(both.sum()), math.hypot(dr, dc) * obstacles.resolution))
    graph = sparse.coo_matrix((np.concatenate(cost), (np.concatenate(src), np.concatenate(dst))),
                              shape=(h * w, h * w)).tocsr()
    rows, cols, _ = obstacles.grid.cell_of(np.vstack([scene.goal, scene.starts]))
    dist = csgraph.dijkstra(graph, directed=False, indices=int(index[rows[0], cols[0]]))
    return np.asarray(dist[index[rows[1:], cols[1:]]])


def check(plan: FloorPlan, scene_path: Path) -> Scene:
    """The written scene loads and validates, and the plan keeps its promises (see the module
    docstring); raises RuntimeError naming what failed."""
    scene = load_scene_file(scene_path)
    obstacles = scene.obstacles
    assert obstacles is not None, "a scene on a map"
    points = np.vstack([scene.starts, scene.goal[None, :]])
    for what, xy in [("start/goal", points), ("person", scene.person_xy)]:
        clearance = obstacles.clearance_at(xy)
        if (clearance < CLEARANCE).any():
            k = int(np.argmin(clearance))
            raise RuntimeError(f"{plan.name}: {what} {k} at {xy[k].tolist()} has clearance "
                               f"{clearance[k]:.2f} m < {CLEARANCE} m")
    blocked = obstacles.blocked_disks(scene.person_xy, scene.body_radius + scene.robot_radius)
    rows, cols, _ = obstacles.grid.cell_of(points)
    reached = ~blocked[rows, cols] & obstacles.reachable(scene.goal, points, scene.robot_radius,
                                                         blocked)
    if not reached.all():
        raise RuntimeError(f"{plan.name}: start/goal {np.flatnonzero(~reached).tolist()} cut "
                           "off by the persons' disks grown by the robot radius")
    if plan.path_range is not None:
        lengths = raster_path_lengths(scene)
        lo, hi = plan.path_range
        if not ((lengths >= lo) & (lengths <= hi)).all():
            raise RuntimeError(f"{plan.name}: raster paths {np.round(lengths, 1).tolist()} m, "
                               f"not all within {lo:g}-{hi:g} m")
    return scene


def write(plan: FloorPlan, root: Path) -> list[Path]:
    """Write maps/NAME.pgm, maps/NAME.yaml and scenes/NAME.json under root, checked first in
    a temporary directory so that a failing plan replaces nothing."""
    names = [Path("maps") / f"{plan.name}.pgm", Path("maps") / f"{plan.name}.yaml",
             Path("scenes") / f"{plan.name}.json"]
    # every place checked before anything is written: a failed rename half-way left a
    # map without its scene
    check_out_places(root, names, "the map tool")
    root.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=root, prefix=f".{plan.name}-") as tmp:
        stage = Path(tmp)
        (stage / "maps").mkdir()
        (stage / "scenes").mkdir()
        Image.fromarray(draw_map(plan)[::-1]).save(stage / names[0])  # top row first
        (stage / names[1]).write_text(map_yaml(plan.name))
        (stage / names[2]).write_text(json.dumps(scene_dict(plan), indent=1) + "\n")
        check(plan, stage / names[2])
        for name in names:
            (root / name.parent).mkdir(exist_ok=True)
            os.replace(stage / name, root / name)
    return [root / name for name in names]


OFFICE = FloorPlan(
    name="office", width=20.0, height=14.0, robot_radius=0.2,
    walls=[
        (0.5, 0.5, 19.5, 0.5), (0.5, 13.5, 19.5, 13.5),  # outer: south, north
        (0.5, 0.5, 0.5, 13.5), (19.5, 0.5, 19.5, 13.5),  # outer: west, east
        (0.5, 5.8, 19.5, 5.8), (0.5, 8.2, 19.5, 8.2),  # corridor
        (6.5, 0.5, 6.5, 5.8), (13.0, 0.5, 13.0, 5.8),  # south room dividers
        (7.5, 8.2, 7.5, 13.5), (13.5, 8.2, 13.5, 13.5),  # north room dividers
    ],
    doors={
        "S1": (4.8, 5.8, 5.8, 5.8), "S2": (7.3, 5.8, 8.3, 5.8), "S3": (17.3, 5.8, 18.3, 5.8),
        "N1": (2.0, 8.2, 3.0, 8.2), "N2": (12.0, 8.2, 13.0, 8.2), "N3": (14.3, 8.2, 15.3, 8.2),
        "S2-S3": (13.0, 1.5, 13.0, 2.5),
    },
    furniture=[
        (1.2, 1.2, 2.8, 2.0), (1.2, 3.4, 2.8, 4.2), (5.7, 0.8, 6.3, 2.2),  # S1: desks, cabinet
        (8.6, 2.2, 11.0, 3.4),  # S2: meeting table
        (15.0, 1.0, 16.6, 1.8), (17.5, 1.0, 19.1, 1.8),  # S3: desks
        (1.0, 11.8, 2.6, 12.6), (4.5, 11.8, 6.1, 12.6),  # N1: desks
        (11.8, 12.3, 13.2, 13.1),  # N2: desk
        (16.0, 10.2, 17.6, 11.0),  # N3: table
    ],
    groups=[
        ([1, 2], (10.1, 7.55), 0.5, math.pi),  # corridor: a pair by the north wall
        ([3, 4, 5], (16.3, 7.0), 0.55, math.pi / 2),  # corridor: a trio between N3 and S3 doors
        ([6, 7, 8, 9], (10.5, 10.8), 0.7, math.pi / 4),  # room N2: four people talking
        ([10, 11], (8.5, 4.4), 0.5, math.pi),  # room S2: a pair between table and door
    ],
    singles=[
        {"id": 12, "x": 5.0, "y": 6.6, "theta": 0.0, "vx": 0.8, "vy": 0.0},  # walking, corridor
        {"id": 13, "x": 16.5, "y": 3.2, "theta": round(math.pi / 2, 6)},  # room S3
        {"id": 14, "x": 6.0, "y": 10.0, "theta": round(math.pi, 6)},  # room N1
    ],
    starts=[[2.0, 2.7], [10.5, 1.3], [16.0, 4.3], [4.0, 10.5], [8.5, 12.6]],  # S1 S2 S3 N1 N2
    goal=[18.0, 12.2],  # room N3
)


# The warehouse, south to north (y): office block 0.5..9.0 (rooms 0.5..6.5, office corridor
# 6.5..9.0), front aisle 9.0..12.0, south rack bank 12.0..24.6, cross aisle ..28.0, north rack
# bank 28.0..40.6, packing area ..49.5 (the supervisor's room in its west corner). West to
# east (x): west racks 0.5..12.5, main corridor 12.5..16.5, east racks 16.5..27.9, east aisle
# 27.9..29.5. The east columns end 0.2 m short of the west rows' banks.
_EAST_BANKS = [(12.0, 24.4), (28.0, 40.4)]  # (y0, y1) of the east columns
_WEST_ROWS = [(y, y + 2.6) for y in (12.0, 17.0, 22.0, 28.0, 33.0, 38.0)]  # aisles 2.4 m
_EAST_COLUMNS = [(16.5, 17.7), (20.3, 22.9), (25.3, 27.9)]  # aisles 2.6, 2.4, 1.5 m

WAREHOUSE = FloorPlan(
    name="warehouse", width=30.0, height=50.0, robot_radius=0.25, path_range=(30.0, 60.0),
    walls=[
        (0.5, 0.5, 29.5, 0.5), (0.5, 49.5, 29.5, 49.5),  # outer: south, north
        (0.5, 0.5, 0.5, 49.5), (29.5, 0.5, 29.5, 49.5),  # outer: west, east
        (0.5, 6.5, 29.5, 6.5), (0.5, 9.0, 29.5, 9.0),  # office corridor
        (7.5, 0.5, 7.5, 6.5), (14.5, 0.5, 14.5, 6.5), (22.0, 0.5, 22.0, 6.5),  # room dividers
        (8.0, 43.0, 8.0, 49.5), (0.5, 43.0, 8.0, 43.0),  # the supervisor's room
    ],
    doors={
        "office": (5.8, 6.5, 6.8, 6.5), "meeting": (8.2, 6.5, 9.2, 6.5),
        "break": (20.5, 6.5, 21.5, 6.5), "office-east": (22.7, 6.5, 23.7, 6.5),
        "floor-main": (13.9, 9.0, 15.1, 9.0), "floor-east": (24.4, 9.0, 25.6, 9.0),
        "supervisor": (8.0, 45.0, 8.0, 46.2),
    },
    furniture=[
        (1.2, 1.2, 3.2, 2.0), (1.2, 3.6, 3.2, 4.4), (4.5, 1.2, 6.5, 2.0),  # office: desks,
        (7.0, 3.0, 7.5, 4.6),  # cabinet
        (9.0, 3.2, 13.0, 4.4),  # meeting room: table
        (15.0, 0.6, 18.0, 1.2), (20.0, 2.5, 21.2, 3.7),  # break room: counter, table
        (23.0, 1.2, 25.0, 2.0), (26.5, 1.2, 28.5, 2.0), (26.5, 4.0, 28.5, 4.8),  # east office:
        (28.9, 2.6, 29.5, 5.4),  # desks, shelf
        *[(0.5, y0, 12.5, y1) for y0, y1 in _WEST_ROWS],  # west racks
        *[(x0, y0, x1, y1) for x0, x1 in _EAST_COLUMNS for y0, y1 in _EAST_BANKS],  # east racks
        (9.0, 48.0, 10.2, 49.2), (10.6, 48.0, 11.8, 49.2),  # packing area: pallets
        (13.0, 47.0, 15.5, 48.0), (22.0, 48.2, 24.5, 49.0),  # packing tables
        (27.5, 47.5, 28.9, 48.9), (20.6, 42.0, 25.7, 44.5),  # pallets
        (16.0, 48.2, 21.5, 49.5),  # a rack along the north wall
        (1.0, 48.2, 3.0, 49.0), (1.0, 44.0, 2.0, 45.5),  # supervisor's room: desks
    ],
    groups=[
        ([1, 2, 3, 4], (19.0, 45.5), 0.7, math.pi / 4),  # packing area: four people
        ([5, 6, 7], (13.6, 33.0), 0.55, 0.0),  # main corridor, by the west racks
        ([8, 9], (11.0, 10.5), 0.5, math.pi),  # front aisle, by the main door
        ([10, 11, 12, 13], (18.0, 3.2), 0.7, 0.0),  # break room
        ([14, 15], (19.0, 8.35), 0.5, math.pi),  # office corridor, by its north wall
        ([16, 17, 18], (7.0, 26.3), 0.5, math.pi / 2),  # cross aisle, west
        ([19, 20], (5.5, 44.8), 0.5, 0.0),  # supervisor's room
    ],
    singles=[
        {"id": 21, "x": 6.0, "y": 15.1, "theta": round(-math.pi / 2, 6)},  # pickers, facing
        {"id": 22, "x": 9.0, "y": 37.5, "theta": round(math.pi / 2, 6)},  # the racks
        {"id": 23, "x": 18.2, "y": 18.0, "theta": round(math.pi, 6)},
        {"id": 24, "x": 24.8, "y": 32.0, "theta": 0.0},
        {"id": 25, "x": 15.5, "y": 20.0, "theta": round(-math.pi / 2, 6),  # walking south
         "vx": 0.0, "vy": -0.8},
        {"id": 26, "x": 27.0, "y": 44.0, "theta": round(math.pi / 2, 6)},  # by the pallets
    ],
    starts=[[3.5, 46.5],  # supervisor's room
            [3.0, 31.8],  # deep in a west aisle
            [24.0, 36.0],  # east aisle, north bank
            [24.0, 46.0],  # packing area, east
            [26.0, 26.2]],  # cross aisle, east
    goal=[11.0, 1.8],  # meeting room
)

PLANS = {plan.name: plan for plan in (OFFICE, WAREHOUSE)}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.tools.make_maps",
                                     description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("name", choices=[*PLANS, "all"])
    parser.add_argument("--out", default=str(PACKAGE_ROOT / "data"),
                        help="data directory to write into (default: the package's data/)")
    args = parser.parse_args(argv)
    if not args.out.strip():  # "" would be the working directory, unsaid
        parser.error("--out '': give the data directory to write into")
    for name in PLANS if args.name == "all" else [args.name]:
        try:
            paths = write(PLANS[name], Path(args.out))
        except (PipelineError, OSError) as e:
            raise SystemExit(report(e, f"the {name} map")) from None
        print("wrote " + ", ".join(str(p) for p in paths))


if __name__ == "__main__":
    run_tool(main)
