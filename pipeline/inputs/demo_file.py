"""Demonstration files (DESIGN §3): JSON, CSV or ROS bag recordings read into Demonstrations."""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
from collections.abc import Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np

from pipeline.core.experts import Demonstration
from pipeline.core.features import FeatureModel
from pipeline.core.nearby import segments_clear_of_disks
from pipeline.core.social import distances_to_persons
from pipeline.core.world import Scene, point
from pipeline.errors import PipelineError, listed
from pipeline.inputs.recorded import ROOM_EDGE_TOLERANCE, START_RADIUS, load_recorded
from pipeline.inputs.recordings import describe, is_recording_folder, subject_recordings
from pipeline.progress import Progress

log = logging.getLogger(__name__)


def load_demo_file(path: Path, scene: Scene, feature_model: FeatureModel, speed: float, *,
                   topic: str | None = None, frame: str | None = None,
                   start_radius: float = START_RADIUS, denoise: bool = True,
                   select_walks: bool = False) -> list[Demonstration]:
    """Read a demonstration file or bag (DESIGN §3, `pipeline.inputs.recorded.load_recorded`).

    Every trajectory is cut at the goal disk, must stay in the room, keep robot_radius from
    every obstacle and out of every person's body disk (its segments become graph edges),
    begin within `start_radius` of a start (it is matched to the nearest) and end near the
    goal (one that ends outside the goal disk is a demonstration that does not reach it, with
    a warning); `topic` and `frame` select and check
    the bag topic (expert.topic, expert.frame); `denoise` smooths tracking noise
    (expert.denoise, `denoise.smooth_jitter`); `select_walks` keeps only the walks from a
    start to the goal in each trajectory (expert.select_walks,
    `recorded.select_track_walks`). A file's `subjects` become the demonstrations'
    `subject`. A folder of recordings (no ROS 2 bag itself) is read one recording after
    another, by name; a recording that names no subjects (a bag cannot) is taken to be of
    one subject, named by its file or by the folder in it that holds it
    (`recordings.subject_recordings`).
    """
    path = Path(path)
    demos_of = functools.partial(_recording_demos, scene=scene, feature_model=feature_model,
                                 speed=speed, topic=topic, frame=frame,
                                 start_radius=start_radius, denoise=denoise,
                                 select_walks=select_walks)
    if not is_recording_folder(path):
        demos, none_left = demos_of(path)
        if none_left:
            raise PipelineError(none_left)
        return demos
    read: list[tuple[Path, Demonstration]] = []
    # recordings none of whose walks a robot could follow, by name in the folder: refusal
    emptied: dict[str, str] = {}
    for recording, subject in subject_recordings(path):
        demos, none_left = demos_of(recording)
        if none_left:
            emptied[recording.relative_to(path).as_posix()] = none_left
        read += [(recording, dataclasses.replace(
                    d, subject=subject if d.subject is None else d.subject,
                    source=f"{recording.relative_to(path).as_posix()}: {d.source}"))
                 for d in demos]
    names, refusals = list(emptied), list(emptied.values())
    if emptied and not read:  # none is left in the whole folder: refused as one file would be
        raise PipelineError(refusals[0] + (
            f"; and so is every walk of the folder's other recordings ({listed(names[1:], 5)})"
            if len(names) > 1 else ""))
    if emptied:
        # one subject who walked only where the scene's people stood: the others still teach
        log.warning("%s: expert.select_walks: recordings %s hold no walk a robot could follow "
                    "(every walk passes through a body disk or too close to an obstacle) and "
                    "are dropped; the first: %s", describe(path), listed(names, 5),
                    refusals[0])
    warn_repeated_recordings(path, read)
    return [d for _, d in read]


def _recording_demos(path: Path, scene: Scene, feature_model: FeatureModel, speed: float, *,
                     topic: str | None, frame: str | None, start_radius: float, denoise: bool,
                     select_walks: bool) -> tuple[list[Demonstration], str | None]:
    """The demonstrations of one recording (`load_demo_file`), and, when `select_walks`
    dropped every walk it read, the refusal that says why (None otherwise)."""
    walks: list[tuple[int, np.ndarray, str | None, str]] = []  # those a robot could follow
    unreached: list[str] = []
    tracks = load_recorded(path, scene.starts, scene.goal, goal_tolerance=scene.goal_tolerance,
                           topic=topic, frame=frame, start_radius=start_radius, room=scene.room,
                           denoise=denoise, select_walks=select_walks)
    pushed: list[str] = []
    blocked: list[str] = []  # walks cut from tracks that no robot path could follow
    first_refusal = ""
    progress = Progress(f"{describe(path)}: checking walks against the scene", len(tracks))
    cleared = []  # each walk's points, moved off a wall where noise took them onto it
    for k, (_, points, _, label) in enumerate(tracks):
        progress(k)
        if scene.obstacles is not None:  # tracking noise along a wall, as at the room's edge
            clear = clear_of_walls(points, scene)
            if clear is not points:
                pushed.append(label)
                points = clear
        cleared.append(points)
    for (start, _, subject, label), points, fault in zip(tracks, cleared,
                                                         walk_faults(cleared, scene),
                                                         strict=True):
        if fault is not None:
            what = f"{describe(path)}: trajectory {label}"
            if not select_walks:
                raise PipelineError(fault.refusal(what))
            first_refusal = first_refusal or fault.refusal(what)
            blocked.append(f"{label} ({fault.does})")
            continue
        walks.append((start, points, subject, label))
    demos = demonstrations(walks, scene, feature_model, speed)
    for demo in demos:
        if not demo.reached:
            end_gap = float(np.linalg.norm(demo.points[-1] - scene.goal))
            unreached.append(f"{demo.source} ({metres_beside(end_gap, scene.goal_tolerance)} m)")
    if pushed:
        log.warning("%s: trajectories %s come closer to an obstacle than robot_radius=%g m by "
                    "at most %g m, as tracking noise along a wall does: there they are moved "
                    "away from it to robot_radius (closer is refused)", describe(path),
                    listed(pushed, 5),
                    scene.robot_radius, ROOM_EDGE_TOLERANCE)
    if blocked and not demos:  # none is left: refused as one file would be
        return [], first_refusal + (
            f"; and no other walk read is one a robot could follow either (all "
            f"{len(blocked)} are dropped by expert.select_walks: "
            f"{listed(blocked, 3)})" if len(blocked) > 1 else "")
    if blocked:
        # A tracker's hundreds of walks and a scene of who stood where at one moment: a few
        # walks pass where someone stood at another time, or a ghost track crosses a wall.
        walls = "" if scene.obstacles is None else \
            f" or closer to an obstacle than robot_radius={scene.robot_radius:g} m"
        emptied = sorted({t.start for t in tracks} - {d.start_index for d in demos})
        log.warning("%s: expert.select_walks: %d of %d walks pass through a person's body "
                    "disk (body_radius=%g m)%s, where no robot path may go, and are dropped: "
                    "%s%s", describe(path), len(blocked), len(tracks), scene.body_radius, walls,
                    listed(blocked, 5),
                    f"; no walk is left that begins at start(s) {emptied}" if emptied else "")
    if unreached:
        log.warning("%s: trajectories %s end outside the goal disk (goal_tolerance=%g m): they "
                    "are learned from as walks to the goal whose end was not recorded; extend "
                    "them to the goal or raise scene.goal_tolerance if they reached it",
                    describe(path),
                    listed(unreached, 5),
                    scene.goal_tolerance)
    return demos, None


def warn_repeated_recordings(folder: Path, read: list[tuple[Path, Demonstration]]) -> None:
    """One warning when a folder's recordings hold the same walks (an all-subjects bag beside
    the per-subject ones): each would be learned from twice, and a held-out subject's walks
    would stay in training under the other recording's subject."""
    first: dict[bytes, Path] = {}
    pairs: dict[tuple[str, str], int] = {}
    for recording, demo in read:
        key = np.round(demo.points, 6).tobytes()
        seen = first.setdefault(key, recording)
        if seen != recording:
            pair = (seen.name, recording.name)
            pairs[pair] = pairs.get(pair, 0) + 1
    if pairs:
        log.warning("%s: recordings repeat one another's walks (%s): each such walk is learned "
                    "from twice, and holding out a subject may leave its walks in training "
                    "under the other's name; keep one copy of each walk in the folder",
                    describe(folder), listed([f"{n} in both {a} and {b}"
                                              for (a, b), n in pairs.items()], 3))


def metres_beside(value: float, limit: float) -> str:
    """`value` to the centimetre, or to 0.1 mm where the centimetre would hide on which side
    of `limit` it lies: 0.1986 m is no "0.20 m" beside 0.2 m, nor 0.304 m "0.30 m" beside
    0.3 m."""
    shown = f"{value:.2f}"
    return shown if (float(shown) < limit) == (value < limit) and float(shown) != limit \
        else f"{value:.4f}"


def clear_of_walls(points: np.ndarray, scene: Scene) -> np.ndarray:
    """The trajectory with its stretches that come closer than robot_radius to an obstacle,
    by at most ROOM_EDGE_TOLERANCE, moved away from it to robot_radius
    (`ObstacleMap.push_clear`): first its points, then, where a segment between them still
    dips in, that segment's points half a map cell apart. `points` itself when nothing
    needed moving, and also when moving did not clear it: a deeper intrusion is refused by
    `checked_demonstration` naming the user's own points, not ones added here."""
    walls, radius = scene.obstacles, scene.robot_radius
    assert walls is not None
    if (walls.segments_min_clearance(points[:-1], points[1:]) >= radius).all():
        return points
    p = walls.push_clear(points, radius, ROOM_EDGE_TOLERANCE)
    for _ in range(3):  # a corner may need its pushed points pushed again
        dips = walls.segments_min_clearance(p[:-1], p[1:]) < radius
        if not dips.any():
            break
        step = walls.resolution / 2
        pieces = []
        for a, b, dip in zip(p[:-1], p[1:], dips, strict=True):
            n = max(1, math.ceil(np.linalg.norm(b - a) / step)) if dip else 1
            pieces.append(a + np.arange(n)[:, None] / n * (b - a))
        p = walls.push_clear(np.vstack(pieces + [p[-1:]]), radius, ROOM_EDGE_TOLERANCE)
    return p if (walls.segments_min_clearance(p[:-1], p[1:]) >= radius).all() else points


def checked_demonstration(start: int, points: np.ndarray, subject: str | None, scene: Scene,
                          feature_model: FeatureModel, speed: float,
                          what: str, source: str | None = None) -> Demonstration:
    """A trajectory (already cut at the goal, `recorded.cut_trajectory`) as a Demonstration,
    refused (naming `what`) where it comes closer than robot_radius to an obstacle or enters
    a body disk (`walk_fault`); it reaches the goal when it ends within goal_tolerance of it."""
    fault = walk_fault(points, scene)
    if fault is not None:
        raise PipelineError(fault.refusal(what))
    return demonstration(start, points, subject, scene, feature_model, speed, source)


def demonstration(start: int, points: np.ndarray, subject: str | None, scene: Scene,
                  feature_model: FeatureModel, speed: float,
                  source: str | None = None) -> Demonstration:
    """A trajectory a robot could follow (`walk_fault` finds nothing) as a Demonstration."""
    return demonstrations([(start, points, subject, source)], scene, feature_model, speed)[0]


def demonstrations(walks: Sequence[tuple[int, np.ndarray, str | None, str | None]],
                   scene: Scene, feature_model: FeatureModel,
                   speed: float) -> list[Demonstration]:
    """`demonstration` of each walk (start, points, subject, source), the features of all
    their segments in one call (`FeatureModel.segments` by runs: each walk's own bits)."""
    # cut_at_goal ends a trajectory that entered the goal disk at its first point there
    return Demonstration.from_polylines(
        [start for start, _, _, _ in walks], [points for _, points, _, _ in walks],
        feature_model, speed, [bool(scene.at_goal(points[-1])[0]) for _, points, _, _ in walks],
        [subject for _, _, subject, _ in walks], [source for _, _, _, source in walks])


class WalkFault(NamedTuple):
    """What keeps a trajectory from being a robot's path, the end of a sentence about it."""
    does: str  # what it does: "passes 0.21 m from person 4"
    detail: str  # where, and what to do about it

    def refusal(self, what: str) -> str:
        """The refusal of the trajectory `what` for it."""
        return f"{what} {self.does}{self.detail}"


def walk_fault(points: np.ndarray, scene: Scene) -> WalkFault | None:
    """What keeps a trajectory from being a robot's path: coming closer than robot_radius to
    an obstacle, or entering a person's body disk (its segments would be graph edges no
    planned path could take); None when nothing does."""
    return walk_faults([points], scene)[0]


def walk_faults(walks: Sequence[np.ndarray], scene: Scene) -> list[WalkFault | None]:
    """`walk_fault` of each walk, the clearances and body disks of all their segments tested
    in one call each (each segment's test is its own: the same answers)."""
    if not walks:
        return []
    a = np.concatenate([points[:-1] for points in walks])
    b = np.concatenate([points[1:] for points in walks])
    at = np.cumsum([len(points) - 1 for points in walks])[:-1]
    clearances = np.split(scene.obstacles.segments_min_clearance(a, b), at) \
        if scene.obstacles is not None else [None] * len(walks)
    clears = np.split(segments_clear_of_disks(a, b, scene.person_xy, scene.body_radius), at) \
        if len(scene.persons) else [None] * len(walks)
    return [_fault(points, clearance, clear, scene)
            for points, clearance, clear in zip(walks, clearances, clears, strict=True)]


def _fault(points: np.ndarray, clearance: np.ndarray | None, clear: np.ndarray | None,
           scene: Scene) -> WalkFault | None:
    """`walk_fault` of a walk from its segments' clearances and whether each keeps out of
    every body disk (None: the scene has no obstacles, no persons)."""
    if clearance is not None:
        worst = int(np.argmin(clearance))
        if clearance[worst] < scene.robot_radius:
            x, y = points[worst]
            return WalkFault(f"comes {metres_beside(clearance[worst], scene.robot_radius)} m "
                             "from an obstacle",
                             f" after ({x:.2f}, {y:.2f}); the robot needs robot_radius="
                             f"{scene.robot_radius:g} m (lower it in the scene file or with "
                             "scene.robot_radius)")
    if clear is None or clear.all():
        return None
    seg = int(np.argmin(clear))
    gaps = distances_to_persons(points[seg:seg + 2], scene.person_xy)
    who = int(np.argmin(gaps))
    person = scene.persons[who]
    x, y = points[seg]
    return WalkFault(f"passes {gaps[who]:.2f} m from person {person.id}",
                     f" at {point(person.x, person.y)} after ({x:.2f}, {y:.2f}), inside the "
                     f"body disk (body_radius={scene.body_radius:g} m) no robot path may enter "
                     "(lower it with scene.body_radius or correct the trajectory)")
