"""Stage 4: reward learning on the adaptive graph -> birl.mcap (DESIGN §8).

The method is `birl=<name>` from the IRL registry (pipeline.irl): BIRL-G `map` (default)
and `mcmc`, the baselines `policywalk` (on the same graph) and `maxent` (on the reference
roadmap). All write the same topics, so stage 5 scores every method alike.

Topics: /birl/expert (the demonstrations as the likelihood sees them), /birl/iteration (one
per iteration: weights, log likelihood, log prior, generated trajectories), for sampling
methods /birl/posterior (posterior mean, std, acceptance, samples: one per sampled
iteration, with the Boltzmann likelihoods one, at the end), and
with birl.grow_nodes the nodes and edges grown during learning (/birl/graph_nodes,
/birl/graph_edges: columns, as graph.mcap's).
"""

from __future__ import annotations

import logging
import time

import numpy as np

from pipeline.app import build
from pipeline.app.context import RunContext
from pipeline.artefacts import codec, topics
from pipeline.artefacts.store import ArtefactWriter
from pipeline.core.adaptive_graph import AdaptiveGraph
from pipeline.core.graph_mdp import SpatialGraph, TrajectoryStats
from pipeline.core.world import Scene
from pipeline.irl.base import IRLProblem, IRLResult, Iteration
from pipeline.irl.environment import GraphEnvironment, GrowingGraphEnvironment

log = logging.getLogger(__name__)


def restore_adaptive_graph(ctx: RunContext, scene: Scene) -> AdaptiveGraph:
    """The stored adaptive graph as a growable AdaptiveGraph (for birl.grow_nodes)."""
    cfg = ctx.cfg
    art = ctx.read("graph", required_topics=[topics.GRAPH_NODES, topics.GRAPH_EDGES,
                                             topics.GRAPH_SOLUTION])
    sol = art.one(topics.GRAPH_SOLUTION)
    # Its own generator: growing must not change the stage's other random draws.
    return build.regrowable_graph(cfg, scene, sol["weights"], sol["min_separation"],
                                  *codec.graph_tables(art), sol["start_nodes"],
                                  ctx.rng("birl", None, 1))


def expert_stats(ctx: RunContext, demos: list[dict], scene: Scene) -> list[TrajectoryStats]:
    """The demonstrations as the likelihood sees them, on the learner's features: as
    demos.mcap holds them when those are the true reward's, else from their polylines."""
    cfg = ctx.cfg
    if cfg.learner_features == list(cfg.reward.features):
        return codec.decode_expert_stats(demos)
    features = build.learner_feature_model(cfg, scene)
    return [d.stats(cfg.mdp) for d in build.demonstrations(demos, features, cfg.mdp.speed)]


class IterationLog:
    """The learner's progress lines. Iterations that repeat the line logged before them (the
    default learner keeps its MAP from iteration 1 on: 19 identical lines) are said in one
    line, before the next other line."""

    def __init__(self) -> None:
        self.last: str | None = None  # the last iteration line logged
        self.repeated: list[int] = []  # the iterations since that repeat it

    def iteration(self, it: Iteration) -> None:
        reached = sum(t.reached for t in it.generated)
        line = (f"w = {np.round(it.weights, 3).tolist()}, log likelihood {it.log_likelihood:.3f}"
                f", log prior {it.log_prior:.3f}, {reached}/{len(it.generated)} reach goal")
        if line == self.last:
            self.repeated.append(it.index)
            return
        self.flush()
        self.last = line
        log.info("  iteration %2d: %s", it.index, line)

    def other(self, msg: str, *args: object) -> None:
        self.flush()
        log.info(msg, *args)

    def flush(self) -> None:
        """Say the repeated iterations not said yet."""
        if self.repeated:
            first, last = self.repeated[0], self.repeated[-1]
            log.info("  iteration%s: as iteration %d", f" {first:2d}" if first == last else
                     f"s {first}-{last}", first - 1)
            self.repeated.clear()


def run(ctx: RunContext) -> None:
    cfg, b = ctx.cfg, ctx.cfg.birl
    demos = codec.training_demos(ctx.read("demos", required_topics=[topics.DEMOS_EXPERT]))
    scene = codec.decode_scene(ctx.read("scene", required_topics=[topics.SCENE]))
    expert = expert_stats(ctx, demos, scene)
    prior = build.prior(cfg)
    rng = ctx.rng("birl")
    w0, w0_source = build.initial_weights(cfg, rng)  # birl=fixed: given or transferred
    grow_nodes = build.learning_growth(cfg, scene)
    lines = IterationLog()
    env: GraphEnvironment
    if grow_nodes > 0:
        def grown(added: int, n_nodes: int) -> None:
            lines.other("    graph grown by %d nodes under the current weights (%d nodes)",
                        added, n_nodes)

        env = GrowingGraphEnvironment(restore_adaptive_graph(ctx, scene), cfg.mdp, grow_nodes,
                                      grown)
    else:
        graph_art = ctx.read("graph", required_topics=[topics.GRAPH_NODES, topics.GRAPH_EDGES,
                                                       topics.GRAPH_SOLUTION])
        env = GraphEnvironment(codec.decode_graph(graph_art, cfg.mdp), cfg.mdp)

    def roadmap() -> SpatialGraph:
        art = ctx.read("demos", required_topics=[topics.DEMOS_ROADMAP])
        return build.with_named_features(cfg, scene, codec.decode_roadmap(art, cfg.mdp),
                                         list(cfg.reward.features), cfg.learner_features)

    problem = IRLProblem(expert, [np.asarray(d["points"], float) for d in demos], env, prior,
                         w0, rng, roadmap, lines.iteration,
                         status=lambda msg: lines.other("  %s", msg),
                         lattice=build.alternatives_lattice(cfg, scene))
    log.info("IRL method %s: %d demonstrations, %d-node graph, %s; starts from w0 = %s (%s)",
             b.kind, len(expert), env.graph.mdp.n_nodes, b.describe_prior(),
             np.round(w0, 3).tolist(), w0_source)
    t0 = time.perf_counter()
    try:
        result = build.irl_method(cfg).fit(problem, b)
    finally:  # interrupted or failed, the log still says how far learning got
        lines.flush()
    # The learning alone (optimisation and MDP solves), without artefact I/O.
    learn = time.perf_counter() - t0
    ctx.timings["time_birl_learn_s"] = round(learn, 4)
    ctx.timings["time_birl_iteration_s"] = round(learn / len(result.iterations), 5)
    write_birl(ctx, expert, result, env)


def write_birl(ctx: RunContext, expert: list[TrajectoryStats], result: IRLResult,
               env: GraphEnvironment) -> None:
    b = ctx.cfg.birl
    with ctx.writer("birl") as w:
        w.add(topics.BIRL_EXPERT, "BirlExpert", {
            "feature_names": ctx.cfg.learner_features,
            "beta": result.beta if result.beta is not None else getattr(b, "beta", None),
            "prior": b.prior.kind,
            "trajectories": [{"start": t.start, "phi": t.phi, "offset": t.offset,
                              "end_discount": t.end_discount, "reached": t.reached}
                             for t in expert]}, log_time=0)
        for it in result.iterations:
            rolled = it.rollout
            w.add(topics.BIRL_ITERATION, "BirlIteration", {
                "index": it.index, "method": b.kind,
                "mdp_solves": int(result.mdp_solves[it.index]),
                "weights": it.weights, "log_likelihood": it.log_likelihood,
                "log_prior": it.log_prior, "log_posterior": it.log_likelihood + it.log_prior,
                "generated": [{"start": t.start, "nodes": p.nodes,
                               "points": rolled.graph.polyline(p),
                               "phi": t.phi, "offset": t.offset, "end_discount": t.end_discount,
                               "reached": t.reached, "quality": t.quality(it.weights)}
                              for t, p in zip(rolled.stats, rolled.paths, strict=True)]},
                  log_time=it.index)
        if isinstance(env, GrowingGraphEnvironment):
            write_growth(w, env)
        # each posterior belongs to one of the last iterations (eq. (2): 1..n; the Boltzmann
        # forms: one, the last, whose weights are its mean)
        first = len(result.iterations) - len(result.posteriors)
        for n, post in enumerate(result.posteriors, start=first):
            w.add(topics.BIRL_POSTERIOR, "BirlPosterior", {
                "iteration": n, "mean": post.mean, "std": post.std,
                "acceptance_rate": post.acceptance_rate, "samples": post.samples,
                "n_chains": post.n_chains, "step": post.step,
                "rhat": None if post.rhat is None else _finite_or_none(post.rhat),
                "ess": None if post.ess is None else _finite_or_none(post.ess)}, log_time=n)


def _finite_or_none(values: np.ndarray) -> list[float | None]:
    """JSON has no NaN: R-hat of a single or constant chain is written as null."""
    return [float(v) if np.isfinite(v) else None for v in values]


def write_growth(w: ArtefactWriter, env: GrowingGraphEnvironment) -> None:
    """The nodes and edges grown during learning (graph.mcap holds the rest), so stage 5 and
    the viewer see the final graph: one GraphNodes and one GraphEdges message, ids
    continuing graph.mcap's."""
    nodes, edges = env.adaptive.node_table(env.base_nodes), env.adaptive.edge_table(env.base_edges)
    w.add(topics.BIRL_GRAPH_NODES, "GraphNodes",
          codec.nodes_message(nodes, env.base_nodes, with_terminal=True),
          log_time=codec.last_iteration(nodes))
    w.add(topics.BIRL_GRAPH_EDGES, "GraphEdges",
          codec.edges_message(edges, env.base_edges, env.adaptive.fm.names),
          log_time=codec.last_iteration(edges))
