"""Generate the shipped maps and their scenes: data/maps/NAME.{pgm,yaml}, data/scenes/NAME.json.

    python -m pipeline.tools.make_maps office             # or: all
    python -m pipeline.tools.make_maps office --out DIR   # DIR/maps, DIR/scenes

office: deterministic (no randomness). A 20 m × 14 m ROS map_server map at 0.05 m/cell
(400 × 280 pixels): a building with 0.15 m walls (outer wall centred 0.5 m inside the map
edge, unknown grey outside it), a 2.4 m corridor along the middle (y 5.8..8.2), three rooms
on each side, 1 m doors into the corridor, one door between the two south-east rooms, and
desks/tables. The scene puts social groups (F-formations) in the corridor and rooms, starts
in five rooms and the goal in the sixth; the script checks every start and the goal are free
with clearance >= 0.3 m and connected to each other around the persons.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
from PIL import Image

from pipeline.app.context import PACKAGE_ROOT

RES = 0.05
WIDTH, HEIGHT = 20.0, 14.0
WALL = 0.15
FREE, OCCUPIED, UNKNOWN = 254, 0, 205  # map_saver's grey values

# axis-aligned walls as centre lines (x0, y0, x1, y1), drawn WALL thick
WALLS = [
    (0.5, 0.5, 19.5, 0.5), (0.5, 13.5, 19.5, 13.5),  # outer: south, north
    (0.5, 0.5, 0.5, 13.5), (19.5, 0.5, 19.5, 13.5),  # outer: west, east
    (0.5, 5.8, 19.5, 5.8), (0.5, 8.2, 19.5, 8.2),  # corridor
    (6.5, 0.5, 6.5, 5.8), (13.0, 0.5, 13.0, 5.8),  # south room dividers
    (7.5, 8.2, 7.5, 13.5), (13.5, 8.2, 13.5, 13.5),  # north room dividers
]
# door openings (x0, y0, x1, y1) cut through the walls
DOORS = {
    "S1": (4.8, 5.8, 5.8, 5.8), "S2": (7.3, 5.8, 8.3, 5.8), "S3": (17.3, 5.8, 18.3, 5.8),
    "N1": (2.0, 8.2, 3.0, 8.2), "N2": (12.0, 8.2, 13.0, 8.2), "N3": (14.3, 8.2, 15.3, 8.2),
    "S2-S3": (13.0, 1.5, 13.0, 2.5),
}
# furniture (x0, y0, x1, y1)
FURNITURE = [
    (1.2, 1.2, 2.8, 2.0), (1.2, 3.4, 2.8, 4.2), (5.7, 0.8, 6.3, 2.2),  # S1: desks, cabinet
    (8.6, 2.2, 11.0, 3.4),  # S2: meeting table
    (15.0, 1.0, 16.6, 1.8), (17.5, 1.0, 19.1, 1.8),  # S3: desks
    (1.0, 11.8, 2.6, 12.6), (4.5, 11.8, 6.1, 12.6),  # N1: desks
    (11.8, 12.3, 13.2, 13.1),  # N2: desk
    (16.0, 10.2, 17.6, 11.0),  # N3: table
]


def draw_map() -> np.ndarray:
    """(H, W) uint8 grey image in map orientation (row 0 = lowest y)."""
    h, w = round(HEIGHT / RES), round(WIDTH / RES)
    xs = (np.arange(w) + 0.5) * RES
    ys = (np.arange(h) + 0.5) * RES
    grid = np.full((h, w), UNKNOWN, dtype=np.uint8)

    def box(x0: float, y0: float, x1: float, y1: float, value: int) -> None:
        cols = (xs >= min(x0, x1)) & (xs <= max(x0, x1))
        rows = (ys >= min(y0, y1)) & (ys <= max(y0, y1))
        grid[np.ix_(rows, cols)] = value

    box(0.5, 0.5, 19.5, 13.5, FREE)
    half = WALL / 2
    for x0, y0, x1, y1 in WALLS:
        box(x0 - half, y0 - half, x1 + half, y1 + half, OCCUPIED)
    for x0, y0, x1, y1 in DOORS.values():
        box(x0 - half * (x0 == x1), y0 - half * (y0 == y1),
            x1 + half * (x0 == x1), y1 + half * (y0 == y1), FREE)
    for rect in FURNITURE:
        box(*rect, OCCUPIED)
    return grid


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


GROUPS = [  # ids, centre, radius, angle of the first person
    ([1, 2], (10.1, 7.55), 0.5, math.pi),  # corridor: a pair by the north wall
    ([3, 4, 5], (16.3, 7.0), 0.55, math.pi / 2),  # corridor: a trio between N3 and S3 doors
    ([6, 7, 8, 9], (10.5, 10.8), 0.7, math.pi / 4),  # room N2: four people talking
    ([10, 11], (8.5, 4.4), 0.5, math.pi),  # room S2: a pair between table and door
]
SINGLES = [
    {"id": 12, "x": 5.0, "y": 6.6, "theta": 0.0, "vx": 0.8, "vy": 0.0},  # walking, corridor
    {"id": 13, "x": 16.5, "y": 3.2, "theta": round(math.pi / 2, 6)},  # room S3
    {"id": 14, "x": 6.0, "y": 10.0, "theta": round(math.pi, 6)},  # room N1
]
STARTS = [[2.0, 2.7], [10.5, 1.3], [16.0, 4.3], [4.0, 10.5], [8.5, 12.6]]  # S1 S2 S3 N1 N2
GOAL = [18.0, 12.2]  # room N3


def scene() -> dict[str, object]:
    persons: list[dict[str, float]] = []
    relations: list[list[int]] = []
    for ids, centre, radius, angle in GROUPS:
        persons += f_formation(ids, centre, radius, angle)
        relations += [[a, b] for i, a in enumerate(ids) for b in ids[i + 1:]]
    return {"name": "office", "map": "../maps/office.yaml", "robot_radius": 0.2,
            "persons": persons + SINGLES, "relations": relations,
            "starts": STARTS, "goal": GOAL}


def check(root: Path, data: dict[str, object]) -> None:
    """Starts and goal free (clearance >= 0.3 m) and connected around the persons."""
    from pipeline.core.obstacles import ObstacleMap
    from pipeline.inputs.map_file import load_map

    obstacles = ObstacleMap(load_map(root / "maps" / "office.yaml"))
    persons = np.array([[p["x"], p["y"]] for p in data["persons"]])  # type: ignore[attr-defined]
    points = np.array(data["starts"] + [data["goal"]])  # type: ignore[operator]
    assert obstacles.points_free(points, 0.3).all(), obstacles.clearance_at(points)
    assert obstacles.points_free(persons, 0.3).all(), obstacles.clearance_at(persons)
    blocked = obstacles.blocked_disks(persons, 0.25 + 0.2)  # body disk grown by the robot
    assert not blocked[obstacles.grid.cell_of(points)[:2]].any()
    assert obstacles.reachable(points[-1], points, 0.2, blocked).all()


def write_office(root: Path) -> None:
    (root / "maps").mkdir(parents=True, exist_ok=True)
    (root / "scenes").mkdir(parents=True, exist_ok=True)
    Image.fromarray(draw_map()[::-1]).save(root / "maps" / "office.pgm")  # top row first
    (root / "maps" / "office.yaml").write_text(
        "image: office.pgm\nresolution: 0.05\norigin: [0.0, 0.0, 0.0]\nnegate: 0\n"
        "occupied_thresh: 0.65\nfree_thresh: 0.196\nmode: trinary\n")
    data = scene()
    (root / "scenes" / "office.json").write_text(json.dumps(data, indent=1) + "\n")
    check(root, data)
    print(f"wrote {root}/maps/office.pgm, maps/office.yaml, scenes/office.json")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.tools.make_maps",
                                     description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("name", choices=["office", "all"])
    parser.add_argument("--out", type=Path, default=PACKAGE_ROOT / "data",
                        help="data directory to write into (default: the package's data/)")
    args = parser.parse_args(argv)
    write_office(args.out)


if __name__ == "__main__":
    main()
