"""Hand a learned reward back to ROS: a Nav2 costmap mask and a ROS 2 bag of paths and people.

    birlg-export RUN_DIR          (or: python -m pipeline.tools.export RUN_DIR)

Writes RUN_DIR/export/ (replaced as a whole, never left half-written):

- `costmap.yaml` + `costmap.pgm`: a map_server map in `mode: scale` holding the learned
  reward's cost per metre of path at every cell, for the features that depend on position
  only: cost = −Σ_j w_j · density_j(cell centre). Occupancy 0 is free, 1..99 the learned cost
  scaled to the map's largest cost, 100 (black) obstacles and person body disks. Nav2's
  map_server loads it unchanged, as a costmap-filter mask (KeepoutFilter, SpeedFilter) or
  for a static layer; the YAML's comment lines give the run, the weights and the scale.
- `paths/`: a ROS 2 bag (mcap storage, written with rosbags) with the learned paths
  (nav_msgs/msg/Path, one per start: adaptive graph on /birlg/learned_paths, reference
  roadmap on /birlg/learned_paths_ref), the demonstrations on /birlg/demos (the held-out
  ones too: the bag's metadata names them, and who demonstrated each) and the people as
  visualization_msgs/msg/MarkerArray on /birlg/people, all in frame `map`; message k of a
  topic is stamped k seconds, so the same run gives the same bag.

How map_server turns the image into occupancy (nav2_map_server map_io.cpp, `mode: scale`):
occ = 1 − v/255 for a grey value v (negate 0); occ > occupied_thresh gives 100, occ <
free_thresh 0, anything between rint(100 (occ − free_thresh) / (occupied_thresh −
free_thresh)). With the thresholds below a white cell is free, black is 100 and the grey
levels written for occupancy 1..99 decode to exactly that occupancy, so no learned cost
becomes lethal. Costmap2D and the KeepoutFilter then read occupancy k as cost
round(254 k / 100): 99 is 251, below the inscribed cost 253.

How a planner weighs the mask against distance: Smac 2D (nav2_smac_planner node_2d.cpp)
charges a step of length s onto a cell of cost c as s (1 + cost_travel_multiplier c / 252);
the learned reward (undiscounted) charges s (f + cost), f = time_cost / speed − w_length the
cost of a free metre. With cost_travel_multiplier = (cost of occupancy 99 / f) 252 / 251 the
two agree up to the 1..99 quantisation, and the YAML says so. NavFn (navfn.cpp) charges
int(50 + 0.8 c) per cell, a fixed factor.
"""

from __future__ import annotations

from pipeline.errors import restore_handlers, stop_quietly_while_starting

_HANDLERS_BEFORE_IMPORTS = stop_quietly_while_starting()  # rosbags, PIL, scipy: ~1 s

import argparse
import dataclasses
import io
import json
import math
import os
import shutil
import sys
import uuid
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike
from PIL import Image
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from pipeline.app.build import config_section, learned_feature_params, learned_weight_box
from pipeline.app.context import input_path_exists, resolve_path
from pipeline.app.provenance import check_inputs
from pipeline.app.rundir import COMPLETE, STATUS_FILE, UNKNOWN, acquire_lock, read_status
from pipeline.artefacts import Artefact, codec, export_topics, read_artefact, topics
from pipeline.artefacts.topics import ARTEFACT_FILE
from pipeline.core.features import NOT_A_DENSITY, FeatureModel, FeatureParams
from pipeline.core.graph_mdp import MDPParams
from pipeline.core.obstacles import OccupancyGrid, rasterise
from pipeline.core.world import OBSTACLE_RESOLUTION, Scene
from pipeline.errors import PipelineError, report
from pipeline.tools import run_tool

restore_handlers(_HANDLERS_BEFORE_IMPORTS)

EXPORT_DIR = "export"
COSTMAP_YAML, COSTMAP_IMAGE = "costmap.yaml", "costmap.pgm"
BAG_DIR = "paths"
FRAME = "map"

TOPIC_LEARNED, TOPIC_LEARNED_REF = export_topics.LEARNED, export_topics.LEARNED_REF
LEARNED_TOPICS = {"graph": TOPIC_LEARNED, "ref": TOPIC_LEARNED_REF}  # by where they were planned
TOPIC_DEMOS, TOPIC_PEOPLE = export_topics.DEMOS, export_topics.PEOPLE

# map_server thresholds: a white cell (occ 0) is below free_thresh, black (occ 1) above
# occupied_thresh, every grey between maps linearly onto occupancy 0..100.
FREE_THRESH, OCCUPIED_THRESH = 0.001, 0.999
COSTMAP_CHUNK_CELLS = 250_000  # cells whose densities are computed at once
LETHAL, MAX_LEARNED = 100, 99  # occupancy of obstacles and bodies; of the costliest learned cell
NAV2_LETHAL = 254  # Costmap2D's cost of occupancy 100; occupancy k is round(254 k / 100)
SMAC_COST_DIVISOR = 252.0  # Smac 2D normalises a cell's cost by 252 (node_2d.cpp)
# Smac 2D's cost_travel_multiplier when left unset: in Nav2's code (smac_planner_2d.cpp); in
# older releases and in its documentation
SMAC_UNSET_NOW, SMAC_UNSET_OLDER = 1.0, 2.0
NAVFN_NEUTRAL, NAVFN_FACTOR = 50, 0.8  # NavFn: a cell of cost c costs int(50 + 0.8 c) (navfn.cpp)

PERSON_HEIGHT = 1.7  # m, drawn height of the body cylinders
ARROW_LENGTH, ARROW_SHAFT, ARROW_HEAD = 0.6, 0.06, 0.12  # m, person heading arrows
BODY_RGBA = (0.92, 0.51, 0.16, 0.9)  # orange persons and red links, as in the viewer/figures
ARROW_RGBA = (0.55, 0.27, 0.05, 1.0)
LINK_RGBA = (0.82, 0.16, 0.16, 1.0)
LINK_WIDTH = 0.05  # m


# -- the costmap -------------------------------------------------------------------------------


def grey_of_occupancy(occupancy: np.ndarray) -> np.ndarray:
    """The PGM grey value (uint8) that map_server (`mode: scale`, negate 0, the thresholds
    above) reads as each occupancy 0..100: 0 white, 100 black, k in between at the centre of
    k's interval, so rounding the grey to an integer never changes the occupancy."""
    k = np.asarray(occupancy, dtype=float)
    occ = FREE_THRESH + k / 100.0 * (OCCUPIED_THRESH - FREE_THRESH)
    grey = np.rint(255.0 * (1.0 - occ))
    grey = np.where(k <= 0, 255, np.where(k >= LETHAL, 0, grey))
    return grey.astype(np.uint8)


@dataclass(frozen=True)
class Costmap:
    """The learned reward on a grid: per-cell cost, occupancy 0..100 and what made them."""
    grid: OccupancyGrid  # origin, resolution, shape; `occupied` = the scene's obstacles
    cost: np.ndarray  # (H, W) −Σ_j w_j density_j at the cell centres (row 0 = lowest y)
    occupancy: np.ndarray  # (H, W) uint8: 0 free, 1..99 learned cost, 100 lethal
    lethal: np.ndarray  # (H, W) bool: obstacle or person body disk
    scale: float  # cost of occupancy 99 (0: the learned cost is 0 everywhere)
    in_mask: tuple[str, ...]  # features whose densities make up the cost
    left_out: dict[str, str]  # feature -> why it is not in the mask
    n_negative: int  # free cells whose cost was negative (a rewarding feature), shown as 0
    # the learned reward's cost of a metre anywhere, the MDP's cost per second at its speed
    # less w_length: the unit that makes the mask's costs a trade-off a planner can copy
    free_metre: float = 0.0
    discounted: bool = False  # the MDP discounts (mdp.gamma < 1): no cost per metre holds

    def smac_multiplier(self) -> float | None:
        """Smac 2D's cost_travel_multiplier that weighs the mask against distance as the
        learned reward does (None without a scale, or without a cost per metre)."""
        if not self.scale > 0 or self.discounted or not self.free_metre > 0:
            return None
        return self.scale / self.free_metre * SMAC_COST_DIVISOR / nav2_cost(MAX_LEARNED)

    def no_cost(self) -> str:
        """Why a costmap without scale (`scale` 0) is free outside obstacles and bodies."""
        if self.n_negative:
            return (f"the learned cost is nowhere positive: it is negative (the reward attracts "
                    f"the robot) in {self.n_negative} cells, shown as free, and 0 elsewhere")
        return "the learned cost is 0 everywhere"


def nav2_cost(occupancy: ArrayLike) -> np.ndarray:
    """The Costmap2D cost of map cells of these occupancies (0..100): std::round, halves away
    from zero (numpy's rint takes them to even: 190 for occupancy 75, not Nav2's 191)."""
    return np.floor(NAV2_LETHAL * np.asarray(occupancy, dtype=float) / LETHAL + 0.5)


def export_grid(scene: Scene) -> OccupancyGrid:
    """The scene's obstacle raster: its map's grid (polygons burnt in) when it has a map, else
    a grid over the room at the obstacle resolution."""
    if scene.obstacles is not None:
        return scene.obstacles.grid
    return rasterise([], None, scene.room.bounds, OBSTACLE_RESOLUTION)


def build_costmap(scene: Scene, params: FeatureParams, weights: np.ndarray,
                  mdp: MDPParams | None = None) -> Costmap:
    """The cost per metre of the learned reward's position-only features at every cell; `mdp`
    the formulation it was planned with (its cost per second is part of a metre's cost;
    default: the pipeline's default, goal reaching)."""
    mdp = mdp or MDPParams()
    weights = np.asarray(weights, dtype=float)
    names = tuple(params.features)
    if weights.shape != (len(names),):
        raise PipelineError(f"{len(weights)} learned weights for {len(names)} features "
                            f"{list(names)}")
    grid = export_grid(scene)
    in_mask, left_out = [], {}
    for j, (name, feature) in enumerate(zip(names, params.selected(), strict=True)):
        if feature.kind in NOT_A_DENSITY:
            left_out[name] = f"not a density of position ({NOT_A_DENSITY[feature.kind]})"
        elif feature.kind == "length":
            left_out[name] = "uniform (the same cost per metre everywhere)"
        else:
            in_mask.append(j)
    cost = np.zeros(grid.shape)
    if in_mask:
        model = FeatureModel.from_scene(
            scene, dataclasses.replace(params, features=[names[j] for j in in_mask]))
        h, w = grid.shape
        step = max(1, COSTMAP_CHUNK_CELLS // w)
        # row blocks: a building's map has millions of cells, each with several densities
        for r0 in range(0, h, step):
            rows = slice(r0, min(h, r0 + step))
            density = model.densities(grid.cell_centres(rows).reshape(-1, 2))
            block = np.zeros(len(density))
            for k, j in enumerate(in_mask):  # in feature order: the same bits every time
                block -= weights[j] * density[:, k]
            cost[rows] = block.reshape(-1, w)
    lethal = grid.occupied | body_cells(scene, grid)
    positive = np.maximum(cost, 0.0)
    free = ~lethal
    scale = float(positive[free].max()) if free.any() else 0.0
    occupancy = np.zeros(grid.shape, dtype=np.uint8)
    if scale > 0:
        occupancy = np.rint(MAX_LEARNED * positive / scale).astype(np.uint8)
    occupancy[lethal] = LETHAL
    length = -sum(weights[j] for j, feature in enumerate(params.selected())
                  if feature.kind == "length")
    return Costmap(grid, cost, occupancy, lethal, scale, tuple(names[j] for j in in_mask),
                   left_out, int((cost[free] < 0).sum()),
                   float(mdp.time_cost / mdp.speed + length), not mdp.undiscounted)


def body_cells(scene: Scene, grid: OccupancyGrid) -> np.ndarray:
    """(H, W) bool: the cells whose centre lies in a person's body disk, tested in a window
    round each person (the same test as scene.in_body over every centre; on a SLAM map of
    16 million cells that took 3.6 s)."""
    mask = np.zeros(grid.shape, dtype=bool)
    r = scene.body_radius
    for xy in scene.person_xy:
        window, centres = grid.window(xy - r, xy + r)
        mask[window] |= scene.in_body(centres.reshape(-1, 2)).reshape(centres.shape[:2])
    return mask


def _num(x: float) -> str:
    """A float as YAML reads it back exactly (shortest round-trip repr)."""
    return repr(float(x))


def costmap_yaml(costmap: Costmap, names: tuple[str, ...], weights: np.ndarray,
                 about: list[str], unmoved: Sequence[str] = ()) -> str:
    """The map_server YAML, its comment lines saying what the map holds."""
    g = costmap.grid
    w = ", ".join(f"{n}={_num(v)}" for n, v in zip(names, weights, strict=True))
    terms = " + ".join(f"w_{n} * {n}_density" for n in costmap.in_mask) or "0"
    lines = ["# BIRL-G learned-reward costmap, written by birlg-export (ROS map_server format)"]
    lines += [f"# {line}" for line in about]
    lines.append(f"# learned weights: {w}")
    if unmoved:
        lines.append(f"# not learned: {', '.join(unmoved)} (left at the middle of the weight "
                     "box, no demonstration moved them: where in the mask, their cost is the "
                     "box's guess)")
    lines.append(f"# features in the mask: {', '.join(costmap.in_mask) or 'none'}")
    for name, why in costmap.left_out.items():
        lines.append(f"# left out: {name}: {why}")
    lines.append(f"# cost per metre of path at a cell centre = -({terms}), reward units per m")
    if costmap.scale > 0:
        lines.append(f"# scale: occupancy k in 1..{MAX_LEARNED} = cost k/{MAX_LEARNED} * "
                     f"{_num(costmap.scale)}; occupancy {MAX_LEARNED} = cost "
                     f"{_num(costmap.scale)} per m (the largest outside obstacles and bodies)")
    else:
        lines.append(f"# scale: {costmap.no_cost()} (occupancy 0 outside obstacles and "
                     "bodies)")
    lines += [f"# {line}" for line in trade_off(costmap)]
    lines.append(f"# occupancy 0 = free (white); {LETHAL} = obstacle or person body disk (black)")
    if costmap.n_negative:
        lines.append(f"# {costmap.n_negative} cells with a negative cost (a rewarding feature) "
                     "are shown as free")
    lines.append(f"# grey value of occupancy k: round(255 * (1 - ({_num(FREE_THRESH)} + k/100 * "
                 f"{_num(OCCUPIED_THRESH - FREE_THRESH)})))")
    # a comment stays one line whatever it quotes (a run dir or scene name with a line break
    # became an uncommented second `image:` key, which map_server may take)
    lines = [" ".join(line.splitlines()) for line in lines]
    lines += [f"image: {COSTMAP_IMAGE}", "mode: scale", f"resolution: {_num(g.resolution)}",
              f"origin: [{_num(g.origin[0])}, {_num(g.origin[1])}, 0.0]", "negate: 0",
              f"occupied_thresh: {_num(OCCUPIED_THRESH)}", f"free_thresh: {_num(FREE_THRESH)}"]
    return "\n".join(lines) + "\n"


def no_trade_off(costmap: Costmap) -> str | None:
    """Why no planner setting weighs the mask against distance as learned (None when one
    does, or the mask is free)."""
    if not costmap.scale > 0:
        return None
    if costmap.discounted:
        return "the learned reward discounts (mdp.gamma < 1), which no cost per metre reproduces"
    if costmap.free_metre > 0:
        return None
    free = "costs nothing (w_length cancels the cost per second)" if costmap.free_metre == 0 \
        else (f"gains reward ({_num(-costmap.free_metre)} per m: w_length outweighs the cost per "
              "second)")
    return (f"a metre of free path {free}, so the learned reward has no cost of distance to "
            "weigh the mask against")


def trade_off(costmap: Costmap) -> list[str]:
    """How to weigh the mask against distance as the learned reward does, or why no planner
    setting can (nothing when the mask is free)."""
    multiplier = costmap.smac_multiplier()
    if multiplier is None:
        reason = no_trade_off(costmap)
        return [] if reason is None else [f"trade-off: none: {reason}"]
    ratio = costmap.scale / costmap.free_metre
    navfn = (int(NAVFN_NEUTRAL + NAVFN_FACTOR * nav2_cost(MAX_LEARNED)) - NAVFN_NEUTRAL) \
        / NAVFN_NEUTRAL
    return [f"trade-off: a metre at occupancy {MAX_LEARNED} adds {significant(ratio, 3)} times "
            f"the cost of a metre of free path ({_num(costmap.free_metre)} per m: the cost per "
            "second at the MDP's speed, less w_length)",
            "Smac 2D weighs it so with cost_travel_multiplier: "
            f"{ros_double(multiplier)} (left unset, {SMAC_UNSET_NOW:g} in Nav2's code and "
            f"{SMAC_UNSET_OLDER:g} in older releases, it "
            f"weighs the mask {_times(SMAC_UNSET_NOW / multiplier)} and "
            f"{_times(SMAC_UNSET_OLDER / multiplier)}); NavFn, whose factor is fixed, adds "
            f"{navfn:.3g} times a free step ({_times(navfn / ratio)})"]


def ros_double(x: float) -> str:
    """`x` to 4 significant digits as a ROS parameter file reads a double: with a decimal
    point and no exponent (`24` would be an integer, which a double parameter refuses)."""
    text = significant(x, 4)
    return text if "." in text else f"{text}.0"


def significant(x: float, digits: int) -> str:
    """`x` to this many significant digits, never with an exponent (1.49e+03 reads badly)."""
    return np.format_float_positional(x, precision=digits, fractional=False, trim="-")


def _times(factor: float) -> str:
    """A planner's weight of the mask against the learned one, in words."""
    if 0.9 <= factor <= 1.1:
        return "about as learned"
    if factor > 1:
        return f"{_factor(factor)} times as much as learned"
    return f"{_factor(1 / factor)} times too little"


def _factor(x: float) -> str:
    """Two significant digits below 10, whole numbers above (never an exponent: 2.1e+02)."""
    return f"{x:.2g}" if x < 10 else f"{x:.0f}"


def costmap_pgm(costmap: Costmap) -> bytes:
    """The binary PGM (P5): image row 0 is the map's top (largest y), as map_server reads."""
    # the grey of each of the 101 occupancies, looked up (a building's map: 16 million cells)
    grey = grey_of_occupancy(np.arange(LETHAL + 1))[costmap.occupancy[::-1]]
    out = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(grey)).save(out, format="PPM")
    return out.getvalue()


# -- the bag -----------------------------------------------------------------------------------


def path_yaws(points: np.ndarray) -> np.ndarray:
    """Heading (n,) at each point of a polyline: along the segment that leaves it (the last
    point: the one that reaches it); repeated points take the heading of the nearest segment
    of non-zero length before them (after them at the start); 0 without any."""
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    if len(p) < 2:
        return np.zeros(len(p))
    d = np.diff(p, axis=0)
    moving = np.hypot(d[:, 0], d[:, 1]) > 0
    if not moving.any():
        return np.zeros(len(p))
    seg = np.arctan2(d[:, 1], d[:, 0])
    # forward fill the headings of zero-length segments, then back fill the leading ones
    last = np.maximum.accumulate(np.where(moving, np.arange(len(seg)), -1))
    last[last < 0] = np.flatnonzero(moving)[0]
    seg = seg[last]
    return np.append(seg, seg[-1])


class BagMessages:
    """ROS 2 messages built with a rosbags typestore."""

    def __init__(self, typestore: Typestore) -> None:
        self.store = typestore
        self.t = typestore.types

    def header(self, stamp_s: int):
        t = self.t
        return t["std_msgs/msg/Header"](stamp=t["builtin_interfaces/msg/Time"](sec=stamp_s,
                                                                               nanosec=0),
                                        frame_id=FRAME)

    def pose(self, x: float, y: float, z: float = 0.0, yaw: float = 0.0):
        t = self.t
        return t["geometry_msgs/msg/Pose"](
            position=t["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=float(z)),
            orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw / 2),
                                                         w=math.cos(yaw / 2)))

    def path(self, points: np.ndarray, stamp_s: int):
        """nav_msgs/msg/Path through the points, each pose heading along the path."""
        t = self.t
        p = np.asarray(points, dtype=float).reshape(-1, 2)
        poses = [t["geometry_msgs/msg/PoseStamped"](header=self.header(stamp_s),
                                                    pose=self.pose(x, y, yaw=yaw))
                 for (x, y), yaw in zip(p, path_yaws(p), strict=True)]
        return t["nav_msgs/msg/Path"](header=self.header(stamp_s), poses=poses)

    def marker(self, ns: str, ident: int, kind: str, pose, scale: tuple[float, float, float],
               rgba: tuple[float, ...], points: list | None = None):
        t = self.t
        marker = t["visualization_msgs/msg/Marker"]
        return marker(
            header=self.header(0), ns=ns, id=int(ident), type=getattr(marker, kind),
            action=marker.ADD, pose=pose,
            scale=t["geometry_msgs/msg/Vector3"](x=scale[0], y=scale[1], z=scale[2]),
            color=t["std_msgs/msg/ColorRGBA"](r=rgba[0], g=rgba[1], b=rgba[2], a=rgba[3]),
            lifetime=t["builtin_interfaces/msg/Duration"](sec=0, nanosec=0), frame_locked=False,
            points=points or [], colors=[], texture_resource="",
            texture=t["sensor_msgs/msg/CompressedImage"](header=self.header(0), format="",
                                                         data=np.zeros(0, dtype=np.uint8)),
            uv_coordinates=[], text="", mesh_resource="",
            mesh_file=t["visualization_msgs/msg/MeshFile"](filename="",
                                                           data=np.zeros(0, dtype=np.uint8)),
            mesh_use_embedded_materials=False)

    def people(self, scene: Scene):
        """visualization_msgs/msg/MarkerArray: per person (ids = person ids) a body cylinder
        (ns `body`) and a heading arrow above it (ns `heading`); the social links as one
        LINE_LIST (ns `relations`, id 0) when the scene has relations."""
        t = self.t
        r = scene.body_radius
        markers = []
        for p in scene.persons:
            markers.append(self.marker("body", p.id, "CYLINDER",
                                       self.pose(p.x, p.y, PERSON_HEIGHT / 2),
                                       (2 * r, 2 * r, PERSON_HEIGHT), BODY_RGBA))
            markers.append(self.marker("heading", p.id, "ARROW",
                                       self.pose(p.x, p.y, PERSON_HEIGHT + ARROW_HEAD, p.theta),
                                       (ARROW_LENGTH, ARROW_SHAFT, ARROW_HEAD), ARROW_RGBA))
        a, b = scene.links
        if len(a):
            ends = [t["geometry_msgs/msg/Point"](x=float(x), y=float(y), z=0.0)
                    for pair in zip(a, b, strict=True) for x, y in pair]
            markers.append(self.marker("relations", 0, "LINE_LIST", self.pose(0.0, 0.0),
                                       (LINK_WIDTH, 0.0, 0.0), LINK_RGBA, ends))
        return t["visualization_msgs/msg/MarkerArray"](markers=markers)


def write_bag(path: Path, scene: Scene, learned: dict[str, list[np.ndarray]],
              demos: list[np.ndarray], about: dict[str, str]) -> dict[str, int]:
    """The ROS 2 bag (mcap storage) at `path` (a new directory), `about` in its metadata's
    custom_data; returns the message count per topic."""
    # Humble's message definitions; Jazzy's Path and MarkerArray are the same (same RIHS01).
    store = get_typestore(Stores.ROS2_HUMBLE)
    build = BagMessages(store)
    per_topic = {
        TOPIC_LEARNED: ("nav_msgs/msg/Path",
                        [build.path(p, k) for k, p in enumerate(learned["graph"])]),
        TOPIC_LEARNED_REF: ("nav_msgs/msg/Path",
                            [build.path(p, k) for k, p in enumerate(learned["ref"])]),
        TOPIC_DEMOS: ("nav_msgs/msg/Path", [build.path(p, k) for k, p in enumerate(demos)]),
        TOPIC_PEOPLE: ("visualization_msgs/msg/MarkerArray", [build.people(scene)]),
    }
    never = QosTime(sec=0, nsec=0)
    # Metadata version 8: Humble cannot parse version 9's QoS lists (ros2/rosbag2#2013);
    # Iron, Jazzy and later read version 8.
    with Writer(path, version=8, storage_plugin=StoragePlugin.MCAP) as writer:
        for key, value in about.items():
            writer.set_custom_data(key, value)
        for topic, (msgtype, messages) in per_topic.items():
            # Latched (reliable, transient local, all messages kept): `ros2 bag play`
            # republishes it so, and a display opened later still gets the static scene.
            qos = Qos(QosHistory.KEEP_LAST, max(1, len(messages)), QosReliability.RELIABLE,
                      QosDurability.TRANSIENT_LOCAL, never, never, QosLiveliness.AUTOMATIC,
                      never, False)
            conn = writer.add_connection(topic, msgtype, typestore=store,
                                         offered_qos_profiles=[qos])
            for k, msg in enumerate(messages):
                writer.write(conn, k * 10**9, store.serialize_cdr(msg, msgtype))
    return {topic: len(messages) for topic, (_, messages) in per_topic.items()}


# -- reading a run -----------------------------------------------------------------------------


@dataclass(frozen=True)
class RunReward:
    """What the export needs from a run dir."""
    scene: Scene
    params: FeatureParams
    weights: np.ndarray
    learned: dict[str, list[np.ndarray]]  # "graph" / "ref" -> path per start, in start order
    demos: list[np.ndarray]
    about: list[str]  # lines naming the run
    short: dict[str, list[int]]  # "graph" / "ref" -> the starts whose path stops short
    # the weights the learner left at the middle of its box: nothing moved them
    unmoved: list[str] = dataclasses.field(default_factory=list)
    mdp: MDPParams = dataclasses.field(default_factory=MDPParams)  # as the paths were planned
    demos_about: dict[str, str] = dataclasses.field(default_factory=dict)  # `demos_about`


def _points(art: Artefact, topic: str, msg: dict) -> np.ndarray:
    """A message's `points` as (K, 2) floats, or one line naming the artefact and topic."""
    try:
        points = np.asarray(msg["points"], dtype=float)
    except (KeyError, TypeError, ValueError):
        raise PipelineError(f"artefact {art.path}: a message on '{topic}' has no list of "
                            "points [x, y]") from None
    if points.ndim != 2 or points.shape[1] != 2 or not np.isfinite(points).all():
        raise PipelineError(f"artefact {art.path}: a message on '{topic}' has points of shape "
                            f"{points.shape}, not finite [x, y] pairs")
    return points


def read_run_files(run_dir: Path) -> None:
    """One line when the run dir lacks an artefact the export reads."""
    missing = [ARTEFACT_FILE[s] for s in ("scene", "demos", "birl", "evaluate")
               if not (run_dir / ARTEFACT_FILE[s]).is_file()]
    if missing:
        raise PipelineError(f"run dir {run_dir} has no {', '.join(missing)}: the export needs a "
                            "run through the birl and evaluate stages")


def _given_weights(birl_cfg: dict) -> str:
    """Where a birl=fixed run's weights came from ('' for a run that learned them)."""
    if birl_cfg.get("kind") != "fixed":
        return ""
    source = birl_cfg.get("from_run")
    return (f"given (birl=fixed), from the run {source}" if source
            else "given (birl=fixed birl.weights)")


def _left_at_the_middle(birl_cfg: dict, names: list[str], weights: np.ndarray) -> list[str]:
    """The weights the learner left at the middle of its weight box (this run's, or for
    birl=fixed birl.from_run=RUN the box RUN learned in): no demonstration moved them, so
    their cost in the costmap is the box's guess. None where that box cannot be read."""
    try:
        if birl_cfg.get("kind") == "fixed":
            source = birl_cfg.get("from_run")
            if not source:
                return []
            birl_cfg = config_section(read_artefact(resolve_path(source)
                                                    / ARTEFACT_FILE["birl"]), "birl")
            if birl_cfg.get("kind") == "fixed":
                return []
        middle = learned_weight_box(birl_cfg, len(names)).at_box(weights)["middle"]
    except (PipelineError, OSError, KeyError, TypeError, ValueError):
        return []
    return [n for n, at in zip(names, middle, strict=True) if at]


def read_run(run_dir: Path) -> RunReward:
    """The scene, learned reward, learned paths and demonstrations of a finished run."""
    read_run_files(run_dir)
    scene_art = read_artefact(run_dir / ARTEFACT_FILE["scene"], required_topics=[topics.SCENE])
    scene = codec.decode_scene(scene_art)
    birl = read_artefact(run_dir / ARTEFACT_FILE["birl"],
                         required_topics=[topics.BIRL_EXPERT, topics.BIRL_ITERATION])
    iterations = birl.all(topics.BIRL_ITERATION)
    names = birl.one(topics.BIRL_EXPERT).get("feature_names")
    last = iterations[-1].get("weights") if iterations else None
    try:
        weights = np.asarray(last, dtype=float)
    except (TypeError, ValueError):
        weights = np.zeros(0)
    if not (isinstance(names, list) and all(isinstance(n, str) for n in names)
            and weights.shape == (len(names),) and np.isfinite(weights).all()):
        raise PipelineError(f"artefact {birl.path}: the last '{topics.BIRL_ITERATION}' weights "
                            f"{last} do not match the feature names {names} of "
                            f"'{topics.BIRL_EXPERT}'")
    params = learned_feature_params(birl, names)
    evaluation = read_artefact(run_dir / ARTEFACT_FILE["evaluate"],
                               required_topics=[topics.EVAL_PATHS])
    learned: dict[str, list[tuple[int, np.ndarray]]] = {where: [] for where in LEARNED_TOPICS}
    short: dict[str, list[int]] = {where: [] for where in LEARNED_TOPICS}
    for msg in evaluation.all(topics.EVAL_PATHS):
        where, start = msg.get("graph"), msg.get("start")
        if where in learned and isinstance(start, int):
            learned[where].append((start, _points(evaluation, topics.EVAL_PATHS, msg)))
            if msg.get("success") == 0:
                short[where].append(start)
    paths = {k: [p for _, p in sorted(v, key=lambda sp: sp[0])] for k, v in learned.items()}
    demos_art = read_artefact(run_dir / ARTEFACT_FILE["demos"])
    # artefacts copied in from other runs would give a costmap of one scene with the
    # weights and paths of another: refused as the stages refuse them
    check_inputs({"scene": scene_art, "demos": demos_art, "birl": birl,
                  "evaluate": evaluation})
    demo_msgs = demos_art.messages.get(topics.DEMOS, [])
    demos = [_points(demos_art, topics.DEMOS, m) for m in demo_msgs]
    try:
        mdp = codec.decode_mdp_params(demos_art.one(topics.DEMOS_EXPERT))
    except (KeyError, TypeError, ValueError):  # ParameterError is a ValueError
        raise PipelineError(f"artefact {demos_art.path}: its '{topics.DEMOS_EXPERT}' message has "
                            "no valid MDP settings (gamma, time_cost, r_goal, speed)") from None
    meta = birl.metadata
    about = [f"run: {run_dir.resolve()}",
             f"scene: {scene.name}, seed {meta.get('seed', '?')}, git revision "
             f"{meta.get('git_revision', '?')}",
             # what the export was made from: a later run into the dir changes these
             f"from: birl.mcap content {birl.digest[:16] or '?'}, eval.mcap content "
             f"{evaluation.digest[:16] or '?'}"]
    try:
        birl_cfg = config_section(birl, "birl")
    except PipelineError:  # an older or damaged config: no origin or box to tell of
        birl_cfg = {}
    given = _given_weights(birl_cfg)
    if given:  # a deployment: its weights were given, not learned in this run
        about.append(f"weights: {given}")
    return RunReward(scene, params, weights, paths, demos, about,
                     {k: sorted(v) for k, v in short.items()},
                     _left_at_the_middle(birl_cfg, names, weights), mdp,
                     demos_about(demo_msgs))


def demos_about(demo_msgs: list[dict]) -> dict[str, str]:
    """The bag metadata that tells the demonstrations on /birlg/demos apart (message k is
    demonstration k): who demonstrated each (where the demonstrations name subjects), where
    each came from in its file (where they were read from one) and which were held out of
    learning (evaluate.holdout), since a Path message has room for none of these."""
    about = {}
    for field, key in (("subject", "birlg.demo_subjects"), ("source", "birlg.demo_sources")):
        said = [m.get(field) for m in demo_msgs]
        if any(isinstance(s, str) for s in said):  # JSON: any id reads back as it was
            about[key] = json.dumps([s if isinstance(s, str) else None for s in said],
                                    ensure_ascii=False)
    heldout = [k for k, m in enumerate(demo_msgs) if m.get("heldout") is True]
    if heldout:
        about["birlg.demos_heldout"] = " ".join(map(str, heldout))
    return about


# -- writing the export ------------------------------------------------------------------------


def _sync_tree(root: Path) -> None:
    """fsync every file and directory under root: durable before it gets the final name."""
    for path in sorted(root.rglob("*")) + [root]:
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _partial_name(run_dir: Path, kind: str) -> Path:
    # Not `*.tmp`: the run dir's next pipeline run deletes stale `*.tmp` *files* with unlink.
    return run_dir / f".{EXPORT_DIR}.{os.getpid()}-{uuid.uuid4().hex[:8]}.{kind}"


def _remove_stale_partials(run_dir: Path) -> None:
    """Temporary export dirs of an export that was killed (its process is gone)."""
    for p in run_dir.glob(f".{EXPORT_DIR}.*-*.*"):
        pid = p.name.split(".")[2].split("-")[0]
        if not (p.is_dir() and pid.isdigit()):
            continue
        try:
            os.kill(int(pid), 0)
        except ProcessLookupError:
            shutil.rmtree(p, ignore_errors=True)
        except OSError:  # alive, owned by someone else
            pass


def short_of_goal(short: dict[str, list[int]]) -> list[str]:
    """One warning per topic whose learned paths (some starts') stop short of the goal."""
    return [f"warning: the learned paths from start{'s' * (len(starts) > 1)} "
            f"{', '.join(map(str, starts))} on {topic} stop short of the goal: exported as "
            "they are (a robot following them does not arrive) and named in the bag's "
            "metadata (birlg.short_of_goal)"
            for where, topic in LEARNED_TOPICS.items() if (starts := short[where])]


def export_run(run_dir: Path) -> tuple[Path, Costmap, dict[str, int], list[str]]:
    """Write RUN_DIR/export/ (see the module docstring); returns it, the costmap, the
    bag's message counts and its warnings (`short_of_goal`). The new export is built beside
    the old one and swapped in."""
    run = read_run(run_dir)
    costmap = build_costmap(run.scene, run.params, run.weights, run.mdp)
    final = run_dir / EXPORT_DIR
    partial = _partial_name(run_dir, "partial")
    old = _partial_name(run_dir, "old")
    try:
        partial.mkdir()
        (partial / COSTMAP_IMAGE).write_bytes(costmap_pgm(costmap))
        (partial / COSTMAP_YAML).write_text(costmap_yaml(
            costmap, tuple(run.params.features), run.weights, run.about, run.unmoved))
        short = {topic: " ".join(map(str, run.short[where]))
                 for where, topic in LEARNED_TOPICS.items() if run.short[where]}
        about = {f"birlg.{k}": v for k, v in (line.split(": ", 1) for line in run.about)}
        if short:  # topic: start indices (message k of a topic is start k's path)
            about["birlg.short_of_goal"] = "; ".join(f"{t}: {v}" for t, v in short.items())
        about.update(run.demos_about)
        counts = write_bag(partial / BAG_DIR, run.scene, run.learned, run.demos, about)
        _sync_tree(partial)
        if final.exists():
            os.replace(final, old)
        try:
            os.replace(partial, final)
        except OSError:
            if old.exists():
                os.replace(old, final)  # put the previous export back
            raise
    finally:
        shutil.rmtree(partial, ignore_errors=True)
        if old.is_dir() and not old.is_symlink():
            shutil.rmtree(old, ignore_errors=True)
        else:  # `export` was a file or a link (rmtree refuses links: it would stay for good)
            old.unlink(missing_ok=True)
    return final, costmap, counts, short_of_goal(run.short)


def check_run_dir(run_dir: Path) -> None:
    """One line, as a PipelineError, when the run dir cannot be exported."""
    if not input_path_exists(run_dir, str(run_dir)):  # (a name too long: one line too)
        raise PipelineError(f"run dir {run_dir} not found")
    if not run_dir.is_dir():
        raise PipelineError(f"run dir {run_dir} is not a directory")
    status = read_status(run_dir)
    if status.state == UNKNOWN and status.error:  # damaged, not merely older than status.json
        raise PipelineError(f"run dir {run_dir} has {status.error}: whether its run finished is "
                            "not known; rerun it into this dir")
    if status.state not in (COMPLETE, UNKNOWN):  # unknown: made before status.json existed
        raise PipelineError(f"run dir {run_dir} is {status.describe()}; export a complete run "
                            "(rerun it into this dir or choose another)")
    # before the lock: a dir that is no run (an empty dir, a sweep dir, ~) gets no .lock file,
    # and before the warning below, which would say its artefacts are being exported
    read_run_files(run_dir)
    if status.state == UNKNOWN:  # said as birl.from_run says it
        print(f"warning: run dir {run_dir} has no {STATUS_FILE}, so whether its run finished "
              "is not known; exporting its artefacts as they are (each is checked as it is "
              "read)", file=sys.stderr)
    check_earlier_export(run_dir / EXPORT_DIR)


def check_earlier_export(final: Path) -> None:
    """The export replaces `final` as a whole: refuse (one line) when it is not an earlier
    export (a file, or a directory without the costmap.yaml every export writes: exports are
    swapped in whole), whose replacing would delete the user's files. A link is replaced,
    its target left alone."""
    if final.is_symlink() or not final.exists():
        return
    if not final.is_dir():
        raise PipelineError(f"{final} is a file, not an earlier export; move it away (the "
                            "export is written there)")
    if not (final / COSTMAP_YAML).is_file():
        raise PipelineError(f"{final} is a directory but not an earlier export (it has no "
                            f"{COSTMAP_YAML}); move it away (an export replaces it as a whole)")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="birlg-export", description=__doc__.split("\n")[0])
    ap.add_argument("run_dir", type=Path, help="a run directory of `python -m pipeline` that "
                    "went through the birl and evaluate stages")
    args = ap.parse_args(argv)
    run_dir: Path = args.run_dir
    try:
        check_run_dir(run_dir)
        lock = acquire_lock(run_dir)  # no pipeline run starts into the dir meanwhile
        try:
            _remove_stale_partials(run_dir)
            final, costmap, counts, warnings = export_run(run_dir)
        finally:
            os.close(lock)
    except (PipelineError, OSError) as e:  # OSError: e.g. a read-only run dir, a full disk
        return report(e, f"the export of {run_dir}")
    h, w = costmap.grid.shape
    scale = f"occupancy {MAX_LEARNED} = cost {costmap.scale:.4g} per m" if costmap.scale > 0 \
        else costmap.no_cost()
    print(f"wrote {final / COSTMAP_YAML} ({w} x {h} cells at {costmap.grid.resolution:g} m; "
          f"features {', '.join(costmap.in_mask) or 'none'}; {scale})")
    print(f"wrote {final / BAG_DIR} (" + ", ".join(f"{t} {n}" for t, n in counts.items()) + ")")
    if (multiplier := costmap.smac_multiplier()) is not None:
        print(f"planner: Smac 2D weighs the mask against distance as learned with "
              f"cost_travel_multiplier: {ros_double(multiplier)} (see {COSTMAP_YAML})")
    elif (reason := no_trade_off(costmap)) is not None:
        print(f"planner: no cost_travel_multiplier weighs the mask as learned: {reason}")
    for warning in warnings:
        print(warning, file=sys.stderr)
    return 0


def cli() -> None:
    """The `birlg-export` command."""
    run_tool(main)


if __name__ == "__main__":
    cli()
