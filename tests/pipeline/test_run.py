"""Runs through the stages of the real Hydra app, in this process: the default experiment's
artefacts, the same bytes from the same seed, stage subsets from an earlier run, a subset of
the features, and bad inputs refused in one line without touching earlier artefacts."""

import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from pipeline.artefacts import codec, read_artefact, topics
from pipeline.errors import PipelineError
from pipeline.tools import mcapinfo
from tests.conftest import POLITE, ROOT, run_app, run_in_process


def test_a_subset_of_the_features_runs_end_to_end(tmp_path):
    metrics, _ = run_in_process(tmp_path, "reward.features=[social,length]",
                                "reward.weights=[-0.7,-0.1]", "graph=small", "birl.n_iterations=3")
    # the learner has the reward's features and crossing
    assert {k for k in metrics if k.startswith("weight_")} == {"weight_social", "weight_length",
                                                               "weight_crossing"}
    assert metrics["policy_loss"] >= 0
    assert read_artefact(tmp_path / "graph.mcap").one("/graph/solution")["n_nodes"] > 0


def test_default_experiment_writes_artefacts(default_dir):
    scene = read_artefact(default_dir / "scene.mcap", required_topics=["/scene"])
    assert scene.one("/scene")["name"] == "metropolis"
    assert "reward:" in scene.config_yaml and "seed: 0" in scene.config_yaml
    assert scene.metadata["seed"] == "0" and "version.numpy" in scene.metadata
    # provenance: the revision, and whether the run used changed code (git asked here anew)
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True,
                          text=True)
    changed = subprocess.run(["git", "diff", "HEAD", "--quiet"], cwd=ROOT).returncode
    if head.returncode == 0:
        assert scene.metadata["git_revision"] == head.stdout.strip()
        assert scene.metadata["git_tree"] == ("modified" if changed else "clean")
    else:
        assert scene.metadata["git_tree"] == "unknown"
    demos = read_artefact(default_dir / "demos.mcap",
                          required_topics=["/demos", "/demos/expert", "/demos/roadmap"])
    assert len(demos.all("/demos")) == 7
    assert demos.one("/demos/expert")["true_weights"] == POLITE.tolist()
    assert all(d["reached"] for d in demos.all("/demos"))
    graph = read_artefact(default_dir / "graph.mcap", required_topics=[
        "/graph/nodes", "/graph/edges", "/graph/best_paths", "/graph/solution"])
    assert len(graph.all("/graph/nodes")) == len(graph.all("/graph/edges")) == 1  # columns
    nodes, edges = codec.decode_nodes(graph), codec.decode_edges(graph)
    solution = graph.one("/graph/solution")
    assert len(nodes) == 460 and solution["n_nodes"] == 460 and len(edges) == solution["n_edges"]
    assert solution["weights_source"] == "prior_mean"
    # Growth replays in order: nodes and edges appear no earlier than their iteration.
    assert (np.diff(nodes.added_at) >= 0).all() and nodes.added_at.max() == solution["iterations"]
    added = nodes.added_at
    assert np.array_equal(edges.added_at, np.maximum(added[edges.src], added[edges.dst]))
    assert (nodes.parent[nodes.kind == "sampled"] >= 0).all()
    assert len(graph.all("/graph/best_paths")) == solution["iterations"] + 1


def _payloads(run_dir):
    return {name: read_artefact(run_dir / name).messages
            for name in ("scene.mcap", "demos.mcap", "graph.mcap")}


def test_same_seed_same_payloads_and_other_seed_differs(tmp_path):
    # One run in a fresh process, two in this one: equal artefacts across processes too.
    args = ["scene=random", "expert=boltzmann", "graph=small", "stages=[scene,demos,graph]"]
    result = run_app(f"hydra.run.dir={tmp_path / 'a'}", "seed=3", *args)
    assert result.returncode == 0, result.stderr
    run_in_process(tmp_path / "b", "seed=3", *args)
    run_in_process(tmp_path / "c", "seed=4", *args)
    a, b, c = (_payloads(tmp_path / n) for n in "abc")
    assert a == b
    for name in ("demos.mcap", "graph.mcap"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
    assert a["scene.mcap"] != c["scene.mcap"]


def test_stage_subset_from_earlier_run(tmp_path, default_dir):
    run_in_process(tmp_path, "stages=[demos,graph]", f"from_run={default_dir}")
    # The scene the run used is linked in (same file), so the dir is complete on its own.
    assert (tmp_path / "scene.mcap").samefile(default_dir / "scene.mcap")
    assert not (tmp_path / "birl.mcap").exists()
    for name in ("demos.mcap", "graph.mcap"):
        assert read_artefact(tmp_path / name).messages == \
            read_artefact(default_dir / name).messages


def _refused_with_one_line(run_dir, overrides, *fragments):
    """In-process twin of tests/cli/test_cli.py's _fails_with_one_line: the PipelineError
    the CLI prints as one line."""
    with pytest.raises(PipelineError) as err:
        run_in_process(run_dir, *overrides)
    message = str(err.value)
    assert "\n" not in message
    for f in fragments:
        assert f in message


def test_malformed_scene_file_is_refused_with_one_line(tmp_path):
    bad = tmp_path / "bad.json"
    text = (ROOT / "data/scenes/metropolis.json").read_text()
    bad.write_text(text.replace('"x": 9.2', '"x": 19.2'))
    _refused_with_one_line(tmp_path / "run", ["scene=file", f"scene.path={bad}"],
                           str(bad), "person 5", "outside the room")


def test_truncated_input_artefact_is_refused_with_one_line(tmp_path, default_dir):
    src = tmp_path / "src"
    src.mkdir()
    data = (default_dir / "scene.mcap").read_bytes()
    (src / "scene.mcap").write_bytes(data[: len(data) // 2])
    overrides = ["stages=[demos]", f"from_run={src}"]
    _refused_with_one_line(tmp_path / "run", overrides, str(src / "scene.mcap"), "truncated")
    (src / "scene.mcap").write_text("{}")
    _refused_with_one_line(tmp_path / "run", overrides, "not an MCAP file")


def test_failing_run_keeps_earlier_artefacts(tmp_path, default_dir):
    run_dir = tmp_path / "run"
    shutil.copytree(default_dir, run_dir)
    before = (run_dir / "demos.mcap").read_bytes()
    _refused_with_one_line(run_dir, ["expert=file", f"expert.path={tmp_path}/none.json"],
                           "none.json", "not found")
    assert (run_dir / "demos.mcap").read_bytes() == before
    assert not list(Path(run_dir).glob("*.tmp"))


def test_demos_stage_writes_k_noisy_demos_per_start(tmp_path):
    run_in_process(tmp_path, "stages=[scene,demos]", "expert=boltzmann", "expert.beta=20",
                   "expert.demos_per_start=3", "expert.n_starts=2")
    demos = read_artefact(tmp_path / "demos.mcap").all("/demos")
    assert [d["start_index"] for d in demos] == [0, 0, 0, 1, 1, 1]
    assert len({len(d["points"]) for d in demos[:3]}) > 1  # three different walks


def test_evaluate_alone_on_a_run_with_a_derived_graph_size(default_run, tmp_path):
    """graph.max_nodes left null is derived from the scene; stage evaluate alone derives it
    too, so the earlier run's artefacts match and score the same."""
    run_dir, metrics = default_run[0], default_run[1]
    again, _ = run_in_process(tmp_path, "stages=[evaluate]", f"from_run={run_dir}")
    assert again["policy_loss_norm"] == metrics["policy_loss_norm"]


def test_a_scene_without_persons_runs_end_to_end(tmp_path):
    """Nobody to keep a distance from: the smallest distance to a person has no value, which
    the artefact leaves out (its stored schema allows that) and the summary shows as n/a (it
    used to fail the run)."""
    scene = json.loads((ROOT / "data" / "scenes" / "metropolis.json").read_text())
    scene |= {"persons": [], "relations": []}
    path = tmp_path / "empty.json"
    path.write_text(json.dumps(scene))
    run_in_process(tmp_path / "run", "scene=file", f"scene.path={path}")
    paths = read_artefact(tmp_path / "run" / "eval.mcap").all(topics.EVAL_PATHS)
    assert paths and all("min_distance_to_person" not in p for p in paths)
    assert all(p["success"] for p in paths)
    assert mcapinfo.main(["--check", str(tmp_path / "run" / "eval.mcap")]) == 0


@pytest.mark.parametrize("overrides, advice", [
    # POSQ runs of at most 10 ms arrive nowhere: the space advice was wrong for these
    (["graph.controller.kind=posq", "graph.controller.max_time=0.01",
      "graph.controller.dt=0.005"], "(check graph.controller)"),
    (["graph.min_separation=2.5"], "(lower graph.min_separation or graph.max_nodes)"),
])
def test_a_graph_that_stops_short_says_whether_space_or_the_controller_stopped_it(
        tmp_path, caplog, overrides, advice):
    with caplog.at_level("WARNING"):
        run_in_process(tmp_path, *overrides, "stages=[scene,demos,graph]")
    [warning] = [r.getMessage() for r in caplog.records if "graph stopped at" in r.getMessage()]
    assert warning.endswith(advice)


@pytest.mark.parametrize("overrides, pattern, expected", [
    (["birl.n_iterations=100", "birl.likelihood=robust", "stages=[scene,demos,graph,birl]"],
     r"eq\. \(2\) loop: iteration (\d+) of 100", list(range(10, 101, 10))),
    (["expert=planner", "expert.n_subjects=10", "stages=[scene,demos]"],
     r"planner: (\d+) of 10 subjects planned", list(range(1, 10))),
    (["expert=planner", "expert.n_subjects=9", "stages=[scene,demos]"],  # short: silent
     r"planner: (\d+) of 9 subjects planned", []),
    (["graph=small", "stages=[scene,demos,graph]"],  # nodes so far, seconds left
     r"iteration +\d+: +(\d+) of 200 nodes, +\d+ edges, [\d.]+ s(, about [\d.]+ s left)?;",
     [139, 160, 181, 200]),
    # many demonstrations: said before their waypoints are connected (7000 took 27 s), and
    # a graph they fill past graph.max_nodes is not said to grow to it
    (["graph=small", "expert=boltzmann", "expert.demos_per_start=40",
      "stages=[scene,demos,graph]"],
     r"initialising from the waypoints of (\d+) demonstrations|initialised: (\d+) nodes, "
     r"\d+ edges, already graph.max_nodes=200 or more: no growth", [280, None]),
])
def test_long_work_inside_a_stage_says_how_far_it_got(tmp_path, caplog, overrides, pattern,
                                                      expected):
    """Long eq. (2) loops and many planner subjects ran for minutes without a line."""
    with caplog.at_level("INFO"):
        run_in_process(tmp_path, *overrides)
    told = [m[1] and int(m[1]) for r in caplog.records
            if (m := re.search(pattern, r.getMessage()))]
    assert told == expected


def test_writing_a_large_graph_is_said_before_and_timed_after(tmp_path, caplog, monkeypatch):
    """graph.mcap of a 55 000-node floor took 25 s to write after growth's last line."""
    from pipeline.app import limits
    monkeypatch.setattr(limits, "LARGE_GRAPH_NODES", 200)  # graph=small grows 200 nodes
    with caplog.at_level("INFO"):
        run_in_process(tmp_path, "graph=small", "stages=[scene,demos,graph]")
    said = [r.getMessage() for r in caplog.records]
    before = next(i for i, m in enumerate(said)
                  if re.fullmatch(r"graph: writing graph\.mcap \(200 nodes, \d+ edges\) \.\.\.", m))
    assert re.fullmatch(r"graph\.mcap written in [\d.]+ s", said[before + 1])
    assert (tmp_path / "graph.mcap").exists()
    monkeypatch.setattr(limits, "LARGE_GRAPH_NODES", 201)  # one more: silent
    caplog.clear()
    with caplog.at_level("INFO"):
        run_in_process(tmp_path / "small", "graph=small", "stages=[scene,demos,graph]")
    assert not any("writing graph.mcap" in r.getMessage() or "written in" in r.getMessage()
                   for r in caplog.records)


def test_the_summary_names_the_weights_at_the_boxs_bounds_and_middle(default_run, tmp_path):
    _, metrics, stdout = default_run
    names = ["relation", "social", "goal_deviation", "length", "crossing"]
    weights = {n: metrics[f"weight_{n}"] for n in names}
    # the default box is [-1, 0] for every weight: say which learned weights lie where
    at = {where: [n for n in names if abs(weights[n] - value) <= 1e-6]
          for where, value in (("lower bound", -1.0), ("upper bound", 0.0), ("middle", -0.5))}
    assert any(at.values())  # the default run has some (relation at -1), else nothing to test
    line = next(x for x in stdout.splitlines() if x.startswith("  weight box"))
    for where, hit in at.items():
        assert (f"{', '.join(hit)} at its {where}" in line) == bool(hit), (where, line)
    for n in names:  # and only those
        assert (n in line) == any(n in hit for hit in at.values()), (n, line)
    # given weights (birl=fixed, all at a bound) are not described as learned
    fixed = run_in_process(tmp_path, "birl=fixed", "birl.weights=[-1,-1,-1,-1,-1]",
                           "stages=[birl,evaluate]", f"from_run={default_run[0]}")[1]
    assert "fixed weights    relation -1.000" in fixed and "weight box" not in fixed
    assert "learned weights" not in fixed and "weights from     birl.weights (given)" in fixed
    # from a run: its learner's notes come along (crossing: nothing moved it)
    deployed = run_in_process(tmp_path / "deployed", "birl=fixed",
                              f"birl.from_run={default_run[0]}", "stages=[birl,evaluate]",
                              f"from_run={default_run[0]}")[1]
    source_notes = line.replace("  weight box       ", "")
    assert f"weights from     {default_run[0]} (learned there)" in deployed
    assert f"  its weight box   {source_notes}" in deployed
    # from a deployment: nothing was learned there, and its box says nothing
    again = run_in_process(tmp_path / "again", "birl=fixed", f"birl.from_run={tmp_path}",
                           "stages=[birl,evaluate]", f"from_run={default_run[0]}")[1]
    assert f"weights from     {tmp_path} (given there too: birl=fixed, its birl.weights)" \
        in again and "learned there" not in again and "weight box" not in again


def test_the_normalised_loss_is_the_roadmap_loss_over_the_contrasts(tmp_path, default_run):
    """policy_loss_norm divides the roadmap's loss (not the adaptive graph's) by the rude
    reward's on the roadmap: weights that lose on both graphs, by different amounts."""
    m = run_in_process(tmp_path, "birl=fixed", "birl.weights=[-0.2,-1,-0.1,-0.5,-0.5]",
                       "stages=[birl,evaluate]", f"from_run={default_run[0]}")[0]
    assert m["policy_loss_ref"] > 0.05 and m["policy_loss"] > 0.01
    assert abs(m["policy_loss"] - m["policy_loss_ref"]) > 0.05
    assert m["policy_loss_norm"] == pytest.approx(m["policy_loss_ref"] / m["policy_loss_ref_rude"],
                                                  rel=1e-12)


def test_graph_edges_name_their_feature_columns(default_run):
    """graph.mcap is made before birl.mcap: its edges' feature columns are named in it (the
    learner's features, as /birl/expert names them), not only by the later artefact."""
    run_dir = default_run[0]
    [edges] = read_artefact(run_dir / "graph.mcap").all(topics.GRAPH_EDGES)
    learner = read_artefact(run_dir / "birl.mcap").one(topics.BIRL_EXPERT)["feature_names"]
    assert edges["feature_names"] == learner == ["relation", "social", "goal_deviation",
                                                 "length", "crossing"]
    assert edges["n_features"] == len(learner)


def test_the_summary_names_the_weights_learning_never_moved(tmp_path, default_run):
    """MaxEnt leaves the weight of a feature no path of its MDP incurs (crossing, on
    metropolis) at its start, a prior draw, which the summary showed as if learned; the
    iterations' weights (birl.mcap) tell which, and the default learner's moved all."""
    stdout = run_in_process(tmp_path, "birl=maxent", "stages=[graph,birl,evaluate]",
                            f"from_run={default_run[0]}")[1]
    weights = np.array([it["weights"] for it in
                        read_artefact(tmp_path / "birl.mcap").all(topics.BIRL_ITERATION)])
    names = ["relation", "social", "goal_deviation", "length", "crossing"]
    still = [n for n, span in zip(names, np.ptp(weights, axis=0), strict=True)
             if span <= 1e-5 * 100]  # MaxEnt's box: [-100, 0]
    assert still == ["crossing"] and weights[0, -1] == pytest.approx(weights[-1, -1], abs=1e-3)
    assert "  not learned      crossing never moved from where learning started" in stdout
    assert "not learned" not in default_run[2]


def test_the_summary_warns_when_the_graphs_paths_are_ruder_than_the_roadmaps(tmp_path,
                                                                            default_run):
    """Deployed without demonstrations and without the medial axis's initial nodes, the
    460-node graph of metropolis (seed 2) lacks the detours round the groups: its paths
    cross links the roadmap's avoid, under the same learned reward, and the summary says
    which to deploy."""
    m, out = run_in_process(tmp_path, "expert=none", "birl=fixed", "graph.medial_axis=false",
                            f"birl.from_run={default_run[0]}", "seed=2")
    assert m["relation_crossings"] > m["ref_relation_crossings"] == 0  # the case
    warning = [x for x in out.splitlines() if "ruder than the roadmap's" in x]
    assert len(warning) == 1
    assert f"crossings {m['relation_crossings']:.0f} against 0" in warning[0]
    assert "/birlg/learned_paths_ref" in warning[0]
    assert "ruder" not in default_run[2]  # with demonstrations: the same paths' quality
    # a true reward no link costs (rude): the graph's crossings lose nothing, no advice
    m, out = run_in_process(tmp_path / "rude", "reward=rude", "expert=boltzmann",
                            "expert.beta=20")
    assert m["relation_crossings"] > m["ref_relation_crossings"]
    assert m["policy_loss"] <= m["policy_loss_ref"] and "ruder" not in out


def test_the_summary_warns_of_demonstrations_that_do_not_reach_the_goal(tmp_path, default_run):
    """The log's warning was the only sign of demonstrations that stop short, which move
    the weights of every method but the default learner's."""
    shipped = json.loads((ROOT / "data" / "demos" / "metropolis_handdrawn.json").read_text())
    walks = shipped["trajectories"]
    walks[2] = walks[2][:-8]  # the third walk stops short of the goal
    path = tmp_path / "short.json"
    path.write_text(json.dumps({**shipped, "trajectories": walks}))
    m, out = run_in_process(tmp_path / "run", "expert=file", f"expert.path={path}",
                            "graph=small", "birl.n_iterations=2")
    assert (m["demos_unreached"], m["demos_count"]) == (1, len(walks))
    assert f"warning          1 of {len(walks)} demonstrations learned from do not reach " \
        "the goal" in out
    assert "do not reach the goal" not in default_run[2]  # every synthetic walk arrives


def test_the_summary_warns_when_learned_paths_stop_short(tmp_path, default_run):
    """A deployment whose graph paths never arrive printed their distances to people
    without a word on the summary (the log's warning only). The case: the office without
    its medial-axis nodes, whose doors the graph's controller runs do not find."""
    m, out = run_in_process(tmp_path, "scene=office", "graph.medial_axis=false", "expert=none",
                            "birl=fixed", "birl.weights=[-1,-0.7,-0.85,-0.1,-0.5]", "seed=0")
    assert m["success"] < 1 <= m["ref_success"]  # the case: the graph's paths stop short
    assert f"learned paths stop short of the goal (success graph {m['success']:.2f})" in out
    assert "stop short" not in default_run[2]  # every default path arrives: no warning


def test_growth_time_left_integrates_a_cost_that_grows_with_the_graph():
    """The graph stage's time left: a constant cost per node gives the rate times the
    nodes left; a cost proportional to the graph's size (seconds per node a·n) is
    integrated exactly, a·(N² − n²)/2, where the last window's rate alone said a·n·(N − n)
    (3-4 times too little on a 200 m floor)."""
    from pipeline.app.limits import growth_seconds_left as time_left
    assert time_left([(100.0, 0.01)], 200, 1000) == pytest.approx(0.01 * 800)
    assert time_left([(100.0, 0.01), (300.0, 0.01)], 400, 1000) == pytest.approx(0.01 * 600)
    a = 1e-5  # s per node per node of the graph
    rates = [(1000.0, a * 1000), (3000.0, a * 3000)]
    assert time_left(rates, 3000, 30_000) == pytest.approx(a * (30_000**2 - 3000**2) / 2)
    # a cost that falls is taken as constant, one that rises faster than n² as n²
    assert time_left([(100.0, 0.02), (200.0, 0.01)], 200, 400) == pytest.approx(0.01 * 200)
    steep = time_left([(100.0, 1e-3), (200.0, 1e-1)], 200, 400)
    assert steep == pytest.approx(1e-1 * 200 / 3 * (2**3 - 1))
    # the exponent comes from every window: one flat window after a rise (noise: on a 200 m
    # floor the estimate swung 97 s <-> 269 s from line to line) keeps part of the rise
    r = 0.01
    wobbly = time_left([(1000.0, r), (2000.0, 2 * r), (3000.0, 2 * r)], 3000, 6000)
    assert 2 * r * 3000 < wobbly < 2 * r * 3000 / 2 * ((6000 / 3000) ** 2 - 1)
