"""World model (DESIGN §3): room, persons, social relations, starts and goal.

Plain data plus validation of the scene-file structure; no Hydra, no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.core.params import require_positive
from pipeline.errors import PipelineError


class SceneError(PipelineError):
    """A scene (file or generated) violates the world model."""


@dataclass
class BodyParams:
    """Sizes every scene has, whatever its source."""
    body_radius: float = 0.25  # m, no robot path may enter a person's body disk
    goal_tolerance: float = 0.3  # m, states this close to the goal are terminal

    def __post_init__(self) -> None:
        require_positive(self, "body_radius", "goal_tolerance")


@dataclass(frozen=True)
class Room:
    x_min: float
    y_min: float
    x_max: float
    y_max: float

    def contains(self, points: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Mask (n,) of points (n, 2) inside the room shrunk by `margin`."""
        p = np.atleast_2d(points)
        return (
            (p[:, 0] >= self.x_min + margin)
            & (p[:, 0] <= self.x_max - margin)
            & (p[:, 1] >= self.y_min + margin)
            & (p[:, 1] <= self.y_max - margin)
        )

    @property
    def area(self) -> float:
        return (self.x_max - self.x_min) * (self.y_max - self.y_min)

    def describe(self) -> str:
        return f"[{self.x_min:g}, {self.x_max:g}] x [{self.y_min:g}, {self.y_max:g}]"


@dataclass(frozen=True)
class Person:
    id: int
    x: float
    y: float
    theta: float = 0.0
    vx: float = 0.0
    vy: float = 0.0


@dataclass(frozen=True)
class Scene:
    name: str
    room: Room
    persons: tuple[Person, ...]
    relations: tuple[tuple[int, int], ...]
    starts: np.ndarray  # (n_starts, 2)
    goal: np.ndarray  # (2,)
    body_radius: float = 0.25
    goal_tolerance: float = 0.3

    @property
    def person_xy(self) -> np.ndarray:
        return np.array([[p.x, p.y] for p in self.persons], dtype=float).reshape(-1, 2)

    @property
    def links(self) -> tuple[np.ndarray, np.ndarray]:
        """Social links as segment end points (a, b), each (n_links, 2)."""
        pos = {p.id: (p.x, p.y) for p in self.persons}
        a = np.array([pos[i] for i, _ in self.relations], dtype=float).reshape(-1, 2)
        b = np.array([pos[j] for _, j in self.relations], dtype=float).reshape(-1, 2)
        return a, b

    def in_body(self, points: np.ndarray, clearance: float = 0.0) -> np.ndarray:
        """Mask (n,) of points (n, 2) inside some person's body disk (grown by `clearance`)."""
        p = np.atleast_2d(points)
        if not self.persons:
            return np.zeros(len(p), dtype=bool)
        d = np.linalg.norm(p[:, None, :] - self.person_xy[None, :, :], axis=2)
        return (d < self.body_radius + clearance).any(axis=1)

    def free(self, points: np.ndarray) -> np.ndarray:
        """Mask (n,) of points (n, 2) inside the room and outside every body disk."""
        return self.room.contains(points) & ~self.in_body(points)

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "room": {k: getattr(self.room, k) for k in ("x_min", "y_min", "x_max", "y_max")},
            "persons": [
                {"id": p.id, "x": p.x, "y": p.y, "theta": p.theta, "vx": p.vx, "vy": p.vy}
                for p in self.persons
            ],
            "relations": [list(r) for r in self.relations],
            "starts": self.starts.tolist(),
            "goal": self.goal.tolist(),
            "body_radius": self.body_radius,
            "goal_tolerance": self.goal_tolerance,
        }


def scene_from_dict(data: dict, source: str = "scene", body_radius: float | None = None,
                    goal_tolerance: float | None = None) -> Scene:
    """Build and validate a Scene from the JSON structure of DESIGN §3.

    Raises SceneError with one line naming `source` and the offending entry.
    """
    def fail(msg: str) -> SceneError:
        return SceneError(f"{source}: {msg}")

    if not isinstance(data, dict):
        raise fail("top level must be a JSON object")
    for key in ("room", "persons", "starts", "goal"):
        if key not in data:
            raise fail(f"missing key '{key}'")
    try:
        room_d = data["room"]
        room = Room(*(float(room_d[k]) for k in ("x_min", "y_min", "x_max", "y_max")))
    except (KeyError, TypeError, ValueError):
        raise fail("'room' needs numbers x_min, y_min, x_max, y_max") from None
    if not (room.x_max > room.x_min and room.y_max > room.y_min):
        raise fail(f"room {room.describe()} is empty")

    persons = []
    for i, p in enumerate(data["persons"]):
        try:
            vx, vy = float(p.get("vx", 0.0)), float(p.get("vy", 0.0))
            theta = float(p["theta"]) if "theta" in p else math.atan2(vy, vx)
            persons.append(Person(int(p["id"]), float(p["x"]), float(p["y"]), theta, vx, vy))
        except (KeyError, TypeError, ValueError, AttributeError):
            raise fail(f"person #{i} needs numbers id, x, y (and optional theta, vx, vy)") from None
    ids = [p.id for p in persons]
    if len(set(ids)) != len(ids):
        raise fail(f"duplicate person ids in {sorted(ids)}")
    for p in persons:
        if not room.contains(np.array([p.x, p.y]))[0]:
            raise fail(f"person {p.id} at ({p.x:g}, {p.y:g}) is outside the room {room.describe()}")

    relations = []
    for r in data.get("relations", []):
        if not (isinstance(r, (list, tuple)) and len(r) == 2):
            raise fail(f"relation {r!r} must be a pair of person ids")
        a, b = (int(v) for v in r)
        for pid in (a, b):
            if pid not in ids:
                raise fail(f"relation [{a}, {b}] names unknown person id {pid}")
        if a == b:
            raise fail(f"relation [{a}, {b}] links a person to itself")
        pa, pb = (next(p for p in persons if p.id == pid) for pid in (a, b))
        if math.hypot(pa.x - pb.x, pa.y - pb.y) < 1e-6:  # a zero-length social link
            raise fail(f"relation [{a}, {b}] links two persons at the same place")
        relations.append((a, b))

    try:
        starts = np.array(data["starts"], dtype=float).reshape(-1, 2)
        goal = np.array(data["goal"], dtype=float).reshape(2)
    except (TypeError, ValueError):
        raise fail("'starts' must be a list of [x, y] and 'goal' one [x, y]") from None
    if len(starts) == 0:
        raise fail("'starts' is empty: at least one start is needed")

    scene = Scene(
        name=str(data.get("name", Path(source).stem)),
        room=room,
        persons=tuple(persons),
        relations=tuple(relations),
        starts=starts,
        goal=goal,
        body_radius=float(
            body_radius if body_radius is not None else data.get("body_radius", 0.25)
        ),
        goal_tolerance=float(
            goal_tolerance if goal_tolerance is not None else data.get("goal_tolerance", 0.3)
        ),
    )
    for label, pts in [("start", starts), ("goal", goal[None, :])]:
        for k, pt in enumerate(pts):
            name = f"{label} {k}" if label == "start" else "goal"
            if not room.contains(pt)[0]:
                raise fail(f"{name} ({pt[0]:g}, {pt[1]:g}) is outside the room {room.describe()}")
            if scene.in_body(pt)[0]:
                raise fail(f"{name} ({pt[0]:g}, {pt[1]:g}) is inside a person's body disk")
    return scene
