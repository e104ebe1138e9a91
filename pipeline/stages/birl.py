"""Stage 4: BIRL-G reward learning on the adaptive graph -> birl.mcap (DESIGN §8).

Topics: /birl/expert (the demonstrations as the likelihood sees them), /birl/iteration (one
per iteration: weights, log likelihood, log prior, generated trajectories), and for
birl=mcmc /birl/posterior (posterior mean, std, acceptance, samples of every iteration).
"""

from __future__ import annotations

import logging
import time

import numpy as np

from pipeline.birl import Iteration, McmcResult, TrajectoryStats, birl_map, mcmc
from pipeline.features import FEATURE_NAMES
from pipeline.graph_mdp import SpatialGraph
from pipeline.run import RunContext
from pipeline.stages.graph import load_graph, make_prior

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


def run(ctx: RunContext) -> None:
    cfg, b = ctx.cfg, ctx.cfg.birl
    demos = ctx.read("demos", required_topics=["/demos"]).all("/demos")
    graph = load_graph(ctx)
    expert = expert_stats(demos)
    prior = make_prior(b)
    rng = ctx.rng("birl")
    w0 = np.asarray(b.init_weights, float) if b.init_weights is not None else prior.sample(rng)
    env = GraphEnvironment(graph, cfg.mdp.gamma)
    posteriors: list[McmcResult] = []

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
    ctx.timings["time_birl_iteration_s"] = round((time.perf_counter() - t0) / (len(records)), 5)

    with ctx.writer("birl") as w:
        w.add("/birl/expert", "BirlExpert", {
            "feature_names": list(FEATURE_NAMES), "beta": b.beta, "prior": b.prior.kind,
            "trajectories": [{"start": t.start, "phi": t.phi, "end_discount": t.end_discount,
                              "reached": t.reached} for t in expert]}, log_time=0)
        for it, paths in zip(records, env.paths):
            w.add("/birl/iteration", "BirlIteration", {
                "index": it.index, "weights": it.weights, "log_likelihood": it.log_likelihood,
                "log_prior": it.log_prior, "log_posterior": it.log_likelihood + it.log_prior,
                "generated": [{"start": t.start, "nodes": p.nodes, "points": graph.polyline(p),
                               "phi": t.phi, "end_discount": t.end_discount,
                               "reached": t.reached, "quality": t.quality(it.weights, cfg.mdp.r_goal)}
                              for t, p in zip(it.generated, paths)]}, log_time=it.index)
        for n, post in enumerate(posteriors, start=1):
            w.add("/birl/posterior", "BirlPosterior", {
                "iteration": n, "mean": post.mean, "std": post.std,
                "acceptance_rate": post.acceptance_rate, "samples": post.samples}, log_time=n)
