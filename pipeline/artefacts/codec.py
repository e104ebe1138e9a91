"""Messages of the stage artefacts decoded back into core objects, and core objects encoded
as messages, so that every reader of an artefact builds the same objects the same way."""

from __future__ import annotations

import base64
import binascii
import dataclasses
from collections.abc import Sequence

import numpy as np

from pipeline.artefacts import topics
from pipeline.artefacts.store import Artefact, ArtefactError
from pipeline.core.graph_mdp import (
    GraphMDP,
    MDPParams,
    Polylines,
    Solution,
    SpatialGraph,
    TrajectoryStats,
)
from pipeline.core.obstacles import OccupancyGrid
from pipeline.core.roadmap import Roadmap, RoadmapParams
from pipeline.core.state_graph import EdgeTable, NodeTable
from pipeline.core.world import Scene, scene_from_dict


def grid_record(grid: OccupancyGrid) -> dict:
    """An occupancy grid as a message: row 0 is the bottom row (lowest y); `occupied` is the
    (height, width) bool raster, row-major, bit-packed (numpy.packbits) and base64-encoded."""
    height, width = grid.shape
    return {"origin": list(grid.origin), "resolution": grid.resolution, "width": width,
            "height": height,
            "occupied": base64.b64encode(np.packbits(grid.occupied).tobytes()).decode("ascii")}


def decode_grid(msg: dict) -> OccupancyGrid:
    bits = np.frombuffer(base64.b64decode(msg["occupied"]), dtype=np.uint8)
    shape = (int(msg["height"]), int(msg["width"]))
    occupied = np.unpackbits(bits, count=shape[0] * shape[1]).reshape(shape).astype(bool)
    return OccupancyGrid(occupied, (float(msg["origin"][0]), float(msg["origin"][1])),
                         float(msg["resolution"]))


def decode_scene(art: Artefact) -> Scene:
    """The scene of scene.mcap (with its map, when it has one)."""
    map_grid = decode_grid(art.one(topics.SCENE_MAP)) if art.messages.get(topics.SCENE_MAP) \
        else None
    return scene_from_dict(art.one(topics.SCENE), source=f"artefact {art.path}",
                           map_grid=map_grid)


# Columns of the /graph/nodes and /graph/edges messages (birlg.GraphNodes, birlg.GraphEdges):
# one row per node or edge, row i being element first_id + i; a numeric column is the base64
# of a little-endian binary array of this dtype (as JSON arrays of numbers they take several
# times longer to parse: docs/artefacts.md), `kind` a JSON array of strings.
F64, I32, U8 = "<f8", "<i4", "|u1"
NODE_COLUMNS = {"x": F64, "y": F64, "theta": F64, "parent": I32, "iteration": I32,
                "gp_mean": F64, "gp_std": F64, "score": F64}
EDGE_COLUMNS = {"src": I32, "dst": I32, "duration": F64, "demo": U8, "iteration": I32,
                "n_waypoints": I32}


# The base64 columns of each columnar topic and their dtypes (`decoded_columns`)
_NODES = {**NODE_COLUMNS, "terminal": U8}
_EDGES = {**EDGE_COLUMNS, "features": F64, "waypoints": F64}
COLUMNAR: dict[str, dict[str, str]] = {
    topics.GRAPH_NODES: _NODES, topics.BIRL_GRAPH_NODES: _NODES,
    topics.GRAPH_EDGES: _EDGES, topics.BIRL_GRAPH_EDGES: _EDGES,
    topics.DEMOS_ROADMAP: {"positions": F64, "src": I32, "dst": I32, "duration": F64,
                           "features": F64, "terminal": U8, "true_values": F64,
                           "true_policy": I32}}
# columns of two numbers per point, and of n_features numbers per row
_POINT_COLUMNS, _FEATURE_COLUMN = ("positions", "waypoints"), "features"


def decoded_columns(art: Artefact, topic: str, msg: dict) -> dict:
    """`msg` of `topic` with its base64 columns (COLUMNAR) as numpy arrays: features
    (rows × n_features), positions and waypoints (points × 2), the others one value per
    row; a message of another topic as it is."""
    dtypes = COLUMNAR.get(topic)
    if dtypes is None:
        return msg
    reader, out = _Columns(art, topic), dict(msg)
    for key, dtype in dtypes.items():
        if not isinstance(msg.get(key), str):  # absent, or null (no true reward)
            continue
        if key == _FEATURE_COLUMN:  # one row per edge, also when there are no features
            rows = reader.count(msg, "n_edges" if topic == topics.DEMOS_ROADMAP else "count")
            d = reader.count(msg, "n_features")
            out[key] = reader.array(msg, key, dtype, rows * d).reshape(rows, d)
            continue
        try:
            n = len(binascii.a2b_base64(msg[key])) // np.dtype(dtype).itemsize
        except ValueError as e:
            raise reader.fail(f"whose column '{key}' is not valid base64 ({e})") from None
        values = reader.array(msg, key, dtype, n)
        out[key] = values.reshape(-1, 2) if key in _POINT_COLUMNS else values
    return out


def column(values: np.ndarray, dtype: str) -> str:
    """An array as a message column: base64 of its values as little-endian `dtype`."""
    values = np.asarray(values)
    converted = np.ascontiguousarray(values, dtype=dtype)
    if values.size and np.dtype(dtype).kind == "i" and not np.array_equal(converted, values):
        raise ValueError(f"values out of the range of {np.dtype(dtype).name}")
    return base64.b64encode(converted.tobytes()).decode("ascii")


def nodes_message(nodes: NodeTable, first_id: int, with_terminal: bool = False) -> dict:
    """A GraphNodes message: `nodes` as columns, ids first_id, first_id + 1, ...; log_time:
    the last iteration among them."""
    values = {"x": nodes.pose[:, 0], "y": nodes.pose[:, 1], "theta": nodes.pose[:, 2],
              "parent": nodes.parent, "iteration": nodes.added_at, "gp_mean": nodes.gp_mean,
              "gp_std": nodes.gp_std, "score": nodes.score}
    msg: dict[str, object] = {k: column(values[k], dtype) for k, dtype in NODE_COLUMNS.items()}
    msg.update(first_id=first_id, count=len(nodes), kind=[str(k) for k in nodes.kind])
    if with_terminal:
        if nodes.terminal is None:
            raise ValueError("nodes without terminal flags")
        msg["terminal"] = column(nodes.terminal, U8)
    return msg


def edges_message(edges: EdgeTable, first_id: int, feature_names: Sequence[str]) -> dict:
    """A GraphEdges message: `edges` as columns, ids first_id, first_id + 1, ...;
    features row-major (count × n_features, the columns named by `feature_names`), waypoints
    the [x, y] points of every edge's path one after the other (n_waypoints of them per
    edge)."""
    if len(feature_names) != edges.features.shape[1]:
        raise ValueError(f"{len(feature_names)} feature names for {edges.features.shape[1]} "
                         "feature columns")
    values = {"src": edges.src, "dst": edges.dst, "duration": edges.duration,
              "demo": edges.demo, "iteration": edges.added_at,
              "n_waypoints": edges.waypoints.counts}
    msg: dict[str, object] = {k: column(values[k], dtype) for k, dtype in EDGE_COLUMNS.items()}
    msg.update(first_id=first_id, count=len(edges), n_features=int(edges.features.shape[1]),
               feature_names=list(feature_names),
               features=column(edges.features, F64), waypoints=column(edges.waypoints.points, F64))
    return msg


def roadmap_message(roadmap: Roadmap, params: RoadmapParams,
                    solution: Solution | None, mdp: GraphMDP) -> dict:
    """A Roadmap message: the reference roadmap as columns, with its solution under w*
    (`solution` of `mdp`, None when the true reward is unknown)."""
    return {"spacing": params.spacing, "connectivity": params.connectivity,
            "n_nodes": len(roadmap.positions), "n_edges": len(roadmap.src),
            "n_features": int(roadmap.features.shape[1]),
            "positions": column(roadmap.positions, F64), "src": column(roadmap.src, I32),
            "dst": column(roadmap.dst, I32), "duration": column(roadmap.duration, F64),
            "features": column(roadmap.features, F64), "terminal": column(roadmap.terminal, U8),
            "start_nodes": roadmap.start_nodes, "goal_node": roadmap.goal_node,
            "true_values": None if solution is None else column(solution.values, F64),
            "true_policy": None if solution is None
            else column(mdp.caller_edges(solution.policy), I32)}


def decode_roadmap(art: Artefact, mdp: MDPParams) -> SpatialGraph:
    """The reference roadmap of demos.mcap as a SpatialGraph (straight edges)."""
    reader = _Columns(art, topics.DEMOS_ROADMAP)
    msg = art.one(topics.DEMOS_ROADMAP)
    if isinstance(msg.get("positions"), list):  # JSON arrays: written before the columns
        raise ArtefactError(f"artefact {art.path} holds the reference roadmap as JSON arrays, "
                            "the layout of an earlier version: re-make it (add 'demos' to "
                            "stages)")
    n, e, d = (reader.count(msg, k) for k in ("n_nodes", "n_edges", "n_features"))
    positions = reader.array(msg, "positions", F64, 2 * n).reshape(n, 2)
    src, dst = (reader.array(msg, k, I32, e).astype(np.int64) for k in ("src", "dst"))
    graph_mdp = GraphMDP(src, dst, reader.array(msg, "duration", F64, e),
                         reader.array(msg, "features", F64, e * d).reshape(e, d),
                         reader.array(msg, "terminal", U8, n).astype(bool), mdp)
    return SpatialGraph(positions, graph_mdp, np.asarray(reader.field(msg, "start_nodes")),
                        Polylines.straight(positions, src, dst))


def last_iteration(table: NodeTable | EdgeTable) -> int:
    """The log_time of a GraphNodes or GraphEdges message: its last growth iteration."""
    return int(table.added_at.max()) if len(table) else 0


class _Columns:
    """Reads the columns of the messages on one topic, with one-line errors naming the
    artefact, topic and field."""

    def __init__(self, art: Artefact, topic: str) -> None:
        self.art, self.topic = art, topic
        self.msgs = art.all(topic)

    def fail(self, what: str) -> ArtefactError:
        return ArtefactError(f"artefact {self.art.path} has a message on topic '{self.topic}' "
                             f"{what}")

    def field(self, msg: dict, key: str) -> object:
        if key not in msg:
            raise self.fail(f"without the field '{key}'")
        return msg[key]

    def count(self, msg: dict, key: str = "count") -> int:
        n = self.field(msg, key)
        if isinstance(n, bool) or not isinstance(n, int) or n < 0:
            raise self.fail(f"whose '{key}' is not a non-negative integer ({n!r})")
        return n

    def array(self, msg: dict, key: str, dtype: str, n: int) -> np.ndarray:
        """Column `key` of `msg`: n values of `dtype` (read-only, native byte order)."""
        text = self.field(msg, key)
        if not isinstance(text, str):
            raise self.fail(f"whose column '{key}' is not a base64 string")
        try:
            raw = binascii.a2b_base64(text)  # as base64.b64decode, without copying the text
        except ValueError as e:  # binascii.Error, or a str that is not ASCII
            raise self.fail(f"whose column '{key}' is not valid base64 ({e})") from None
        size = np.dtype(dtype).itemsize
        if len(raw) != n * size:
            raise self.fail(f"whose column '{key}' holds {len(raw)} bytes, expected {n} "
                            f"values of {size} bytes")
        return np.frombuffer(raw, dtype=dtype).astype(np.dtype(dtype).newbyteorder("="),
                                                       copy=False)

    def first_ids(self, first_id: int | None) -> int:
        """The number of rows, after checking that message k starts at the id after message
        k − 1's last, the first at first_id (None: at whichever it says)."""
        n = 0
        for msg in self.msgs:
            first = self.count(msg, "first_id")
            if first_id is None:
                first_id = first
            if first != first_id + n:
                raise ArtefactError(
                    f"artefact {self.art.path}: the rows on topic '{self.topic}' start at id "
                    f"{first}, expected {first_id + n} (rows missing, repeated or out of order)")
            n += self.count(msg)
        return n


def _cat(parts: list[np.ndarray], dtype: str, tail: tuple[int, ...] = ()) -> np.ndarray:
    if len(parts) == 1:
        return parts[0]
    return np.concatenate(parts) if parts else np.zeros((0, *tail), dtype=dtype)


def decode_nodes(art: Artefact, topic: str = topics.GRAPH_NODES,
                 first_id: int | None = 0) -> NodeTable:
    """The nodes on `topic` (GraphNodes messages, in log_time order), ids from first_id
    (None: from whichever the first row has)."""
    reader = _Columns(art, topic)
    cols: dict[str, list[np.ndarray]] = {k: [] for k in [*NODE_COLUMNS, "terminal"]}
    kinds: list[str] = []
    for msg in reader.msgs:
        n = reader.count(msg)
        for key, dtype in NODE_COLUMNS.items():
            cols[key].append(reader.array(msg, key, dtype, n))
        if "terminal" in msg:
            cols["terminal"].append(reader.array(msg, "terminal", U8, n).astype(bool))
        kind = reader.field(msg, "kind")
        if not isinstance(kind, list) or len(kind) != n \
                or not all(isinstance(k, str) for k in kind):
            raise reader.fail(f"whose 'kind' is not a list of {n} strings")
        kinds += kind
    reader.first_ids(first_id)
    c = {k: _cat(v, NODE_COLUMNS.get(k, U8)) for k, v in cols.items()}
    has_terminal = len(cols["terminal"]) == len(reader.msgs)
    return NodeTable(np.stack([c["x"], c["y"], c["theta"]], axis=1), np.array(kinds, dtype=str),
                     c["parent"].astype(np.int64), c["iteration"].astype(np.int64),
                     c["gp_mean"], c["gp_std"], c["score"], c["terminal"] if has_terminal else None)


def decode_edges(art: Artefact, topic: str = topics.GRAPH_EDGES,
                 first_id: int | None = 0) -> EdgeTable:
    """The edges on `topic` (GraphEdges messages, in log_time order), ids from first_id
    (None: from whichever the first row has)."""
    reader = _Columns(art, topic)
    cols: dict[str, list[np.ndarray]] = {k: [] for k in [*EDGE_COLUMNS, "features", "waypoints"]}
    dims = set()
    for msg in reader.msgs:
        n, d = reader.count(msg), reader.count(msg, "n_features")
        dims.add(d)
        for key, dtype in EDGE_COLUMNS.items():
            cols[key].append(reader.array(msg, key, dtype, n))
        cols["features"].append(reader.array(msg, "features", F64, n * d).reshape(n, d))
        counts = cols["n_waypoints"][-1]
        if n and counts.min() < 0:
            raise reader.fail("with a negative 'n_waypoints'")
        cols["waypoints"].append(reader.array(msg, "waypoints", F64, 2 * int(counts.sum()))
                                 .reshape(-1, 2))
    if len(dims) > 1:
        raise reader.fail(f"with another 'n_features' than the others ({sorted(dims)})")
    reader.first_ids(first_id)
    c = {k: _cat(v, EDGE_COLUMNS.get(k, F64)) for k, v in cols.items()
         if k not in ("features", "waypoints")}
    features = _cat(cols["features"], F64, (dims.pop() if dims else 0,))
    waypoints = Polylines(_cat(cols["waypoints"], F64, (2,)), c["n_waypoints"])
    return EdgeTable(c["src"].astype(np.int64), c["dst"].astype(np.int64), c["duration"],
                     features, waypoints, c["demo"].astype(bool), c["iteration"].astype(np.int64))


def graph_tables(art: Artefact, grown: Artefact | None = None) -> tuple[NodeTable, EdgeTable]:
    """The nodes and edges of graph.mcap (terminal flags from /graph/solution), plus those
    the BIRL stage grew (`grown` = birl.mcap with birl.grow_nodes > 0), in id order."""
    nodes, edges = decode_nodes(art), decode_edges(art)
    terminal = np.asarray(art.one(topics.GRAPH_SOLUTION)["terminal"], dtype=bool)
    if len(terminal) != len(nodes):
        raise ArtefactError(f"artefact {art.path} has {len(terminal)} terminal flags on "
                            f"'{topics.GRAPH_SOLUTION}' for {len(nodes)} nodes")
    nodes = dataclasses.replace(nodes, terminal=terminal)
    if grown is not None and topics.BIRL_GRAPH_NODES in grown.messages:
        more = decode_nodes(grown, topics.BIRL_GRAPH_NODES, len(nodes))
        if more.terminal is None:
            raise ArtefactError(f"artefact {grown.path} has nodes on "
                                f"'{topics.BIRL_GRAPH_NODES}' without 'terminal'")
        nodes = nodes.concat(more)
        edges = edges.concat(decode_edges(grown, topics.BIRL_GRAPH_EDGES, len(edges)))
    return nodes, edges


def decode_graph(art: Artefact, mdp: MDPParams, grown: Artefact | None = None) -> SpatialGraph:
    """The adaptive graph of graph.mcap (and the part grown during learning)."""
    sol = art.one(topics.GRAPH_SOLUTION)
    nodes, edges = graph_tables(art, grown)
    assert nodes.terminal is not None  # graph_tables sets it, or raises
    graph_mdp = GraphMDP(edges.src, edges.dst, edges.duration, edges.features, nodes.terminal,
                         mdp)
    return SpatialGraph(nodes.positions, graph_mdp, np.asarray(sol["start_nodes"]),
                        edges.waypoints, snap_tolerance=sol["min_separation"])


def training_demos(art: Artefact) -> list[dict]:
    """The demonstrations of demos.mcap that learning may see: the held-out ones left out
    (DESIGN §9); none with expert=none."""
    return [m for m in art.messages.get(topics.DEMOS, []) if not m.get("heldout", False)]


def heldout_demos(art: Artefact) -> list[dict]:
    """The demonstrations of demos.mcap held out of learning (evaluate.holdout)."""
    return [m for m in art.messages.get(topics.DEMOS, []) if m.get("heldout", False)]


def decode_mdp_params(expert_msg: dict) -> MDPParams:
    """The MDP settings the demonstrations were made with (demos.mcap's /demos/expert)."""
    return MDPParams(gamma=expert_msg["gamma"], time_cost=expert_msg["time_cost"],
                     r_goal=expert_msg["r_goal"], speed=expert_msg["speed"])


def decode_expert_stats(demo_msgs: list[dict]) -> list[TrajectoryStats]:
    """The demonstrations of demos.mcap as the BIRL likelihood sees them."""
    return [TrajectoryStats(int(m["start_index"]), np.asarray(m["discounted_features"], float),
                            float(m["offset"]), float(m["end_discount"]), bool(m["reached"]))
            for m in demo_msgs]
