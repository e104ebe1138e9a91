"""Stage 4: BIRL-G reward learning on the adaptive graph -> birl.mcap (DESIGN §8).

`birl=map` (default) and `birl=mcmc` are BIRL-G; `birl=policywalk` (Ramachandran & Amir
2007, on the same graph) and `birl=maxent` (Ziebart et al. 2008, on the reference roadmap)
are the baselines, written to the same topics so stage 5 scores every method alike.

Topics: /birl/expert (the demonstrations as the likelihood sees them), /birl/iteration (one
per iteration: weights, log likelihood, log prior, generated trajectories), and for
birl=mcmc /birl/posterior (posterior mean, std, acceptance, samples of every iteration).
"""

from __future__ import annotations

import dataclasses
import logging
import time

import numpy as np

from scipy.spatial import cKDTree

from pipeline.adaptive_graph import AdaptiveGraph
from pipeline.baselines import expert_state_actions, maxent_irl, policywalk
from pipeline.birl import Iteration, McmcResult, TrajectoryStats, birl_map, mcmc
from pipeline.errors import PipelineError
from pipeline.features import FEATURE_NAMES
from pipeline.graph_mdp import Path, SpatialGraph
from pipeline.config import ALL_STAGES
from pipeline.run import RunContext
from pipeline.stages.demos import feature_model, load_roadmap
from pipeline.stages.graph import (edge_record, graph_params, load_graph, make_controller,
                                   make_prior, node_record)
from pipeline.stages.scene import load_scene

log = logging.getLogger(__name__)


def expert_stats(demo_msgs) -> list[TrajectoryStats]:
    return [TrajectoryStats(int(m["start_index"]), np.asarray(m["discounted_features"], float),
                            float(m["end_discount"]), bool(m["reached"])) for m in demo_msgs]


class GraphEnvironment:
    """`generate(w)` for the BIRL loop: rewards w·φ on the graph, warm-started policy
    iteration, the greedy trajectory from every start. Keeps the paths for the artefact."""

    def __init__(self, graph: SpatialGraph, gamma: float):
        self.graph, self.gamma = graph, gamma
        self.values = None
        self.paths: list[list] = []  # per call: the greedy Path from every start

    def __call__(self, w: np.ndarray) -> list[TrajectoryStats]:
        mdp = self.graph.mdp
        sol = mdp.solve(w, init_values=self.values)
        self.values = sol.values
        paths = [mdp.follow(sol.policy, int(s)) for s in self.graph.start_nodes]
        self.paths.append(paths)
        return [TrajectoryStats.from_edges(k, mdp.features[p.edges], mdp.duration[p.edges],
                                           self.gamma, p.reached) for k, p in enumerate(paths)]


class GrowingGraphEnvironment(GraphEnvironment):
    """`birl.grow_nodes: k`: before each iteration's solve, the adaptive graph grows k more
    nodes under the current weights, so it adapts to the reward being learned."""

    def __init__(self, adaptive: AdaptiveGraph, gamma: float, grow_nodes: int):
        super().__init__(self._spatial(adaptive), gamma)
        self.adaptive, self.grow_nodes, self.calls = adaptive, grow_nodes, 0
        self.base_nodes, self.base_edges = adaptive.n_nodes, len(adaptive.src)

    @staticmethod
    def _spatial(g: AdaptiveGraph) -> SpatialGraph:
        return SpatialGraph(g.positions.copy(), g.mdp(), g.start_nodes, list(g.waypoints),
                            snap_tolerance=g.p.min_separation)

    def __call__(self, w: np.ndarray) -> list[TrajectoryStats]:
        if self.calls > 0:  # iteration 0 scores the stored graph under w0
            self.adaptive.set_weights(w)
            added = self.adaptive.grow_by(self.grow_nodes)
            self.graph = self._spatial(self.adaptive)
            self.values = None  # node set changed: a cold solve (cheap next to the growth)
            log.info("    graph grown by %d nodes under the current weights (%d nodes)", added,
                     self.adaptive.n_nodes)
        self.calls += 1
        return super().__call__(w)


def restore_adaptive_graph(ctx: RunContext) -> AdaptiveGraph:
    """The stored adaptive graph as a growable AdaptiveGraph (for birl.grow_nodes)."""
    cfg = ctx.cfg
    art = ctx.read("graph", required_topics=["/graph/node", "/graph/edge", "/graph/solution"])
    sol = art.one("/graph/solution")
    scene = load_scene(ctx)
    params = dataclasses.replace(graph_params(cfg.graph), min_separation=sol["min_separation"])
    # Its own generator: growing must not change the stage's other random draws.
    rng = np.random.default_rng([int(cfg.seed), ALL_STAGES.index("birl"), 1])
    g = AdaptiveGraph(scene, feature_model(cfg, scene), make_controller(cfg), sol["weights"],
                      params, rng, gamma=cfg.mdp.gamma, r_goal=cfg.mdp.r_goal, v_max=cfg.mdp.v_max)
    g.restore(sorted(art.all("/graph/node"), key=lambda n: n["id"]),
              sorted(art.all("/graph/edge"), key=lambda e: e["id"]), sol["start_nodes"])
    return g


def demo_graph_paths(graph: SpatialGraph, demo_msgs) -> list[Path]:
    """The demonstrations as paths of a graph: waypoints snapped to the nodes the graph
    merged them into, consecutive nodes joined by existing edges (internal indices)."""
    tree = cKDTree(graph.positions)
    mdp = graph.mdp
    edge_of = {(int(a), int(b)): e for e, (a, b) in enumerate(zip(mdp.src, mdp.dst))}
    paths = []
    for k, msg in enumerate(demo_msgs):
        dist, nodes = tree.query(np.asarray(msg["points"], float))
        if dist.max() > graph.snap_tolerance + 1e-9:
            raise PipelineError(f"demonstration {k} is not a path of the graph: a waypoint lies "
                                f"{dist.max():.3f} m from the nearest node")
        nodes = [int(n) for i, n in enumerate(nodes) if i == 0 or n != nodes[i - 1]]
        missing = [(a, b) for a, b in zip(nodes[:-1], nodes[1:]) if (a, b) not in edge_of]
        if missing:
            raise PipelineError(f"demonstration {k} is not a path of the graph: no edge {missing[0]}")
        edges = [edge_of[(a, b)] for a, b in zip(nodes[:-1], nodes[1:])]
        paths.append(Path(np.array(nodes), np.array(edges, dtype=np.int64),
                          bool(mdp.terminal[nodes[-1]])))
    return paths


def run_baseline(ctx, b, demos, graph, prior, rng, w0, env) -> tuple[list[Iteration], list[int]]:
    """PolicyWalk on the adaptive graph or MaxEnt IRL on the reference roadmap, reported as
    BIRL iterations (weights after each recorded step, greedy paths on the graph), with the
    number of MDP solves spent up to each."""
    if b.kind == "policywalk":
        expert = expert_state_actions(graph.mdp, demo_graph_paths(graph, demos))
        result = policywalk(graph.mdp, expert, prior, rng, alpha=b.alpha, n_samples=b.n_samples,
                            burn_in=b.burn_in, thin=b.thin, step=b.step, w0=w0,
                            n_records=b.n_iterations)
        solves = result.extra["solves_at_record"]
    else:
        roadmap = load_roadmap(ctx)
        result = maxent_irl(roadmap.mdp, demo_graph_paths(roadmap, demos),
                            (prior.lower, prior.upper), n_iterations=b.n_iterations,
                            learning_rate=b.learning_rate, w0=w0)
        solves = list(range(1, len(result.history) + 1))
    records = [Iteration(k, w, ll, prior.log_pdf(w), env(w))
               for k, (w, ll) in enumerate(zip(result.history, result.log_likelihood))]
    return records, solves


def run(ctx: RunContext) -> None:
    cfg, b = ctx.cfg, ctx.cfg.birl
    demos = ctx.read("demos", required_topics=["/demos"]).all("/demos")
    expert = expert_stats(demos)
    prior = make_prior(b)
    rng = ctx.rng("birl")
    w0 = np.asarray(b.init_weights, float) if b.init_weights is not None else prior.sample(rng)
    if b.grow_nodes > 0:  # the restored graph reads graph.mcap itself
        env = GrowingGraphEnvironment(restore_adaptive_graph(ctx), cfg.mdp.gamma, b.grow_nodes)
    else:
        env = GraphEnvironment(load_graph(ctx), cfg.mdp.gamma)
    graph = env.graph
    posteriors: list[McmcResult] = []
    if b.kind in ("policywalk", "maxent"):
        t0 = time.perf_counter()
        records, solves = run_baseline(ctx, b, demos, graph, prior, rng, w0, env)
        learn = time.perf_counter() - t0
        ctx.timings["time_birl_learn_s"] = round(learn, 4)
        ctx.timings["time_birl_iteration_s"] = round(learn / len(records), 5)
        write_birl(ctx, b, expert, records, env, graph, posteriors, solves)
        return

    def fit_mcmc(posterior, w_prev):
        result = mcmc(posterior, w_prev, rng, n_samples=b.n_samples, burn_in=b.burn_in,
                      thin=b.thin, step=b.step)
        posteriors.append(result)
        return result.mean

    def progress(it: Iteration) -> None:
        reached = sum(t.reached for t in it.generated)
        log.info("  iteration %2d: w = %s, log likelihood %.3f, log prior %.3f, %d/%d reach goal",
                 it.index, np.round(it.weights, 3).tolist(), it.log_likelihood, it.log_prior,
                 reached, len(it.generated))

    log.info("BIRL-G %s: %d demonstrations, %d-node graph, beta %g, %s prior, w0 = %s",
             b.kind, len(expert), graph.mdp.n_nodes, b.beta, b.prior.kind,
             np.round(w0, 3).tolist())
    t0 = time.perf_counter()
    records = birl_map(expert, env, prior, beta=b.beta, r_goal=cfg.mdp.r_goal,
                       n_iterations=b.n_iterations, w0=w0, progress=progress,
                       fit=fit_mcmc if b.kind == "mcmc" else None)
    # The loop alone (MAP steps and warm-started policy iteration), without artefact I/O.
    learn = time.perf_counter() - t0
    ctx.timings["time_birl_learn_s"] = round(learn, 4)
    ctx.timings["time_birl_iteration_s"] = round(learn / len(records), 5)
    # BIRL-G solves the graph MDP once per iteration (its greedy trajectories).
    write_birl(ctx, b, expert, records, env, env.graph, posteriors,
               list(range(1, len(records) + 1)))


def write_birl(ctx, b, expert, records, env, graph, posteriors, mdp_solves) -> None:
    cfg = ctx.cfg
    with ctx.writer("birl") as w:
        w.add("/birl/expert", "BirlExpert", {
            "feature_names": list(FEATURE_NAMES), "beta": b.beta, "prior": b.prior.kind,
            "trajectories": [{"start": t.start, "phi": t.phi, "end_discount": t.end_discount,
                              "reached": t.reached} for t in expert]}, log_time=0)
        for it, paths in zip(records, env.paths[-len(records):]):
            w.add("/birl/iteration", "BirlIteration", {
                "index": it.index, "method": b.kind, "mdp_solves": int(mdp_solves[it.index]),
                "weights": it.weights, "log_likelihood": it.log_likelihood,
                "log_prior": it.log_prior, "log_posterior": it.log_likelihood + it.log_prior,
                "generated": [{"start": t.start, "nodes": p.nodes, "points": graph.polyline(p),
                               "phi": t.phi, "end_discount": t.end_discount,
                               "reached": t.reached, "quality": t.quality(it.weights, cfg.mdp.r_goal)}
                              for t, p in zip(it.generated, paths)]}, log_time=it.index)
        if isinstance(env, GrowingGraphEnvironment):
            write_growth(w, env)
        for n, post in enumerate(posteriors, start=1):
            w.add("/birl/posterior", "BirlPosterior", {
                "iteration": n, "mean": post.mean, "std": post.std,
                "acceptance_rate": post.acceptance_rate, "samples": post.samples}, log_time=n)


def write_growth(w, env: GrowingGraphEnvironment) -> None:
    """The nodes and edges grown during learning (graph.mcap holds the rest), so stage 5 and
    the viewer see the final graph: /birl/graph_node, /birl/graph_edge."""
    g = env.adaptive
    for i in range(env.base_nodes, g.n_nodes):
        w.add("/birl/graph_node", "GraphNode", {**node_record(g, i), "terminal": bool(g.terminal[i])},
              log_time=int(g.added_at[i]))
    for e in range(env.base_edges, len(g.src)):
        rec = edge_record(g, e)
        w.add("/birl/graph_edge", "GraphEdge", rec, log_time=rec["iteration"])
