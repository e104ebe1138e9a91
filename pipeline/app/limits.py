"""Size guards: refuse, before building, what cannot fit in memory or cannot resolve the
scene, with the estimate and the key to change (instead of a MemoryError after minutes).
`pipeline.app.preflight` runs them all before the first stage.

Memory was measured on this pipeline as the peak RSS (`resource.getrusage(...).ru_maxrss`)
of a fresh process above its ~85-120 MB of imports, one case per process:

- obstacle raster (a scene's room at 5 cm, or its map, with the clearance transform and the
  reachability labels): 100 m and 200 m rooms with one box (4e6, 1.6e7 cells) took 184 and
  572 MB; maps of 2000², 4000², 6000² px took 181, 594 and 1298 MB: 36-46 bytes per cell;
- lattices (the reference roadmap, 16-connected at 0.25 m; a random room's reachability
  check, 8-connected at 0.2 m): roadmaps (edges and their features) of 20, 40 and 80 m
  random rooms (0.10, 0.41, 1.64 M edges by `lattice_edges`) took 60, 188 and 654 MB, about
  30 MB + 380 B/edge, as much with 199, 395 and 785 persons as with none (the body-disk
  tests look only at the persons near an edge, `pipeline.core.nearby`, and the features
  tile by tile); the same rooms' reachability lattices 100-140 B/edge; an obstacle added
  113 B/edge (roadmap of a 40 m room). Before the disk tests were cut off, every edge was
  tested against every person: 1122 B/edge with 12 persons, 3598 with 40;
- the adaptive graph at 20,000 nodes peaked at 523 MB.

The constants below are these rounded up, so an estimate is never below what a run takes.
"""

from __future__ import annotations

import math
import os

from pipeline.core.adaptive_graph import GraphParams
from pipeline.errors import PipelineError

BYTES_FIXED = 150e6  # working set besides the per-element arrays
BYTES_PER_RASTER_CELL = 48.0  # occupancy, clearance (float64), distance transform, labels
# a random scene drawn on a map also labels the map's free regions and tests every draw's
# reachability on the raster: maps of 120 × 40, 200 × 200 and 300 × 300 m at 5 cm took 0.35,
# 2.13 and 4.58 GB for stages=[scene], 105-124 bytes per cell
BYTES_PER_RANDOM_MAP_CELL = 140.0
BYTES_PER_LATTICE_EDGE = 500.0  # edge arrays, features, sub-step integration chunks ...
BYTES_PER_LATTICE_EDGE_PERSON = 1.0  # ... and per person in the room (not measurable: a margin
# for crowded feature tiles)
BYTES_PER_LATTICE_EDGE_OBSTACLES = 150.0  # ... and the clearance samples with obstacles
BYTES_PER_GRAPH_NODE = 30e3  # nodes, edges, GP data, per-iteration history
# a synthetic demonstration, its points, features and artefact rows (2000 Boltzmann walks
# on metropolis: 36 MB)
BYTES_PER_DEMONSTRATION = 20e3
# a candidate controller run of the graph's expansion (graph.n_new=2000 on metropolis: 10 MB)
BYTES_PER_CANDIDATE = 10e3
# The planner expert's lattice: 0.76 GB peak at 250 000 points, 2.7 GB at a million (the
# expert alone, metropolis): about 2.6 kB per point. Unchecked, 10 million ran 24 s and then
# failed to allocate.
BYTES_PER_PLANNER_NODE = 2.7e3
MEMORY_SHARE = 0.8  # of the memory available now


def lattice_edges(area: float, spacing: float, connectivity: int) -> float:
    """Edges of a `spacing` lattice over `area` m² with `connectivity` neighbours per node."""
    return area / spacing**2 * connectivity


# Building a lattice roadmap and solving it takes 17-21 µs per lattice point on metropolis
# (spacings 0.025-0.1 m, 8-connected, on 2 cores), and more on large floors: 33 µs in a 100 m
# room, 43 µs in a 200 m one (16-connected at 0.25 m); from LONG_WORK_S on, the log says how
# long to expect before the work starts (roadmap.spacing=0.01: a million points). The rate
# is the large floors', where the wait is long: on a small one it errs long.
LATTICE_SECONDS_PER_POINT = 40e-6
LONG_WORK_S = 5.0
# graph.mcap of this many nodes or more is announced before it is written, and its time
# said after: writing took 0.6 s at 5000 nodes, 2.7 s at 20 000 and 25 s at 55 000 (the
# growth history's best paths lengthen with the graph)
LARGE_GRAPH_NODES = 10_000


def lattice_seconds(area: float, spacing: float) -> float:
    """About how long building a lattice of `spacing` over `area` m² takes."""
    return LATTICE_SECONDS_PER_POINT * area / spacing**2


def bytes_per_lattice_edge(n_persons: int, obstacles: bool) -> float:
    return BYTES_PER_LATTICE_EDGE + BYTES_PER_LATTICE_EDGE_PERSON * n_persons \
        + (BYTES_PER_LATTICE_EDGE_OBSTACLES if obstacles else 0.0)


def available_memory() -> float:
    """Bytes available to a new allocation now (MemAvailable), else physical memory."""
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024
    except OSError:
        pass
    return float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))


def _size(n_bytes: float) -> str:
    for unit, scale in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6)):
        if n_bytes >= scale:
            return f"{n_bytes / scale:,.1f} {unit}"
    return f"{n_bytes / 1e6:.2f} MB"


def check_memory(what: str, n: float, per_element: float, fix: str) -> None:
    need = BYTES_FIXED + n * per_element
    have = available_memory()
    if need > MEMORY_SHARE * have:
        raise PipelineError(f"{what} would need about {_size(need)} ({n:,.0f} elements) "
                            f"but {_size(have)} are available: {fix}")


def growth_seconds_left(rates: list[tuple[float, float]], nodes: int,
                        total: int) -> float:
    """Graph growth's time left: seconds to grow from `nodes` to `total` nodes, from the
    seconds per node of the progress windows so far, `rates` ((nodes at a window's middle,
    s per node), oldest first; not empty). Each node costs more as the graph grows (an MDP
    repair over more nodes), about as a power of its size: a least-squares line through
    the windows' log rates against log size gives the exponent (clipped to [0, 2]), and the
    last window's rate, so grown, is integrated from here on. On a 200 m floor (55 556
    nodes) the last window's rate alone said 0.27-0.42 of what followed; the exponent of
    the last two windows alone swung between 0.46 and 1.27 times it, that of all windows
    stayed between 0.58 and 0.92 times."""
    n_now, rate = rates[-1]
    usable = [(n, r) for n, r in rates if n > 0 and r > 0]
    power = 0.0
    if len(usable) > 1 and rate > 0:
        x = [math.log(n) for n, _ in usable]
        y = [math.log(r) for _, r in usable]
        x_mean, y_mean = sum(x) / len(x), sum(y) / len(y)
        spread = sum((a - x_mean) ** 2 for a in x)
        if spread > 0:
            slope = sum((a - x_mean) * (b - y_mean) for a, b in zip(x, y, strict=True)) / spread
            power = min(max(slope, 0.0), 2.0)
    return rate * n_now / (power + 1) * ((total / n_now) ** (power + 1)
                                          - (nodes / n_now) ** (power + 1))


def nodes_to_resolve(free_area: float, rho_personal: float) -> int:
    """Nodes that put on average one node on every rho_personal × rho_personal square of
    `free_area` m²: the fewest with which the adaptive graph resolves personal space."""
    return math.ceil(free_area / rho_personal**2)


# graph.max_nodes=null: twice nodes_to_resolve (nodes crowd along the best paths, and the
# medial-axis nodes on maps may take up to half), at least the paper's 460 (GraphParams)
GRAPH_NODES_MARGIN = 2


def graph_size(free_area: float, rho_personal: float, scene_name: str) -> tuple[int, str]:
    """graph.max_nodes derived from the scene (graph.max_nodes=null), and why, for the log."""
    needed = nodes_to_resolve(free_area, rho_personal)
    derived = max(GraphParams.max_nodes, GRAPH_NODES_MARGIN * needed)
    base = (f"{GRAPH_NODES_MARGIN} × the {needed} nodes of one per {rho_personal:g} m × "
            f"{rho_personal:g} m (reward.rho_personal) on the {free_area:.0f} m² of free space "
            f"of scene '{scene_name}'")
    if derived == GraphParams.max_nodes:
        return derived, f"the paper's {derived}, as {base} is no more"
    return derived, f"{base}, more than the paper's {GraphParams.max_nodes}"


# birl.grow_nodes derived for a scene with obstacles, for a learner whose estimate depends
# on the graph (measured with eq. (2): random scenes on the office map and the office itself
# learn closer to the true reward when the graph grows under the weights being learned; in
# open rooms it changes little and costs up to a second per run)
GROW_ON_MAPS = 10


def learning_growth(obstacles: bool, scene_name: str,
                    learns_on_the_graph: bool = True) -> tuple[int, str]:
    """birl.grow_nodes derived from the scene and the learner (birl.grow_nodes=null), and
    why, for the log."""
    if not learns_on_the_graph:
        return 0, ("the learner compares the demonstrations with a lattice's paths "
                   "(birl.alternatives=lattice): growing the graph would change nothing it "
                   "learns")
    if obstacles:
        return GROW_ON_MAPS, (f"scene '{scene_name}' has obstacles: on a map the graph grows "
                              "under the weights being learned (BIRL-G's loop), which finds "
                              "the routes that walls and doors leave few of")
    return 0, f"scene '{scene_name}' is an open room: the graph stays as stage 3 grew it"


# birl.alternatives=lattice: at most this many lattice nodes (a 0.2 m lattice of a 14 m × 14 m
# room); a larger floor gets a coarser one. Learning on the lattice costs about its nodes^1.5
# (sparse LUs), and its near-optimal paths multiply with the distance (more solves): a 20 m
# room on a 10 000-node lattice took 25 s to learn, the 10 m metropolis on 2 546 nodes 1 s
ALTERNATIVES_MAX_NODES = 5_000


def alternatives_spacing(area: float, spacing: float, scene_name: str) -> tuple[float, str]:
    """The spacing of the alternatives lattice over `area` m² of free space (its nodes lie
    there only; birl.alternatives_spacing, or coarser to stay within
    ALTERNATIVES_MAX_NODES), and why, for the log ('' if as set)."""
    if area / spacing**2 <= ALTERNATIVES_MAX_NODES:
        return spacing, ""
    coarse = math.sqrt(area / ALTERNATIVES_MAX_NODES)
    return coarse, (f"the alternatives lattice of scene '{scene_name}' is {coarse:.2f} m apart, "
                    f"not {spacing:g} m (birl.alternatives_spacing): {area:.0f} m² of free "
                    f"space at most {ALTERNATIVES_MAX_NODES} nodes")


def check_graph_resolution(max_nodes: int, free_area: float, rho_personal: float,
                           scene_name: str) -> None:
    """The adaptive graph must be able to resolve personal space: on average at least one
    node per rho_personal × rho_personal square of free space, or learned paths cannot
    route around people (with graph.max_nodes=1 they cross social links)."""
    needed = nodes_to_resolve(free_area, rho_personal)
    if max_nodes < needed:
        raise PipelineError(
            f"config error: graph.max_nodes={max_nodes} is too few for scene '{scene_name}': "
            f"{free_area:.0f} m² of free space at one node per {rho_personal:g} m × "
            f"{rho_personal:g} m (reward.rho_personal) needs graph.max_nodes >= {needed}")


def check_graph_size(max_nodes: int, free_area: float | None, rho_personal: float,
                     scene_name: str) -> None:
    """The adaptive graph's size checks, before any work: its memory, and (where the scene's
    free area is known) its resolution of personal space."""
    check_memory(f"an adaptive graph of {max_nodes} nodes", max_nodes, BYTES_PER_GRAPH_NODE,
                 "lower graph.max_nodes")
    if free_area is not None:
        check_graph_resolution(max_nodes, free_area, rho_personal, scene_name)
