"""End to end through the real app: BIRL-G learns socially compliant rewards."""

import re
import warnings

import numpy as np
import pytest

from pipeline.app.metric_keys import is_metric_key
from pipeline.artefacts import codec, read_artefact
from pipeline.core.evaluation import discrete_frechet, resample
from tests.conftest import ROOT, run_in_process


def run_experiment(tmp_path_factory, *overrides):
    run_dir = tmp_path_factory.mktemp("exp")
    metrics, stdout = run_in_process(run_dir, *overrides)
    return run_dir, metrics, stdout


@pytest.fixture(scope="module")
def polite(default_run):
    return default_run


def test_polite_expert_is_learned_on_metropolis(polite):
    run_dir, m, stdout = polite
    print({k: m[k] for k in ("policy_loss", "policy_loss_ref", "policy_loss_norm")})
    assert m["policy_loss_norm"] <= 0.005  # the target for optimal experts
    assert m["relation_crossings"] == 0 and m["ref_relation_crossings"] == 0
    assert m["success"] == 1.0
    assert m["policy_loss"] < m["policy_loss_initial"]
    assert "policy loss" in stdout and "learned weights" in stdout  # the one-screen summary
    for key in ("time_scene_s", "time_demos_s", "time_graph_s", "time_birl_s", "time_evaluate_s"):
        assert m[key] > 0
    assert all(isinstance(v, float) for v in m.values())  # flat, numbers only


def test_birl_and_eval_artefacts(polite):
    run_dir, m, _ = polite
    birl = read_artefact(run_dir / "birl.mcap", required_topics=["/birl/iteration", "/birl/expert"])
    its = birl.all("/birl/iteration")
    assert [it["index"] for it in its] == list(range(21))
    for it in its:
        assert np.all(np.array(it["weights"]) <= 0) and np.all(np.array(it["weights"]) >= -1)
        assert len(it["generated"]) == 7
    assert its[-1]["weights"] == [m[f"weight_{n}"] for n in
                                  ("relation", "social", "goal_deviation", "length", "crossing")]
    ev = read_artefact(run_dir / "eval.mcap",
                       required_topics=["/eval/policy_loss", "/eval/paths", "/eval/metrics"])
    losses = ev.all("/eval/policy_loss")
    assert len(losses) == 21 and losses[-1]["ref"] == pytest.approx(m["policy_loss_ref"])
    assert all(row["graph"] >= 0 and row["ref"] >= 0 for row in losses)
    assert ev.one("/eval/metrics")["policy_loss_norm"] == m["policy_loss_norm"]


def test_rude_expert_learns_to_cross_links(tmp_path_factory):
    _, m, _ = run_experiment(tmp_path_factory, "reward=rude")
    assert m["relation_crossings"] > 0 and m["ref_relation_crossings"] > 0
    assert m["policy_loss_norm"] <= 0.02


@pytest.mark.parametrize("seed", [1, pytest.param(2, marks=pytest.mark.slow),
                                  pytest.param(3, marks=pytest.mark.slow)])
def test_random_scenes(tmp_path_factory, seed):
    # Every form learns optimal demonstrations on random scenes (docs/methods.md)
    for likelihood, bound in (("paper", 0.02), ("boltzmann", 0.02), ("robust", 0.02)):
        _, m, _ = run_experiment(tmp_path_factory, "scene=random", f"seed={seed}",
                                 f"birl.likelihood={likelihood}")
        print(seed, likelihood,
              {k: m[k] for k in ("policy_loss", "policy_loss_ref", "policy_loss_norm")})
        assert m["policy_loss_norm"] <= bound and m["ref_relation_crossings"] == 0


def test_boltzmann_expert_beats_initial_weights(tmp_path_factory):
    _, m, _ = run_experiment(tmp_path_factory, "expert=boltzmann")
    assert m["policy_loss_ref"] < 0.5 * m["policy_loss_ref_initial"]


@pytest.mark.parametrize("likelihood, n_posteriors", [("paper", 5), ("boltzmann", 1),
                                                       ("robust", 1)])
def test_mcmc_reports_posterior_spread(tmp_path_factory, likelihood, n_posteriors):
    """paper: a posterior sample every iteration; boltzmann and robust: one sample of the
    Boltzmann posterior at the end, its mean one more iteration."""
    run_dir, m, out = run_experiment(tmp_path_factory, "birl=mcmc", "birl.n_iterations=5",
                                     f"birl.likelihood={likelihood}", "graph=small",
                                     "birl.n_samples=300", "birl.burn_in=200")
    birl = read_artefact(run_dir / "birl.mcap")
    post = birl.all("/birl/posterior")
    names = ("relation", "social", "goal_deviation", "length", "crossing")
    assert len(post) == n_posteriors and post[-1]["n_chains"] == 4
    # each labels the iteration whose weights are its mean: the last ones (the Boltzmann
    # forms' one was labelled 1, the MAP's iteration, though it gives the extra last one)
    its = birl.all("/birl/iteration")
    assert [p["iteration"] for p in post] == list(range(len(its) - len(post), len(its)))
    last = np.clip(post[-1]["mean"], -1.0, 0.0)
    assert np.allclose(its[post[-1]["iteration"]]["weights"], last)
    # the expert message's β is the likelihood's at the estimate (learned; eq. (2): birl.beta)
    beta = birl.one("/birl/expert")["beta"]
    assert (beta == 10.0) == (likelihood == "paper") or likelihood == "robust"
    assert post[-1]["mean"] == [m[f"weight_{n}"] for n in names] or likelihood != "paper"
    assert all(m[f"weight_std_{n}"] > 0 for n in names)
    assert 0.2 <= m["mcmc_acceptance_rate"] <= 0.5  # the adapted step
    assert m["mcmc_rhat_max"] == max(post[-1]["rhat"]) and m["mcmc_ess_min"] > 0
    assert m["mcmc_ess_min"] == min(post[-1]["ess"]) == min(m[f"weight_ess_{n}"] for n in names)
    assert m["mcmc_rhat_max"] == max(m[f"weight_rhat_{n}"] for n in names)
    # 300 per chain, or more while the chains did not agree
    blocks, rest = divmod(len(post[-1]["samples"]), 4 * 300)
    assert rest == 0 and 1 <= blocks <= 4
    # eq. (2)'s posteriors on the way only move the estimate: sampled at the fixed length
    assert all(len(p["samples"]) == 4 * 300 for p in post[:-1])
    # the summary gives the posterior mean ± std and the chains' diagnostics
    assert f"relation {m['weight_relation']:.3f} ± {m['weight_std_relation']:.3f}" in out
    assert f"R-hat max {m['mcmc_rhat_max']:.3f}, ESS min {m['mcmc_ess_min']:.0f}" in out
    agree = m["mcmc_rhat_max"] <= 1.05 and m["mcmc_ess_min"] >= 100  # the verdict follows them
    assert ("the chains agree" in out) == agree
    assert ("the chains do not agree yet" in out) == (not agree)
    assert blocks == 4 or agree  # they stop early only where they agree
    assert all(is_metric_key(k) for k in m)  # every key can be a sweep's objective



def test_one_chain_mcmc_says_convergence_is_untested(tmp_path_factory):
    """One chain has no R-hat (it compares chains): the summary says so (it ended the run
    with a KeyError before)."""
    _, m, out = run_experiment(tmp_path_factory, "birl=mcmc", "birl.n_chains=1",
                               "birl.n_iterations=2", "graph=small", "birl.n_samples=200")
    assert "mcmc_rhat_max" not in m and m["mcmc_acceptance_rate"] > 0
    assert "R-hat max n/a" in out and "one chain: convergence untested" in out
    assert "the chains agree" not in out


def test_chains_too_short_for_r_hat_are_not_called_one_chain(tmp_path_factory):
    """Four chains of three samples each have no R-hat either (it needs four per chain):
    the summary said "one chain" beside a log that sampled chain 4 of 4."""
    _, m, out = run_experiment(tmp_path_factory, "birl=mcmc", "birl.n_samples=3",
                               "birl.max_samples=3", "birl.n_iterations=2", "graph=small")
    assert "mcmc_rhat_max" not in m and m["mcmc_chains"] == 4
    assert "too few samples per chain" in out and "raise birl.n_samples" in out
    assert "one chain" not in out


def test_chains_that_creep_are_told_to_take_larger_steps(tmp_path_factory):
    """Steps of 1e-300 accept every proposal and go nowhere: the summary said "raise
    birl.max_samples", which would not help."""
    _, m, out = run_experiment(tmp_path_factory, "birl=mcmc", "birl.adapt=false",
                               "birl.proposal_step=1e-300", "birl.n_iterations=2",
                               "graph=small", "birl.n_samples=100")
    assert m["mcmc_acceptance_rate"] > 0.99
    assert "raise birl.proposal_step" in out and "birl.max_samples" not in out


def test_chains_that_never_move_are_called_stuck_not_unconverged(tmp_path_factory):
    """A proposal far too large, kept (adapt=false): nothing is accepted and R-hat is huge;
    raising birl.max_samples (what it said) would not help."""
    _, m, out = run_experiment(tmp_path_factory, "birl=mcmc", "birl.adapt=false",
                               "birl.proposal_step=1", "birl.n_iterations=2", "graph=small",
                               "birl.n_samples=100")
    assert m["mcmc_acceptance_rate"] < 0.01
    assert "the chains barely moved: lower birl.proposal_step" in out
    assert "raise it" not in out


def test_a_short_burn_in_warns_of_nothing(tmp_path_factory):
    """Fewer burn-in states than weights: no proposal shape is estimated, and numpy's
    'Degrees of freedom <= 0' warnings no longer reach the terminal."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        _, m, _ = run_experiment(tmp_path_factory, "birl=mcmc", "birl.burn_in=3",
                                 "birl.n_samples=20", "birl.n_iterations=2", "graph=small")
    assert m["mcmc_acceptance_rate"] > 0

def test_file_demos_report_similarity(tmp_path_factory):
    run_dir, m, _ = run_experiment(tmp_path_factory, "expert=file",
                                   f"expert.path={ROOT}/data/demos/metropolis_polite_smoothed.json")
    assert "policy_loss" not in m  # no true weights, no policy loss
    # the reported similarity is that of the paths in eval.mcap to the demonstrations
    demos = read_artefact(run_dir / "demos.mcap").all("/demos")
    paths = {p["start"]: p["points"] for p in read_artefact(run_dir / "eval.mcap").all(
        "/eval/paths") if p["graph"] == "graph"}
    dists = [discrete_frechet(resample(paths[d["start_index"]], 0.1),
                              resample(d["points"], 0.1)) for d in demos]
    assert m["frechet_to_demos"] == pytest.approx(np.mean(dists), abs=1e-12)
    assert m["frechet_to_demos_max"] == pytest.approx(np.max(dists), abs=1e-12)
    # most learned paths follow their demonstration (a graph of the demonstrations' own
    # waypoints: no evidence of learning, only that the learned reward keeps to them)
    assert np.median(dists) < 0.5 and m["relation_crossings"] == 0


@pytest.mark.parametrize("method, overrides", [
    ("policywalk", ["birl.n_samples=100", "birl.burn_in=20", "birl.n_iterations=5"]),
    ("maxent", ["birl.n_iterations=8"]),
])
def test_baselines_write_the_same_topics(tmp_path_factory, method, overrides):
    run_dir, m, _ = run_experiment(tmp_path_factory, f"birl={method}", "graph=small", *overrides)
    its = read_artefact(run_dir / "birl.mcap", required_topics=["/birl/iteration"]).all(
        "/birl/iteration")
    assert all(it["method"] == method for it in its)
    solves = [it["mdp_solves"] for it in its]
    assert solves == sorted(solves) and solves[-1] > solves[0]
    assert len(its) == len([k for k in m if k.startswith("policy_loss_ref_iter_")])
    assert m["policy_loss_ref"] >= 0 and m["time_birl_learn_s"] > 0
    if method == "policywalk":  # every proposal solves the MDP: many more than iterations
        assert solves[-1] > 100


def test_graph_grows_under_the_learned_weights(tmp_path_factory):
    # The paper's loop: one solve (and growth) per iteration. The robust form also runs
    # that loop and then records its choice among the iterates, which grows nothing more.
    run_dir, m, _ = run_experiment(tmp_path_factory, "graph=small", "birl.n_iterations=3",
                                   "birl.grow_nodes=5", "birl.likelihood=paper")
    birl = read_artefact(run_dir / "birl.mcap", required_topics=["/birl/graph_nodes",
                                                                 "/birl/graph_edges"])
    base = read_artefact(run_dir / "graph.mcap").one("/graph/solution")
    # ids continue graph.mcap's (checked by the decoder)
    grown = codec.decode_nodes(birl, "/birl/graph_nodes", first_id=base["n_nodes"])
    grown_edges = codec.decode_edges(birl, "/birl/graph_edges", first_id=base["n_edges"])
    assert 15 <= len(grown) <= 18  # 5 per iteration after the first (an expansion adds <= 2)
    assert (grown.kind == "sampled").all() and (grown.parent >= 0).all()
    assert grown.terminal is not None and len(grown_edges) > len(grown)
    assert grown.added_at.min() >= base["iterations"]
    # The last iteration's trajectories run on the grown graph and stage 5 scores that graph.
    last = birl.all("/birl/iteration")[-1]
    assert max(max(g["nodes"]) for g in last["generated"]) < base["n_nodes"] + len(grown)
    assert m["policy_loss"] >= 0 and m["success"] == 1.0
    # The viewer shows the grown nodes too.
    from rerun.chunk import RrdReader

    from pipeline.tools.viewer import build_recording

    rrd = build_recording(run_dir)
    assert "/birl/grown_nodes" in {str(p) for p in RrdReader(rrd).store().schema().entity_paths()}


def test_no_loop_of_the_grown_graph_is_free(tmp_path):
    """Demonstration edges (with the hops that merge waypoints into nearby nodes) cost what
    the robot drives, and every second costs, so no loop is free: from every start the greedy
    policy reaches the goal for every weight vector of a grid over the box. The graph is the
    noisy expert's where a free 2-cycle between demonstration nodes used to trap start 4
    (under the paper's setting, w = [-1, -1, 0, 0] still does)."""
    run_dir = tmp_path / "run"
    run_in_process(run_dir, "expert=boltzmann", "expert.beta=5", "seed=4",
                   "stages=[scene,demos,graph]")
    art = read_artefact(run_dir / "graph.mcap")
    mdp_params = codec.decode_mdp_params(
        read_artefact(run_dir / "demos.mcap").one("/demos/expert"))
    graph = codec.decode_graph(art, mdp_params)
    edges = codec.decode_edges(art)
    driven = np.array([np.linalg.norm(np.diff(edges.waypoints[e], axis=0), axis=1).sum()
                       for e in range(len(edges))])
    np.testing.assert_allclose(edges.duration, driven / mdp_params.speed, rtol=1e-9)
    assert edges.demo.any() and (edges.duration > 0).all()
    d = graph.mdp.features.shape[1]
    grid = np.array(np.meshgrid(*[[-1.0, -0.5, 0.0]] * d)).reshape(d, -1).T
    for w in grid:
        policy = graph.mdp.solve(w).policy
        for start in graph.start_nodes:
            assert graph.mdp.follow(policy, int(start)).reached, (w, start)


def test_the_lattice_of_alternatives_identifies_what_the_graph_leaves_open(tmp_path):
    """Metropolis seed 2, optimal expert: compared with the adaptive graph's paths only, two
    starts' routes nearly tie with a long detour the graph does not hold, nothing bounds the
    length and goal-deviation weights, and the learned reward takes the detour on the
    roadmap; compared with every path of the lattice, it does not."""
    lattice, _ = run_in_process(tmp_path / "lattice", "seed=2")
    graph, _ = run_in_process(tmp_path / "graph", "seed=2", "birl.alternatives=graph")
    assert lattice["policy_loss_norm"] <= 0.005 < graph["policy_loss_norm"]
    assert lattice["ref_relation_crossings"] == 0


def test_a_final_loss_worse_than_the_initial_one_is_said(tmp_path):
    """A random scene, seed 1, compared with the adaptive graph's paths only: the initial
    weights happen to lose nothing on the roadmap, the learned ones a little; the summary
    says so and what it means (metropolis seed 0 does not)."""
    m, out = run_in_process(tmp_path, "scene=random", "seed=1", "birl.alternatives=graph")
    assert m["policy_loss_ref"] > m["policy_loss_ref_initial"]
    warning = [line for line in out.splitlines() if line.strip().startswith("warning")]
    assert len(warning) == 1
    assert f"roadmap {m['policy_loss_ref']:.4f} > {m['policy_loss_ref_initial']:.4f}" \
        in warning[0] and "further from the true reward" in warning[0]


def test_a_final_loss_better_than_the_initial_one_gets_no_warning(polite):
    _, m, out = polite
    assert m["policy_loss_ref"] <= m["policy_loss_ref_initial"]
    assert m["policy_loss"] <= m["policy_loss_initial"] and "warning" not in out


# The default learner's targets on cases that once failed (results/bench/learning.csv).

def test_a_noisy_expert_is_learned_within_the_target(tmp_path):
    m, _ = run_in_process(tmp_path, "expert=boltzmann", "expert.beta=20")
    assert m["policy_loss_norm"] <= 0.05 and m["ref_relation_crossings"] == 0


def test_hand_drawn_paths_are_learned_with_every_segment_costed(tmp_path):
    """Seed 1 of the hand-drawn set (waypoints 0.1 m apart, nodes at least 0.16 m): the
    learned reward plans no crossing and no intimate intrusion on the roadmap. The
    drawings' waypoints merge several into one node; their edges on the adaptive graph
    still cost what the drawn stretch costs, so the graph paths take about their length in
    time at mdp.speed (1 m/s; the hops to merged nodes make the polylines a little longer).
    When each such edge kept one 0.1 m segment's cost, they took half of it, and the
    drawings looked cheap to every reward."""
    m, _ = run_in_process(tmp_path, "expert=file",
                          "expert.path=data/demos/metropolis_handdrawn.json", "seed=1")
    assert m["ref_relation_crossings"] == 0 and m["ref_intimate_intrusion_m"] <= 0.9
    assert m["time_to_goal"] >= 0.8 * m["path_length"]


def test_the_log_says_which_candidate_the_robust_learner_chose(tmp_path, caplog):
    """A user reading iteration lines whose log likelihood falls is told why: the estimate is
    an admissible eq. (2) iterate (by number) or the Boltzmann MAP, with its β."""
    with caplog.at_level("INFO"):
        run_in_process(tmp_path, "graph=small", "stages=[scene,demos,graph,birl]",
                       "birl.likelihood=robust")
    [said] = [r.getMessage() for r in caplog.records if "estimate: " in r.getMessage()]
    chosen = re.search(r"estimate: (eq\. \(2\)'s iterate (\d+), admissible against the "
                       r"Boltzmann MAP \(β = [0-9.e+]+\)|the Boltzmann MAP \(β = [0-9.e+]+\); "
                       r"no eq\. \(2\) iterate was admissible)", said)
    assert chosen is not None, said
    birl = read_artefact(tmp_path / "birl.mcap").all("/birl/iteration")
    if chosen[2] is not None:  # iteration n records the choice among the MAP and iterates
        assert birl[-1]["weights"] == birl[int(chosen[2])]["weights"]  # 1..n: it won there


def test_the_default_learner_is_the_boltzmann_map(tmp_path, caplog):
    """birl.likelihood=boltzmann (the default): the MAP is found in iteration 1 and kept (on
    the lattice of alternatives the graph's growth does not change it), and the log says
    which estimate it is, with its β."""
    with caplog.at_level("INFO"):
        run_in_process(tmp_path, "graph=small", "stages=[scene,demos,graph,birl]",
                       "birl.n_iterations=3")
    [said] = [r.getMessage() for r in caplog.records if "estimate: " in r.getMessage()]
    assert re.fullmatch(r"\s*estimate: the Boltzmann MAP \(β = [0-9.e+]+\)", said), said
    birl = read_artefact(tmp_path / "birl.mcap").all("/birl/iteration")
    assert len(birl) == 4 and birl[0]["weights"] != birl[1]["weights"]
    assert birl[1]["weights"] == birl[2]["weights"] == birl[3]["weights"]
    # the log says the repeats in one line, not one line each
    said = [r.getMessage() for r in caplog.records if "iteration" in r.getMessage()
            and r.name == "pipeline.stages.birl"]
    assert [m.split(":")[0].strip() for m in said] == ["iteration  0", "iteration  1",
                                                       "iterations 2-3"], said
    assert said[-1].endswith("iterations 2-3: as iteration 1")


@pytest.mark.parametrize("shift, drawn", [((500_000.0, 5_600_000.0), True),
                                           ((10.0, 20.0), False)])
def test_a_scene_moved_anywhere_learns_the_same(tmp_path, shift, drawn):
    """metropolis moved by a UTM offset (coordinates near 10^6 m, as a ROS map in a
    georeferenced frame has) with its hand-drawn paths, and by (10, 20) m with the optimal
    expert: the same graph and the same learned weights as at the origin. Before ties were
    decided with a tolerance and the Voronoi centroids computed in the room's frame, the UTM
    graph lost its 8 Voronoi nodes (Qhull put them 100 m off) and `relation` differed by up
    to 0.05 on some lattice edges (weights 1e-4 apart); at (10, 20) m an alternatives
    lattice node exactly goal_tolerance from the goal was terminal in one frame and not in
    the other (social −0.479 against −0.461)."""
    import json

    from tests.conftest import moved_metropolis, write_json

    paths = json.loads((ROOT / "data/demos/metropolis_handdrawn.json").read_text())
    runs = []
    for name, by in (("here", (0.0, 0.0)), ("there", shift)):
        scene = write_json(tmp_path / f"{name}.json", moved_metropolis(by))
        expert = []
        if drawn:
            moved = paths | {"trajectories": [[[x + by[0], y + by[1], *rest]
                                               for x, y, *rest in t]
                                              for t in paths["trajectories"]]}
            expert = ["expert=file",
                      f"expert.path={write_json(tmp_path / f'{name}_demos.json', moved)}"]
        runs.append(run_in_process(tmp_path / name, "scene=file", f"scene.path={scene}",
                                   *expert)[0])
    here, there = runs
    tables = [codec.graph_tables(read_artefact(tmp_path / name / "graph.mcap"))
              for name in ("here", "there")]
    (nodes, edges), (nodes_there, edges_there) = tables
    np.testing.assert_array_equal(nodes.kind, nodes_there.kind)
    np.testing.assert_array_equal(edges.src, edges_there.src)
    np.testing.assert_array_equal(edges.dst, edges_there.dst)
    weights = sorted(k for k in here if k.startswith("weight_"))
    assert weights
    np.testing.assert_allclose([there[k] for k in weights], [here[k] for k in weights],
                               rtol=0, atol=1e-6)


def test_a_learner_that_fails_after_repeated_iterations_still_logs_them(tmp_path, caplog,
                                                                       monkeypatch):
    """Iterations that repeat the one before are said in one line before the next other
    line; a learner stopped after them (an error, Ctrl-C) had its log end at iteration 1,
    as if it had stopped there. They are said before the error."""
    from types import SimpleNamespace

    from pipeline.app import build
    from pipeline.errors import PipelineError

    class Stops:
        def fit(self, problem, config):
            for index in range(4):
                problem.progress(SimpleNamespace(
                    index=index, weights=np.zeros(problem.prior.dim), log_likelihood=-1.0,
                    log_prior=0.0, generated=[]))
            raise PipelineError("stopped at iteration 3")

    monkeypatch.setattr(build, "irl_method", lambda cfg: Stops())
    with caplog.at_level("INFO"), pytest.raises(PipelineError, match="stopped at iteration 3"):
        run_in_process(tmp_path, "graph=small", "stages=[scene,demos,graph,birl]")
    said = [r.getMessage() for r in caplog.records if "iteration" in r.getMessage()
            and r.name == "pipeline.stages.birl"]
    assert said[-1].endswith("iterations 1-3: as iteration 0"), said
