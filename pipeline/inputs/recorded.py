"""Recorded demonstrations (DESIGN §3): JSON, CSV and ROS bags read into start-to-goal polylines.

Path forms read by `read_recording`:

- `.json`: `{"trajectories": [[[x, y], ...], ...]}`, one polyline per trajectory, optional
  `"subjects"` (one id string per trajectory: who demonstrated it) and `"source"` (free text),
  checked against the published `pipeline/schemas/demos.schema.json`;
- `.csv` (UTF-8, with or without the byte-order mark Excel writes): a header line naming the
  columns `x,y`, optional `trajectory` (an id), `t` (a time) and `subject` (who demonstrated
  it); any other column is refused, never silently ignored;
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
  make one track that `stream_spans` cuts into trajectories). rosbags names ROS 1 types the
  ROS 2 way (`nav_msgs/Path` is read as `nav_msgs/msg/Path`), so one set of names serves both;
  messages to the user name them as the bag's ROS does (`ros_type_name`).

Then, whatever the format (`load_recorded`): a pose stream is cut into trajectories, every
trajectory is cut at the goal disk (`cut_at_goal`: it ends at its first point in the disk,
what follows is dropped), pose streams are resampled (`clean_track`), polylines only lose
repeated points.
Tracking noise that makes the trajectories zig-zag from point to point is smoothed out first
(`smooth_jitter`). Every problem with the input is a `PipelineError` with one line naming the file.
"""

from __future__ import annotations

import csv
import difflib
import itertools
import logging
import math
import re
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import scipy.linalg
from scipy.spatial import cKDTree

from pipeline.core.ties import within
from pipeline.core.world import Room, in_goal_disk, metres, point
from pipeline.errors import PipelineError, file_kind, listed
from pipeline.inputs.schemas import read_json

log = logging.getLogger(__name__)


# s: long work (reading a tracker's file of millions of rows, growing a large graph) says
# how far it is about this often, never more often
PROGRESS_SECONDS = 10.0
LARGE_FILE_BYTES = 20_000_000  # a CSV file this large is said to be read, and when it is
MANY_TRACKS = 5_000  # mending this many tracks is said before it starts


class Progress:
    """Info lines on long work: called with how much is done, it says so at most every
    PROGRESS_SECONDS (`what` names the work and what `total` counts), and never on work
    done sooner."""

    def __init__(self, what: str, total: int, logger: logging.Logger = log) -> None:
        self.what, self.total, self.log = what, total, logger
        self.started = self.said = time.perf_counter()

    def __call__(self, done: int) -> None:
        now = time.perf_counter()
        if now - self.said >= PROGRESS_SECONDS:
            self.said = now
            self.log.info("  %s: %d of %d, %.0f s", self.what, done, self.total,
                          now - self.started)

PATH_TYPE = "nav_msgs/msg/Path"
# Pose stream message types and how to find the position in each.
STREAM_TYPES: dict[str, Callable[[Any], Any]] = {
    "geometry_msgs/msg/PoseStamped": lambda m: m.pose.position,
    "geometry_msgs/msg/PoseWithCovarianceStamped": lambda m: m.pose.pose.position,
    "nav_msgs/msg/Odometry": lambda m: m.pose.pose.position,
}
SUPPORTED_TYPES = (PATH_TYPE, *STREAM_TYPES)
BAG_SUFFIXES = (".bag", ".mcap", ".db3")
START_RADIUS = 1.0  # m, by default a demonstration begins this close to a start
CSV_COLUMNS = ("x", "y", "trajectory", "t", "subject")
# other usual names of those columns: refused with the name to use rather than left unread
# (an unread time column would leave the rows in file order, an unread id one stream)
# A person's id names a track in a tracker's file (ATC's, THOR's) and who walked in a lab's:
# either may be meant
PERSON_ID = ("trajectory", "subject")
CSV_COLUMN_ALIASES: dict[str, str | tuple[str, ...]] = {
    "time": "t", "timestamp": "t", "stamp": "t", "time_s": "t", "frame": "t",
    "frame_number": "t",
    "traj": "trajectory", "track": "trajectory", "track_id": "trajectory",
    "trajectory_id": "trajectory", "id": "trajectory", "ped_id": "trajectory",
    "pedestrian_id": "trajectory", "agent_id": "trajectory",
    "person": PERSON_ID, "person_id": PERSON_ID,
    "subject_id": "subject", "participant": "subject", "participant_id": "subject",
    "pos_x": "x", "pos_y": "y"}
CSV_NUMBER = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?", re.ASCII)
REPEAT_TOLERANCE = 1e-6  # m: consecutive points closer than this are one point
# m: no coordinate of a recording lies this far from its origin (UTM: under 10^7 m)
FARTHEST_COORDINATE = 1e9
# m: how far outside the room a recorded point may stray and be moved onto its edge (with a
# warning) rather than refused: tracking noise (laser trackers err by a few centimetres,
# camera trackers by about ten) of a person walking along a wall the room was drawn at
ROOM_EDGE_TOLERANCE = 0.1
# A pose stream's trajectory resampled into more points than this (1000 km at 0.1 m) is
# refused: no walk is that long, a pose far off is (without a room to refuse it by)
MAX_RESAMPLED_POINTS = 10_000_000
# A track ordered by its clock (a CSV's t column, a bag's header.stamp) may be at most this
# many times longer than as given (`clock_order`): sorting fixes poses exported or logged
# out of order, it does not turn a walk into a zig-zag.
T_ORDER_GROWTH = 2.0
# Ordering that makes a track longer than as given by more than this fraction and distance
# is not done: the clock stepped back (a clock set back mid-recording), the rows are in
# order (a timestamp jittering a frame against its neighbour stays within it)
T_ORDER_SLACK, T_ORDER_SLACK_M = 0.05, 0.2
# Positions are rounded to this many decimals of a metre (a nanometre, far below any sensor):
# formats reach the same polyline by different float arithmetic (an odometry stream's 0.6 is
# 0.5999999999999999), and learning should not tell them apart.
COORDINATE_DECIMALS = 9
# Where a pose stream's demonstration begins (`motion_begin`): a robot waiting at a start
# jitters by centimetres, so poses within STOP_TOLERANCE of its closest approach to the start
# count as its stop; only visits within VISIT_SLACK of the closest approach to any start in
# the stretch are candidates (passing another start 0.5 m away on the way is no stop there).
STOP_TOLERANCE = 0.05  # m
VISIT_SLACK = 0.25  # m
# Tracking noise (`smooth_jitter`, per trajectory): a tracker's centimetres of noise at a
# few centimetres between poses zig-zag a straight walk into one two or three times as long,
# and learning then reads a long, winding walk (measured on hand-drawn paths with 2-3 cm of
# noise: the learned weights fell to about zero). Trajectories whose length the noise
# inflates by more than JITTER_INFLATION (3 %) are smoothed; the shipped hand-drawn paths
# (1 cm tremor at 10 cm) are inflated by 1 % and kept as they are.
JITTER_INFLATION = 1.03
# The lengthening is not said of a track shorter than this once smoothed: a person standing
# in a tracker's view, whose 5 cm of jitter made a stay of a centimetre "11191.92 times as
# long as the path it follows"
INFLATION_MIN_LENGTH = 1.0
# `smooth_to_noise` departs from the points by this many times the estimated noise (Morozov's
# discrepancy principle takes a factor above 1: an estimate a little low, as one trajectory's
# few hundred points give, must not leave some of the noise in)
DISCREPANCY = 1.25
# `noise_sigma`: the ratio measured 1.0-1.06 on noisy tracks, 1.24 hand-drawn, 4-9 clean
NOISE_SPAN_RATIO = 1.5
# `noise_sigma` reads noise only in trajectories of at least this many points: in a sparse
# polyline the few second differences are its corners, which the span test above cannot
# tell from noise (8-point planner paths through a door read as 1.2-1.4 m of "noise" and
# were smoothed through the wall; 1 Hz walks of 8-9 points as 0.2-0.4 m, smoothed to 0.23 m
# of a person they passed at 0.86 m). Tracked walks have a hundred points and more.
MIN_NOISE_POINTS = 20
# Noise moves every point. A trajectory of which at least this share of the points lie
# exactly on the line through their neighbours (to STRAIGHT_SINE of a turn) is a planned or
# drawn polyline, straight runs between corners, whose corners `noise_sigma` cannot tell
# from noise either: a run's own roadmap paths written to a file (0.25 m lattice paths, 25-70 %
# of their points on straight runs) read as 15 cm of noise, were smoothed, and learned
# relation -0.62, social -0.70, length -0.31 in place of the run's -1, -0.44, -0.07. Tracked
# walks have none (70 social-force walks: 0 %; the hand-drawn set: 0-1 %).
PLANNED_STRAIGHT_SHARE = 0.1
STRAIGHT_SINE = 1e-6  # a file's nanometres in 0.1 m steps: 1e-8; noise of a millimetre: 1e-2
# A step between consecutive poses longer than JUMP_STEPS times the trajectory's usual step
# (the 75th percentile of its steps: pauses do not shrink it) and than JUMP_MIN is a jump: the
# tracker lost the person and found them, or someone else, again (`largest_jump`, one warning).
JUMP_STEPS = 10.0
# A trajectory that ends outside the goal disk by less than GOAL_NOISE_SIGMAS times its
# tracking noise (`noise_sigma`) reaches the goal (`cut_trajectory`): a walker who stopped at
# the disk's edge is recorded a few centimetres either side of it, and learning reads a
# demonstration that does not reach the goal otherwise (measured before the default learner
# read such a walk as one whose end was not recorded, when it forwent the goal's reward:
# 5-6 of 40-70 social-force walks per scene 0.3-28 mm outside a 0.3 m disk held β at 11,
# 230 when they reach, and the weights at the box's edge). 3σ: noise moves a point at the
# disk's edge farther out in about 1 of 700. At least GOAL_MARGIN_FLOOR, whatever the
# estimate: a recorded position is not known to the millimetre, and the noise estimate
# misses noise it cannot see (a track kept as recorded, expert.denoise=false; points added
# along the segments; a sparse polyline), where one walk 0.3 mm outside the disk moved the
# learned social weight 17-fold (under that earlier reading). At most GOAL_NOISE_MARGIN: a
# tracker's noise is centimetres, and a walk that stopped farther out did not reach the
# goal, however jerky its track.
GOAL_NOISE_SIGMAS = 3.0
GOAL_MARGIN_FLOOR = 0.05  # m
GOAL_NOISE_MARGIN = 0.1  # m
# m, the spacing a pose stream's poses and a smoothed trajectory are resampled to
RESAMPLE_SPACING = 0.1
JUMP_MIN = 1.0  # m
# `match_to_starts` warns of a trajectory whose second-nearest start is less than this much
# farther than its nearest: which start it is learned from is then a coin toss
START_TIE = 0.2  # m
# `revisit`: a trajectory is back on its own route where it comes within REVISIT_RADIUS of
# where it was more than REVISIT_ARC metres of walking before (no walk to a goal does that;
# a loop of 0.5 m radius does after 3 m)
REVISIT_RADIUS = 0.25  # m
REVISIT_ARC = 2.0  # m
REVISIT_STEP = 0.1  # m
# `warn_replans`: a trajectory that begins within REPLAN_RADIUS of the one before it, more
# than REPLAN_ARC along that one's route, is a plan made on the way (a robot's /plan topic:
# Nav2 plans again every second as it drives, each from where the robot is); walks of people
# begin where they stood still, at the start
REPLAN_RADIUS = 0.1  # m
REPLAN_ARC = 0.3  # m
# `broken_track_chains`: a tracker that loses someone (behind a pillar, another walker) and
# finds them again gives them a new id. The new track continues the lost one when it begins
# within REJOIN_GAP seconds after that one ends, within REJOIN_REACH of where the lost walker
# was heading, widened by REJOIN_SPREAD for every second out of view (they turn, slow down).
# Motion is measured over a track's first or last MOTION_WINDOW seconds; headings are compared
# only above MOVING (a standing person's jitter has no heading). A pair is joined only when
# no other track (but the same person's next piece) comes within AMBIGUITY times those
# limits of either: in a simulated crowd with gaps of up to 8 s, 1.0 joined 7 % of the pairs
# wrongly, 1.5 4 % (of 60 % as many); in a helper's densest crowd, 3.2 % and 4.1 %
REJOIN_GAP = 2.0  # s
REJOIN_REACH = 0.5  # m
REJOIN_SPREAD = 1.0  # m/s
MOTION_WINDOW = 1.0  # s
MOVING = 0.3  # m/s
AMBIGUITY = 1.5
# `id_switches`: a pose this far from where its track's motion predicted is a jump; two
# tracks that jump at one time, each to where the other was heading, exchanged whom they
# follow (5 cm of tracking noise misses the prediction by about 7 cm)
SWITCH_MISS = 0.3  # m
# ... and at least this many times what the tracks' noise misses a prediction by (a second
# sensor 0.2 m off in random directions, averaged in, made 9 cm of noise and 6 false switches)
SWITCH_NOISES = 4.0
# ... and do not each go on their own way more nearly than the other's by this much (the
# distance of unit headings: 0.5 is 29 degrees), a heading being the direction of the last
# (or first) HEADING_REACH metres of motion
SWITCH_HEADING_MARGIN = 0.5
HEADING_REACH = 0.5  # m
# `mend_tracks` mends only tracks whose t is in seconds: the median speed of the tracks that
# end WALKED_AT_LEAST metres from their beginning lies in WALKING_SPEEDS (frame numbers at
# 12.5 Hz give 0.1, ms 0.0013; a frame number's gap of 2 read as 2 s joined friends walking
# side by side)
WALKED_AT_LEAST = 2.0  # m
WALKING_SPEEDS = (0.2, 5.0)  # m/s
# `drop_shared_times`: two people's positions at one time are at least this far apart;
# rows of one track at one time closer than this are one person measured twice
BODIES_APART = 0.3  # m
# `_same_time`: rows of one track closer in time than this share of its frame interval are
# at one time
SAME_TIME = 0.25
# `select_track_walks` names the tracks that set off from a start and come within NEAR_MISS
# times the goal tolerance of the goal but never into its disk: walkers bound for the goal
# whom a tolerance a little too small loses (a tracker's people pass a goal point by 0.3 m)
NEAR_MISS = 2.0
# `no_walk_found` asks whether x and y are swapped when fewer than the first share of the
# poses lie in the room and at least the second would with x and y exchanged (tracking
# noise takes a few poses of people by a wall past it)
SWAPPED_INSIDE = (0.95, 0.99)


def is_recording_folder(path: Path) -> bool:
    """A directory that is no ROS 2 bag (no metadata.yaml): a folder of recordings, e.g. one
    bag per subject."""
    return path.is_dir() and not (path / "metadata.yaml").exists()


def recordings_in(folder: Path, nested: bool = True) -> list[Path]:
    """The recordings a folder holds, by name: .json, .csv and bag files, ROS 2 bag
    directories and (`nested`) folders that may hold more (hidden entries and other files
    left out)."""
    return sorted(p for p in folder.iterdir() if not p.name.startswith(".") and (
        (p.is_dir() and (p / "metadata.yaml").is_file())
        or (nested and is_recording_folder(p))
        or (p.is_file() and p.suffix.lower() in (".json", ".csv", *BAG_SUFFIXES))))


def subject_recordings(folder: Path) -> list[tuple[Path, str]]:
    """Each recording of a folder of recordings with the subject it is taken to be of when it
    names none: its name without the extension (`ana.bag`: ana), or the name of the folder in
    it that holds it (`ana/monday.bag`: ana, one subject's sessions)."""
    found: list[tuple[Path, str]] = []
    for entry in recordings_in(folder):
        if is_recording_folder(entry):  # one subject's sessions (none deeper down)
            found += [(r, entry.name) for r in recordings_in(entry, nested=False)]
        else:
            found.append((entry, entry.name if entry.is_dir() else entry.stem))
    return found


def describe(path: Path) -> str:
    """How error messages name a recorded demonstration."""
    if is_recording_folder(path):
        return f"demonstration folder {path}"
    if path.is_dir() or path.suffix.lower() in BAG_SUFFIXES:
        return f"demonstration bag {path}"
    return f"demonstration file {path}"


@dataclass(frozen=True)
class Recording:
    """What a demonstration file holds, before cutting and cleaning."""
    tracks: list[np.ndarray]  # (K, 2) each
    is_stream: bool  # True: tracks[0] is one pose stream still to be cut into trajectories
    # who demonstrated: one per track (polylines) or one per pose (a stream); None: unknown
    subjects: list[str | None] | None = None
    source: str | None = None  # a JSON file's "source"
    planned: bool = False  # nav_msgs/Path messages: a planner's paths (`warn_replans`)
    ids: list[str] | None = None  # a CSV's trajectory ids, one per track
    # a CSV's times (its t column), one array per track, in the track's pose order; None
    # without a t column or trajectory ids
    times: list[np.ndarray] | None = None


class Recorded(NamedTuple):
    """One demonstration as read from a file: matched start, cleaned polyline, subject."""
    start: int
    points: np.ndarray  # (K, 2), ends at the goal when it reached the goal disk
    subject: str | None
    label: str  # its name in messages: its number in the file (`label`)


# ---------------------------------------------------------------------------------------------
# Reading


def read_recording(path: Path, *, topic: str | None = None, frame: str | None = None,
                   single_rows: bool = False) -> Recording:
    """Read the tracks (and subjects) of a recorded demonstration.

    `topic` and `frame` apply to ROS bags only (see the module docstring). With
    `single_rows`, a CSV trajectory of one row is a track of one pose (a tracker's glimpse of
    someone, which `expert.select_walks` drops), not refused.
    """
    path = Path(path)
    where = describe(path)
    check_readable(path)
    suffix = path.suffix.lower()
    if path.is_dir() or suffix in BAG_SUFFIXES:
        return _read_bag(path, where, topic, frame)
    if suffix in (".json", ".csv"):
        given = [f"expert.{k}={v}" for k, v in (("topic", topic), ("frame", frame)) if v]
        if given:  # a user who set them expects a check that does not happen
            log.warning("%s is no ROS bag: %s %s to bags only and %s not used", where,
                        " and ".join(given), *(("applies", "is") if len(given) == 1
                                               else ("apply", "are")))
        _check_text(path, where)
        return _read_json(path, where) if suffix == ".json" else \
            _read_csv(path, where, single_rows)
    raise PipelineError(f"{where}: unknown format {path.suffix or '(no extension)'!r}; expected "
                        f".json, .csv, a ROS 2 bag directory, .mcap, .db3 or a ROS 1 .bag")


def check_readable(path: Path) -> None:
    """Refuse, in the words `read_recording` would use, a demonstration path that is missing,
    a directory that is no ROS 2 bag, a device or a pipe (cheap: for the start-up checks)."""
    path = Path(path)
    where = describe(path)
    if not path.exists():
        if path.is_symlink():
            raise PipelineError(f"{where} is a symbolic link to nothing (or a loop of links)")
        raise PipelineError(f"{where} not found")
    if is_recording_folder(path):
        recordings = subject_recordings(path)
        if not recordings:
            raise PipelineError(f"{where} is a directory without metadata.yaml (not a ROS 2 bag) "
                                "and holds no recording: .json, .csv, .bag, .mcap or .db3 "
                                "files, or ROS 2 bag directories")
        for recording, _ in recordings:
            check_readable(recording)
        return
    if path.is_dir():
        if not (path / "metadata.yaml").is_file():
            raise PipelineError(f"{where} is a directory whose metadata.yaml is no file, not a "
                                "ROS 2 bag")
        return
    kind = file_kind(path)
    if kind is not None:
        what = "a ROS bag" if path.suffix.lower() in BAG_SUFFIXES else "a demonstration file"
        raise PipelineError(f"{where} is {kind}, not {what}")


def _check_text(path: Path, where: str) -> None:
    """Refuse what is no UTF-8 text before a text reader takes it in whole: a UTF-16 or
    UTF-32 byte-order mark, or NUL bytes in the first 8 KiB (binary, or UTF-16/32 without
    a mark; UTF-8 text has none)."""
    with path.open("rb") as f:
        head = f.read(8192)
    save_as = "save it as UTF-8" + (" (Excel: CSV UTF-8)" if path.suffix.lower() == ".csv" else "")
    if head.startswith((b"\xff\xfe\x00\x00", b"\x00\x00\xfe\xff")):
        raise PipelineError(f"{where} is UTF-32 text; {save_as}")
    if head.startswith((b"\xff\xfe", b"\xfe\xff")):
        raise PipelineError(f"{where} is UTF-16 text; {save_as}")
    if b"\x00" in head:
        raise PipelineError(f"{where} holds NUL bytes: binary, or UTF-16/32 text without a "
                            f"byte-order mark; {save_as}")


def read_tracks(path: Path, *, topic: str | None = None,
                frame: str | None = None) -> tuple[list[np.ndarray], bool]:
    """The (K, 2) tracks of a recorded demonstration and whether they are one pose stream
    (`read_recording` without the subjects)."""
    recording = read_recording(path, topic=topic, frame=frame)
    return recording.tracks, recording.is_stream


def refuse_unprintable(ident: str, what: str) -> None:
    """An id with a line break, tab or other control character is refused: errors and tables
    that name it must stay one line (held-out subjects are named in messages)."""
    if not ident.isprintable():
        raise PipelineError(f"{what} {ident!r} holds a control character (a line break, a "
                            "tab); give ids of printable characters")


def _read_json(path: Path, where: str) -> Recording:
    # demos.schema.json: at least one trajectory, each at least two finite [x, y]; subjects
    # strings
    data = read_json(path, "demos", where)
    tracks = [np.asarray(t, dtype=float) for t in data["trajectories"]]
    subjects = data.get("subjects")
    if subjects is not None:  # trimmed, as the CSV reader trims: " ann" is subject "ann"
        subjects = [s.strip() for s in subjects]
        blank = next((i for i, s in enumerate(subjects) if not s), None)
        if blank is not None:
            raise PipelineError(f"{where}: subjects[{blank}] is blank; give every trajectory "
                                f"a subject id")
        for i, subject in enumerate(subjects):
            refuse_unprintable(subject, f"{where}: subjects[{i}]")
    if subjects is not None and len(subjects) != len(tracks):
        raise PipelineError(f"{where}: subjects has {len(subjects)} entries but there are "
                            f"{len(tracks)} trajectories; give one subject id per trajectory")
    return Recording(tracks, False, subjects, data.get("source"))


def _csv_header(header: list[str], where: str) -> list[str]:
    """The header's column names (trimmed, lower case). Other columns (a pose log's theta,
    vx, ...) are not read, with one warning; one that looks meant as a column the reader
    knows (misspelt, or another usual name for it) is refused with the name to use, as is a
    header that is no header."""
    names = [h.strip().lower() for h in header]
    shown = ",".join(h.strip() for h in header)
    ignored, renames = [], []
    for i, name in enumerate(names):
        if name in CSV_COLUMNS:
            continue
        meant = CSV_COLUMN_ALIASES.get(name) or next(
            iter(difflib.get_close_matches(name, CSV_COLUMNS, n=1, cutoff=0.75)), None)
        hint = ""
        if any(sep in name for sep in (";", "\t")):
            hint = "; the columns must be separated by commas"
        elif all(_is_number(h) for h in header if h.strip()):
            hint = "; the first line must be a header naming the columns"
        elif meant is not None:  # said with every other such column, in one line
            if not isinstance(meant, str):  # a person's id: not as a column already given
                meant = tuple(m for m in meant if m not in names) or meant
                meant = meant[0] if len(meant) == 1 else meant
            renames.append((header[i].strip(), meant))
            continue
        elif not name.isprintable():  # e.g. a second byte-order mark: shown, not unread
            hint = "; the name holds characters that do not print"
        elif name:
            ignored.append(header[i].strip())
            continue
        problem = f"unknown column {header[i].strip()!r}" if name else \
            f"column {i + 1} of the header has no name"
        raise PipelineError(f"{where}: {problem} (header: {shown[:80]}); expected x,y and "
                            f"optionally trajectory,t,subject{hint}")
    if renames:
        given = ", ".join(repr(r[0]) for r in renames)
        meant = ", ".join(repr(m) if isinstance(m, str) else
                          " or ".join(map(repr, m)) + " (a track's id, or who walked it)"
                          for _, m in renames)
        one = len(renames) == 1
        these = ("it", "it is", "that column") if one else ("them", "they are", "those columns")
        raise PipelineError(f"{where}: unknown column{'' if one else 's'} {given} (header: "
                            f"{shown[:80]}); expected x,y and optionally trajectory,t,subject; "
                            f"name {these[0]} {meant} if {these[1]} meant as {these[2]}, or "
                            f"rename {these[0]}")
    if ignored:
        log.warning("%s: column%s %s not read (the reader reads x, y, trajectory, t and "
                    "subject)", where, "s" if len(ignored) > 1 else "",
                    ", ".join(repr(c) for c in ignored[:5]) + (" ..." if len(ignored) > 5
                                                              else ""))
    missing = [c for c in ("x", "y") if c not in names]
    if missing:
        raise PipelineError(f"{where} has no column {' or '.join(missing)} (columns: "
                            f"{shown}); expected x,y and optionally trajectory,t,subject")
    dupes = sorted({n for n in names if n in CSV_COLUMNS and names.count(n) > 1})
    if dupes:
        raise PipelineError(f"{where}: column {dupes[0]} appears more than once")
    return names


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _read_csv(path: Path, where: str, single_rows: bool = False) -> Recording:
    size = path.stat().st_size
    if size >= LARGE_FILE_BYTES:  # a tracker's day: a few seconds a million rows
        log.info("reading %s (%.0f MB) ...", where, size / 1e6)
    started = time.perf_counter()
    try:
        # utf-8-sig: Excel's "CSV UTF-8" starts with a byte-order mark, which is not a column
        with path.open(newline="", encoding="utf-8-sig") as f:
            col, table, lines, ids, subjects = _csv_table(csv.reader(f), where)
        if size >= LARGE_FILE_BYTES:
            log.info("  %d rows read in %.0f s", len(table), time.perf_counter() - started)
    except UnicodeDecodeError:
        raise PipelineError(f"{where} is not UTF-8 text") from None
    except csv.Error as e:
        raise PipelineError(f"{where}: not valid CSV ({e})") from None
    return _csv_recording(col, table, lines, ids, subjects, where, single_rows)


def _csv_table(reader, where: str) -> tuple[dict[str, int], np.ndarray, np.ndarray, list[str],
                                            list[str]]:
    """The CSV's columns (name -> index), its rows as (x, y, t) (t 0 without a t column), the
    file line of each row, and its trajectory ids and subjects (empty without those columns).
    A refusal names the first line at fault and, of its fields, the first in the order
    count, x, y, t, trajectory, subject. Rows are read CSV_CHUNK_ROWS at a time, each field
    a column at a time (`_csv_chunk`; a tracker's file has millions of rows: a row at a time
    took 11 µs a row, now 4)."""
    header = next((row for row in reader if any(c.strip() for c in row)), None)
    if header is None:
        raise PipelineError(f"{where} is empty; expected a header line with columns x,y")
    names = _csv_header(header, where)
    col = {n: names.index(n) for n in names}
    chunks: list[tuple[np.ndarray, np.ndarray, dict[str, list[str]]]] = []
    rows: list[list[str]] = []
    lines: list[int] = []
    try:
        for row in reader:
            if not row or (not row[0].strip() and all(not c.strip() for c in row)):
                continue  # blank line
            rows.append(row)
            lines.append(reader.line_num)
            if len(rows) == CSV_CHUNK_ROWS or len(row) != len(header):  # the latter: refused
                chunks.append(_csv_chunk(rows, lines, col, len(header), where))
                rows, lines = [], []
    except (csv.Error, UnicodeDecodeError):  # a line after the rows held: theirs come first
        if rows:
            _csv_chunk(rows, lines, col, len(header), where)
        raise
    if rows:
        chunks.append(_csv_chunk(rows, lines, col, len(header), where))
    if not chunks:
        raise PipelineError(f"{where} has no rows")
    idents = {name: [i for _, _, chunk in chunks for i in chunk[name]] for name in chunks[0][2]}
    return (col, np.vstack([table for table, _, _ in chunks]),
            np.concatenate([at for _, at, _ in chunks]), idents.get("trajectory", []),
            idents.get("subject", []))


CSV_CHUNK_ROWS = 65_536  # a chunk's fields are held as text until read: 20 MB, not 700


def _csv_chunk(rows: list[list[str]], lines: list[int], col: dict[str, int], n_fields: int,
               where: str) -> tuple[np.ndarray, np.ndarray, dict[str, list[str]]]:
    """Rows of a CSV (at file `lines`) as a table (n, 3) of x, y, t (0 without a t column),
    their lines, and their ids by column (trajectory, subject); refused at the first row at
    fault (`_refuse_csv_row`)."""
    numbers = [name for name in ("x", "y", "t") if name in col]
    counted = all(len(row) == n_fields for row in rows)
    values = [_plain_decimals([row[col[name]].strip() for row in rows]) if counted else None
              for name in numbers]
    idents = {name: [row[col[name]].strip() for row in rows] if counted else []
              for name in ("trajectory", "subject") if name in col}
    if not counted or any(v is None for v in values) or \
            not all(all(ids) and "".join(ids).isprintable() for ids in idents.values()):
        for row, line in zip(rows, lines, strict=True):  # the first at fault
            _refuse_csv_row(row, line, col, n_fields, where)
    table = np.zeros((len(rows), 3))
    for name, column in zip(numbers, values, strict=True):
        table[:, ("x", "y", "t").index(name)] = column
    return table, np.array(lines, dtype=np.int64), idents


def _refuse_csv_row(row: list[str], line: int, col: dict[str, int], n_fields: int,
                    where: str) -> None:
    """Refuse the CSV row at `line` for the first of its fields at fault, if any."""
    where = f"{where}, line {line}"
    if len(row) != n_fields:
        raise PipelineError(f"{where}: {len(row)} fields, the header has {n_fields}")
    for name in ("x", "y", "t"):
        _csv_number(row, col, name, where)
    for name in ("trajectory", "subject"):
        if name in col:
            ident = row[col[name]].strip()
            what = "trajectory id" if name == "trajectory" else "subject"
            if not ident:
                raise PipelineError(f"{where}: empty {what}: every row of a {name} column "
                                    "needs one (leave the column out if none is known)")
            refuse_unprintable(ident, f"{where}: {what}")


DECIMAL_CHARACTERS = frozenset("0123456789.+-eE")


def _plain_decimals(texts: list[str]) -> np.ndarray | None:
    """`texts` as finite numbers when each is a plain decimal number (CSV_NUMBER), else
    None. Of strings of these characters alone, float() reads just those (the words nan
    and inf, "_" and other digits need others), at a fraction of the cost of matching each."""
    if not DECIMAL_CHARACTERS.issuperset("".join(texts)):
        return None
    try:
        numbers = np.array(list(map(float, texts)), dtype=float)
    except ValueError:  # "1e", "--1", "", ...
        return None
    return numbers if np.isfinite(numbers).all() else None  # 1e999 is plain but infinite


def _csv_number(row: list[str], col: dict[str, int], name: str, where: str) -> float:
    """Column `name` of a CSV row as a finite number (0.0 where the file has no such column)."""
    if name not in col:
        return 0.0
    text = row[col[name]].strip()
    # a plain decimal number: Python's float() would also read "0_5" (as 5), full-width and
    # Arabic-Indic digits, "nan" and "infinity"
    if not CSV_NUMBER.fullmatch(text):
        if text.lower().lstrip("+-") in ("nan", "inf", "infinity"):
            raise PipelineError(f"{where}: {name}={text!r} is not finite")
        raise PipelineError(f"{where}: {name}={text[:40]!r} is not a number")
    v = float(text)
    if not math.isfinite(v):
        raise PipelineError(f"{where}: {name}={text!r} is not finite")
    return v


def _polyline_length(points: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())


class ClockOrder(NamedTuple):
    """How a track's poses are ordered (`clock_order`)."""
    order: np.ndarray  # indices of the poses, as given, in the order read
    stepped_back: str | None  # where the clock stepped back, the poses kept as given; else None
    why: str = ""  # what the step back looks like: set back, or jitter of under a time step


def clock_order(where: str, what: str, points: np.ndarray, times: np.ndarray,
                clock: str, as_given: str, place: Callable[[int], str], fix: str) -> ClockOrder:
    """The order of a track's poses by their clock (`points` and their `times`, as given;
    stable). Ordering must make the track more coherent, never less: poses exported or
    logged out of order fall into place. Where ordering makes the track longer than as given
    by more than T_ORDER_SLACK (and T_ORDER_SLACK_M), the order as given is the coherent one
    and is kept, and `stepped_back` says where the clock goes back furthest: the clock was
    set back mid-walk (1 s at walking pace interleaves 10 rows into a zig-zag that looked
    like two people under one id), or went back where tracking was lost. Refused instead:
    ordering that makes the track more than T_ORDER_GROWTH times longer where the clock goes
    back at a jump (`is_jump`; at any set-back or the largest step back; the set-backs at no
    jump moved on first, whose zig-zag is no restart's), or on a track too short to tell
    one: two recordings appended
    with clocks that both start at 0, one walk's end followed by the other's start, each
    read alone would be many times shorter. `place(k)` names the k-th pose."""
    order = np.argsort(times, kind="stable")
    as_filed, as_timed = _polyline_length(points), _polyline_length(points[order])
    if as_timed <= as_filed * (1 + T_ORDER_SLACK) + T_ORDER_SLACK_M:
        return ClockOrder(order, None)
    time_steps = np.diff(times)
    back = int(np.argmin(time_steps)) + 1  # the largest step back
    set_back, interval = _set_back_steps(time_steps)
    steps, usual = _steps_and_usual(points)
    # every set-back is judged, not the largest alone: a mid-walk set-back larger than an
    # appended recording's restart would otherwise let the recordings through; by the
    # length ordering gives with the set-backs at no jump moved on (`_moved_on`), so
    # that a step back where tracking was lost is not refused for a mid-walk one's zig-zag
    judged = np.union1d(np.flatnonzero(set_back) + 1, [back])
    at_jumps = [k for k in judged if usual is None or is_jump(float(steps[k - 1]), usual)]
    mid_walk = set_back.copy()
    mid_walk[np.array(at_jumps, dtype=int) - 1] = False
    as_jumped = _polyline_length(points[np.argsort(_moved_on(times, mid_walk, interval),
                                                   kind="stable")])
    if at_jumps and as_jumped > T_ORDER_GROWTH * as_filed + REPEAT_TOLERANCE:
        k = min(at_jumps, key=lambda k: time_steps[k - 1])  # the largest step back at a jump
        raise PipelineError(
            f"{where}: ordered by {clock}, {what} is {as_timed:.1f} m long against "
            f"{as_filed:.1f} m {as_given} ({clock} goes back from {times[k - 1]:.3f} to "
            f"{times[k]:.3f} at {place(k)}); are several recordings appended? {fix}")
    jitter = not set_back[back - 1]
    return ClockOrder(np.arange(len(times)), (
        f"{clock} goes back from {times[back - 1]:.3f} to {times[back]:.3f} at {place(back)} "
        f"({as_timed:.1f} m ordered by it, {as_filed:.1f} m {as_given})"),
        "its times jitter back by less than one time step" if jitter
        else "was the clock set back while recording?")


def _moved_on(times: np.ndarray, steps_moved: np.ndarray, usual: float | None = None
              ) -> np.ndarray:
    """The times with the steps back `steps_moved` (a bool per time step) moved on by their
    size and one usual interval (`usual` if given, else the times' own); the rest as given."""
    steps = np.diff(times)
    if usual is None:
        usual = _usual_interval(steps) or 0.0
    return np.concatenate([times[:1], times[1:] + np.cumsum(np.where(steps_moved,
                                                                     usual - steps, 0.0))])


def _usual_interval(steps: np.ndarray) -> float | None:
    """A track's usual time step: the median of its time steps that move on (None without
    any)."""
    forward = steps[steps > 0]
    return float(np.median(forward)) if len(forward) else None


def _set_back_steps(steps: np.ndarray, usual: float | None = None
                    ) -> tuple[np.ndarray, float]:
    """Which time steps set the clock back: back by more than a usual interval (a smaller step
    back is a stamp jittering against its neighbours); and that usual interval (`usual` if
    given, else the steps' own; 0 without)."""
    if usual is None:
        usual = _usual_interval(steps) or 0.0
    return steps < -usual, usual


def set_backs(times: np.ndarray, usual: float | None = None) -> int:
    """How many times the clock is set back (`_set_back_steps`)."""
    return int(np.count_nonzero(_set_back_steps(np.diff(times), usual)[0]))


def stepped_forward(times: np.ndarray, usual: float | None = None) -> np.ndarray:
    """Times in the order recorded that never go back: after each set back (`_set_back_steps`,
    `clock_order`) the rest moved on by its size and one usual interval (`usual` if given,
    else the times' own); a smaller step back (a stamp's jitter) held at the time before it,
    so that the times do not drift."""
    set_back, usual = _set_back_steps(np.diff(times), usual)
    return np.maximum.accumulate(_moved_on(times, set_back, usual))


def one_clock(table_times: np.ndarray, stepped_tracks: list[np.ndarray]) -> np.ndarray | None:
    """The times of a file's rows on one clock, where the tracks' clock was set back
    (`stepped_tracks`, their rows' times in file order): a tracker's clock is set back for
    every track at once, and the mending compares times across tracks, so the times after
    the step are moved on in every track alike. That needs the rows in the order recorded
    (by frame, or walk after walk): only where the file's times go back at no more places
    than those tracks' do (a file grouped by id goes back where each track begins) is it so;
    else None (each track is moved on alone). The usual interval is the tracks' (a frame's):
    the file's own steps are mostly the milliseconds between people's rows within a frame
    where a tracker stamps each row apart."""
    intervals = [i for t in stepped_tracks if (i := _usual_interval(np.diff(t))) is not None]
    usual = float(np.median(intervals)) if intervals else None
    if set_backs(table_times, usual) > sum(set_backs(t) for t in stepped_tracks):
        return None
    return stepped_forward(table_times, usual)


def _csv_recording(col: dict[str, int], table: np.ndarray, lines: np.ndarray, ids: list[str],
                   subjects: list[str], where: str, single_rows: bool = False) -> Recording:
    """Rows grouped into trajectories by id (a pose stream without ids), ordered by t if given
    (`clock_order`); a trajectory of one row refused unless `single_rows`."""
    # (what, where, why, rows) of the tracks whose clock stepped back, kept in file order
    stepped_back: list[tuple[str, str, str, np.ndarray]] = []

    def ordered(sel: np.ndarray, what: str) -> np.ndarray:
        if "t" not in col:
            return sel
        order, stepped, why = clock_order(
            where, what, table[sel, :2], table[sel, 2], "t", "in file order",
            lambda k: f"line {lines[sel[k]]}", "give each walk (from a start to the goal) its "
            "own id in a trajectory column, or leave out t and give the rows in recorded order")
        if stepped is not None:
            stepped_back.append((what, stepped, why, sel))
        return sel[order]

    def warn_stepped_back() -> None:
        if not stepped_back:
            return
        if "trajectory" not in col:
            [(what, stepped, why, _)] = stepped_back
        else:
            n = len(stepped_back)
            what = "1 trajectory" if n == 1 else f"{n} trajectories"
            stepped = listed([f"{w}: {s}" for w, s, _, _ in stepped_back], 3, "; ")
            whys = {y for _, _, y, _ in stepped_back}
            why = whys.pop() if len(whys) == 1 else "a clock set back, or jittering times?"
        log.warning("%s: ordered by t, %s would zig-zag back over %s own route: read in file "
                    "order (%s): %s", where, what,
                    "their" if len(stepped_back) > 1 else "its", why, stepped)

    if "trajectory" not in col:
        order = ordered(np.arange(len(table)), "the pose stream")
        warn_stepped_back()
        if len(order) < 2:
            raise PipelineError(f"{where} has 1 row; a pose stream needs at least two")
        stream_subjects: list[str | None] | None = \
            [subjects[k] for k in order] if subjects else None
        return Recording([table[order, :2]], True, stream_subjects)
    groups: dict[str, list[int]] = {}
    for k, ident in enumerate(ids):
        groups.setdefault(ident, []).append(k)
    rows_read: list[np.ndarray] = []
    track_subjects: list[str | None] = []
    for i, (ident, members) in enumerate(groups.items()):
        if len(members) < 2 and not single_rows:
            glimpses = sum(len(m) == 1 for m in groups.values())
            hint = "" if glimpses < 2 else \
                f"; {glimpses} trajectories have 1 row (a tracker's glimpses of people?): " \
                "expert.select_walks=true drops them and keeps the walks from a start to the goal"
            raise PipelineError(f"{where}: trajectory {i} (id {ident!r}) has 1 row; a trajectory "
                                f"needs at least two{hint}")
        rows_read.append(ordered(np.array(members), f"trajectory {i} (id {ident!r})"))
        if subjects:
            names_here = sorted({subjects[k] for k in members})
            if len(names_here) > 1:
                raise PipelineError(f"{where}: trajectory {i} (id {ident!r}) has rows of several "
                                    f"subjects: {', '.join(repr(n) for n in names_here[:3])}")
            track_subjects.append(names_here[0])
    warn_stepped_back()
    # the mending reads the times in pose order, and compares them across tracks
    clock = one_clock(table[:, 2], [table[sel, 2] for *_, sel in stepped_back]) \
        if stepped_back else None
    if clock is not None:  # the file in the order recorded: each track's rows too
        rows_read = [np.sort(sel) for sel in rows_read]
    times = [clock[sel] if clock is not None else stepped_forward(table[sel, 2])
             for sel in rows_read]
    tracks = [table[sel, :2] for sel in rows_read]
    return Recording(tracks, False, track_subjects if subjects else None, ids=list(groups),
                     times=times if "t" in col else None)


def _read_bag(path: Path, where: str, topic: str | None, frame: str | None) -> Recording:
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    # where reading got to, for the error: (message, step); None until the bag is open
    at: tuple[int, str] | None = None
    try:
        with AnyReader([path], default_typestore=get_typestore(Stores.LATEST)) as reader:
            topic, msgtype = _bag_topic(reader, where, topic)
            type_name = ros_type_name(msgtype, reader.is2)
            connections = [c for c in reader.connections if c.topic == topic]
            tracks: list[np.ndarray] = []
            stream: list[tuple[float, float]] = []
            stamps: list[float] = []  # each stream message's header.stamp (s)
            frames: dict[str, int] = {}  # frame_id -> first message with it
            too_short: list[int] = []  # Path messages with fewer than two poses
            count = 0
            at = (0, "read")
            for count, (conn, _, raw) in enumerate(reader.messages(connections=connections), 1):
                what = f"{where}: topic {topic} message {count - 1}"
                at = (count - 1, "decode")
                msg: Any = reader.deserialize(raw, conn.msgtype)
                at = (count - 1, "use")
                found = msg.header.frame_id
                # ROS 1's tf named frames with a leading slash ("/map"); tf2 drops it
                if frame is not None and found.lstrip("/") != frame.lstrip("/"):
                    raise PipelineError(f"{what} has frame_id {found!r}, not "
                                        f"expert.frame={frame!r}")
                frames.setdefault(found, count - 1)
                if msgtype == PATH_TYPE:
                    track = _path_track(msg, f"{where}: topic {topic} path message {count - 1}")
                    if len(track) < 2:  # a planner publishes an empty path when it has none
                        too_short.append(count - 1)
                    else:
                        tracks.append(track)
                else:
                    pos = STREAM_TYPES[msgtype](msg)
                    if not (math.isfinite(pos.x) and math.isfinite(pos.y)):
                        raise PipelineError(f"{what} has a non-finite position")
                    stream.append((pos.x, pos.y))
                    stamps.append(msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec)
                at = (count, "read")
    except PipelineError:
        raise
    except Exception as e:  # rosbags raises many kinds on malformed bags; report, never trace
        detail = str(e).splitlines()[0] if str(e) else type(e).__name__
        if at is not None:  # the bag opened; one message is damaged or of another type
            index, step = at
            failed = {"read": "cannot be read", "decode": f"cannot be decoded as {type_name}",
                      "use": f"({type_name}) is not as ROS defines it"}[step]
            raise PipelineError(f"{where}: topic {topic} message {index} {failed}: damaged, or "
                                f"its type is defined differently in the bag ({detail[:120]})") \
                from None
        raise PipelineError(f"{where} cannot be read as a ROS bag: its metadata or index is "
                            f"damaged or incomplete ({detail[:160]})") from None
    if count == 0:
        raise PipelineError(f"{where}: topic {topic} has no messages")
    if len(frames) == 1 and frame is None:  # taken to be the scene's frame: say which it is
        log.info("%s: topic %s, %d %s messages in frame_id %r, read as the scene's frame "
                 "(expert.frame=... checks it)", where, topic, count, type_name, *frames)
    if len(frames) > 1:
        log.warning("%s: topic %s mixes frame_ids %s (first in messages %s); positions are "
                    "read as they are, all in the scene's frame (expert.frame=... keeps one)",
                    where, topic, ", ".join(repr(f) for f in frames), list(frames.values()))
    if msgtype == PATH_TYPE:
        if too_short and not tracks:
            raise PipelineError(f"{where}: every path message of topic {topic} has fewer than "
                                f"two poses; a trajectory needs at least two")
        if too_short:
            log.warning("%s: skipped %d of %d path messages of topic %s with fewer than two "
                        "poses (messages %s)", where, len(too_short), count, topic,
                        too_short[:5])
        return Recording(tracks, False, planned=True)
    if len(stream) < 2:
        raise PipelineError(f"{where}: topic {topic} has 1 message; a pose stream needs at "
                            f"least two")
    poses = np.array(stream, dtype=float)
    # A bag lists messages as they arrived; over a network some arrive after later ones, and
    # in arrival order a walk zig-zags back and forth. Their header stamps (when every
    # message has one: 0 is "not set") say when each pose was taken.
    when = np.array(stamps)
    backwards = int(np.count_nonzero(np.diff(when) < 0))
    if (when > 0).all() and backwards:
        if backwards > (len(when) - 1) / 2:  # late arrivals are a few: this is the clock
            raise PipelineError(
                f"{where}: topic {topic}'s header.stamp goes back at {backwards} of "
                f"{len(when) - 1} steps in the order its messages were logged; is the "
                f"recording's clock wrong? (poses are read in header.stamp order)")
        order, stepped, why = clock_order(
            f"{where}: topic {topic}", "the pose stream", poses, when, "header.stamp",
            "in the order it was logged", lambda k: f"message {k}",
            "record each in a bag of its own")
        if stepped is not None:
            log.warning("%s: topic %s: %s; ordered by it the pose stream would zig-zag back "
                        "over its own route: read in the order logged (%s)", where, topic,
                        stepped, why)
        else:
            moved = int(np.count_nonzero(order != np.arange(len(order))))
            log.warning("%s: %d of %d messages of topic %s arrived out of the order of their "
                        "header.stamp; read in stamp order", where, moved, len(order), topic)
        poses = poses[order]
    return Recording([poses], True)


def ros_type_name(msgtype: str, ros2: bool) -> str:
    """A message type as the bag's ROS names it: rosbags names every type the ROS 2 way
    (`nav_msgs/msg/Path`), ROS 1 without `msg` (`nav_msgs/Path`)."""
    return msgtype if ros2 else msgtype.replace("/msg/", "/", 1)


def _bag_topic(reader: Any, where: str, topic: str | None) -> tuple[str, str]:
    """The topic to read (`topic`, or the bag's one topic of a supported type) and its type."""
    topics = {name: info.msgtype or "(several types)" for name, info in reader.topics.items()}
    listing = ", ".join(f"{n} ({ros_type_name(t, reader.is2)})"
                        for n, t in topics.items()) or "none"
    supported = ", ".join(ros_type_name(t, reader.is2) for t in SUPPORTED_TYPES)
    if topic is None:
        usable = [n for n, t in topics.items() if t in SUPPORTED_TYPES]
        if not usable:
            raise PipelineError(f"{where} has no topic of a supported type "
                                f"({supported}); its topics: {listing}")
        if len(usable) > 1:
            raise PipelineError(f"{where} has several usable topics: {', '.join(usable)}; "
                                f"choose one with expert.topic=...")
        topic = usable[0]
    if topic not in topics:
        raise PipelineError(f"{where} has no topic {topic!r} (expert.topic); its topics: "
                            f"{listing}")
    if topics[topic] not in SUPPORTED_TYPES:
        raise PipelineError(f"{where}: topic {topic} has type "
                            f"{ros_type_name(topics[topic], reader.is2)}; supported: {supported}")
    return topic, topics[topic]


def _path_track(msg: Any, what: str) -> np.ndarray:
    """A nav_msgs/Path message's positions (K, 2), all finite."""
    track = np.array([[p.pose.position.x, p.pose.position.y] for p in msg.poses],
                     dtype=float).reshape(-1, 2)
    if not np.isfinite(track).all():
        raise PipelineError(f"{what} has a non-finite position")
    return track


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


def noise_sigma(tracks: Sequence[np.ndarray]) -> float:
    """The standard deviation of the tracking noise on each coordinate of the points, estimated
    from all the tracks' second differences p[i-1] - 2 p[i] + p[i+1] (of independent noise
    their variance is 6 sigma^2; the median, scaled by 1.4826, ignores the few at sharp turns).
    0 when they are not noise: second differences over twice the span, p[i-2] - 2 p[i] +
    p[i+2], are as large as those of noise (the same variance) and NOISE_SPAN_RATIO times
    larger or more where they measure the route's turns (4 times for a smooth curve), as in
    a sparse polyline of a few corners; 0 without tracks of MIN_NOISE_POINTS points that are
    no planned polyline (`straight_share`, PLANNED_STRAIGHT_SHARE)."""
    dense = [t for t in tracks if len(t) >= MIN_NOISE_POINTS
             and straight_share(t) < PLANNED_STRAIGHT_SHARE]
    if not dense:
        return 0.0
    near = np.median(np.abs(np.concatenate([(t[2:] - 2 * t[1:-1] + t[:-2]).ravel()
                                            for t in dense])))
    wide = np.median(np.abs(np.concatenate([(t[4:] - 2 * t[2:-2] + t[:-4]).ravel()
                                            for t in dense])))
    if not near > 0 or wide > NOISE_SPAN_RATIO * near:
        return 0.0
    return float(1.4826 * near / math.sqrt(6.0))


def straight_share(track: np.ndarray) -> float:
    """The share of the interior points of `track` (n, 2) that lie on the straight line
    through their neighbours: |sin| of the turn there below STRAIGHT_SINE."""
    a, b = track[1:-1] - track[:-2], track[2:] - track[1:-1]
    if not len(a):
        return 0.0
    cross = np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    return float(np.mean(cross <= STRAIGHT_SINE * np.linalg.norm(a, axis=1)
                         * np.linalg.norm(b, axis=1)))


def _steps_and_usual(track: np.ndarray) -> tuple[np.ndarray, float | None]:
    """A trajectory's steps and its usual step (the 75th percentile of those that move; None
    with fewer than three or a step that is not finite)."""
    with np.errstate(over="ignore", invalid="ignore"):
        steps = np.linalg.norm(np.diff(track, axis=0), axis=1)
    moving = steps[steps >= REPEAT_TOLERANCE]
    if len(moving) < 3 or not np.isfinite(moving).all():
        return steps, None
    return steps, float(np.percentile(moving, 75))


def is_jump(step: float, usual: float) -> bool:
    """Whether a step is a jump (see JUMP_STEPS) on a trajectory of this usual step."""
    return step > max(JUMP_MIN, JUMP_STEPS * usual)


def largest_jump(track: np.ndarray) -> tuple[int, float, float] | None:
    """The largest jump of a trajectory (see JUMP_STEPS) as (i, its length, the usual step):
    poses i and i + 1 are that far apart; None without one or with fewer than three steps."""
    steps, usual = _steps_and_usual(track)
    if usual is None:
        return None
    i = int(np.argmax(steps))
    return (i, float(steps[i]), usual) if is_jump(float(steps[i]), usual) else None


def label(labels: Sequence[str] | None, k: int) -> str:
    """Trajectory k's name in messages: its number in the file, or `labels[k]` (a walk
    `expert.select_walks` cut from a trajectory is named by that trajectory's number)."""
    return labels[k] if labels is not None else str(k)


def warn_jumps(tracks: Sequence[np.ndarray], where: str,
               offsets: Sequence[int] | None = None,
               labels: Sequence[str] | None = None) -> None:
    """One warning naming the trajectories with a jump (`largest_jump`), at their pose numbers
    in the file (`offsets`: where each begins in a pose stream). They are kept, the jump a
    straight segment: a polyline may be drawn with long straight segments, and a short loss
    of tracking is bridged well enough by one; a long one the user should see."""
    found = []
    for k, track in enumerate(tracks):
        jump = largest_jump(track)
        if jump is not None:
            i, size, usual = jump
            i += offsets[k] if offsets is not None else 0
            found.append(f"{label(labels, k)} ({size:.2f} m from pose {i} to {i + 1}, "
                         f"usually {usual:.2f} m)")
    if found:
        log.warning("%s: %d of %d trajectories jump, each kept with a straight segment there "
                    "(was tracking lost?): %s", where, len(found), len(tracks),
                    listed(found, 3, "; "))


def revisit(track: np.ndarray) -> tuple[np.ndarray, float] | None:
    """Where a trajectory comes back to its own route: the first point (on the polyline,
    sampled every REVISIT_STEP) within REVISIT_RADIUS of a point more than REVISIT_ARC metres
    of walking earlier, with that walk; None when it never does (a loop, a walk out and
    back, a U-turn do)."""
    with np.errstate(over="ignore", invalid="ignore"):  # a glitch at 1e300 m: no length
        if not np.isfinite(_polyline_length(np.asarray(track, float).reshape(-1, 2))):
            return None
    p = clean_track(track, REVISIT_STEP)
    if len(p) < 3:
        return None
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    pairs = cKDTree(p).query_pairs(REVISIT_RADIUS, output_type="ndarray")
    if len(pairs) == 0:
        return None
    walked = np.abs(arc[pairs[:, 1]] - arc[pairs[:, 0]])
    far = walked > REVISIT_ARC
    if not far.any():
        return None
    later = pairs[far].max(axis=1)
    k = int(np.argmin(later))
    return p[later[k]], float(walked[far][k])


def _first_at_goal(track: np.ndarray, goal: np.ndarray, goal_tolerance: float) -> int:
    """The index of the first pose of `track` within `goal_tolerance` of `goal` (its last
    index when none is)."""
    with np.errstate(over="ignore", invalid="ignore"):
        at = np.flatnonzero(in_goal_disk(track, goal, goal_tolerance))
    return int(at[0]) if len(at) else len(track) - 1


def warn_repeated_walks(tracks: Sequence[np.ndarray], starts: np.ndarray, goal: np.ndarray,
                        start_radius: float, goal_tolerance: float, where: str) -> None:
    """One warning naming the trajectories that walk from a start to the goal more than once
    (`stream_spans`): one id given to several walks (two sessions' ids 0, 1, ... in one
    file), of which every trajectory's cut at the goal keeps only the first."""
    found = []
    for k, track in enumerate(tracks):
        with np.errstate(over="ignore", invalid="ignore"):
            walks = len(stream_spans(track, starts, goal, start_radius, goal_tolerance))
        if walks > 1:
            found.append(f"{k} ({walks} walks)")
    if found:
        log.warning("%s: %d of %d trajectories go from a start to the goal more than once "
                    "(one trajectory id for several walks, e.g. one id per recording or two "
                    "sessions' ids in one file?): trajectories %s, numbered from 0 in file "
                    "order; each is cut at its first arrival, so only its first walk is "
                    "learned from: give every walk its own id, or learn from every walk with "
                    "expert.select_walks=true", where, len(found), len(tracks),
                    listed(found, 5))


def track_name(k: int | Sequence[int], ids: Sequence[str] | None,
               walk: int | None = None) -> str:
    """Track k's name in messages: its number in the file, "/2" for its second walk (cut
    by `select_track_walks`), and its id in the file where `ids` gives them (what a user
    finds there). A track joined from several (`broken_track_chains`) is named by all of
    theirs: "12+31 (ids '112', '140')"."""
    chain = [k] if isinstance(k, int) else list(k)
    number = "+".join(map(str, chain)) + ("" if walk is None else f"/{walk}")
    if ids is None:
        return number
    return f"{number} (id{'s' if len(chain) > 1 else ''} " \
           f"{', '.join(repr(ids[i]) for i in chain)})"


def _motion(points: np.ndarray, times: np.ndarray, at_end: bool) -> np.ndarray:
    """A track's velocity over its last (`at_end`) or first MOTION_WINDOW seconds; zero
    where those hold a single time."""
    if at_end:
        a, b = int(np.argmax(times >= times[-1] - MOTION_WINDOW)), len(times) - 1
    else:
        a, b = 0, int(np.flatnonzero(times <= times[0] + MOTION_WINDOW)[-1])
    dt = times[b] - times[a]
    return (points[b] - points[a]) / dt if dt > 0 else np.zeros(2)


def broken_track_chains(tracks: Sequence[np.ndarray], times: Sequence[np.ndarray],
                        subjects: Sequence[str | None] | None) -> tuple[list[list[int]], int]:
    """The tracks that continue one another, as chains of track numbers (every track is in
    one chain, and the chains are in the order of their first tracks), and how many tracks
    are left apart from a continuation for its rivals. Track j continues track i when j
    begins within REJOIN_GAP seconds (and a stamp's jitter: SAME_TIME of a frame) after i
    ends, within REJOIN_REACH + REJOIN_SPREAD per second of the gap of where i's end, moved
    on at its final velocity, would be; when the two do not head apart by more than 90
    degrees (both moving); and when they have the same subject. Only an unambiguous pair is
    joined: no other track comes within AMBIGUITY times those limits of continuing i, and i
    is the only track j comes that close to continuing, apart from the tracks that would
    continue j or be continued by i in turn (the same person lost again). A guess could
    make one walk of two people."""
    n = len(tracks)
    ends = np.array([t[-1] for t in times], dtype=float)
    begins = np.array([t[0] for t in times], dtype=float)
    end_at = np.array([p[-1] for p in tracks], dtype=float).reshape(-1, 2)
    begin_at = np.array([p[0] for p in tracks], dtype=float).reshape(-1, 2)
    by_begin = np.argsort(begins, kind="stable")
    sorted_begins = begins[by_begin]
    velocity_out = np.array([_motion(p, t, at_end=True) for p, t in zip(tracks, times,
                                                                         strict=True)])
    velocity_in = np.array([_motion(p, t, at_end=False) for p, t in zip(tracks, times,
                                                                         strict=True)])
    moving_in = np.linalg.norm(velocity_in.reshape(-1, 2), axis=1) >= MOVING
    who = np.array(subjects, dtype=object) if subjects is not None else None
    # a gap of whole frames at the limit is within it, whatever its stamps' jitter (4 frames
    # lost at 2.5 Hz: 2.002 s)
    gap_limit = REJOIN_GAP + SAME_TIME * _tracks_frame_interval(times)
    pairs, within_limits = [], []  # pairs within AMBIGUITY times the limits; within them
    for i in range(n):
        lo, hi = np.searchsorted(sorted_begins, [ends[i], ends[i] + AMBIGUITY * gap_limit],
                                 side="right")  # begins after i's end
        js = by_begin[lo:hi]
        gap = begins[js] - ends[i]
        heading_for = end_at[i] + velocity_out[i] * gap[:, None]
        miss = np.linalg.norm(begin_at[js] - heading_for, axis=1) / (REJOIN_REACH
                                                                     + REJOIN_SPREAD * gap)
        turned = (np.linalg.norm(velocity_out[i]) >= MOVING) & moving_in[js] & \
            (velocity_in[js] @ velocity_out[i] < 0)
        kept = (miss <= AMBIGUITY) & ~turned
        if who is not None:
            kept &= who[js] == who[i]
        pairs += [(i, int(j)) for j in js[kept]]
        within_limits += list((miss[kept] <= 1.0) & (gap[kept] <= gap_limit))
    # a rival of pair (i, j): another track that could continue i, or be continued by j,
    # except the piece that follows j or precedes i (one person lost twice in a row)
    candidates = set(pairs)
    successors: dict[int, set[int]] = {}
    predecessors: dict[int, set[int]] = {}
    for i, j in pairs:
        successors.setdefault(i, set()).add(j)
        predecessors.setdefault(j, set()).add(i)
    after = {i: j for (i, j), close in zip(pairs, within_limits, strict=True)
             if close and all((j, k) in candidates for k in successors[i] - {j})
             and all((h, i) in candidates for h in predecessors[j] - {i})}
    continuing = set(after.values())
    chains = []
    for i in range(n):
        if i not in continuing:
            chains.append([i])
            while chains[-1][-1] in after:
                chains[-1].append(after[chains[-1][-1]])
    ambiguous = {i for (i, _), close in zip(pairs, within_limits, strict=True) if close} \
        - set(after)
    return chains, len(ambiguous)


def join_chain(tracks: Sequence[np.ndarray], times: Sequence[np.ndarray],
               chain: Sequence[int]) -> np.ndarray:
    """The chain's tracks as one track, each gap bridged by poses on the straight line across
    it at the first track's usual interval (no jump for `warn_jumps`: the join is reported
    where it is made)."""
    parts = [tracks[chain[0]]]
    for i, j in itertools.pairwise(chain):
        a, b, e, s = tracks[i][-1], tracks[j][0], times[i][-1], times[j][0]
        interval = _usual_interval(np.diff(times[i])) or s - e
        # not within half an interval of the next track's first pose: no near-repeat
        share = np.arange(interval, s - e - interval / 2, interval)[:, None] / (s - e)
        parts += [a + share * (b - a), tracks[j]]
    return np.vstack(parts)


def _headings(points: np.ndarray, i: int) -> tuple[np.ndarray | None, np.ndarray | None]:
    """A track's heading (a unit vector) into pose i - 1 and out of pose i: along its last
    HEADING_REACH of motion before, and its first after (standing still in between says
    nothing of where a person goes); None where the track never moves that far."""
    def along(ahead: np.ndarray, at: np.ndarray) -> np.ndarray | None:
        far = np.flatnonzero(np.linalg.norm(ahead - at, axis=1) >= HEADING_REACH)
        if not len(far):
            return None
        step = ahead[far[0]] - at
        return step / np.linalg.norm(step)
    into = along(points[:i][::-1], points[i - 1]) if i >= 1 else None
    return (None if into is None else -into), along(points[i:], points[i])


def _predicted(points: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Where each pose of a track would be, moved on from the pose before at the velocity of
    the MOTION_WINDOW seconds before that; where it is, where those hold one time (the first
    two poses): no motion is known to predict from, so no jump is seen."""
    prev = np.arange(len(points) - 1)
    first = np.searchsorted(times, times[prev] - MOTION_WINDOW, side="left")
    dt = (times[prev] - times[first])[:, None]
    velocity = np.divide(points[prev] - points[first], dt, out=np.zeros((len(prev), 2)),
                         where=dt > 0)
    moved_on = points[prev] + velocity * (times[1:] - times[prev])[:, None]
    return np.vstack([points[:1], np.where(dt > 0, moved_on, points[1:])])


def _each_walks_on_its_own_way(a: tuple[np.ndarray | None, np.ndarray | None],
                               b: tuple[np.ndarray | None, np.ndarray | None]) -> bool:
    """Whether each of two tracks, given as its heading into a jump and out of it
    (`_headings`), goes on the way it was going more nearly (by SWITCH_HEADING_MARGIN) than
    the way the other was: two people who meet head-on, stop and walk on (at 2.5 Hz a
    frame's stop misses a prediction by half a metre, where the other's predicted it)
    swapped no ids, however long they stood. Both must: in a crowd, one person turning as
    the ids switch is common. Unknown without all four headings."""
    (into_a, out_a), (into_b, out_b) = a, b
    if into_a is None or into_b is None or out_a is None or out_b is None:
        return False
    return all(np.linalg.norm(out - own) + SWITCH_HEADING_MARGIN < np.linalg.norm(out - other)
               for out, own, other in ((out_a, into_a, into_b), (out_b, into_b, into_a)))


def id_switches(tracks: Sequence[np.ndarray], times: Sequence[np.ndarray],
                subjects: Sequence[str | None] | None) -> list[tuple[float, int, int]]:
    """The id switches of a tracker's tracks, as (time, a, b): from that time on, track a
    follows whom b followed before and b whom a did. At that time both jump SWITCH_MISS or
    more from where their motion predicted (`_predicted`; more on noisier tracks:
    SWITCH_NOISES times what their noise misses by), each to within that of the other's
    prediction, and do not each go on their own way (`_each_walks_on_its_own_way`); no
    third track does so with either, and the two have the same subject. One time: stamps
    within SAME_TIME of a frame interval (a tracker that stamps each person's row a few
    milliseconds apart); tracks that jump frames apart are never taken for a switch. The
    time given is the earlier of the two jumps'."""
    # noise misses a prediction by sqrt(2) sigma on each coordinate: a jump is well above it
    miss_limit = max(SWITCH_MISS, SWITCH_NOISES * math.sqrt(2.0) * noise_sigma(tracks))
    jumps = []  # (time, track, pose, predicted, (heading into it, heading out))
    for k, (points, ts) in enumerate(zip(tracks, times, strict=True)):
        predicted = _predicted(points, ts)
        for i in np.flatnonzero(np.linalg.norm(points - predicted, axis=1) > miss_limit):
            jumps.append((float(ts[i]), k, int(i), predicted[i], _headings(points, int(i))))
    frame = _tracks_frame_interval(times)
    jumps.sort(key=lambda jump: (jump[0], jump[1]))
    at = np.array([jump[0] for jump in jumps])
    cuts = [0, *(np.flatnonzero(np.diff(at) > SAME_TIME * frame) + 1), len(jumps)]
    moments = [jumps[a:b] for a, b in itertools.pairwise(cuts)]
    switches = []
    for jumped in moments:
        pairs = [(min(ta, tb), min(a, b), max(a, b))
                 for (ta, a, i, pa, ha), (tb, b, j, pb, hb) in itertools.combinations(jumped, 2)
                 if a != b and max(np.linalg.norm(tracks[a][i] - pb),
                                   np.linalg.norm(tracks[b][j] - pa)) <= miss_limit
                 and (subjects is None or subjects[a] == subjects[b])
                 and not _each_walks_on_its_own_way(ha, hb)]
        partners = np.bincount([k for _, a, b in pairs for k in (a, b)], minlength=len(tracks))
        switches += [(t, a, b) for t, a, b in pairs if partners[a] == partners[b] == 1]
    return sorted(switches)


def undo_switches(tracks: Sequence[np.ndarray], times: Sequence[np.ndarray],
                  switches: Sequence[tuple[float, int, int]]
                  ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The tracks (and times) with each switch's tails exchanged back. The latest first: an
    earlier exchange then carries the later ones' corrected tails along with its own."""
    tracks, times = list(tracks), list(times)
    for t, a, b in sorted(switches, reverse=True):
        i, j = np.searchsorted(times[a], t), np.searchsorted(times[b], t)
        tracks[a], tracks[b] = (np.vstack([tracks[a][:i], tracks[b][j:]]),
                                np.vstack([tracks[b][:j], tracks[a][i:]]))
        times[a], times[b] = (np.concatenate([times[a][:i], times[b][j:]]),
                              np.concatenate([times[b][:j], times[a][i:]]))
    return tracks, times


def _tracks_frame_interval(times: Sequence[np.ndarray]) -> float:
    """The tracker's frame interval (`_frame_interval`) from the time steps of all its tracks."""
    return _frame_interval(np.concatenate([np.diff(t) for t in times] + [np.zeros(0)]))


def _frame_interval(steps: np.ndarray) -> float:
    """A tracker's frame interval from its time steps: their 75th percentile of those above
    0 (0 without any), which rows stamped milliseconds apart within a frame do not lower."""
    return float(np.percentile(steps[steps > 0], 75)) if (steps > 0).any() else 0.0


def _same_time(ts: np.ndarray) -> np.ndarray:
    """Each row's group of rows at one time (ids 0, 1, ... in order): times closer than
    SAME_TIME of the track's frame interval (`_frame_interval`) are one (a tracker that
    stamps each person's row a few milliseconds apart within one frame)."""
    steps = np.diff(ts)
    return np.r_[0, np.cumsum(steps > SAME_TIME * _frame_interval(steps))]


def _nearest(rows: np.ndarray, to: np.ndarray) -> np.ndarray:
    return rows[int(np.argmin(np.linalg.norm(rows - to, axis=1)))]


def drop_shared_times(tracks: Sequence[np.ndarray], times: Sequence[np.ndarray]
                      ) -> tuple[list[np.ndarray], list[np.ndarray], dict[int, np.ndarray]]:
    """The tracks (and times) with one row at each time (`_same_time`). Rows at one time
    within BODIES_APART of the first are one person measured twice (logged twice, rounded,
    two sensors fused): their mean is kept. Rows farther apart are two people under one id
    (a tracker that gave two friends one id for a while): the track keeps the row nearest
    its pose at the time before (at times before any of one person, the time after; where
    every time holds two people, it follows the first row's). Returns the tracks, times
    and, by track, its times of two people; a track of fewer than two times (a t column
    that is no clock) is kept whole."""
    tracks, times = list(tracks), list(times)
    two_people = {}
    for k, (points, ts) in enumerate(zip(tracks, times, strict=True)):
        group = _same_time(ts)
        if group[-1] + 1 == len(ts) or group[-1] == 0:
            continue
        bounds = np.flatnonzero(np.r_[True, np.diff(group) > 0, True])
        rows = [points[a:b] for a, b in itertools.pairwise(bounds)]
        one = [np.linalg.norm(r - r[0], axis=1).max() < BODIES_APART for r in rows]
        kept: list[np.ndarray | None] = [r.mean(axis=0) if o else None
                                         for r, o in zip(rows, one, strict=True)]
        first = next((g for g, o in enumerate(one) if o), 0)
        kept[first] = kept[first] if one[first] else rows[first][0]
        for g in range(first + 1, len(rows)):
            kept[g] = kept[g] if one[g] else _nearest(rows[g], kept[g - 1])
        for g in range(first - 1, -1, -1):
            kept[g] = _nearest(rows[g], kept[g + 1])
        tracks[k], times[k] = np.array(kept, dtype=float), ts[bounds[:-1]]
        if not all(one):
            two_people[k] = ts[bounds[:-1]][~np.array(one)]
    return tracks, times, two_people


def walking_speed(tracks: Sequence[np.ndarray], times: Sequence[np.ndarray]) -> float:
    """The median over the tracks that end WALKED_AT_LEAST metres from where they began of
    that distance over their duration, in metres per unit of t (NaN where none does). Not
    their length: a 100 Hz tracker's 4 cm of noise made people walk 7 m/s."""
    speeds = [float(np.linalg.norm(p[-1] - p[0])) / (t[-1] - t[0])
              for p, t in zip(tracks, times, strict=True)
              if t[-1] > t[0] and np.linalg.norm(p[-1] - p[0]) >= WALKED_AT_LEAST]
    return float(np.median(speeds)) if speeds else math.nan


def mend_tracks(recording: Recording, where: str
                ) -> tuple[list[np.ndarray], list[str | None] | None, list[list[int]]]:
    """A tracker's tracks mended where a CSV's t column gives their times (without them
    every track stays as it is): rows of a second person under its id dropped
    (`drop_shared_times`), id switches undone (`id_switches`), then the tracks lost
    and found again under a new id joined (`broken_track_chains`). Returns the tracks, their
    subjects and the chain of file tracks each is made of; one line names each kind of
    mending."""
    tracks, subjects = recording.tracks, recording.subjects
    alone = [[k] for k in range(len(tracks))]  # each track its own chain
    if recording.times is None:
        return list(tracks), subjects, alone
    tracks, times, shared = drop_shared_times(tracks, recording.times)
    if shared:
        log.warning("%s: expert.select_walks: trajectories with rows at one time %g m or more "
                    "apart (two people under one id?) keep, at those times, the row that "
                    "continues their own (%d): %s", where, BODIES_APART, len(shared),
                    listed([f"{track_name(k, recording.ids)} ({len(v)} times from t={v[0]:.3f})"
                            for k, v in shared.items()], 5, "; "))
    speed = walking_speed(tracks, times)
    if not math.isnan(speed) and not WALKING_SPEEDS[0] <= speed <= WALKING_SPEEDS[1]:
        log.warning("%s: expert.select_walks: the tracks that move go %.3g m per unit of t "
                    "(the median), where people walk %g-%g m/s: is t in frames or "
                    "milliseconds? The tracks are not mended (broken tracks joined, id "
                    "switches undone) until t is in seconds", where, speed, *WALKING_SPEEDS)
        return tracks, subjects, alone
    switches = id_switches(tracks, times, subjects)
    if switches:
        log.warning("%s: expert.select_walks: pairs of tracks that exchange whom they follow "
                    "(an id switch: at one time each jumps to where the other was heading) are "
                    "exchanged back from then on (%d): %s", where, len(switches),
                    listed([f"{track_name([a, b], recording.ids).replace('+', ' and ')} at "
                            f"t={t:.3f}" for t, a, b in switches], 5, "; "))
    tracks, times = undo_switches(tracks, times, switches)
    chains, ambiguous = broken_track_chains(tracks, times, subjects)
    joined = [c for c in chains if len(c) > 1]
    apart = f"{ambiguous} broken tracks left apart: more than one track could continue " \
        "each" if ambiguous else ""
    if joined:
        log.warning("%s: expert.select_walks: %d tracks lost and found again under a new id "
                    "are joined into %d (each began within %g s of one ending, where that one "
                    "was heading, and no other did): %s%s", where,
                    sum(map(len, joined)), len(joined), REJOIN_GAP,
                    listed([track_name(c, recording.ids) for c in joined], 5),
                    f"; {apart}" if apart else "")
    elif apart:
        log.warning("%s: expert.select_walks: %s", where, apart)
    return ([join_chain(tracks, times, c) for c in chains],
            None if subjects is None else [subjects[c[0]] for c in chains], chains)


def select_track_walks(tracks: Sequence[np.ndarray], subjects: Sequence[str | None] | None,
                       starts: np.ndarray, goal: np.ndarray, start_radius: float,
                       goal_tolerance: float, where: str, room: Room | None = None,
                       ids: Sequence[str] | None = None,
                       chains: Sequence[Sequence[int]] | None = None
                       ) -> tuple[list[np.ndarray], list[str | None], list[str], list[int]]:
    """The walks from a start to the goal in each track, cut as a pose stream is
    (`stream_spans`): their polylines, subjects (their track's), labels (their track's
    number in file order, "/2" for its second walk, ..., and its id in the file where
    `ids` gives them: what a user finds in their file) and first poses' numbers in their
    track. A tracker follows everyone in view, and only some go from a start to the
    goal (others go elsewhere, come into view mid-room or are lost and found again under a
    new id). One warning counts the tracks that hold no such walk and names the ones that
    hold several; none in any track is refused."""
    walks: list[np.ndarray] = []
    walk_subjects: list[str | None] = []
    labels: list[str] = []
    offsets: list[int] = []
    without: list[str] = []
    several: list[tuple[str, int]] = []  # (track, its walks)
    near_misses: list[tuple[str, float]] = []  # (track, its closest approach to the goal)
    from_afar: list[tuple[str, float]] = []  # (track, its closest approach to a start)
    chains = chains if chains is not None else [[k] for k in range(len(tracks))]
    in_file, with_walks = sum(map(len, chains)), 0  # trajectories in the file
    for k, track in enumerate(tracks):
        with np.errstate(over="ignore", invalid="ignore"):
            spans = stream_spans(track, starts, goal, start_radius, goal_tolerance)
        walks += [track[b:g + 1] for b, g in spans]
        walk_subjects += [subjects[k] if subjects else None] * len(spans)
        labels += [track_name(chains[k], ids)] if len(spans) == 1 else \
            [track_name(chains[k], ids, j + 1) for j in range(len(spans))]
        offsets += [b for b, _ in spans]
        with_walks += len(chains[k]) if spans else 0
        if not spans:
            without.append(track_name(chains[k], ids))
            with np.errstate(over="ignore", invalid="ignore"):
                to_start = np.linalg.norm(track[:, None, :] - np.reshape(starts, (1, -1, 2)),
                                          axis=2).min(axis=1, initial=math.inf)
            closest = _closest_after_a_start(track, to_start, goal, start_radius)
            if closest <= NEAR_MISS * goal_tolerance:
                near_misses.append((track_name(chains[k], ids), closest))
            arrival = np.flatnonzero(in_goal_disk(track, goal, goal_tolerance))
            if len(arrival) and arrival[0] > 0:  # came to the goal from no start
                from_afar.append((track_name(chains[k], ids),
                                  float(to_start[:arrival[0] + 1].min())))
        elif len(spans) > 1:
            several.append((track_name(chains[k], None), len(spans)))
    if not walks:
        raise no_walk_found(where, tracks, room, start_radius, goal_tolerance)
    if without or several:
        log.warning("%s: expert.select_walks: %d walks from a start to the goal read from %d "
                    "of %d trajectories (numbered from 0 in file order; a walk is named by "
                    "its trajectory's number)%s%s", where,
                    len(walks), with_walks, in_file,
                    f"; {len(without)} hold none and are dropped: {listed(without, 8)}"
                    if without else "",
                    f"; several in {listed([f'{k} ({n} walks)' for k, n in several], 5)}, whose "
                    f"walks are named {several[0][0]}/1, {several[0][0]}/2, ..."
                    if several else "")
    if near_misses:
        wider = math.ceil(max(d for _, d in near_misses) * 20 - 1e-9) / 20  # up to 5 cm
        log.warning("%s: expert.select_walks: trajectories that set off from a start and pass "
                    "%s m from the goal, never into its disk of %g m (scene.goal_tolerance), "
                    "hold no walk (%d; walks read: %d; scene.goal_tolerance=%g takes them "
                    "in): %s", where, _metres_range([d for _, d in near_misses]), goal_tolerance,
                    len(near_misses), len(walks), wider,
                    listed([n for n, _ in near_misses], 5))
    if from_afar:
        log.warning("%s: expert.select_walks: trajectories that reach the goal but come no "
                    "nearer a start than %s m (expert.start_radius=%g), so hold no walk "
                    "(%d): %s; came into view mid-room, or from where the scene has no "
                    "start?", where, _metres_range([d for _, d in from_afar]), start_radius,
                    len(from_afar), listed([n for n, _ in from_afar], 5))
    return walks, walk_subjects, labels, offsets


def _metres_range(values: Sequence[float]) -> str:
    """'0.32-0.36' (or '0.35' where they round alike), for a warning's "… m"."""
    lo, hi = (f"{f(values):.2f}" for f in (min, max))
    return lo if lo == hi else f"{lo}-{hi}"


def _closest_after_a_start(track: np.ndarray, to_start: np.ndarray, goal: np.ndarray,
                           start_radius: float) -> float:
    """How close a track comes to the goal after it is first near a start (inf if never);
    `to_start`: each pose's distance to its nearest start."""
    with np.errstate(over="ignore", invalid="ignore"):
        near = to_start <= start_radius
        if not near.any():
            return math.inf
        return float(np.nanmin(np.linalg.norm(track[int(np.argmax(near)):] - goal, axis=1),
                               initial=math.inf))


def no_walk_found(where: str, tracks: Sequence[np.ndarray], room: Room | None,
                  start_radius: float, goal_tolerance: float) -> PipelineError:
    """The error for a recording whose tracks hold no walk from a start to the goal, with
    the extent of their poses (and a hint at another frame when none is in `room`, at x and
    y swapped when only that puts them in it, SWAPPED_INSIDE)."""
    poses = np.vstack(tracks)
    with np.errstate(invalid="ignore"):
        lo, hi = np.nanmin(poses, axis=0), np.nanmax(poses, axis=0)
    span = f"x {metres(lo[0])}..{metres(hi[0])}, y {metres(lo[1])}..{metres(hi[1])}"
    outside = ""
    inside = room.contains(poses) if room is not None else None
    if room is not None and not inside.any():
        outside = f", all outside the room {room.describe()}: recorded in another frame, " \
            "with another origin or in other units than the scene's (metres)?"
    elif room is not None and inside.mean() < SWAPPED_INSIDE[0] and \
            room.contains(poses[:, ::-1]).mean() >= SWAPPED_INSIDE[1]:
        outside = f", some outside the room {room.describe()}, which would hold them " \
            "with x and y exchanged: are the columns swapped?"
    of = "" if len(tracks) == 1 else f" of {len(tracks)} trajectories"
    return PipelineError(
        f"{where}: found no trajectory from a start (within {start_radius:g} m, "
        f"expert.start_radius) to the goal (within {goal_tolerance:g} m) in the "
        f"{len(poses)} poses{of} read ({span}{outside})")


def without_walks_hint(tracks: Sequence[np.ndarray], starts: np.ndarray, goal: np.ndarray,
                       start_radius: float, goal_tolerance: float, planned: bool = False) -> str:
    """What to add to a refused trajectory's line when other trajectories too go from no
    start to the goal: for a tracker's tracks the option that keeps only the walks, for a
    planner's paths (`planned`: its replans, which that option would keep several of per
    walk) the robot's pose to record instead."""
    with np.errstate(over="ignore", invalid="ignore"):
        without = sum(not stream_spans(t, starts, goal, start_radius, goal_tolerance)
                      for t in tracks)
    if without < 2 or without == len(tracks):  # none holds a walk: selecting cannot help
        return ""
    if planned:
        return (f"; {without} of {len(tracks)} paths hold no walk from a start to the goal (a "
                "planner's replans, a robot's /plan topic?): record the robot's pose instead "
                "(Odometry, PoseWithCovarianceStamped)")
    return (f"; {without} of {len(tracks)} trajectories hold no walk from a start to the goal "
            "(a tracker's tracks of everyone in view?): expert.select_walks=true learns from "
            "the walks alone")


def warn_revisits(tracks: Sequence[np.ndarray], where: str,
                  labels: Sequence[str] | None = None) -> None:
    """One warning naming the trajectories that come back to their own route (`revisit`):
    learned as they are, a loop reads as a longer, more winding walk."""
    found = []
    for k, track in enumerate(tracks):
        hit = revisit(track)
        if hit is not None:
            found.append(f"{label(labels, k)} (back at {point(*hit[0])} after {hit[1]:.1f} m)")
    if found:
        log.warning("%s: %d of %d trajectories come back to their own route (a loop, a walk out "
                    "and back): %s; they are learned as they are, so cut out what is not part "
                    "of the walk to the goal", where, len(found), len(tracks),
                    listed(found, 3, "; "))


def warn_replans(tracks: Sequence[np.ndarray], where: str,
                 labels: Sequence[str] | None = None) -> None:
    """One warning naming the trajectories that begin on the route of the one before them,
    some way along it (REPLAN_RADIUS, REPLAN_ARC): a planner's replans, each of which would
    be learned from as a walk of its own, so that one route counts several times."""
    found = []
    for k in range(1, len(tracks)):
        route = clean_track(tracks[k - 1], REVISIT_STEP)
        if len(route) < 2 or not np.isfinite(route).all() or not np.isfinite(tracks[k][0]).all():
            continue
        gaps = np.linalg.norm(route - tracks[k][0], axis=1)
        i = int(np.argmin(gaps))
        if gaps[i] <= REPLAN_RADIUS and i * REVISIT_STEP > REPLAN_ARC:
            found.append(f"{label(labels, k)} ({i * REVISIT_STEP:.1f} m along "
                         f"{label(labels, k - 1)}'s route)")
    if found:
        log.warning("%s: %d of %d trajectories begin on the route of the one before them, some "
                    "way along it: %s; are they a planner's replans (a robot's /plan topic)? "
                    "Each is learned from as a walk of its own, so one route counts several "
                    "times: record the robot's pose instead (Odometry, "
                    "PoseWithCovarianceStamped)", where, len(found), len(tracks),
                    listed(found, 3, "; "))


def whittaker(points: np.ndarray, penalty: float) -> np.ndarray:
    """The Whittaker smoother (Eilers 2003) of a polyline (n, 2), n >= 4, its ends held: z
    with z's first and last points the polyline's, the others minimising
    |points - z|^2 + penalty |D z|^2 (D the second differences) given them, one banded
    solve. (Not the free solution with its ends overwritten: at a large penalty that is a
    straight line near each end, which a walk setting off from rest leaves behind its first
    point, and the overwritten end then hooked back, away from the goal, by 13 cm.)"""
    return whittaker_of(points)(penalty)


def whittaker_of(points: np.ndarray) -> Callable[[float], np.ndarray]:
    """`whittaker` of one polyline (n, 2) at any penalty: what does not depend on the
    penalty is built once (`smooth_to_noise` tries 30 penalties; built each time, it was
    half of a tracker file's reading)."""
    p = np.asarray(points, dtype=float)
    n = len(p)
    diagonal = np.full(n, 6.0)
    diagonal[[0, -1]], diagonal[[1, -2]] = 1.0, 5.0
    first = np.full(n - 1, -4.0)
    first[[0, -1]] = -2.0
    banded = np.zeros((3, n))  # (I + penalty D'D), upper form for LAPACK's pbsv
    pbsv, = scipy.linalg.get_lapack_funcs(("pbsv",), (banded,))

    def smoothed(penalty: float) -> np.ndarray:
        banded[0, 2:] = penalty
        banded[1, 1:] = penalty * first
        banded[2] = 1.0 + penalty * diagonal
        rhs = p[1:-1].copy()  # the ends' terms of (I + penalty D'D) z move to the right side
        rhs[0] -= banded[1, 1] * p[0]
        rhs[1] -= banded[0, 2] * p[0]
        rhs[-2] -= banded[0, n - 1] * p[-1]
        rhs[-1] -= banded[1, n - 1] * p[-1]
        # scipy.linalg.solveh_banded's own call, without its checks of our finite arrays
        _, inner, info = pbsv(banded[:, 1:-1], rhs, lower=0)
        if info != 0:  # never: the matrix is I plus a semi-definite one
            raise np.linalg.LinAlgError(f"pbsv failed ({info})")
        return np.vstack([p[:1], inner, p[-1:]])
    return smoothed


def smooth_to_noise(points: np.ndarray, sigma: float) -> np.ndarray:
    """The Whittaker-smoothed polyline that departs from `points` by DISCREPANCY·`sigma`
    (root mean square per coordinate), about the noise's own size (the discrepancy principle:
    the penalty is found by bisection over 10^-4..10^12, the departure growing with it);
    first and last point kept."""
    p = np.asarray(points, dtype=float)
    if len(p) < 4 or not sigma > 0:
        return p.copy()
    origin = p[0].copy()  # map coordinates (UTM: 10^6 m) lose no precision in the solve
    p = p - origin
    smoothed = whittaker_of(p)
    low, high = -4.0, 12.0
    for _ in range(30):
        mid = (low + high) / 2
        if np.mean((smoothed(10.0 ** mid) - p) ** 2) > (DISCREPANCY * sigma) ** 2:
            high = mid
        else:
            low = mid
    return smoothed(10.0 ** low) + origin


def smooth_jitter(tracks: Sequence[np.ndarray],
                  where: str) -> tuple[list[np.ndarray], list[bool], list[float]]:
    """The tracks, each smoothed of its tracking noise (`noise_sigma`, `smooth_to_noise`)
    when that inflates its length by more than JITTER_INFLATION, with one warning; the
    others as they are. Each track is judged on its own points, so a held-out one
    (evaluate.holdout) changes nothing in those learned from. Tracks with non-finite or
    far-off points are left for the checks that refuse them. Returns (tracks, smoothed,
    each track's noise σ in m: 0 where none is found)."""
    out, smoothed, noise, sigmas, inflation = [], [], [], [], []
    progress = Progress(f"{where}: denoising trajectories", len(tracks))
    for k, t in enumerate(tracks):
        progress(k)
        with np.errstate(over="ignore", invalid="ignore"):
            usable = np.isfinite(t).all() and np.abs(t).max(initial=0.0) < FARTHEST_COORDINATE
        p = drop_repeats(t) if usable else t
        sigma = noise_sigma([p]) if usable else 0.0
        smooth = smooth_to_noise(p, sigma) if sigma > 0 else p
        ratio = _polyline_length(p) / _polyline_length(smooth) if sigma > 0 else 1.0
        changed = bool(ratio > JITTER_INFLATION)
        out.append(smooth if changed else t)
        smoothed.append(changed)
        noise.append(sigma)
        if changed:
            sigmas.append(sigma)
            if _polyline_length(smooth) >= INFLATION_MIN_LENGTH:
                inflation.append(ratio)
    if sigmas:
        log.warning("%s: %d of %d trajectories zig-zag by about %.1f cm from point to point "
                    "(tracking noise, the median)%s: smoothed to that noise and resampled "
                    "(expert.denoise=false keeps them as recorded)", where, len(sigmas),
                    len(tracks), 100 * float(np.median(sigmas)),
                    f" and are up to {max(inflation):.2f} times as long as the paths they "
                    "follow" if inflation else "")
    return out, smoothed, noise


def cut_at_goal(points: np.ndarray, goal: np.ndarray, goal_tolerance: float) -> np.ndarray | None:
    """DESIGN §3: the trajectory up to its first point within `goal_tolerance` of the goal;
    what follows is not part of the demonstration.

    The polyline is taken as the path it describes: where segment i → i+1 is the first to
    come within the tolerance, the trajectory is `points[:i + 2]` when vertex i+1 lies in
    the goal disk, else (a sparse polyline passing through the disk) `points[:i + 1]` and
    the point where the segment enters the disk (`disk_entry`). It ends there, not at the
    goal itself: the run's paths end where they enter the goal disk (its states are
    terminal), and the goal's centre lies up to `goal_tolerance` farther on, a last piece
    no path compared with it has (an optimal expert's own paths, ending at the goal, learned
    relation -1, social -0.25, goal_deviation -0.38, length -0.02 in place of its -1, -0.44,
    -0.62, -0.07). Returns `points` unchanged when it never comes within the tolerance, None
    when its first point already does (nothing is left before the goal).
    """
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    goal = np.asarray(goal, dtype=float)
    if len(p) == 0 or in_goal_disk(p[0], goal, goal_tolerance):
        return None
    if len(p) < 2:
        return p.copy()
    a, b = p[:-1], p[1:]
    ab = b - a
    len2 = np.einsum("nk,nk->n", ab, ab)
    t = np.clip(np.einsum("nk,nk->n", goal - a, ab) / np.where(len2 > 0, len2, 1.0), 0.0, 1.0)
    gap = np.linalg.norm(a + t[:, None] * ab - goal, axis=1)
    entered = np.flatnonzero(within(gap, goal_tolerance))
    if len(entered) == 0:
        return p.copy()
    i = int(entered[0])
    if in_goal_disk(p[i + 1], goal, goal_tolerance):
        return p[:i + 2].copy()
    return np.vstack([p[:i + 1], disk_entry(p[i], p[i + 1], goal, goal_tolerance)[None, :]])


def disk_entry(a: np.ndarray, b: np.ndarray, goal: np.ndarray, radius: float) -> np.ndarray:
    """The first point (2,) of the segment a → b at `radius` from `goal`, a outside that
    disk and the segment coming within it; the segment's point nearest the goal where it
    only grazes the disk (within TIE)."""
    ab = b - a
    to_goal = goal - a
    len2 = float(ab @ ab)
    along = float(to_goal @ ab)
    # |a + t·ab − goal|² = radius²: len2·t² − 2·along·t + |a − goal|² − radius² = 0
    discriminant = max(along * along - len2 * (float(to_goal @ to_goal) - radius * radius), 0.0)
    t = min(max((along - np.sqrt(discriminant)) / len2, 0.0), 1.0)
    return a + t * ab


def _visits(near: np.ndarray) -> list[tuple[int, int]]:
    """The runs [r0, r1) of consecutive True in the mask `near` (K,)."""
    edges = np.diff(np.concatenate([[0], near.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1).tolist(), np.flatnonzero(edges == -1).tolist(),
                    strict=True))


def motion_begin(gaps: np.ndarray, start_radius: float) -> int:
    """Where the demonstration begins in a stretch of poses (their distances to every start,
    (K, n)), the first of which is within `start_radius` of a start.

    A *visit* is a run of consecutive poses within `start_radius` + VISIT_SLACK of one start
    that comes within `start_radius` of it (the slack: a noisy track that leaves a start
    crosses the radius several times, and a last re-entry of one pose at the radius was
    taken for the visit, its stop of 60 poses ignored); only each start's last visit in the
    stretch counts (the robot came back to it). The visit's closest approach is its smallest
    distance to that start, and the robot *stops* there at the poses within STOP_TOLERANCE
    of it and within `start_radius`. Among the visits that come within VISIT_SLACK of the
    closest approach of any of them, the one with the longest stop wins (then the closer
    one, then the later one): passing near another start on the way, before or after the
    stop, does not begin a demonstration. It begins at the winner's last stop pose, where the
    robot moves away towards the goal.
    """
    candidates = []  # (stop length, -closest approach, last stop pose)
    for s in range(gaps.shape[1]):
        visits = [(r0, r1) for r0, r1 in _visits(gaps[:, s] <= start_radius + VISIT_SLACK)
                  if gaps[r0:r1, s].min() <= start_radius]
        if not visits:
            continue
        r0, r1 = visits[-1]
        d = gaps[r0:r1, s]
        closest = float(d.min())
        # within the radius too: a stop at 0.99 m jittering to 1.004 m began a demonstration
        # that matching then refused for starting too far off, and with it the whole file
        stop = np.flatnonzero(d <= min(closest + STOP_TOLERANCE, start_radius))
        candidates.append((len(stop), -closest, r0 + int(stop[-1])))
    best = max(c[1] for c in candidates)
    return max(c for c in candidates if c[1] >= best - VISIT_SLACK)[2]


def stream_spans(track: np.ndarray, starts: np.ndarray, goal: np.ndarray, start_radius: float,
                 goal_tolerance: float) -> list[tuple[int, int]]:
    """Cut a continuous pose stream (K, 2) into start-to-goal trajectories: index pairs (b, g),
    the trajectory being track[b : g + 1].

    A pose is *near* start s when it is within `start_radius` of s, and *at the goal* when it
    is within `goal_tolerance` of `goal`. From a position p (initially 0):

    1. a = the first index >= p near some start; none: stop.
    2. g = the first index > a at the goal; none: stop (the rest never reaches the goal).
    3. b = `motion_begin` of the stretch [a, g): the last pose of the robot's stop at a start,
       where it moves away towards the goal.
    4. (b, g) is a trajectory; continue from p = g + 1.

    So every trajectory begins where the robot sets off from a start and ends at its first pose
    within `goal_tolerance` of the goal; passing near another start on the way, before or after
    the stop, neither cuts it nor shortens it. Stretches before the robot first comes near a
    start, or after the last goal arrival that never reach the goal again, are dropped.
    """
    track = np.asarray(track, dtype=float).reshape(-1, 2)
    starts = np.asarray(starts, dtype=float).reshape(-1, 2)
    if len(track) == 0 or len(starts) == 0:
        return []
    gaps = np.linalg.norm(track[:, None, :] - starts[None, :, :], axis=2)  # (K, n)
    near_any = np.flatnonzero((gaps <= start_radius).any(axis=1))
    at_goal = np.flatnonzero(in_goal_disk(track, goal, goal_tolerance))
    spans = []
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
        spans.append((a + motion_begin(gaps[a:g], start_radius), g))
        pos = g + 1
    return spans


def cut_stream(track: np.ndarray, starts: np.ndarray, goal: np.ndarray, start_radius: float,
               goal_tolerance: float) -> list[np.ndarray]:
    """The trajectories of `stream_spans`, as copies of the stream's poses."""
    track = np.asarray(track, dtype=float).reshape(-1, 2)
    return [track[b:g + 1].copy()
            for b, g in stream_spans(track, starts, goal, start_radius, goal_tolerance)]


def match_to_starts(tracks: Sequence[np.ndarray], starts: np.ndarray, goal: np.ndarray,
                    start_radius: float, goal_tolerance: float, source: str,
                    labels: Sequence[str] | None = None) -> list[int]:
    """Index of the start nearest to each track's first point.

    Each track must begin within `start_radius` of its nearest start and end within
    max(1 m, `goal_tolerance`) of the goal; otherwise one line naming `source`, the trajectory
    (numbered from 0) and the distance is raised. One warning names the tracks that begin
    more than half `start_radius` from their start, or within START_TIE as near another.
    """
    starts = np.asarray(starts, dtype=float).reshape(-1, 2)
    goal = np.asarray(goal, dtype=float)
    goal_limit = max(1.0, goal_tolerance)
    matched: list[int] = []
    doubtful: list[str] = []
    for i, t in enumerate(tracks):
        gaps = np.linalg.norm(starts - t[0], axis=1)
        k = int(np.argmin(gaps))
        if gaps[k] > start_radius:
            raise PipelineError(
                f"{source}: trajectory {label(labels, i)} starts {gaps[k]:.2f} m from the "
                f"nearest start "
                f"{point(*starts[k])}; at most {start_radius:g} m "
                f"(expert.start_radius)")
        end_gap = float(np.linalg.norm(t[-1] - goal))
        if end_gap > goal_limit:
            raise PipelineError(f"{source}: trajectory {label(labels, i)} ends {end_gap:.2f} m "
                                f"from the goal "
                                f"{point(*goal)}; at most {goal_limit:g} m (extend "
                                "it to the goal, or check that it belongs to this scene)")
        matched.append(k)
        second = int(np.argsort(gaps, kind="stable")[1]) if len(gaps) > 1 else k
        if second != k and gaps[second] - gaps[k] < START_TIE:
            doubtful.append(f"{label(labels, i)} ({gaps[k]:.2f} m from start {k}, "
                            f"{gaps[second]:.2f} m from start {second})")
        elif gaps[k] > start_radius / 2:
            doubtful.append(f"{label(labels, i)} ({gaps[k]:.2f} m from start {k})")
    if doubtful:
        log.warning("%s: trajectories %s begin far from the start they are assigned to, or as "
                    "near another: check that they begin where the scene's starts are "
                    "(the part before them is not learned from)", source,
                    listed(doubtful, 3, "; "))
    return matched


def _span_subject(subjects: list[str | None] | None, b: int, g: int, where: str,
                  i: int) -> str | None:
    """The subject of the stream poses b..g (a CSV pose stream's `subject` column)."""
    if subjects is None:
        return None
    found = sorted({s for s in subjects[b:g + 1] if s is not None})
    if len(found) > 1:
        raise PipelineError(f"{where}: trajectory {i} (cut from the pose stream) has rows of "
                            f"several subjects: {', '.join(repr(n) for n in found[:3])}; a "
                            f"file of several people's tracks gives each track's id in a "
                            f"trajectory column")
    return found[0] if found else None


def cut_trajectory(track: np.ndarray, goal: np.ndarray, goal_tolerance: float,
                   room: Room | None, what: str, resample: float | None = None,
                   goal_margin: float = 0.0) -> np.ndarray:
    """A trajectory as it is learned from: repeated points dropped, cut at the goal disk
    (`cut_at_goal`), with `resample` the part before its last point resampled to that spacing
    (`clean_track`: a pose stream's dense, noisy poses); refused (naming `what`) when it
    begins at the goal, leaves `room` or never moves. One that never enters the disk but
    ends within `goal_margin` of its edge (the tracking noise, GOAL_NOISE_SIGMAS) reaches
    the goal: it ends at the disk's point nearest its end."""
    goal = np.asarray(goal, dtype=float)
    # coordinates far outside any room (1e300) overflow to inf and nan on the way, which never
    # count as within a tolerance: the room check below refuses them by name
    with np.errstate(over="ignore", invalid="ignore"):
        cut = cut_at_goal(drop_repeats(track), goal, goal_tolerance)
        if cut is not None and goal_margin > 0:
            gap = float(np.linalg.norm(cut[-1] - goal))
            if not within(gap, goal_tolerance) and within(gap, goal_tolerance + goal_margin):
                # on to the disk's nearest point, where a path into the disk would end
                cut = np.vstack([cut, goal + (cut[-1] - goal) * (goal_tolerance / gap)])
    if cut is None:
        raise PipelineError(f"{what} begins within goal_tolerance={goal_tolerance:g} m of the "
                            f"goal {point(*goal)} (recorded from the goal back to a start? a "
                            "demonstration goes from a start to the goal)")

    def refuse_outside(area: Room, points: np.ndarray, margin: float = 0.0) -> None:
        inside = area.contains(points, margin)
        if not inside.all():
            if not inside.any():  # never inside: not a stray pose but another frame
                raise other_frame(what, area, points)
            raise PipelineError(f"{what} leaves the room {area.describe()} at "
                                f"{_place(points[int(np.argmin(inside))])}")

    if resample is not None:  # resample what leads to its last point (in the goal disk)
        if room is not None:
            # Every vertex lies within half a step of a resampled point, so a vertex outside
            # the room grown by a step would be refused after resampling too: refused now,
            # a glitched pose 10⁷ m away does not first fill memory with points towards it.
            refuse_outside(room, cut, -resample)
        with np.errstate(over="ignore"):  # 1e300: an infinite length, refused below
            length = _polyline_length(cut)
        if not length <= MAX_RESAMPLED_POINTS * resample:
            raise PipelineError(f"{what} is {length:.3g} m long: more than "
                                f"{MAX_RESAMPLED_POINTS:,} points at {resample:g} m apart "
                                "(a pose far off, e.g. a glitch in the recording?)")
        cut = np.vstack([clean_track(cut[:-1], resample), cut[-1:]])
    if room is not None:
        refuse_outside(room, cut)
    if len(cut) < 2:
        raise PipelineError(f"{what} never moves (all its points are within "
                            f"{REPEAT_TOLERANCE:g} m of each other)")
    return cut


def _place(p: np.ndarray) -> str:
    x, y = p
    return f"({x:.2f}, {y:.2f})" if max(abs(x), abs(y)) < 1e6 else f"({x:.3g}, {y:.3g})"


def other_frame(what: str, room: Room, points: np.ndarray) -> PipelineError:
    """The error for a trajectory with no point in the room."""
    return PipelineError(f"{what} lies wholly outside the room {room.describe()}, from "
                         f"{_place(points[0])}: recorded in another frame, with another origin "
                         "or in other units than the scene's (metres)?")


def refuse_other_frames(tracks: Sequence[np.ndarray], room: Room, names: Sequence[str]) -> None:
    """Refuse, before any other work on them, the first trajectory with no point in the
    room (`other_frame`, naming it by `names`): in millimetres a walk first read as 20 m of
    tracking noise."""
    for name, t in zip(names, tracks, strict=True):
        with np.errstate(over="ignore", invalid="ignore"):  # inf, nan: refused later
            if len(t) and not room.contains(t).any() and np.isfinite(t).all():
                raise other_frame(name, room, t)


def onto_room_edge(tracks: Sequence[np.ndarray], room: Room, where: str,
                   labels: Sequence[str] | None = None) -> list[np.ndarray]:
    """The tracks, those that stray at most ROOM_EDGE_TOLERANCE outside `room` moved onto its
    edge there (one warning for all of them); farther out, left for cut_trajectory to
    refuse."""
    moved, farthest, out = [], 0.0, []
    for i, t in enumerate(tracks):
        with np.errstate(invalid="ignore", over="ignore"):  # inf, nan: refused later
            stray = float(room.outside_distance(t).max(initial=0.0))
        if 0.0 < stray <= ROOM_EDGE_TOLERANCE:
            t = room.clip(t)
            moved.append(label(labels, i))
            farthest = max(farthest, stray)
        out.append(t)
    if moved:
        log.warning("%s: %s (%s) stray%s up to %.3f m outside the room %s, as tracking noise "
                    "along a wall does; those points are moved onto its edge (farther than %g m "
                    "out is refused)", where,
                    "1 trajectory" if len(moved) == 1 else f"{len(moved)} trajectories",
                    listed(moved, 5),
                    "s" if len(moved) == 1 else "", farthest, room.describe(),
                    ROOM_EDGE_TOLERANCE)
    return out


def goal_margin(sigma: float) -> float:
    """How far outside the goal disk a recorded trajectory with tracking noise `sigma` (m)
    may end and still reach the goal (GOAL_NOISE_SIGMAS, GOAL_MARGIN_FLOOR,
    GOAL_NOISE_MARGIN)."""
    return min(max(GOAL_NOISE_SIGMAS * sigma, GOAL_MARGIN_FLOOR), GOAL_NOISE_MARGIN)


def warn_noisy_ends(tracks: Sequence[np.ndarray], cleaned: Sequence[np.ndarray],
                    goal: np.ndarray, goal_tolerance: float, where: str,
                    labels: Sequence[str] | None = None) -> None:
    """One warning naming the trajectories that end outside the goal disk within their
    tracking noise and so reach the goal (`cut_trajectory`'s goal_margin, `goal_margin`)."""
    found = []
    for k, (track, cut) in enumerate(zip(tracks, cleaned, strict=True)):
        if not in_goal_disk(cut[-1], goal, goal_tolerance):
            continue
        with np.errstate(over="ignore", invalid="ignore"):
            plain = cut_at_goal(drop_repeats(track), goal, goal_tolerance)
        if plain is not None and not in_goal_disk(plain[-1], goal, goal_tolerance):
            gap = float(np.linalg.norm(plain[-1] - goal)) - goal_tolerance
            found.append(f"{label(labels, k)} ({1000 * gap:.1f} mm)")
    if found:
        log.warning("%s: trajectories %s end outside the goal disk (goal_tolerance=%g m) by "
                    "less than their tracking noise (%g cm, or %g times the noise, at most "
                    "%g cm): taken to reach the goal, with a last segment to the disk's edge",
                    where,
                    listed(found, 5), goal_tolerance, 100 * GOAL_MARGIN_FLOOR,
                    GOAL_NOISE_SIGMAS, 100 * GOAL_NOISE_MARGIN)


def refuse_far_points(tracks: Sequence[np.ndarray], names: Sequence[str]) -> None:
    """Refuse the first track (named by `names`) with a point FARTHEST_COORDINATE or more
    from the origin, or not a number: read without a room, a glitch at 1e300 m overflowed
    the steps after this to a traceback."""
    for name, t in zip(names, tracks, strict=True):
        with np.errstate(invalid="ignore"):
            far = np.flatnonzero(~(np.abs(t) < FARTHEST_COORDINATE).all(axis=1))
        if len(far):
            why = "no map is that large (over {:g} m from the origin)".format(
                FARTHEST_COORDINATE) if np.isfinite(t[far[0]]).all() else "not a number"
            raise PipelineError(f"{name} has a point at {point(*t[far[0]])}: {why}; a "
                                "glitched pose?")


def clean_tracks(tracks: Sequence[np.ndarray], goal: np.ndarray, goal_tolerance: float,
                 room: Room | None, where: str, names: Sequence[str], *, denoise: bool = True,
                 resample: bool = False, spacing: float = RESAMPLE_SPACING,
                 labels: Sequence[str] | None = None) -> list[np.ndarray]:
    """Tracks read from a recording (`names` name each in errors, `where` the recording in
    warnings) as they are learned from: one wholly outside `room` refused at once; with
    `denoise` smoothed of tracking noise (`smooth_jitter`); those straying a few centimetres
    out of `room` moved onto its edge; each cut at the goal disk (`cut_trajectory`), one
    that ends outside it within its noise (`goal_margin`) taken to reach it; resampled
    every `spacing` m when smoothed, or all of them with `resample` (a pose stream);
    positions rounded to COORDINATE_DECIMALS. `labels` name the tracks in warnings (`label`)."""
    smoothed, noise = [False] * len(tracks), [0.0] * len(tracks)
    if room is not None:
        refuse_other_frames(tracks, room, names)
    else:  # with a room, a glitch at 1e300 m leaves it and is refused so
        refuse_far_points(tracks, names)
    if denoise:
        tracks, smoothed, noise = smooth_jitter(tracks, where)
    if room is not None:
        tracks = onto_room_edge(tracks, room, where, labels)
    cleaned = [cut_trajectory(t, goal, goal_tolerance, room, name,
                              spacing if resample or smoothed[i] else None, goal_margin(noise[i]))
               for i, (name, t) in enumerate(zip(names, tracks, strict=True))]
    warn_noisy_ends(tracks, cleaned, goal, goal_tolerance, where, labels)
    return [np.round(c, COORDINATE_DECIMALS) for c in cleaned]


def load_recorded(path: Path, starts: np.ndarray, goal: np.ndarray, *, goal_tolerance: float,
                  topic: str | None = None, frame: str | None = None,
                  start_radius: float = START_RADIUS, spacing: float = RESAMPLE_SPACING,
                  room: Room | None = None, denoise: bool = True,
                  select_walks: bool = False) -> list[Recorded]:
    """Read a recorded demonstration into its demonstrations (matched start, polyline, subject).

    Whatever the format, every trajectory is cut at the goal disk (`cut_at_goal`): recordings
    rarely stop at the goal, and what follows the first point within `goal_tolerance` is not
    part of the demonstration (never an error). A pose stream (Odometry, PoseStamped, a CSV
    without `trajectory` ids) is first cut into trajectories (`stream_spans`), and each is
    resampled up to its last pose before the goal with `clean_track(track, spacing)`: dense,
    noisy and repeated poses become an evenly spaced polyline. Trajectories given as polylines
    (JSON, CSV with ids, nav_msgs/Path) keep their points, only repeated points dropped, so the
    same polylines learn the same reward whatever the file format (positions rounded to the
    nanometre, COORDINATE_DECIMALS). With `denoise`, tracking noise that inflates the
    trajectories' length by more than JITTER_INFLATION is smoothed out first (`smooth_jitter`)
    and the smoothed polylines are resampled like a pose stream. With `room`, every
    trajectory must stay inside it. Each is then matched with `match_to_starts`; a start no
    demonstration begins at is named in one warning line. With `select_walks`, trajectories
    are cut like a pose stream (`select_track_walks`: a tracker's tracks, of which only some
    go from a start to the goal); without it, a trajectory that is no such walk is refused,
    and the refusal says how many others are none either.
    """
    path = Path(path)
    where = describe(path)
    recording = read_recording(path, topic=topic, frame=frame, single_rows=select_walks)
    goal = np.asarray(goal, dtype=float)
    if recording.is_stream:
        reach = np.linalg.norm(np.asarray(starts, float).reshape(-1, 2) - goal, axis=1)
        if len(reach) and start_radius + goal_tolerance >= reach.min():
            k = int(np.argmin(reach))
            raise PipelineError(
                f"{where}: expert.start_radius={start_radius:g} m reaches the goal's disk from "
                f"start {k} ({reach[k]:.2f} m from the goal): a pose stream's trajectories would "
                f"begin at the goal; give a radius below {reach[k] - goal_tolerance:.2f} m")
        stream = recording.tracks[0]
        spans = stream_spans(stream, starts, goal, start_radius, goal_tolerance)
        if not spans:
            raise no_walk_found(where, [stream], room, start_radius, goal_tolerance)
        tracks = [stream[b:g + 1] for b, g in spans]
        subjects = [_span_subject(recording.subjects, b, g, where, i)
                    for i, (b, g) in enumerate(spans)]
        labels = [str(i) for i in range(len(tracks))]
        warn_jumps(tracks, where, [b for b, _ in spans])
    elif select_walks:
        if len(recording.tracks) >= MANY_TRACKS:  # a few seconds for every 10 000
            log.info("  mending %d tracks and cutting their walks ...", len(recording.tracks))
        tracks, subjects, chains = mend_tracks(recording, where)
        tracks, subjects, labels, offsets = select_track_walks(
            tracks, subjects, starts, goal, start_radius, goal_tolerance, where, room,
            recording.ids, chains)
        warn_jumps(tracks, where, offsets, labels)
    else:
        tracks = recording.tracks
        subjects = recording.subjects or [None] * len(tracks)
        labels = [track_name(i, recording.ids) for i in range(len(tracks))]
        # what follows the goal is cut away: a jump there is no jump in a demonstration
        warn_jumps([t[:_first_at_goal(t, goal, goal_tolerance) + 1] for t in tracks], where,
                   labels=labels)
        warn_repeated_walks(tracks, starts, goal, start_radius, goal_tolerance, where)
    try:
        cleaned = clean_tracks(tracks, goal, goal_tolerance, room, where,
                               [f"{where}: trajectory {n}" for n in labels], denoise=denoise,
                               resample=recording.is_stream, spacing=spacing, labels=labels)
        warn_revisits(cleaned, where, labels)
        if recording.planned:
            warn_replans(cleaned, where, labels)
        matched = match_to_starts(cleaned, starts, goal, start_radius, goal_tolerance, where,
                                  labels)
    except PipelineError as e:
        if recording.is_stream or select_walks:
            raise
        raise PipelineError(str(e) + without_walks_hint(tracks, starts, goal, start_radius,
                                                        goal_tolerance, recording.planned)) \
            from None
    without = sorted(set(range(len(np.asarray(starts).reshape(-1, 2)))) - set(matched))
    if without:
        log.warning("%s: no demonstration begins at start(s) %s (%d demonstrations read)",
                    where, without, len(cleaned))
    return [Recorded(k, p, s, n)
            for k, p, s, n in zip(matched, cleaned, subjects, labels, strict=True)]
