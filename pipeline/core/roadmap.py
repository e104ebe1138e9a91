"""Reference roadmap (DESIGN §6): a 16-connected lattice over the room plus starts and goal.

It is independent of the adaptive graph; stage 2 solves it exactly under the true weights
to make expert demonstrations, stage 5 evaluates learned rewards on it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import breadth_first_order
from scipy.spatial import cKDTree

from pipeline.core.features import FeatureModel
from pipeline.core.graph_mdp import GraphMDP, MDPParams, Polylines, SpatialGraph
from pipeline.core.nearby import segments_clear_of_disks
from pipeline.core.params import require, require_step
from pipeline.core.ties import TIE
from pipeline.core.world import Scene

# Lattice offsets (di, dj): 8 king moves plus 8 knight moves = 16-connected.
_OFFSETS_8 = [(1, 0), (0, 1), (-1, 0), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1)]
_OFFSETS_16 = _OFFSETS_8 + [(1, 2), (2, 1), (-1, 2), (-2, 1), (1, -2), (2, -1), (-1, -2), (-2, -1)]


@dataclass
class RoadmapParams:
    spacing: float = 0.25  # m, lattice spacing
    connectivity: int = 16  # 8 (king moves) or 16 (plus knight moves)

    def __post_init__(self) -> None:
        require_step(self, "spacing")
        require(self.connectivity in (8, 16), "connectivity", self.connectivity, "8 or 16")


@dataclass(frozen=True)
class Roadmap:
    positions: np.ndarray  # (n, 2)
    src: np.ndarray  # (E,)
    dst: np.ndarray  # (E,)
    duration: np.ndarray  # (E,) seconds
    features: np.ndarray  # (E, d)
    terminal: np.ndarray  # (n,) bool
    start_nodes: np.ndarray  # node index of every scene start
    goal_node: int

    def mdp(self, params: MDPParams | None = None) -> GraphMDP:
        return GraphMDP(self.src, self.dst, self.duration, self.features, self.terminal, params)

    def starts_without_path_to_goal(self) -> list[int]:
        """Indices of the starts from which no sequence of roadmap edges reaches the goal."""
        n = len(self.positions)
        reverse = csr_matrix((np.ones(len(self.src)), (self.dst, self.src)), shape=(n, n))
        reaches_goal = np.zeros(n, bool)
        reaches_goal[breadth_first_order(reverse, self.goal_node, return_predecessors=False)] = True
        return [k for k, s in enumerate(self.start_nodes) if not reaches_goal[s]]

    def spatial(self, mdp: GraphMDP) -> SpatialGraph:
        """The roadmap with its MDP `mdp` as a SpatialGraph (straight edges)."""
        return SpatialGraph(self.positions, mdp, self.start_nodes,
                            Polylines.straight(self.positions, self.src, self.dst))


def segments_feasible(scene: Scene, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Mask (n,) of the straight segments a[i] → b[i] (each (n, 2)) that stay in the
    (convex) room, keep out of every body disk and keep robot_radius from every obstacle
    (clearance sampled at most half a raster cell apart). Only the persons near a segment
    are tested (`nearby`): the same mask as testing every person."""
    ok = scene.room.contains(a) & scene.room.contains(b)
    if scene.obstacles is not None and len(a):
        ok &= scene.obstacles.segments_free(a, b, scene.robot_radius)
    if len(scene.persons) and len(a):
        ok &= segments_clear_of_disks(a, b, scene.person_xy, scene.body_radius - TIE)
    return ok


# `pulled_taut`: a straight segment across collinear path vertices costs what they cost, up
# to round-off (relative to the path's cost so far)
TAUT_TOLERANCE = 1e-9
TAUT_CHUNK = 16  # shortcuts costed at a time, from the farthest
SegmentCost = Callable[[np.ndarray, np.ndarray], np.ndarray]


def segment_cost(features: FeatureModel, params: MDPParams, w: np.ndarray) -> SegmentCost:
    """The cost (n,) of straight segments a[i] → b[i] under weights w, as the undiscounted
    MDP counts a straight edge's: c · length / speed − w · φ."""
    w = np.asarray(w, dtype=float)

    def cost(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        out = params.time_cost * np.linalg.norm(b - a, axis=1) / params.speed
        return out - features.segments(a, b) @ w if w.any() else out
    return cost


def pulled_taut(scene: Scene, points: np.ndarray,
                cost: SegmentCost) -> np.ndarray:
    """A roadmap path (K, 2) pulled taut under the reward it was planned with: from each kept
    vertex, straight on to the farthest later vertex the straight segment to which is
    feasible (`segments_feasible`) and costs no more (`cost`: the costs (n,) of the
    straight segments a[i] → b[i], `segment_cost`) than the stretch of path it replaces.
    Same ends, never costlier; under length alone, never longer. The lattice's paths are
    staircases of its directions, which can stray a metre from the straight line across a
    16 m lobby (which staircase, among about equally good ones, is the solver's choice)."""
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    if len(p) < 3:
        return p
    walked = np.concatenate([[0.0], np.cumsum(cost(p[:-1], p[1:]))])
    kept, i = [0], 0
    while i < len(p) - 1:
        later = np.arange(i + 2, len(p))
        feasible = later[segments_feasible(scene, np.repeat(p[i:i + 1], len(later), axis=0),
                                           p[later])][::-1]
        step = i + 1
        # the farthest feasible vertex reached no more costly: costed from the far end in
        # chunks (a feature integral per segment is most of the time)
        chunks = np.array_split(feasible, max(1, len(feasible) // TAUT_CHUNK)) \
            if len(feasible) else []
        for chunk in chunks:
            ends = p[chunk]
            ok = cost(np.repeat(p[i:i + 1], len(chunk), axis=0), ends) <= \
                walked[chunk] - walked[i] + TAUT_TOLERANCE * (1 + np.abs(walked[chunk]))
            if ok.any():
                step = int(chunk[np.argmax(ok)])
                break
        i = step
        kept.append(i)
    return p[kept]


def lattice_graph(scene: Scene, spacing: float = 0.25,
                  connectivity: int = 16) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Node positions (n, 2) and feasible edges src, dst (E,) of the roadmap; starts and goal
    are the last nodes (starts first, then the goal).

    Lattice nodes closer than spacing/2 to a start or the goal are dropped so no two nodes
    sit at (almost) the same place; starts and goal connect to every lattice node within
    the lattice's longest edge.
    """
    if connectivity not in (8, 16):
        raise ValueError(f"connectivity must be 8 or 16, got {connectivity}")
    room = scene.room
    xs = np.arange(room.x_min, room.x_max + TIE, spacing)
    ys = np.arange(room.y_min, room.y_max + TIE, spacing)
    gi, gj = np.meshgrid(np.arange(len(xs)), np.arange(len(ys)), indexing="ij")
    lattice = np.column_stack([xs[gi.ravel()], ys[gj.ravel()]])
    special = np.vstack([scene.starts, scene.goal[None, :]])
    near_special = cKDTree(special).query(lattice)[0] < spacing / 2 - TIE
    usable = scene.free(lattice) & ~near_special
    index: np.ndarray = np.full(len(lattice), -1)
    index[usable] = np.arange(usable.sum())
    index = index.reshape(len(xs), len(ys))

    # Lattice edges from the offset table.
    offsets = _OFFSETS_16 if connectivity == 16 else _OFFSETS_8
    src_l, dst_l = [], []
    for di, dj in offsets:
        a = index[max(0, -di):len(xs) - max(0, di), max(0, -dj):len(ys) - max(0, dj)]
        b = index[max(0, di):len(xs) + min(0, di), max(0, dj):len(ys) + min(0, dj)]
        ok = (a >= 0) & (b >= 0)
        src_l.append(a[ok])
        dst_l.append(b[ok])
    positions = np.vstack([lattice[usable], special])
    n_lattice = int(usable.sum())
    src, dst = np.concatenate(src_l), np.concatenate(dst_l)

    # Starts and goal connect both ways to lattice nodes within the longest lattice edge.
    reach = spacing * (np.sqrt(5.0) if connectivity == 16 else np.sqrt(2.0)) + TIE
    tree = cKDTree(positions[:n_lattice])
    extra_src, extra_dst = [], []
    for k, p in enumerate(special):
        node = n_lattice + k
        for j in tree.query_ball_point(p, reach):
            extra_src += [node, j]
            extra_dst += [j, node]
    src = np.concatenate([src, np.array(extra_src, dtype=np.int64)])
    dst = np.concatenate([dst, np.array(extra_dst, dtype=np.int64)])

    ok = segments_feasible(scene, positions[src], positions[dst])
    return positions, src[ok], dst[ok]


def build_roadmap(scene: Scene, feature_model: FeatureModel, params: RoadmapParams | None = None,
                  speed: float = 1.0) -> Roadmap:
    """Lattice of `spacing` over the room, nodes in body disks removed, plus starts and goal."""
    params = params or RoadmapParams()
    positions, src, dst = lattice_graph(scene, params.spacing, params.connectivity)
    features = feature_model.edge_features(positions, src, dst)
    duration = np.linalg.norm(positions[dst] - positions[src], axis=1) / speed
    terminal = scene.at_goal(positions)
    n_starts = len(scene.starts)
    n_lattice = len(positions) - n_starts - 1
    return Roadmap(positions, src, dst, duration, features, terminal,
                   start_nodes=np.arange(n_lattice, n_lattice + n_starts),
                   goal_node=n_lattice + n_starts)
