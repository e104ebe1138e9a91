"""Held-out demonstrations (DESIGN §9), the learner's own feature set, and deployment
without demonstrations, through the real stages."""

import json
import shutil

import numpy as np
import pytest

from pipeline.artefacts import codec, read_artefact, topics
from pipeline.core.evaluation import frechet
from pipeline.core.experts import choose_heldout
from pipeline.core.features import FeatureModel, FeatureParams
from pipeline.core.graph_mdp import MDPParams
from pipeline.core.roadmap import pulled_taut, segment_cost
from pipeline.core.social import min_distance_to_person
from pipeline.errors import PipelineError
from tests.conftest import CLEAN_DRIVES, ROOT, odometry, run_in_process, write_bag
from tests.pipeline.conftest import FAST


def test_held_out_demonstrations_never_enter_the_graph_or_the_likelihood(subjects_run):
    run_dir, metrics, _ = subjects_run
    demos = read_artefact(run_dir / "demos.mcap").all(topics.DEMOS)
    held = [d for d in demos if d["heldout"]]
    kept = [d for d in demos if not d["heldout"]]
    assert {d["subject"] for d in held} == {"s2"} and len(held) == 7 and len(kept) == 14
    assert {d["source"] for d in demos} == {None}  # synthetic: no file to trace back to
    nodes = codec.decode_nodes(read_artefact(run_dir / "graph.mcap"))
    demo_nodes = nodes.positions[nodes.kind == "demo"]
    # every demonstration node is a waypoint of a kept demonstration, none only of a held one
    kept_points = np.vstack([d["points"] for d in kept])
    held_only = np.vstack([d["points"] for d in held])
    near_kept = np.linalg.norm(demo_nodes[:, None] - kept_points[None], axis=2).min(axis=1)
    assert near_kept.max() < 1e-9
    near_held = np.linalg.norm(held_only[:, None] - demo_nodes[None], axis=2).min(axis=1)
    assert (near_held > 1e-9).any()  # the held-out paths are not in the graph
    expert = read_artefact(run_dir / "birl.mcap").one(topics.BIRL_EXPERT)
    assert len(expert["trajectories"]) == len(kept)
    # the demos carry the true reward's features, the learner has its own: compare those
    # both have, by name
    shared = [expert["feature_names"].index(n) for n in ("relation", "social",
                                                          "goal_deviation", "length")]
    np.testing.assert_allclose([np.asarray(t["phi"])[shared] for t in expert["trajectories"]],
                               [d["discounted_features"] for d in kept])
    assert metrics["heldout_count"] == 7


def test_held_out_metrics_compare_with_the_fastest_path(subjects_run):
    _, metrics, out = subjects_run
    for key in ("heldout_frechet_m", "heldout_frechet_m_shortest",
                "heldout_min_distance_error_m", "heldout_min_distance_error_m_shortest"):
        assert metrics[key] >= 0, key
    # people avoid people; the fastest path does not, so it predicts them worse, and so
    # does its reward (the cost per second alone) as a model of their paths
    assert metrics["heldout_frechet_m"] < metrics["heldout_frechet_m_shortest"]
    assert metrics["heldout_log_likelihood"] > metrics["heldout_log_likelihood_shortest"]
    assert "held out (7)" in out
    # a median hides a start whose paths go the other way round; the largest does not
    for suffix in ("", "_shortest"):
        assert metrics[f"heldout_frechet_m{suffix}_max"] >= metrics[f"heldout_frechet_m{suffix}"]
    assert f"worst held-out Fréchet {metrics['heldout_frechet_m_max']:.2f} m" in out
    assert "predicts them worse than no reward does" not in out


def test_held_out_distances_are_medians_over_the_held_out_demonstrations(subjects_run):
    """heldout_frechet_m and heldout_min_distance_error_m: the median over the held-out
    demonstrations of each one's distance to the learned roadmap path from its start
    (eval.mcap), and the largest of them; recomputed here from the artefacts."""
    run_dir, metrics, _ = subjects_run
    scene = codec.decode_scene(read_artefact(run_dir / "scene.mcap"))
    learned = {p["start"]: np.asarray(p["points"], float)
               for p in read_artefact(run_dir / "eval.mcap").all(topics.EVAL_PATHS)
               if p["graph"] == "ref"}
    held = [d for d in read_artefact(run_dir / "demos.mcap").all(topics.DEMOS) if d["heldout"]]
    frechets = [frechet(learned[d["start_index"]], np.asarray(d["points"], float))
                for d in held]
    errors = [abs(min_distance_to_person(learned[d["start_index"]], scene.person_xy)
                  - min_distance_to_person(np.asarray(d["points"], float), scene.person_xy))
              for d in held]
    assert np.ptp(frechets) > 0.05  # mean, median and largest differ
    assert metrics["heldout_frechet_m"] == pytest.approx(np.median(frechets), rel=1e-12)
    assert metrics["heldout_frechet_m_max"] == pytest.approx(max(frechets), rel=1e-12)
    assert metrics["heldout_min_distance_error_m"] == pytest.approx(np.median(errors),
                                                                    rel=1e-12, abs=1e-15)


def test_held_out_distances_of_the_paths_pulled_taut_are_recomputed_from_the_artefacts(
        subjects_run):
    """heldout_*_taut: the learned roadmap paths (eval.mcap) pulled taut under the learned
    weights on the learner's features, and the same medians as for the lattice paths."""
    run_dir, metrics, _ = subjects_run
    scene = codec.decode_scene(read_artefact(run_dir / "scene.mcap"))
    names = read_artefact(run_dir / "birl.mcap").one(topics.BIRL_EXPERT)["feature_names"]
    w = np.array([metrics[f"weight_{n}"] for n in names])
    cost = segment_cost(FeatureModel.from_scene(scene, FeatureParams(features=list(names))),
                        MDPParams(), w)
    learned = {p["start"]: pulled_taut(scene, np.asarray(p["points"], float), cost)
               for p in read_artefact(run_dir / "eval.mcap").all(topics.EVAL_PATHS)
               if p["graph"] == "ref"}
    held = [d for d in read_artefact(run_dir / "demos.mcap").all(topics.DEMOS) if d["heldout"]]
    frechets = [frechet(learned[d["start_index"]], np.asarray(d["points"], float))
                for d in held]
    assert metrics["heldout_frechet_m_taut"] == pytest.approx(np.median(frechets), rel=1e-12)
    # on metropolis the lattice decides nothing: no warning
    assert metrics["heldout_frechet_m_taut"] < metrics["heldout_frechet_m_shortest_taut"]
    assert "the lattice's doing" not in subjects_run[2]


def test_the_summary_warns_when_the_lattice_decides_the_comparison(tmp_path):
    """Held-out walks that are the learned roadmap paths themselves (staircases a hinge of
    the social feature chose among equally short ones, to keep 1.2 m from a person the
    straight line passes farther from): on the lattice the learned paths predict them
    perfectly and the shortest paths do not; pulled taut under their own reward, both are
    the straight line, equally far from them. The summary says the lead is the lattice's."""
    hall = {"name": "hall", "room": {"x_min": 0, "y_min": 0, "x_max": 10, "y_max": 9},
            "persons": [{"id": 1, "x": 3.0, "y": 7.9, "theta": 0.0}], "relations": [],
            "starts": [[1.0, 1.0], [1.0, 7.0]], "goal": [9.0, 4.5]}
    scene = tmp_path / "hall.json"
    scene.write_text(json.dumps(hall))
    lines = [np.linspace(s, hall["goal"], 30).tolist() for s in hall["starts"]]
    walks = tmp_path / "lines.json"
    walks.write_text(json.dumps({"trajectories": lines * 2, "subjects": ["a", "a", "b", "b"]}))
    args = ("scene=file", f"scene.path={scene}", "expert=file", "evaluate.holdout=[b]",
            "graph=small", "birl=fixed", "birl.weights=[0,-0.3,0,-1,0]")
    run_in_process(tmp_path / "first", *args, f"expert.path={walks}")
    learned = [p["points"] for p in read_artefact(tmp_path / "first" / "eval.mcap")
               .all(topics.EVAL_PATHS) if p["graph"] == "ref"]
    walks.write_text(json.dumps({"trajectories": learned * 2, "subjects": ["a", "a", "b", "b"]}))
    m, out = run_in_process(tmp_path / "second", *args, f"expert.path={walks}")
    assert m["heldout_frechet_m"] < m["heldout_frechet_m_shortest"]  # the case
    assert m["heldout_frechet_m_taut"] == pytest.approx(m["heldout_frechet_m_shortest_taut"])
    assert (f"the learned paths predict the held-out demonstrations no better (Fréchet "
            f"{m['heldout_frechet_m_taut']:.2f} m against "
            f"{m['heldout_frechet_m_shortest_taut']:.2f} m") in out
    assert "the difference above is the lattice's doing, not the learned reward's" in out
    # only the measures whose comparison turned are named
    assert m["heldout_min_distance_error_m"] < m["heldout_min_distance_error_m_shortest"]
    assert ("min-distance error" in out.split("pulled taut")[1].split("\n")[0]) == (
        m["heldout_min_distance_error_m_taut"] >= m["heldout_min_distance_error_m_shortest_taut"])
    # the other way round: held-out walks that are the shortest paths' staircases, the
    # learned ones another: on the lattice the learned paths predict them worse (the summary
    # says so), pulled taut no worse, and the summary says that too
    run_in_process(tmp_path / "fastest", *args[:-1], "birl.weights=[0,0,0,0,0]",
                   f"expert.path={walks}")
    fastest = [p["points"] for p in read_artefact(tmp_path / "fastest" / "eval.mcap")
               .all(topics.EVAL_PATHS) if p["graph"] == "ref"]
    walks.write_text(json.dumps({"trajectories": fastest * 2, "subjects": ["a", "a", "b", "b"]}))
    m, out = run_in_process(tmp_path / "third", *args, f"expert.path={walks}")
    assert m["heldout_frechet_m"] > m["heldout_frechet_m_shortest"]  # the case
    assert m["heldout_frechet_m_taut"] <= m["heldout_frechet_m_shortest_taut"]
    assert "the learned paths are farther from the held-out demonstrations" in out
    assert (f"predict the held-out demonstrations no worse (Fréchet "
            f"{m['heldout_frechet_m_taut']:.2f} m against "
            f"{m['heldout_frechet_m_shortest_taut']:.2f} m") in out


def test_the_summary_warns_when_the_shortest_path_predicts_better(subjects_run, tmp_path):
    """A reward deployed where its demonstrators behave otherwise can predict them worse
    than going straight (a social-force demonstrator learned on metropolis, deployed on a
    random scene: 2.17 m against 0.60 m); the summary says so. The case: a reward of the
    links alone, which detours round every group the planner's subjects pass."""
    run_dir, _, _ = subjects_run
    m, out = run_in_process(tmp_path, "graph=small", "expert=planner", "expert.n_subjects=3",
                            "evaluate.holdout=[s2]", "birl=fixed",
                            "birl.weights=[-1,0,0,0,-1]", "stages=[birl,evaluate]",
                            f"from_run={run_dir}")
    assert m["heldout_frechet_m"] > m["heldout_frechet_m_shortest"]  # the case
    assert "the learned paths are farther from the held-out demonstrations than the " \
        "shortest paths are" in out


def test_the_summary_warns_when_the_learned_paths_predict_no_better_than_the_shortest(
        subjects_run, tmp_path):
    """Weights that plan the shortest paths (all zero) predict the held-out demonstrations
    exactly as well as the shortest paths: neither "worse" warning holds, and the summary
    still says that the reward adds nothing (a Nav2-like planner's walks, learned without a
    wall feature, were told nothing)."""
    run_dir, _, _ = subjects_run
    m, out = run_in_process(tmp_path, "graph=small", "expert=planner", "expert.n_subjects=3",
                            "evaluate.holdout=[s2]", "birl=fixed",
                            "birl.weights=[0,0,0,0,0]", "stages=[birl,evaluate]",
                            f"from_run={run_dir}")
    assert m["heldout_frechet_m"] == m["heldout_frechet_m_shortest"]  # the case
    assert m["heldout_min_distance_error_m"] == m["heldout_min_distance_error_m_shortest"]
    assert "as far from the held-out demonstrations as the shortest paths are" in out
    assert "worse than no reward does" not in out
    assert "as far from the held-out" not in subjects_run[2]


def test_one_held_out_likelihood_judges_every_method(subjects_run, tmp_path):
    """PolicyWalk's reward is scored by the same model: on the same demonstrations its
    baseline (w = 0) is the BIRL-G run's to the bit, and its own score is another."""
    run_dir, metrics, _ = subjects_run
    walk, _ = run_in_process(tmp_path, *FAST, "expert=planner", "expert.n_subjects=3",
                             "evaluate.holdout=[s2]", "birl=policywalk",
                             "stages=[birl,evaluate]", f"from_run={run_dir}")
    assert walk["heldout_log_likelihood_shortest"] == metrics["heldout_log_likelihood_shortest"]
    assert np.isfinite(walk["heldout_log_likelihood"])
    assert walk["heldout_log_likelihood"] != metrics["heldout_log_likelihood"]


@pytest.mark.parametrize("holdout, expected", [
    (None, [False] * 5),
    ("all", [True] * 5),
    (["b"], [False, True, False, True, False]),
])
def test_choose_heldout(holdout, expected):
    starts, subjects = [0, 0, 0, 1, 1], ["a", "b", "c", "b", "a"]
    assert choose_heldout(starts, subjects, holdout, np.random.default_rng(3)).tolist() \
        == expected


def test_a_held_out_fraction_is_drawn_per_start_and_seeded():
    starts = [0, 0, 0, 1, 1]  # half of 3 rounds to 2, half of 2 is 1
    held = choose_heldout(starts, [None] * 5, 0.5, np.random.default_rng(3))
    assert held[:3].sum() == 2 and held[3:].sum() == 1
    again = choose_heldout(starts, [None] * 5, 0.5, np.random.default_rng(3))
    assert held.tolist() == again.tolist()


def test_choose_heldout_keeps_one_per_start_and_refuses_unknown_subjects():
    held = choose_heldout([0, 0, 1], [None] * 3, 0.99, np.random.default_rng(0))
    assert held[:2].sum() == 1 and not held[2]  # start 1's only demonstration is kept
    with pytest.raises(PipelineError, match="subject 'zz'"):
        choose_heldout([0], ["a"], ["zz"], np.random.default_rng(0))
    # a bag names no subjects: the message says where they come from
    with pytest.raises(PipelineError, match=r"subject 'zz', which demonstrated nothing "
                                            r"\(subjects: none: the demonstrations name no "
                                            r"subjects .*a folder of recordings, one per "
                                            r"subject, as expert.path\)"):
        choose_heldout([0], [None], ["zz"], np.random.default_rng(0))


def test_the_learner_may_order_its_features_differently_from_the_true_reward(tmp_path):
    """A learner on the same features in another order learns the same reward: its policy
    loss, scored on the true reward's features, is the default run's."""
    base, _ = run_in_process(tmp_path / "a", *FAST,
                             "birl.init_weights=[-0.3,-0.5,-0.7,-0.2,-0.4]")
    perm, _ = run_in_process(tmp_path / "b", *FAST,
                             "birl.init_weights=[-0.2,-0.4,-0.7,-0.5,-0.3]",
                             "birl.features=[length,crossing,goal_deviation,social,relation]")
    assert perm["policy_loss_norm"] == pytest.approx(base["policy_loss_norm"], abs=1e-6)
    for name in ("relation", "social", "goal_deviation", "length", "crossing"):
        assert perm[f"weight_{name}"] == pytest.approx(base[f"weight_{name}"], abs=1e-4)


def test_a_learner_with_more_features_is_scored_on_the_true_reward(tmp_path):
    metrics, _ = run_in_process(tmp_path, *FAST,
                                "birl.features=[relation,intimate,social,goal_deviation,length]")
    assert "weight_intimate" in metrics and metrics["policy_loss_norm"] >= 0
    names = read_artefact(tmp_path / "birl.mcap").one(topics.BIRL_EXPERT)["feature_names"]
    assert names == ["relation", "intimate", "social", "goal_deviation", "length"]


def test_deployment_without_demonstrations_plans_with_the_given_reward(tmp_path):
    weights = "birl.weights=[-1.0,-0.7,-0.85,-0.1,-0.5]"  # the polite weights, crossing -0.5
    metrics, out = run_in_process(tmp_path, "graph=small", "expert=none", "birl=fixed",
                                  weights)
    demos = read_artefact(tmp_path / "demos.mcap")
    assert demos.one(topics.DEMOS_EXPERT)["kind"] == "none"
    assert not demos.messages.get(topics.DEMOS)
    assert "policy_loss" not in metrics and metrics["ref_success"] == 1.0
    assert json.loads((tmp_path / "status.json").read_text())["state"] == "complete"


def test_a_deployment_plans_on_the_features_its_reward_was_learned_on(tmp_path):
    """birl=fixed birl.from_run=RUN without birl.features takes RUN's learner features
    (here six, one more than the default five)."""
    learned = tmp_path / "learned"
    six = "[relation,social,social_squared,goal_deviation,length,crossing]"
    metrics, _ = run_in_process(learned, *FAST, "expert=file",
                                "expert.path=data/demos/metropolis_handdrawn.json",
                                f"birl.features={six}")
    deployed, out = run_in_process(tmp_path / "deployed", "graph=small", "expert=none",
                                   "birl=fixed", f"birl.from_run={learned}")
    names = read_artefact(tmp_path / "deployed" / "birl.mcap").one(
        topics.BIRL_EXPERT)["feature_names"]
    assert names == six.strip("[]").split(",")
    for name in names:
        assert deployed[f"weight_{name}"] == metrics[f"weight_{name}"]
    assert deployed["ref_success"] == 1.0


def test_held_out_subject_ids_are_read_as_the_files_ids_are():
    """Ids in the file are trimmed, so ' b ' on the command line is subject b; a subject
    named true, given bare ([true]), is read by the command line as a boolean: still true."""
    starts, subjects = [0, 0, 1], ["a", "true", "b"]
    rng = np.random.default_rng(0)
    assert choose_heldout(starts, subjects, [" b "], rng).tolist() == [False, False, True]
    assert choose_heldout(starts, subjects, [True], rng).tolist() == [False, True, False]
    with pytest.raises(PipelineError, match="subject 'false', which demonstrated nothing"):
        choose_heldout(starts, subjects, [False], rng)


def test_a_demonstration_file_edited_since_its_run_is_not_reused(tmp_path):
    """Re-running later stages from a run whose demonstrations came from a file: the file
    as it is now must be the one that was read (the path alone was compared, so a file cut
    from 21 to 10 drawings went on being learned from as 21)."""
    drawn = json.loads((ROOT / "data" / "demos" / "metropolis_handdrawn.json").read_text())
    path = tmp_path / "walks.json"
    path.write_text(json.dumps(drawn))
    first = tmp_path / "first"
    run_in_process(first, *FAST, "expert=file", f"expert.path={path}")
    again = ("stages=[graph,birl,evaluate]", f"from_run={first}", "expert=file",
             f"expert.path={path}")
    run_in_process(tmp_path / "same", *FAST, *again)  # unchanged: reused
    path.write_text(json.dumps({"trajectories": drawn["trajectories"][:10]}))
    with pytest.raises(PipelineError, match=r"demos\.mcap was made from other contents of "
                                            r"expert\.path than it names now \(another file, "
                                            r"or the file changed since\): add "
                                            r"'demos' to stages"):
        run_in_process(tmp_path / "edited", *FAST, *again)


def test_a_scene_file_or_its_map_edited_since_its_run_is_not_reused(tmp_path):
    """As for demonstrations: later stages from a run whose scene came from a file must find
    the file, and the map it names, as they were (the path alone was compared, so a moved
    person or a redrawn map went on unseen)."""
    shutil.copytree(ROOT / "data" / "maps", tmp_path / "maps")
    (tmp_path / "scenes").mkdir()
    scene = tmp_path / "scenes" / "office.json"
    data = json.loads((ROOT / "data" / "scenes" / "office.json").read_text())
    scene.write_text(json.dumps(data))
    first = tmp_path / "first"
    run_in_process(first, *FAST, "scene=file", f"scene.path={scene}", "stages=[scene]")
    again = ("stages=[demos]", f"from_run={first}", "scene=file", f"scene.path={scene}")
    run_in_process(tmp_path / "same", *FAST, *again)  # unchanged: reused
    data["persons"][0]["x"] += 0.5
    scene.write_text(json.dumps(data))
    refused = r"scene\.mcap was made from other contents of scene\.path than it names now"
    with pytest.raises(PipelineError, match=refused):
        run_in_process(tmp_path / "moved", *FAST, *again)
    data["persons"][0]["x"] -= 0.5
    scene.write_text(json.dumps(data))
    image = tmp_path / "maps" / "office.pgm"
    image.write_bytes(image.read_bytes()[:-1] + b"\x00")  # one pixel black
    with pytest.raises(PipelineError, match=refused):
        run_in_process(tmp_path / "redrawn", *FAST, *again)


def test_the_summary_warns_when_the_shortest_path_passes_people_more_like_them(tmp_path):
    """The min-distance error has a warning of its own: demonstrators who walk straight past
    a person 1.45 m off their line, held out, and a reward that keeps 3 m from everyone
    (a hinge at 3 m, weight -20) detour round the person; the shortest path passes as they
    do."""
    scene = {"name": "pass", "room": {"x_min": 0, "y_min": 0, "x_max": 10, "y_max": 6},
             "persons": [{"id": 1, "x": 5.0, "y": 3.2, "theta": -1.57}], "relations": [],
             "starts": [[1.0, 1.5], [1.0, 2.0]], "goal": [9.0, 1.75]}
    walks = [np.linspace(start, scene["goal"], 30).tolist()
             for start in scene["starts"] for _ in "ab"]
    (tmp_path / "scene.json").write_text(json.dumps(scene))
    (tmp_path / "demos.json").write_text(json.dumps({"trajectories": walks,
                                                     "subjects": ["a", "b"] * 2}))
    m, out = run_in_process(tmp_path / "run", "graph=small", "scene=file",
                            f"scene.path={tmp_path / 'scene.json'}", "expert=file",
                            f"expert.path={tmp_path / 'demos.json'}", "evaluate.holdout=[b]",
                            "birl=fixed", "birl.features=[social@3.0]", "birl.weights=[-20]",
                            "birl.lower=[-100]")
    assert m["heldout_min_distance_error_m"] > m["heldout_min_distance_error_m_shortest"] + 1
    assert "closest approach to a person differs more from the held-out demonstrations' " \
        "than the shortest paths' does (min-distance error)" in out


def test_the_summary_warns_when_the_learned_paths_pass_closer_than_every_demonstrator(
        tmp_path):
    """Demonstrators who go round a person standing on their straight line, 1.5 m off it,
    and a reward deployed on their scene: with no person cost its roadmap paths go straight
    through, closer than any of them (the summary says so and what to add); with a
    strong one they keep their distance, and nothing is said."""
    scene = {"name": "round", "room": {"x_min": 0, "y_min": 0, "x_max": 10, "y_max": 6},
             "persons": [{"id": 1, "x": 5.0, "y": 2.0, "theta": 1.57}], "relations": [],
             "starts": [[1.0, 2.0]], "goal": [9.0, 2.0]}
    detour = [[1.0, 2.0], [3.0, 3.3], [5.0, 3.5], [7.0, 3.3], [9.0, 2.0]]
    (tmp_path / "scene.json").write_text(json.dumps(scene))
    (tmp_path / "demos.json").write_text(json.dumps({"trajectories": [detour, detour]}))
    common = ("graph=small", "scene=file", f"scene.path={tmp_path / 'scene.json'}",
              "expert=file", f"expert.path={tmp_path / 'demos.json'}", "birl=fixed",
              "birl.features=[social@2.0,length]")
    rude, out = run_in_process(tmp_path / "rude", *common, "birl.weights=[0,-1]")
    # the detour's second segment, (3, 3.3) to (5, 3.5), passes the person at 1.49 m: the
    # cross product of its direction (2, 0.2) with (5 - 3, 2 - 3.3), over its length
    assert rude["demos_min_distance_to_person"] == pytest.approx(
        abs(2.0 * -1.3 - 0.2 * 2.0) / np.hypot(2.0, 0.2), abs=1e-9)
    assert rude["ref_min_distance_to_person"] < 0.5
    assert f"the learned roadmap paths pass {rude['ref_min_distance_to_person']:.2f} m from " \
        f"a person, closer than any demonstration " \
        f"({rude['demos_min_distance_to_person']:.2f} m)" in out
    assert "learn again with social_squared, social@1.5 or both added to birl.features" in out
    # judging a deployment against new walks holds out every one of them: the check stayed
    # silent there, where it matters most
    judged, out = run_in_process(tmp_path / "judged", *common, "birl.weights=[0,-1]",
                                 "evaluate.holdout=all")
    assert judged["heldout_count"] == 2 and "demos_count" not in judged
    assert judged["demos_min_distance_to_person"] == rude["demos_min_distance_to_person"]
    assert "closer than any demonstration" in out
    # a learner that has the squared hinge already is not told to add it
    squared, out = run_in_process(tmp_path / "squared", *common[:-1],
                                  "birl.features=[social_squared,length]", "birl.weights=[0,-1]")
    assert "closer than any demonstration" in out and \
        "learn again with social@1.5 added to birl.features" in out
    # nor to one that has a hinge near their closest approach (1.49 m) of a hinge there
    near, out = run_in_process(tmp_path / "near", *common[:-1], "birl.features=[social@1.3,length]",
                               "birl.weights=[0,-1]")
    assert "closer than any demonstration" in out and \
        "learn again with social_squared added to birl.features" in out
    polite, out = run_in_process(tmp_path / "polite", *common, "birl.weights=[-1,-0.1]")
    assert polite["ref_min_distance_to_person"] > 1.45
    assert "closer than any demonstration" not in out
    # nor for paths a few centimetres closer than the demonstrations: the same reward keeps
    # its hinge's 2 m, demonstrators who went round at 2.03 m
    wide = [[1.0, 2.0], [1.0, 4.03], [9.0, 4.03], [9.0, 2.0]]
    (tmp_path / "demos.json").write_text(json.dumps({"trajectories": [wide, wide]}))
    close, out = run_in_process(tmp_path / "close", *common, "birl.weights=[-1,-0.1]")
    assert close["demos_min_distance_to_person"] == pytest.approx(2.03, abs=1e-9)
    assert 2.03 - 0.05 < close["ref_min_distance_to_person"] < 2.03
    assert "closer than any demonstration" not in out


def test_a_subject_of_a_folder_of_bags_is_held_out(tmp_path):
    """One bag per subject, the folder given as expert.path: `evaluate.holdout=[bo]` holds
    out bo's bag, which named no subject (before: 'demonstrated nothing (subjects: none)')."""
    folder = tmp_path / "bags"
    folder.mkdir()
    for name, drives in (("ann", CLEAN_DRIVES), ("bo", CLEAN_DRIVES[:1])):
        write_bag(folder / name, {"/odom": ("nav_msgs/msg/Odometry", list(odometry(drives)))})
    m, _ = run_in_process(tmp_path / "run", *FAST, "expert=file", f"expert.path={folder}",
                          "evaluate.holdout=[bo]")
    demos = read_artefact(tmp_path / "run" / "demos.mcap")
    held = codec.heldout_demos(demos)
    assert [d["subject"] for d in held] == ["bo"] and m["heldout_count"] == 1
    assert [d["subject"] for d in codec.training_demos(demos)] == ["ann", "ann"]
    # each demonstration says where it came from, so a held-out walk can be traced back
    assert [d["source"] for d in held] == ["bo: 0"]
    assert [d["source"] for d in codec.training_demos(demos)] == ["ann: 0", "ann: 1"]
