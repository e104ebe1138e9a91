"""Recorded demonstrations (DESIGN §3): JSON, CSV and ROS bags read into start-to-goal polylines.

Path forms read by `read_tracks`:

- `.json`: `{"trajectories": [[[x, y], ...], ...]}`, one polyline per trajectory (checked
  against the published `pipeline/schemas/demos.schema.json`);
- `.csv`: columns `x,y`, optional `trajectory` (an id) and `t` (a time);
- ROS bags, read with the `rosbags` library (`rosbags.highlevel.AnyReader`): a ROS 2 bag
  directory (with `metadata.yaml`; `mcap` or `sqlite3` storage, also zstd-compressed), a single
  ROS 2 storage file (`.mcap`, `.db3`) or a ROS 1 `.bag` file.

  A single `.mcap` (or `.db3`) file is opened as it is: rosbags' rosbag2 `Reader` reads a bare
  storage file without its `metadata.yaml`, taking the message definitions embedded in the file.
  Only the messages in that file are read, so for a bag split into several files pass the bag
  directory instead. Storage files without embedded definitions (older `sqlite3` bags) are
  decoded with the standard ROS 2 message types.

  Messages: `nav_msgs/msg/Path` (each message is one trajectory) and the pose streams
  `geometry_msgs/msg/PoseStamped`, `geometry_msgs/msg/PoseWithCovarianceStamped` and
  `nav_msgs/msg/Odometry` (all messages of the topic, in the order of their bag time stamps,
  make one track that `cut_stream` cuts into trajectories). rosbags names ROS 1 types the ROS 2
  way (`nav_msgs/Path` is read as `nav_msgs/msg/Path`), so one set of names serves both.

Recorded tracks are noisy: `clean_track` drops repeated points and resamples by arc length.
Every problem with the input is a `PipelineError` with one line naming the file.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.core.world import Room
from pipeline.errors import PipelineError
from pipeline.inputs.schemas import read_json

PATH_TYPE = "nav_msgs/msg/Path"
# Pose stream message types and how to find the position in each.
STREAM_TYPES: dict[str, Callable[[Any], Any]] = {
    "geometry_msgs/msg/PoseStamped": lambda m: m.pose.position,
    "geometry_msgs/msg/PoseWithCovarianceStamped": lambda m: m.pose.pose.position,
    "nav_msgs/msg/Odometry": lambda m: m.pose.pose.position,
}
SUPPORTED_TYPES = (PATH_TYPE, *STREAM_TYPES)
BAG_SUFFIXES = (".bag", ".mcap", ".db3")
REPEAT_TOLERANCE = 1e-6  # m: consecutive points closer than this are one point


def describe(path: Path) -> str:
    """How error messages name a recorded demonstration."""
    if path.is_dir() or path.suffix.lower() in BAG_SUFFIXES:
        return f"demonstration bag {path}"
    return f"demonstration file {path}"


# ---------------------------------------------------------------------------------------------
# Reading


def read_tracks(path: Path, *, topic: str | None = None,
                frame: str | None = None) -> tuple[list[np.ndarray], bool]:
    """Read the (K, 2) tracks of a recorded demonstration and whether they are one pose stream.

    Returns (tracks, is_stream): is_stream is True when `tracks` is one continuous pose stream
    still to be cut into trajectories (`cut_stream`), False when every track is a trajectory.
    `topic` and `frame` apply to ROS bags only (see the module docstring).
    """
    path = Path(path)
    where = describe(path)
    if not path.exists():
        raise PipelineError(f"{where} not found")
    suffix = path.suffix.lower()
    if path.is_dir() or suffix in BAG_SUFFIXES:
        return _read_bag(path, where, topic, frame)
    if suffix == ".json":
        return _read_json(path, where), False
    if suffix == ".csv":
        return _read_csv(path, where)
    raise PipelineError(f"{where}: unknown format {path.suffix or '(no extension)'!r}; expected "
                        f".json, .csv, a ROS 2 bag directory, .mcap, .db3 or a ROS 1 .bag")


def _read_json(path: Path, where: str) -> list[np.ndarray]:
    # demos.schema.json: at least one trajectory, each at least two finite [x, y]
    data = read_json(path, "demos", where)
    return [np.asarray(t, dtype=float) for t in data["trajectories"]]


def _read_csv(path: Path, where: str) -> tuple[list[np.ndarray], bool]:
    try:
        with path.open(newline="") as f:
            reader = csv.reader(f)
            header = next(reader, None)
            if header is None:
                raise PipelineError(f"{where} is empty; expected a header line with columns x,y")
            names = [h.strip().lower() for h in header]
            missing = [c for c in ("x", "y") if c not in names]
            if missing:
                raise PipelineError(f"{where} has no column {' or '.join(missing)} (columns: "
                                    f"{','.join(h.strip() for h in header)}); expected x,y and "
                                    f"optionally trajectory,t")
            dupes = sorted({n for n in names if n and names.count(n) > 1})
            if dupes:
                raise PipelineError(f"{where}: column {dupes[0]} appears more than once")
            col = {n: names.index(n) for n in ("x", "y", "t", "trajectory") if n in names}
            ids: list[str] = []
            rows: list[tuple[float, float, float]] = []
            for row in reader:
                if not row or all(not c.strip() for c in row):
                    continue  # blank line
                line = reader.line_num
                if len(row) != len(header):
                    raise PipelineError(f"{where}, line {line}: {len(row)} fields, the header "
                                        f"has {len(header)}")
                values = []
                for name in ("x", "y", "t"):
                    if name not in col:
                        values.append(0.0)
                        continue
                    text = row[col[name]].strip()
                    try:
                        v = float(text)
                    except ValueError:
                        raise PipelineError(f"{where}, line {line}: {name}={text!r} is not a "
                                            f"number") from None
                    if not math.isfinite(v):
                        raise PipelineError(f"{where}, line {line}: {name}={text!r} is not "
                                            f"finite")
                    values.append(v)
                if "trajectory" in col:
                    ident = row[col["trajectory"]].strip()
                    if not ident:
                        raise PipelineError(f"{where}, line {line}: empty trajectory id")
                    ids.append(ident)
                rows.append((values[0], values[1], values[2]))
    except UnicodeDecodeError:
        raise PipelineError(f"{where} is not a text file") from None
    except csv.Error as e:
        raise PipelineError(f"{where}: not valid CSV ({e})") from None
    if not rows:
        raise PipelineError(f"{where} has no rows")
    table = np.array(rows, dtype=float)

    def ordered(sel: np.ndarray) -> np.ndarray:
        if "t" in col:
            sel = sel[np.argsort(table[sel, 2], kind="stable")]
        return table[sel, :2]

    if "trajectory" not in col:
        track = ordered(np.arange(len(table)))
        if len(track) < 2:
            raise PipelineError(f"{where} has 1 row; a pose stream needs at least two")
        return [track], True
    groups: dict[str, list[int]] = {}
    for k, ident in enumerate(ids):
        groups.setdefault(ident, []).append(k)
    tracks = []
    for i, (ident, members) in enumerate(groups.items()):
        if len(members) < 2:
            raise PipelineError(f"{where}: trajectory {i} (id {ident!r}) has 1 row; a trajectory "
                                f"needs at least two")
        tracks.append(ordered(np.array(members)))
    return tracks, False


def _read_bag(path: Path, where: str, topic: str | None,
              frame: str | None) -> tuple[list[np.ndarray], bool]:
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    if path.is_dir() and not (path / "metadata.yaml").is_file():
        raise PipelineError(f"{where} is a directory without metadata.yaml, not a ROS 2 bag")
    try:
        with AnyReader([path], default_typestore=get_typestore(Stores.LATEST)) as reader:
            topics = {name: info.msgtype or "(several types)"
                      for name, info in reader.topics.items()}
            listing = ", ".join(f"{n} ({t})" for n, t in topics.items()) or "none"
            if topic is None:
                usable = [n for n, t in topics.items() if t in SUPPORTED_TYPES]
                if not usable:
                    raise PipelineError(
                        f"{where} has no topic of a supported type ({', '.join(SUPPORTED_TYPES)}"
                        f"); its topics: {listing}")
                if len(usable) > 1:
                    raise PipelineError(
                        f"{where} has several usable topics: {', '.join(usable)}; choose one "
                        f"with expert.topic=...")
                topic = usable[0]
            if topic not in topics:
                raise PipelineError(f"{where} has no topic {topic!r} (expert.topic); its topics: "
                                    f"{listing}")
            msgtype = topics[topic]
            if msgtype not in SUPPORTED_TYPES:
                raise PipelineError(f"{where}: topic {topic} has type {msgtype}; supported: "
                                    f"{', '.join(SUPPORTED_TYPES)}")
            connections = [c for c in reader.connections if c.topic == topic]
            tracks: list[np.ndarray] = []
            stream: list[tuple[float, float]] = []
            count = 0
            for count, (conn, _, raw) in enumerate(reader.messages(connections=connections), 1):
                msg: Any = reader.deserialize(raw, conn.msgtype)
                found = msg.header.frame_id
                if frame is not None and found != frame:
                    raise PipelineError(
                        f"{where}: topic {topic} message {count - 1} has frame_id {found!r}, "
                        f"not expert.frame={frame!r}")
                if msgtype == PATH_TYPE:
                    track = np.array([[p.pose.position.x, p.pose.position.y] for p in msg.poses],
                                     dtype=float).reshape(-1, 2)
                    if len(track) < 2:
                        raise PipelineError(
                            f"{where}: topic {topic} path message {count - 1} has {len(track)} "
                            f"pose(s); a trajectory needs at least two")
                    if not np.isfinite(track).all():
                        raise PipelineError(f"{where}: topic {topic} path message {count - 1} "
                                            f"has a non-finite position")
                    tracks.append(track)
                else:
                    pos = STREAM_TYPES[msgtype](msg)
                    if not (math.isfinite(pos.x) and math.isfinite(pos.y)):
                        raise PipelineError(f"{where}: topic {topic} message {count - 1} has a "
                                            f"non-finite position")
                    stream.append((pos.x, pos.y))
    except PipelineError:
        raise
    except Exception as e:  # rosbags raises many kinds on malformed bags; report, never trace
        detail = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise PipelineError(f"{where} cannot be read as a ROS bag ({detail})") from None
    if count == 0:
        raise PipelineError(f"{where}: topic {topic} has no messages")
    if msgtype == PATH_TYPE:
        return tracks, False
    if len(stream) < 2:
        raise PipelineError(f"{where}: topic {topic} has 1 message; a pose stream needs at "
                            f"least two")
    return [np.array(stream, dtype=float)], True


# ---------------------------------------------------------------------------------------------
# Cleaning, cutting and matching


def drop_repeats(points: np.ndarray, tolerance: float = REPEAT_TOLERANCE) -> np.ndarray:
    """Drop points closer than `tolerance` to the previous kept point; the first and last points
    are kept exactly (the last replaces the kept point it repeats). Returns a new array; a track
    that never moves by `tolerance` becomes its first point alone."""
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    if len(p) < 2:
        return p.copy()
    step = np.linalg.norm(np.diff(p, axis=0), axis=1)
    if (step >= tolerance).all():
        return p.copy()
    keep = [0]
    last = p[0]
    for i in range(1, len(p)):
        if math.hypot(p[i, 0] - last[0], p[i, 1] - last[1]) >= tolerance:
            keep.append(i)
            last = p[i]
    if keep[-1] != len(p) - 1:  # the last point repeats a kept one: it takes that one's place
        keep.pop()
        while len(keep) > 1 and np.linalg.norm(p[-1] - p[keep[-1]]) < tolerance:
            keep.pop()
        if len(keep) == 1 and np.linalg.norm(p[-1] - p[0]) < tolerance:
            return p[:1].copy()
        keep.append(len(p) - 1)
    return p[keep]


def clean_track(points: np.ndarray, spacing: float) -> np.ndarray:
    """Drop repeated points (`drop_repeats`, < 1e-6 m apart), then resample the polyline by arc
    length: n = ceil(L / spacing) equal steps of L / n <= `spacing` metres, where L is its
    length. The first and last points are kept exactly and every point lies on the polyline, so
    a straight line keeps its length and no polyline gets longer. A track that never moves is
    returned as its one point."""
    if not spacing > 0:
        raise PipelineError(f"resampling spacing must be positive, got {spacing}")
    p = drop_repeats(points)
    if len(p) < 2:
        return p
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    length = float(s[-1])
    n = max(1, math.ceil(length / spacing - 1e-9))
    at = length * np.arange(n + 1) / n
    out = np.column_stack([np.interp(at, s, p[:, 0]), np.interp(at, s, p[:, 1])])
    out[0], out[-1] = p[0], p[-1]
    return out


def cut_stream(track: np.ndarray, starts: np.ndarray, goal: np.ndarray, start_radius: float,
               goal_tolerance: float) -> list[np.ndarray]:
    """Cut a continuous pose stream (K, 2) into start-to-goal trajectories.

    A point is *near* start s when it is within `start_radius` of s, and *at the goal* when it
    is within `goal_tolerance` of `goal`. From a position p (initially 0):

    1. a = the first index >= p near some start; none: stop. s = the start nearest to track[a].
    2. g = the first index > a at the goal; none: stop (the rest never reaches the goal).
    3. b = the last index in [a, g) near s: the point where the robot leaves the vicinity of s
       (for the last time, if it came back to s before reaching the goal).
    4. track[b : g + 1] is a trajectory; continue from p = g + 1.

    So every trajectory begins within `start_radius` of a start, ends at its first point within
    `goal_tolerance` of the goal, and passing near another start on the way does not cut it.
    Stretches before the robot first comes near a start, or after the last goal arrival that
    never reach the goal again, are dropped. Returns [] when no trajectory is found.
    """
    track = np.asarray(track, dtype=float).reshape(-1, 2)
    starts = np.asarray(starts, dtype=float).reshape(-1, 2)
    if len(track) == 0 or len(starts) == 0:
        return []
    gaps = np.linalg.norm(track[:, None, :] - starts[None, :, :], axis=2)  # (K, n)
    near_any = np.flatnonzero((gaps <= start_radius).any(axis=1))
    at_goal = np.flatnonzero(np.linalg.norm(track - np.asarray(goal, dtype=float), axis=1)
                             <= goal_tolerance)
    pieces = []
    pos = 0
    while True:
        i = int(np.searchsorted(near_any, pos))
        if i == len(near_any):
            break
        a = int(near_any[i])
        j = int(np.searchsorted(at_goal, a, side="right"))
        if j == len(at_goal):
            break
        g = int(at_goal[j])
        s = int(np.argmin(gaps[a]))
        b = a + int(np.flatnonzero(gaps[a:g, s] <= start_radius)[-1])  # a itself qualifies
        pieces.append(track[b:g + 1].copy())
        pos = g + 1
    return pieces


def match_to_starts(tracks: Sequence[np.ndarray], starts: np.ndarray, goal: np.ndarray,
                    start_radius: float, goal_tolerance: float, source: str) -> list[int]:
    """Index of the start nearest to each track's first point.

    Each track must begin within `start_radius` of its nearest start and end within
    max(1 m, `goal_tolerance`) of the goal; otherwise one line naming `source`, the trajectory
    (numbered from 0) and the distance is raised.
    """
    starts = np.asarray(starts, dtype=float).reshape(-1, 2)
    goal = np.asarray(goal, dtype=float)
    goal_limit = max(1.0, goal_tolerance)
    matched = []
    for i, t in enumerate(tracks):
        gaps = np.linalg.norm(starts - t[0], axis=1)
        k = int(np.argmin(gaps))
        if gaps[k] > start_radius:
            raise PipelineError(
                f"{source}: trajectory {i} starts {gaps[k]:.2f} m from the nearest start "
                f"({starts[k, 0]:g}, {starts[k, 1]:g}); at most {start_radius:g} m "
                f"(expert.start_radius)")
        end_gap = float(np.linalg.norm(t[-1] - goal))
        if end_gap > goal_limit:
            raise PipelineError(f"{source}: trajectory {i} ends {end_gap:.2f} m from the goal "
                                f"({goal[0]:g}, {goal[1]:g}); at most {goal_limit:g} m")
        matched.append(k)
    return matched


def load_recorded(path: Path, starts: np.ndarray, goal: np.ndarray, *, goal_tolerance: float,
                  topic: str | None = None, frame: str | None = None, start_radius: float = 1.0,
                  spacing: float = 0.1, room: Room | None = None) -> list[tuple[int, np.ndarray]]:
    """Read a recorded demonstration into (start index, cleaned (K, 2) polyline) pairs.

    A pose stream (Odometry, PoseStamped, a CSV without `trajectory` ids) is cut with
    `cut_stream` and cleaned with `clean_track(track, spacing)`: dense, noisy and repeated
    poses become an evenly spaced polyline. Trajectories given as polylines (JSON, CSV with
    ids, nav_msgs/Path) keep their points, only repeated points dropped, so the same
    polylines learn the same reward whatever the file format. With `room`, every trajectory
    (before cleaning) must stay inside it. Each trajectory is then matched with `match_to_starts`.
    """
    path = Path(path)
    where = describe(path)
    tracks, is_stream = read_tracks(path, topic=topic, frame=frame)
    if is_stream:
        n_points = len(tracks[0])
        tracks = cut_stream(tracks[0], starts, goal, start_radius, goal_tolerance)
        if not tracks:
            raise PipelineError(
                f"{where}: found no trajectory from a start (within {start_radius:g} m, "
                f"expert.start_radius) to the goal (within {goal_tolerance:g} m) in the "
                f"{n_points} poses read")
    if room is not None:
        for i, t in enumerate(tracks):
            if not room.contains(t).all():
                raise PipelineError(f"{where}: trajectory {i} leaves the room {room.describe()}")
    if is_stream:
        cleaned = [clean_track(t, spacing) for t in tracks]
    else:
        cleaned = [drop_repeats(t) for t in tracks]
    for i, t in enumerate(cleaned):
        if len(t) < 2:
            raise PipelineError(f"{where}: trajectory {i} never moves (all its points are "
                                f"within {REPEAT_TOLERANCE:g} m of each other)")
    matched = match_to_starts(cleaned, starts, goal, start_radius, goal_tolerance, where)
    return list(zip(matched, cleaned, strict=True))
