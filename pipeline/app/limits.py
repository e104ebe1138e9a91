"""Size guards: refuse, before building, what cannot fit in memory or cannot resolve the
scene, with the estimate and the key to change (instead of a MemoryError after minutes).

Memory per element was measured on this pipeline (peak RSS above the ~230 MB of imports):
the reference roadmap of 10, 20 and 30 m rooms (24k, 100k, 228k edges) took 122, 206 and
271 MB; the adaptive graph at 20,000 nodes peaked at 523 MB. The constants below round
these up, so the guard errs on the side of letting a run start.
"""

from __future__ import annotations

import math
import os

from pipeline.errors import PipelineError

BYTES_FIXED = 150e6  # working set besides the per-element arrays
BYTES_PER_LATTICE_EDGE = 1024.0  # edge arrays, features, sub-step integration chunks
BYTES_PER_GRAPH_NODE = 30e3  # nodes, edges, GP data, per-iteration history
MEMORY_SHARE = 0.8  # of the memory available now


def lattice_edges(area: float, spacing: float, connectivity: int) -> float:
    """Edges of a `spacing` lattice over `area` m² with `connectivity` neighbours per node."""
    return area / spacing**2 * connectivity


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


def check_memory(what: str, n: float, per_element: float, fix: str) -> None:
    need = BYTES_FIXED + n * per_element
    have = available_memory()
    if need > MEMORY_SHARE * have:
        raise PipelineError(f"{what} would need about {need / 1e9:.1f} GB ({n:,.0f} elements) "
                            f"but {have / 1e9:.1f} GB are available: {fix}")


def check_graph_resolution(max_nodes: int, free_area: float, rho_personal: float,
                           scene_name: str) -> None:
    """The adaptive graph must be able to resolve personal space: on average at least one
    node per rho_personal × rho_personal square of free space, or learned paths cannot
    route around people (with graph.max_nodes=1 they cross social links)."""
    needed = math.ceil(free_area / rho_personal**2)
    if max_nodes < needed:
        raise PipelineError(
            f"config error: graph.max_nodes={max_nodes} is too few for scene '{scene_name}': "
            f"{free_area:.0f} m² of free space at one node per {rho_personal:g} m × "
            f"{rho_personal:g} m (reward.rho_personal) needs graph.max_nodes >= {needed}")
