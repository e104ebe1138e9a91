"""Recordings (DESIGN §3): JSON, CSV and ROS bags read into tracks (`read_recording`).

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
"""

from __future__ import annotations

import codecs
import contextlib
import csv
import difflib
import gc
import io
import itertools
import logging
import math
import operator
import re
import time
import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np

from pipeline.errors import PipelineError, file_kind, listed
from pipeline.inputs.polylines import REPEAT_TOLERANCE, is_jump, polyline_length, steps_and_usual
from pipeline.inputs.schemas import read_json

if TYPE_CHECKING:
    from _csv import Reader as CsvReader  # csv.reader's type: _csv names it, csv does not

log = logging.getLogger(__name__)


LARGE_FILE_BYTES = 20_000_000  # a CSV file this large is said to be read, and when it is
PATH_TYPE = "nav_msgs/msg/Path"
# Pose stream message types and how to find the position in each.
STREAM_TYPES: dict[str, Callable[[Any], Any]] = {
    "geometry_msgs/msg/PoseStamped": lambda m: m.pose.position,
    "geometry_msgs/msg/PoseWithCovarianceStamped": lambda m: m.pose.pose.position,
    "nav_msgs/msg/Odometry": lambda m: m.pose.pose.position,
}
SUPPORTED_TYPES = (PATH_TYPE, *STREAM_TYPES)
BAG_SUFFIXES = (".bag", ".mcap", ".db3")
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
# A track ordered by its clock (a CSV's t column, a bag's header.stamp) may be at most this
# many times longer than as given (`clock_order`): sorting fixes poses exported or logged
# out of order, it does not turn a walk into a zig-zag.
T_ORDER_GROWTH = 2.0
# Ordering that makes a track longer than as given by more than this fraction and distance
# is not done: the clock stepped back (a clock set back mid-recording), the rows are in
# order (a timestamp jittering a frame against its neighbour stays within it)
T_ORDER_SLACK, T_ORDER_SLACK_M = 0.05, 0.2


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
        plain = _plain_csv_table(path, where) if size >= CSV_PLAIN_MIN_BYTES else _PlainRead()
        header = plain.names  # read already: not twice
        # utf-8-sig: Excel's "CSV UTF-8" starts with a byte-order mark, which is not a column
        with _collector_paused():
            if plain.table is not None:
                col, table, lines, ids, subjects = plain.table
            else:
                try:
                    with path.open(newline="", encoding="utf-8-sig") as f:
                        col, table, lines, ids, subjects = _csv_table(csv.reader(f), where,
                                                                      names=header)
                except _ReadByRow:  # read again a row at a time, for its lines and refusal
                    with path.open(newline="", encoding="utf-8-sig") as f:
                        col, table, lines, ids, subjects = _csv_table(
                            csv.reader(f), where, by_row=True, names=header)
        if size >= LARGE_FILE_BYTES:
            log.info("  %d rows read in %.0f s", len(table), time.perf_counter() - started)
    except UnicodeDecodeError:
        raise PipelineError(f"{where} is not UTF-8 text") from None
    except csv.Error as e:
        raise PipelineError(f"{where}: not valid CSV ({e})") from None
    return _csv_recording(col, table, lines, ids, subjects, where, single_rows)


@contextlib.contextmanager
def _collector_paused() -> Iterator[None]:
    """Python's cyclic garbage collector paused: the reader makes a list of every row, and
    the collector, run every few hundred new lists, scanned them and all else alive (a third
    of reading a tracker's millions of rows); rows hold no cycles and are freed as they go."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


class _ReadByRow(Exception):
    """A CSV that `_csv_blocks` cannot read a block at a time."""


def _is_blank(row: list[str]) -> bool:
    return not row or (not row[0].strip() and all(not c.strip() for c in row))


def _csv_blocks(reader: CsvReader) -> Iterator[tuple[list[list[str]], np.ndarray]]:
    """The rows after the header, CSV_CHUNK_ROWS lines at a time, blank lines left out, with
    their file lines: counted, not asked of the reader at every row (a Python step a row, a
    quarter of the reading), where each row is one line. Raises _ReadByRow where one is not
    (a quoted line break) or the reader fails (an earlier row's refusal comes first)."""
    while True:
        before = reader.line_num
        try:
            rows = list(itertools.islice(reader, CSV_CHUNK_ROWS))
        except (csv.Error, UnicodeDecodeError):
            raise _ReadByRow from None
        if not rows:
            return
        if reader.line_num - before != len(rows):
            raise _ReadByRow
        lines = np.arange(before + 1, before + 1 + len(rows))
        if not (all(rows) and all(map(str.strip, map(operator.itemgetter(0), rows)))):
            kept = [k for k, row in enumerate(rows) if not _is_blank(row)]
            rows, lines = [rows[k] for k in kept], lines[kept]
        if rows:
            yield rows, lines


def _csv_table(reader: CsvReader, where: str, by_row: bool = False,
               names: list[str] | None = None
               ) -> tuple[dict[str, int], np.ndarray, np.ndarray, list[str], list[str]]:
    """The CSV's columns (name -> index), its rows as (x, y, t) (t 0 without a t column), the
    file line of each row, and its trajectory ids and subjects (empty without those columns).
    A refusal names the first line at fault and, of its fields, the first in the order
    count, x, y, t, trajectory, subject. Rows are read CSV_CHUNK_ROWS at a time, each field
    a column at a time (`_csv_chunk`; a tracker's file has millions of rows: a row at a time
    took 11 µs a row, now 4), a block of lines at a time (`_csv_blocks`) unless `by_row`.
    `names`: the header's, when `_plain_csv_table` read them already (its warnings said once)."""
    header = next((row for row in reader if any(c.strip() for c in row)), None)
    if header is None:
        raise PipelineError(f"{where} is empty; expected a header line with columns x,y")
    if names is None:  # else the header's names as `_plain_csv_table` read them
        names = _csv_header(header, where)
    col = {n: names.index(n) for n in names}
    chunks = _csv_row_chunks(reader, col, len(header), where) if by_row else \
        [_csv_chunk(block, at, col, len(header), where) for block, at in _csv_blocks(reader)]
    if not chunks:
        raise PipelineError(f"{where} has no rows")
    idents = {name: [i for _, _, chunk in chunks for i in chunk[name]] for name in chunks[0][2]}
    return (col, np.vstack([table for table, _, _ in chunks]),
            np.concatenate([at for _, at, _ in chunks]), idents.get("trajectory", []),
            idents.get("subject", []))


CSV_CHUNK_ROWS = 65_536  # a chunk's fields are held as text until read: 20 MB, not 700


def _csv_row_chunks(reader: CsvReader, col: dict[str, int], n_fields: int, where: str
                    ) -> list[tuple[np.ndarray, np.ndarray, dict[str, list[str]]]]:
    """The rows after the header read a row at a time, with the line the reader says each
    ends on (`_csv_blocks` cannot count them), as `_csv_chunk`s of CSV_CHUNK_ROWS rows."""
    chunks = []
    rows: list[list[str]] = []
    lines: list[int] = []
    try:
        for row in reader:
            if _is_blank(row):
                continue
            rows.append(row)
            lines.append(reader.line_num)
            if len(rows) == CSV_CHUNK_ROWS or len(row) != n_fields:  # the latter: refused
                chunks.append(_csv_chunk(rows, lines, col, n_fields, where))
                rows, lines = [], []
    except (csv.Error, UnicodeDecodeError):  # a line after the rows held: theirs come first
        if rows:
            _csv_chunk(rows, lines, col, n_fields, where)
        raise
    if rows:
        chunks.append(_csv_chunk(rows, lines, col, n_fields, where))
    return chunks


def _csv_chunk(rows: list[list[str]], lines: list[int] | np.ndarray, col: dict[str, int],
               n_fields: int, where: str) -> tuple[np.ndarray, np.ndarray, dict[str, list[str]]]:
    """Rows of a CSV (at file `lines`) as a table (n, 3) of x, y, t (0 without a t column),
    their lines, and their ids by column (trajectory, subject); refused at the first row at
    fault (`_refuse_csv_row`)."""
    numbers = [name for name in ("x", "y", "t") if name in col]
    counted = set(map(len, rows)) == {n_fields}

    def field(name: str) -> list[str]:  # a column's fields, trimmed (map: no loop in Python)
        return list(map(str.strip, map(operator.itemgetter(col[name]), rows)))

    values = [_plain_decimals(field(name)) if counted else None for name in numbers]
    idents: dict[str, list[str]] = {name: field(name) if counted else []
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


DECIMALS = b"0123456789.+-eE"


def _plain_decimals(texts: list[str]) -> np.ndarray | None:
    """`texts` as finite numbers when each is a plain decimal number (CSV_NUMBER), else
    None. Of strings of these characters alone, float() reads just those (the words nan
    and inf, "_" and other digits need others), at a fraction of the cost of matching each."""
    # the bytes of other characters are left once those are deleted (quicker than a set's test)
    try:
        if "".join(texts).encode("ascii").translate(None, DECIMALS):
            return None
    except UnicodeEncodeError:
        return None
    try:
        numbers = np.fromiter(map(float, texts), dtype=float, count=len(texts))
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


class Labels(NamedTuple):
    """A CSV column of ids (trajectory, subject) as each row's code and the ids coded, in the
    order they first appear: `_plain_csv_table` reads them so (a list of millions of
    strings, numbered through a dict, took a second)."""
    codes: np.ndarray  # (n,) intp: row k's id is names[codes[k]]
    names: list[str]


# A CSV file this large is first read by `_plain_csv_table` (pandas' C reader, imported for
# it); a smaller one as a CSV in Python, which reads it in a tenth of a second
CSV_PLAIN_MIN_BYTES = 1_000_000
# the bytes of a file `_plain_csv_table` reads: printable ASCII without the quote, line ends
PLAIN_CSV_BYTES = bytes(range(0x20, 0x7F)).replace(b'"', b"") + b"\r\n"


class _PlainRead(NamedTuple):
    """What `_plain_csv_table` made of a file: the table as `_csv_table` gives it (ids as
    `Labels`) when the file is plain, else None; and its header's names once read (None
    before), which `_csv_table` then need not read, nor warn about, again."""
    table: tuple[dict[str, int], np.ndarray, np.ndarray, Labels | list[str],
                 Labels | list[str]] | None = None
    names: list[str] | None = None


def _plain_csv_table(path: Path, where: str) -> _PlainRead:
    """A CSV file read as `_csv_table` reads it, to the bit, when it is plain: ASCII text
    without quotes or control characters (line ends LF or CRLF, a byte-order mark first),
    its first line the header, each other line empty or of the header's number of fields,
    every x, y and t field a finite plain decimal number (no spaces around it) and every
    id a printable one. Else no table: `_csv_table` reads the file, and refuses it if it is
    at fault.

    Such a file is what the csv module splits at commas and line ends alone, and its
    numbers are what pandas' C reader reads as float() does (correctly rounded, fields
    of the characters of plain numbers only: checked on the bytes) and refuses otherwise;
    it reads a tracker's millions of rows five times as fast."""
    data = path.read_bytes()
    bom = data.startswith(codecs.BOM_UTF8)
    # all but the bytes of a plain file deleted: the byte-order mark alone is left, if any
    if data.translate(None, PLAIN_CSV_BYTES) != (codecs.BOM_UTF8 if bom else b""):
        return _PlainRead()
    if b"\r" in data:  # CRLF line ends, as LF (a lone CR ends a line too: left to csv)
        if data.count(b"\r") != data.count(b"\r\n"):
            return _PlainRead()
        data = data.replace(b"\r\n", b"\n")
    text = np.frombuffer(data, dtype=np.uint8)
    ends = np.flatnonzero(text == ord("\n"))
    if not data.endswith(b"\n"):
        ends = np.append(ends, len(data))
    starts = np.concatenate(([3 if bom else 0], ends[:-1] + 1))
    if len(ends) < 2 or int((ends - starts).max()) >= csv.field_size_limit():
        return _PlainRead()  # no rows, or a line the csv module refuses
    header = data[starts[0]:ends[0]].decode("ascii").split(",")
    if not any(h.strip() for h in header):  # blank lines before the header: left to csv
        return _PlainRead()
    names = _csv_header(header, where)
    col = {n: names.index(n) for n in names}
    full = ends[1:] > starts[1:]  # an empty line is no row
    if not full.any():  # a header and empty lines: no rows, which csv refuses
        return _PlainRead(names=names)
    commas = np.flatnonzero(text == ord(","))  # how many each line holds: counted between ends
    per_line = np.diff(np.searchsorted(commas, ends))
    del commas
    if not (per_line[full] == len(header) - 1).all():
        return _PlainRead(names=names)
    numbers = [name for name in ("x", "y", "t") if name in col]
    # the bytes of the rows' fields that no plain number holds: none, else those of the ids
    # (and of columns not read) alone. Spaces too: pandas reads " +7.0991917945441956068 " (a
    # plus sign and a space) as 7.099191794544195, not correctly rounded (7.099191794544196)
    not_plain = len(data.translate(None, DECIMALS + b",\n")) - \
        len(data[:ends[0]].translate(None, DECIMALS + b",\n"))
    texts = [i for i in range(len(header)) if i not in {col[n] for n in numbers}] \
        if not_plain else [col[n] for n in ("trajectory", "subject") if n in col]
    import pandas as pd

    try:
        with warnings.catch_warnings(record=True) as warned:
            warnings.simplefilter("always")
            frame = pd.read_csv(
                io.BytesIO(data), sep=",", header=None, names=range(len(header)), skiprows=1,
                usecols=sorted([col[n] for n in numbers] + texts), index_col=False,
                dtype={i: np.float64 if i in {col[n] for n in numbers} else object
                       for i in range(len(header))},
                engine="c", na_filter=False, quoting=csv.QUOTE_NONE, skip_blank_lines=True)
    except ValueError:  # a number pandas does not read (nor does float())
        return _PlainRead(names=names)
    del text, data
    if warned or len(frame) != int(full.sum()):
        return _PlainRead(names=names)
    if not_plain:
        in_texts = sum(len("".join(frame[i]).encode("ascii").translate(None, DECIMALS))
                       for i in texts)
        if in_texts != not_plain:  # a number's field holds other characters
            return _PlainRead(names=names)
    table = np.zeros((len(frame), 3))
    for name in numbers:
        table[:, ("x", "y", "t").index(name)] = frame[col[name]].to_numpy(dtype=np.float64)
    if not np.isfinite(table).all():
        return _PlainRead(names=names)
    idents: dict[str, Labels] = {}
    for ident in ("trajectory", "subject"):
        if ident in col:
            codes, found = pd.factorize(frame[col[ident]].to_numpy(dtype=object))
            trimmed = [str(i).strip() for i in found]  # printable ASCII: spaces trimmed
            if not all(trimmed):
                return _PlainRead(names=names)
            if trimmed != list(found):  # " a" and "a" are one id
                codes = pd.factorize(np.array(trimmed, dtype=object))[0][codes]
                trimmed = list(dict.fromkeys(trimmed))
            idents[ident] = Labels(codes.astype(np.intp, copy=False), trimmed)
    lines = np.flatnonzero(full) + 2  # the header is line 1
    return _PlainRead((col, table, lines, idents.get("trajectory", []),
                      idents.get("subject", [])), names)


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
    if not (np.diff(times) < 0).any():  # in order as given (a tracker's every track): kept
        return ClockOrder(np.arange(len(times)), None)
    order = np.argsort(times, kind="stable")
    as_filed, as_timed = polyline_length(points), polyline_length(points[order])
    if as_timed <= as_filed * (1 + T_ORDER_SLACK) + T_ORDER_SLACK_M:
        return ClockOrder(order, None)
    time_steps = np.diff(times)
    back = int(np.argmin(time_steps)) + 1  # the largest step back
    set_back, interval = _set_back_steps(time_steps)
    steps, usual = steps_and_usual(points)
    # every set-back is judged, not the largest alone: a mid-walk set-back larger than an
    # appended recording's restart would otherwise let the recordings through; by the
    # length ordering gives with the set-backs at no jump moved on (`_moved_on`), so
    # that a step back where tracking was lost is not refused for a mid-walk one's zig-zag
    judged = np.union1d(np.flatnonzero(set_back) + 1, [back])
    at_jumps = [k for k in judged if usual is None or is_jump(float(steps[k - 1]), usual)]
    mid_walk = set_back.copy()
    mid_walk[np.array(at_jumps, dtype=int) - 1] = False
    as_jumped = polyline_length(points[np.argsort(_moved_on(times, mid_walk, interval),
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
        usual = usual_interval(steps) or 0.0
    return np.concatenate([times[:1], times[1:] + np.cumsum(np.where(steps_moved,
                                                                     usual - steps, 0.0))])


def usual_interval(steps: np.ndarray) -> float | None:
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
        usual = usual_interval(steps) or 0.0
    return steps < -usual, usual


def set_backs(times: np.ndarray, usual: float | None = None) -> int:
    """How many times the clock is set back (`_set_back_steps`)."""
    return int(np.count_nonzero(_set_back_steps(np.diff(times), usual)[0]))


def stepped_forward(times: np.ndarray, usual: float | None = None) -> np.ndarray:
    """Times in the order recorded that never go back: after each set back (`_set_back_steps`,
    `clock_order`) the rest moved on by its size and one usual interval (`usual` if given,
    else the times' own); a smaller step back (a stamp's jitter) held at the time before it,
    so that the times do not drift."""
    steps = np.diff(times)
    if not (steps < 0).any():  # nothing is set back, whatever the usual interval: no median
        return np.maximum.accumulate(_moved_on(times, np.zeros(len(steps), dtype=bool), 0.0))
    set_back, usual = _set_back_steps(steps, usual)
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
    intervals = [i for t in stepped_tracks if (i := usual_interval(np.diff(t))) is not None]
    usual = float(np.median(intervals)) if intervals else None
    if set_backs(table_times, usual) > sum(set_backs(t) for t in stepped_tracks):
        return None
    return stepped_forward(table_times, usual)


def _labels(ids: Labels | list[str]) -> Labels:
    """Ids as `Labels`: numbered through a dict, in the order they first appear (millions of
    rows: not appended to a list a row at a time)."""
    if isinstance(ids, Labels):
        return ids
    number = {ident: g for g, ident in enumerate(dict.fromkeys(ids))}
    return Labels(np.fromiter(map(number.__getitem__, ids), dtype=np.intp, count=len(ids)),
                  list(number))


def _csv_recording(col: dict[str, int], table: np.ndarray, lines: np.ndarray,
                   ids: Labels | list[str], subjects: Labels | list[str], where: str,
                   single_rows: bool = False) -> Recording:
    """Rows grouped into trajectories by id (a pose stream without ids), ordered by t if given
    (`clock_order`); a trajectory of one row refused unless `single_rows`."""
    who = _labels(subjects) if len(subjects) else None  # who walked each row
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
            list(map(who.names.__getitem__, who.codes[order].tolist())) if who is not None \
            else None
        return Recording([table[order, :2]], True, stream_subjects)
    # each id's rows, ids in the order they first appear: sorted stably by their number
    codes, idents = _labels(ids)
    sizes = np.bincount(codes)
    bounds = np.cumsum(sizes)[:-1]
    by_track = np.argsort(codes, kind="stable")
    groups = dict(zip(idents, np.split(by_track, bounds), strict=True))
    # which tracks' times never go back (a tracker's every track): `clock_order` keeps those
    # as filed, found here for all at once, not a track at a time (30 000 tracks)
    filed = table[by_track, 2]  # the times, track after track, each in file order
    back = np.flatnonzero(np.diff(filed) < 0) + 1
    track_of = np.repeat(np.arange(len(sizes)), sizes)
    in_order = np.ones(len(sizes), dtype=bool)
    in_order[track_of[back[track_of[back] == track_of[back - 1]]]] = False
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
        rows_read.append(members if in_order[i] else
                         ordered(np.array(members), f"trajectory {i} (id {ident!r})"))
        if who is not None:
            names_here = sorted(set(map(who.names.__getitem__, who.codes[members].tolist())))
            if len(names_here) > 1:
                raise PipelineError(f"{where}: trajectory {i} (id {ident!r}) has rows of several "
                                    f"subjects: {', '.join(repr(n) for n in names_here[:3])}")
            track_subjects.append(names_here[0])
    warn_stepped_back()
    if "t" not in col:
        return Recording([table[sel, :2] for sel in rows_read], False,
                         track_subjects if who is not None else None, ids=list(groups))
    # the mending reads the times in pose order, and compares them across tracks
    clock = one_clock(table[:, 2], [table[sel, 2] for *_, sel in stepped_back]) \
        if stepped_back else None
    if clock is not None:  # the file in the order recorded: each track's rows too
        rows_read = [np.sort(sel) for sel in rows_read]
        times = [clock[sel] for sel in rows_read]
    else:  # times that never go back and are never 0 (nor -0) are as `stepped_forward` gives
        as_filed = in_order & (np.bincount(track_of, filed == 0, len(sizes)) == 0)
        times = [t.copy() if as_filed[i] else stepped_forward(table[sel, 2])
                 for i, (t, sel) in enumerate(zip(np.split(filed, bounds), rows_read,
                                                  strict=True))]
    tracks = [table[sel, :2] for sel in rows_read]
    return Recording(tracks, False, track_subjects if who is not None else None,
                     ids=list(groups), times=times)


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
