"""Messages of the stage artefacts decoded back into core objects, and core objects encoded
as messages, so that every reader of an artefact builds the same objects the same way."""

from __future__ import annotations

import base64

import numpy as np

from pipeline.artefacts import topics
from pipeline.artefacts.store import Artefact
from pipeline.core.graph_mdp import GraphMDP, MDPParams, SpatialGraph, TrajectoryStats
from pipeline.core.obstacles import OccupancyGrid
from pipeline.core.state_graph import StateGraph
from pipeline.core.world import Scene, scene_from_dict


def grid_record(grid: OccupancyGrid) -> dict:
    """An occupancy grid as a message: row 0 is the bottom row (lowest y); `occupied` is the
    (height, width) bool raster, row-major, bit-packed (numpy.packbits) and base64-encoded."""
    height, width = grid.shape
    return {"origin": list(grid.origin), "resolution": grid.resolution, "width": width,
            "height": height,
            "occupied": base64.b64encode(np.packbits(grid.occupied)).decode("ascii")}


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


def decode_roadmap(art: Artefact, mdp: MDPParams) -> SpatialGraph:
    """The reference roadmap of demos.mcap as a SpatialGraph (straight edges)."""
    msg = art.one(topics.DEMOS_ROADMAP)
    positions = np.asarray(msg["positions"], float)
    src, dst = np.asarray(msg["src"]), np.asarray(msg["dst"])
    graph_mdp = GraphMDP(src, dst, msg["duration"], msg["features"], msg["terminal"], mdp)
    return SpatialGraph(positions, graph_mdp, np.asarray(msg["start_nodes"]),
                        [positions[[a, b]] for a, b in zip(src, dst, strict=True)])


def graph_records(art: Artefact, grown: Artefact | None = None) -> tuple[list[dict], list[dict]]:
    """Node and edge records of graph.mcap in id order, plus those the BIRL stage grew
    (`grown` = birl.mcap with birl.grow_nodes > 0)."""
    extra_nodes = grown.messages.get(topics.BIRL_GRAPH_NODE, []) if grown else []
    extra_edges = grown.messages.get(topics.BIRL_GRAPH_EDGE, []) if grown else []
    nodes = sorted(art.all(topics.GRAPH_NODE) + extra_nodes, key=lambda n: n["id"])
    edges = sorted(art.all(topics.GRAPH_EDGE) + extra_edges, key=lambda e: e["id"])
    return nodes, edges


def decode_graph(art: Artefact, mdp: MDPParams, grown: Artefact | None = None) -> SpatialGraph:
    """The adaptive graph of graph.mcap (and the part grown during learning)."""
    sol = art.one(topics.GRAPH_SOLUTION)
    nodes, edges = graph_records(art, grown)
    extra = grown.messages.get(topics.BIRL_GRAPH_NODE, []) if grown else []
    terminal = list(sol["terminal"]) + [n["terminal"] for n in sorted(extra, key=lambda n: n["id"])]
    graph_mdp = GraphMDP([e["src"] for e in edges], [e["dst"] for e in edges],
                         [e["duration"] for e in edges], [e["features"] for e in edges],
                         terminal, mdp)
    positions = np.array([[n["x"], n["y"]] for n in nodes])
    return SpatialGraph(positions, graph_mdp, np.asarray(sol["start_nodes"]),
                        [np.asarray(e["waypoints"], float) for e in edges],
                        snap_tolerance=sol["min_separation"])


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


def _none_if_nan(x: float) -> float | None:
    return None if not np.isfinite(x) else float(x)


def node_record(graph: StateGraph, i: int) -> dict:
    """A GraphNode message for node i (log_time: its "iteration")."""
    return {"id": i, "x": graph.pose[i, 0], "y": graph.pose[i, 1], "theta": graph.pose[i, 2],
            "kind": graph.node_kind[i], "parent": int(graph.parent[i]),
            "iteration": int(graph.added_at[i]), "gp_mean": _none_if_nan(graph.gp_mean[i]),
            "gp_std": _none_if_nan(graph.gp_std[i]), "score": _none_if_nan(graph.score[i])}


def edge_record(graph: StateGraph, e: int) -> dict:
    """A GraphEdge message for edge e; an edge exists from the iteration both its ends do."""
    return {"id": int(e), "src": int(graph.src[e]), "dst": int(graph.dst[e]),
            "duration": graph.duration[e], "features": graph.features[e],
            "waypoints": graph.waypoints[e], "demo": graph.edge_is_demo[e],
            "iteration": int(max(graph.added_at[graph.src[e]], graph.added_at[graph.dst[e]]))}
