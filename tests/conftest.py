"""Where a new test goes: into the folder of the layer of the module it tests (tests/core,
tests/irl, tests/inputs, tests/artefacts, tests/app, tests/tools), in a file named after that
module (pipeline/core/features.py: tests/core/test_features.py); end-to-end runs through the
stages go to tests/pipeline, the command line (subprocesses or `cli()`, exit codes) to
tests/cli. Mark a slow test `@pytest.mark.slow`: `make test` leaves it out, `make test-all`
runs it. A helper that several test files use lives here, or in its folder's conftest.py when
only that folder uses it, never in a test file that others import.

Shared fixtures: the real Hydra config composed in-process, one default run per session.

Most end-to-end tests run the pipeline in this process (`run_in_process`: Hydra's compose
API and the same `run_pipeline` the CLI calls), which saves the ~2 s of imports a
subprocess pays. A few tests keep the subprocess (`run_app`) because what they check is the
command line itself: exit codes, one-line errors, multiruns. Also here, for tests in several
folders: the walled metropolis scene, a writer of real ROS bags, and a graph of two routes.
"""

import contextlib
import io
import json
import logging
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hydra import compose, initialize_config_dir
from omegaconf import DictConfig
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from pipeline.app.build import preset_weights
from pipeline.app.config import register_configs
from pipeline.app.provenance import INPUT_KEY
from pipeline.artefacts import topics
from pipeline.artefacts.store import read_artefact
from pipeline.artefacts.topics import ARTEFACT_FILE
from pipeline.core.features import FEATURE_NAMES
from pipeline.core.graph_mdp import GraphMDP, MDPParams
from pipeline.core.graph_mdp import Path as GraphPath
from pipeline.inputs.scene_file import load_scene_file
from pipeline.stages import run_pipeline

ROOT = Path(__file__).resolve().parent.parent
METROPOLIS = ROOT / "data" / "scenes" / "metropolis.json"
OFFICE_SCENE = ROOT / "data" / "scenes" / "office.json"
OFFICE_MAP = ROOT / "data" / "maps" / "office.yaml"
POLITE = preset_weights("polite", list(FEATURE_NAMES))  # conf/reward/polite.yaml
RUDE = preset_weights("rude", list(FEATURE_NAMES))
# The paper's discounted graph MDP (mdp=paper), for tests of that formulation.
PAPER_MDP = MDPParams(gamma=0.95, time_cost=0.0)

register_configs()


@pytest.fixture(autouse=True)
def _no_logging_into_closed_streams():
    """The in-process CLI lets Hydra attach log handlers to the stderr pytest captured for
    that test; later tests would log into the closed stream ("--- Logging error ---")."""
    yield
    root = logging.getLogger()
    for handler in list(root.handlers):
        if getattr(getattr(handler, "stream", None), "closed", False):
            root.removeHandler(handler)


@pytest.fixture(scope="session")
def metropolis():
    return load_scene_file(METROPOLIS)


def compose_config(*overrides: str) -> DictConfig:
    """The app's config with command-line style overrides, as `python -m pipeline` sees it."""
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides))


def run_in_process(run_dir: Path, *overrides: str) -> tuple[dict, str]:
    """Run the pipeline into run_dir; returns (metrics.json or {}, what it printed)."""
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        run_pipeline(compose_config(*overrides), Path(run_dir))
    metrics_path = Path(run_dir) / "metrics.json"
    metrics = json.loads(metrics_path.read_text()) if metrics_path.exists() else {}
    return metrics, out.getvalue()


def run_app(*overrides: str, cwd: Path = ROOT) -> subprocess.CompletedProcess:
    """Run the real Hydra app in a subprocess, as a user would."""
    return subprocess.run([sys.executable, "-m", "pipeline", *overrides], cwd=cwd,
                          capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="session")
def default_run(tmp_path_factory) -> tuple[Path, dict, str]:
    """The default experiment (metropolis, polite optimal expert), run once per session."""
    run_dir = tmp_path_factory.mktemp("default_run")
    metrics, stdout = run_in_process(run_dir)
    return run_dir, metrics, stdout


@pytest.fixture(scope="module")
def default_dir(default_run):
    """The default run's dir (the first item of `default_run`)."""
    return default_run[0]


# ---------------------------------------------------------------------------------------------
# A run dir's soundness after a fault

FILE_STAGE = {name: stage for stage, name in ARTEFACT_FILE.items()}


def is_timing(key: str) -> bool:
    return key.startswith("time_") and key.endswith("_s")


def check_run_dir(d: Path) -> list[str]:
    """The consistency checks any run dir must pass, killed or not; returns the problems
    (empty when the dir is sound), so a failing kill can be reported with its context."""
    problems: list[str] = []
    arts = {}
    for path in sorted(d.glob("*.mcap")):
        try:
            arts[FILE_STAGE[path.name]] = read_artefact(path)
        except Exception as e:  # noqa: BLE001 - any failure to read is the finding
            problems.append(f"{path.name} does not read: {type(e).__name__}: {e}")
    for later, art in arts.items():
        for earlier, other in arts.items():
            recorded = art.metadata.get(INPUT_KEY + earlier)
            if recorded is not None and recorded != other.digest:
                problems.append(f"{ARTEFACT_FILE[later]} was made from another "
                                f"{ARTEFACT_FILE[earlier]} (recorded {recorded[:12]}, "
                                f"present {other.digest[:12]})")
    metrics_path = d / "metrics.json"
    if metrics_path.exists():
        if "evaluate" not in arts:
            problems.append("metrics.json without eval.mcap")
        else:
            try:
                metrics = json.loads(metrics_path.read_text())
            except ValueError as e:
                problems.append(f"metrics.json does not parse: {e}")
            else:
                in_eval = arts["evaluate"].one(topics.EVAL_METRICS)
                if {k: v for k, v in metrics.items() if not is_timing(k)} != in_eval:
                    problems.append("metrics.json is not the one that came with eval.mcap")
    return problems


# ---------------------------------------------------------------------------------------------
# Metropolis with a wall across the room at y = 8 (0.1 m thick) and a 1 m gap at x 4.3..5.3,
# plus a table. The starts on the room's border (closer than robot_radius to it) are dropped;
# every remaining start lies south of the wall, the goal (5.5, 9) north of it.
ROBOT_RADIUS = 0.2
GAP = (4.3, 5.3)
WALL_Y = 8.0
WALL = [[[0.0, 7.95], [GAP[0], 7.95], [GAP[0], 8.05], [0.0, 8.05]],
        [[GAP[1], 7.95], [10.0, 7.95], [10.0, 8.05], [GAP[1], 8.05]]]
TABLE = [[8.0, 3.3], [9.0, 3.3], [9.0, 4.0], [8.0, 4.0]]
INNER_STARTS = [[0.5, 0.5], [2.0, 3.0], [8.5, 5.2], [4.0, 3.0]]


def walled_metropolis() -> dict:
    data = json.loads(METROPOLIS.read_text())
    data.update(name="walled", starts=INNER_STARTS, robot_radius=ROBOT_RADIUS,
                obstacles=WALL + [TABLE])
    return data


def moved_metropolis(shift: tuple[float, float]) -> dict:
    """metropolis.json's data with every coordinate moved by `shift` (dx, dy) m."""
    return moved_scene(json.loads(METROPOLIS.read_text()), shift)


def moved_scene(data: dict, shift: tuple[float, float]) -> dict:
    """A scene file's data with its room (if it has one: a map's scene has none), persons,
    starts and goal moved by `shift` (dx, dy) m."""
    dx, dy = shift
    moved = json.loads(json.dumps(data))
    if "room" in moved:
        room = moved["room"]
        room.update(x_min=room["x_min"] + dx, x_max=room["x_max"] + dx,
                    y_min=room["y_min"] + dy, y_max=room["y_max"] + dy)
    for p in moved["persons"]:
        p["x"] += dx
        p["y"] += dy
    moved["starts"] = [[x + dx, y + dy] for x, y in moved["starts"]]
    moved["goal"] = [moved["goal"][0] + dx, moved["goal"][1] + dy]
    return moved


def write_json(path: Path, data: dict) -> Path:
    path.write_text(json.dumps(data))
    return path


def one_line(err: pytest.ExceptionInfo) -> str:
    text = str(err.value)
    assert text and "\n" not in text and "Traceback" not in text
    return text


# ---------------------------------------------------------------------------------------------
# Writing real ROS bags

ROS2 = get_typestore(Stores.ROS2_HUMBLE)
ROS1 = get_typestore(Stores.ROS1_NOETIC)


def header(ts, stamp_ns: int, frame: str):
    t = ts.types
    stamp = t["builtin_interfaces/msg/Time"](sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
    if ts is ROS1:
        return t["std_msgs/msg/Header"](seq=0, stamp=stamp, frame_id=frame)
    return t["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)


def pose(ts, x: float, y: float):
    t = ts.types
    return t["geometry_msgs/msg/Pose"](
        position=t["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=0.0),
        orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0))


def make_msg(ts, msgtype: str, stamp: int, frame: str, data: np.ndarray):
    """A message of `msgtype`: a Path through the points `data` (K, 2) or a pose at `data`."""
    t = ts.types
    h = header(ts, stamp, frame)
    if msgtype == "nav_msgs/msg/Path":
        poses = [t["geometry_msgs/msg/PoseStamped"](header=h, pose=pose(ts, x, y)) for x, y in data]
        return t[msgtype](header=h, poses=poses)
    if msgtype == "geometry_msgs/msg/PoseStamped":
        return t[msgtype](header=h, pose=pose(ts, *data))
    cov = t["geometry_msgs/msg/PoseWithCovariance"](pose=pose(ts, *data),
                                                    covariance=np.zeros(36))
    if msgtype == "geometry_msgs/msg/PoseWithCovarianceStamped":
        return t[msgtype](header=h, pose=cov)
    assert msgtype == "nav_msgs/msg/Odometry"
    zero = t["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    twist = t["geometry_msgs/msg/TwistWithCovariance"](
        twist=t["geometry_msgs/msg/Twist"](linear=zero, angular=zero), covariance=np.zeros(36))
    return t[msgtype](header=h, child_frame_id="base_link", pose=cov, twist=twist)


def write_bag(path: Path, topics: dict[str, tuple[str, list[np.ndarray]]],
              frame: str | list[str] = "map", storage: str = "mcap",
              arrival: list[int] | None = None) -> Path:
    """Write `topics` {name: (msgtype, [data per message])}; storage mcap|sqlite3|ros1;
    `frame` is every message's frame_id, or one per message. Message k's header stamp is
    1 s + k·0.1 s; `arrival` (a permutation of the messages, or of some of them: the others
    are not written) is the order they arrive in, the bag's log times (default: in stamp
    order)."""
    ts = ROS1 if storage == "ros1" else ROS2
    if storage == "ros1":
        writer = Writer1(path)
    else:
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        writer = Writer2(path, version=9, storage_plugin=plugin)
    with writer:
        for name, (msgtype, items) in topics.items():
            conn = writer.add_connection(name, msgtype, typestore=ts)
            for slot, k in enumerate(range(len(items)) if arrival is None else arrival):
                stamp = 10**9 + k * 10**8
                frame_id = frame if isinstance(frame, str) else frame[k]
                msg = make_msg(ts, msgtype, stamp, frame_id,
                               np.asarray(items[k], dtype=float))
                raw = ts.serialize_ros1(msg, msgtype) if storage == "ros1" else \
                    ts.serialize_cdr(msg, msgtype)
                writer.write(conn, 10**9 + slot * 10**8, raw)
    return path


# ---------------------------------------------------------------------------------------------
# Two routes to the goal, a graph small enough for hand computations

TWO_ROUTES_GAMMA = 0.9


def two_routes():
    """Start 0, goal 3 (terminal). Route A: 0→3 directly (1 s, feature 1.0); route B:
    0→1→3 (1 s + 1 s, features 0.2 and 0.3); node 2 is a dead end reached from 1."""
    src, dst = [0, 0, 1, 1], [3, 1, 3, 2]
    feats = [[1.0], [0.2], [0.3], [0.0]]
    mdp = GraphMDP(src, dst, np.ones(4), feats, [False, False, False, True],
                   MDPParams(gamma=TWO_ROUTES_GAMMA, time_cost=0.0))
    edge = {(s, d): i for i, (s, d) in enumerate(zip(mdp.src, mdp.dst, strict=True))}
    route_a = GraphPath([0, 3], [edge[0, 3]], True)
    route_b = GraphPath([0, 1, 3], [edge[0, 1], edge[1, 3]], True)
    return mdp, route_a, route_b


# ---------------------------------------------------------------------------------------------
# Recordings as they really occur: metropolis drives stepping exactly 0.1 m (so resampling a
# pose stream at 0.1 m gives them back), recorded running on into the goal disk and beyond,
# and a robot's pose stream with pauses

METROPOLIS_STARTS = np.array([[0.5, 0.5], [4.0, 0.1], [2.0, 3.0], [8.5, 5.2], [8.9, 0.1],
                              [0.1, 8.5], [4.0, 3.0]])
METROPOLIS_GOAL = np.array([5.5, 9.0])
GOAL_TOLERANCE = 0.3  # the world model's default


def stepped(corners: list[list[float]], goal: np.ndarray = METROPOLIS_GOAL,
            step: float = 0.1) -> np.ndarray:
    """Points exactly `step` apart along the corners (each piece a multiple of `step` long),
    then on towards the goal up to its first point inside the goal disk: a polyline as the
    goal-disk cut leaves it, and a fixed point of resampling at `step`."""
    c = np.asarray(corners, float)
    pts = [c[0]]
    for a, b in zip(c[:-1], c[1:], strict=True):
        n = round(np.linalg.norm(b - a) / step)
        assert abs(n * step - np.linalg.norm(b - a)) < 1e-9, "piece not a multiple of the step"
        u = (b - a) / np.linalg.norm(b - a)
        pts += [a + k * step * u for k in range(1, n + 1)]
    last = pts[-1]
    u = (goal - last) / np.linalg.norm(goal - last)
    k = 1
    while np.linalg.norm(last + k * step * u - goal) > GOAL_TOLERANCE:
        pts.append(last + k * step * u)
        k += 1
    return np.vstack(pts + [last + k * step * u])


# Two drives in metropolis, from start 0 and from start 2, clear of the persons' body disks
CLEAN_DRIVES = [stepped([[0.5, 0.5], [0.5, 4.0], [3.5, 8.0]]),
                stepped([[2.0, 3.0], [2.9, 4.2], [2.9, 8.0]])]


def into_the_disk(clean: np.ndarray) -> np.ndarray:
    """A recording of the clean polyline that does not stop at its first point in the goal
    disk: it runs on (a pose every 5 cm), past the goal and out of the room."""
    first_in = clean[-1]
    u = (first_in - clean[-2]) / np.linalg.norm(first_in - clean[-2])
    assert np.linalg.norm(first_in - METROPOLIS_GOAL) <= GOAL_TOLERANCE
    beyond = [first_in + k * 0.05 * u for k in range(40)] + [np.array([12.0, 12.0])]
    return np.vstack([clean[:-1], beyond])


def pause(at: np.ndarray, n: int) -> np.ndarray:
    return np.repeat(np.asarray(at, float)[None], n, axis=0)


def walk(a: np.ndarray, b: np.ndarray, step: float = 0.05) -> np.ndarray:
    """Poses from a (excluded) to b (included) at most `step` apart."""
    n = max(1, int(np.ceil(np.linalg.norm(b - a) / step)))
    return a + np.linspace(0.0, 1.0, n + 1)[1:, None] * (b - a)


def odometry(drives: list[np.ndarray], goal: np.ndarray = METROPOLIS_GOAL) -> np.ndarray:
    """A robot's pose stream: it waits at each drive's start, drives it into the goal disk and
    past the goal, waits there, and is driven back (straight) to the next drive's start."""
    parts: list[np.ndarray] = []
    for k, drive in enumerate(drives):
        if k:
            parts.append(walk(parts[-1][-1], drive[0]))
        parts += [pause(drive[0], 20), into_the_disk(drive)[:-1], pause(goal + [0.05, 0.0], 10)]
    parts.append(walk(parts[-1][-1], np.array([8.0, 1.0])))  # wanders off: never back at goal
    return np.vstack(parts)
