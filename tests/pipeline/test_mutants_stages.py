"""What the evaluate and demos stages write, checked against what the artefacts say
independently (eval.mcap's loss rows and paths, graph.mcap's nodes, demos.mcap's
demonstrations), against runs whose answer is known (a contrast reward's normalised loss is
1, a transfer to the run's own scene repeats its roadmap numbers) and against the summary's
own rules for its lines and warnings (a mutation audit of pipeline/stages/evaluate.py and
pipeline/stages/demos.py)."""

import json

import numpy as np
import pytest
import yaml

from pipeline.artefacts import codec, read_artefact, topics
from pipeline.core.evaluation import frechet
from pipeline.core.social import min_distance_to_person
from pipeline.errors import PipelineError
from tests.conftest import METROPOLIS, POLITE, ROOT, RUDE, run_in_process
from tests.pipeline.conftest import FAST

# weights that lose on both graphs (test_run's normalised-loss case), crossing last
LOSING = "birl.weights=[-0.2,-1,-0.1,-0.5,-0.5]"
POLITE_DEMOS = ROOT / "data" / "demos" / "metropolis_polite_smoothed.json"


def _weights(values) -> str:
    return "birl.weights=[" + ",".join(repr(float(v)) for v in values) + "]"


@pytest.fixture(scope="module")
def synth(tmp_path_factory):
    """The optimal polite expert on metropolis, a few iterations."""
    run_dir = tmp_path_factory.mktemp("synth")
    m, out = run_in_process(run_dir, *FAST)
    return run_dir, m, out


@pytest.fixture(scope="module")
def losing(synth, tmp_path_factory):
    """synth's graph and demonstrations, losing weights given, transferred to its own scene."""
    run_dir = tmp_path_factory.mktemp("losing")
    m, out = run_in_process(run_dir, "birl=fixed", LOSING, "graph=small", "stages=[birl,evaluate]",
                            f"from_run={synth[0]}", f"evaluate.transfer_scenes=[{METROPOLIS}]")
    return run_dir, m, out


def check_summary(m: dict, out: str, learned_from: float | None = None) -> None:
    """The summary's lines say the metrics they name, and each warning is there exactly
    when its rule holds (run_summary.summary_text's docstrings)."""
    if "policy_loss" in m:
        assert (f"  policy loss      roadmap {m['policy_loss_ref']:.4f}, normalised "
                f"{m['policy_loss_norm']:.4f}, graph {m['policy_loss']:.4f} (initial "
                f"{m['policy_loss_initial']:.4f})") in out
        worse = (m["policy_loss_ref"] > m["policy_loss_ref_initial"] + 1e-9
                 or m["policy_loss"] > m["policy_loss_initial"] + 1e-9)
        assert ("lose more than the initial ones" in out) == worse
    for label, p in (("  roadmap paths    ", "ref_"), ("  graph paths      ", "")):
        assert (label + f"crossings {m[p + 'relation_crossings']:.0f}, "
                f"intimate {m[p + 'intimate_intrusion_m']:.2f} m, personal "
                f"{m[p + 'personal_intrusion_m']:.2f} m, min distance "
                f"{m[p + 'min_distance_to_person']:.2f} m, success {m[p + 'success']:.2f}"
                ) in out, label
    ruder = (m.get("policy_loss", np.inf) > m.get("policy_loss_ref", -np.inf)
             and (any(m[k] > m["ref_" + k] + 1e-9
                      for k in ("relation_crossings", "intimate_intrusion_m"))
                  or m["min_distance_to_person"] < min(
                      m["ref_min_distance_to_person"],
                      m.get("ref_min_distance_to_person_taut", np.inf)) - 0.05
                  or m["personal_intrusion_m"] > max(m["ref_personal_intrusion_m"] + 1.0,
                                                     1.5 * m["ref_personal_intrusion_m"])))
    assert ("ruder than the roadmap's" in out) == ruder
    closer = ("demos_min_distance_to_person" in m and m["ref_min_distance_to_person"]
              < m["demos_min_distance_to_person"] - 0.05) or learned_from is not None and \
        "demos_min_distance_to_person" not in m and \
        m["ref_min_distance_to_person"] < learned_from - 0.05
    # the roadmap's paths are offered for deployment only when they are not ruder than
    # every demonstrator
    assert ("are the better ones, but see the next line" in out) == (ruder and closer)
    assert ("; deploy the roadmap's paths" in out) == (ruder and not closer)
    assert ("stop short of the goal" in out) == (m["success"] < 1 or m["ref_success"] < 1)
    share = m["graph_demo_node_share"]
    assert ("demonstration waypoints: these say little" in out) == (share > 0.5)
    assert ("do not reach the goal" in out) == (m.get("demos_unreached", 0) > 0)
    assert ("the learned roadmap paths pass" in out and "closer than any demonstration" in out
            or "the weights were learned from kept" in out) == closer
    same = "heldout_count" in m and all(
        abs(m[k] - m[k + "_shortest"]) <= 0.05 + 1e-9
        for k in ("heldout_frechet_m", "heldout_min_distance_error_m") if k in m)
    assert ("as far from the held-out demonstrations as the shortest paths" in out) == same
    for k, said in (("heldout_frechet_m", "predicts them worse than no reward does"),
                    ("heldout_min_distance_error_m", "pass people worse than no reward does")):
        assert (said in out) == (k in m and m[k] - m[k + "_shortest"] > 0.05 + 1e-9), k
    def turned(k: str) -> bool:
        raw, taut = m[k] - m[k + "_shortest"], m[k + "_taut"] - m[k + "_shortest_taut"]
        raw = 0.0 if abs(raw) <= 0.05 + 1e-9 else raw  # a tie on the lattice turns nothing
        return raw < 0 <= taut or raw > 0 >= taut
    flipped = any(k + "_taut" in m and turned(k)
                  for k in ("heldout_frechet_m", "heldout_min_distance_error_m"))
    assert ("the difference above is the lattice's doing" in out) == flipped
    kept = m.get("ref_min_distance_to_person_taut", np.inf) < \
        m["ref_min_distance_to_person"] - 0.05
    assert ("their distance from people is the lattice's doing" in out) == kept
    demos = m.get("demos_min_distance_to_person", learned_from)
    taut_ruder = kept and demos is not None and \
        m["ref_min_distance_to_person_taut"] < demos - 0.05 <= m["ref_min_distance_to_person"]
    assert ("the learned reward's, closer than any demonstration" in out) == taut_ruder
    if "frechet_to_demos" in m:
        assert f"discrete Fréchet mean {m['frechet_to_demos']:.3f} m" in out
    else:
        assert "vs demos" not in out


def test_the_losses_are_eval_mcaps_rows(synth):
    run_dir, m, out = synth
    rows = read_artefact(run_dir / "eval.mcap").all(topics.EVAL_POLICY_LOSS)
    assert [r["iteration"] for r in rows] == [0, 1, 2, 3]
    assert m["policy_loss"] == rows[-1]["graph"] and m["policy_loss_ref"] == rows[-1]["ref"]
    assert m["policy_loss_initial"] == rows[0]["graph"]
    assert m["policy_loss_ref_initial"] == rows[0]["ref"]
    for k, r in enumerate(rows):
        assert m[f"policy_loss_iter_{k:02d}"] == r["graph"]
        assert m[f"policy_loss_ref_iter_{k:02d}"] == r["ref"]
        assert r["norm"] == pytest.approx(r["ref"] / m["policy_loss_ref_rude"], rel=1e-12)
    # the final weights are the last iteration's
    its = read_artefact(run_dir / "birl.mcap").all(topics.BIRL_ITERATION)
    names = ["relation", "social", "goal_deviation", "length", "crossing"]
    assert [m[f"weight_{n}"] for n in names] == its[-1]["weights"]
    check_summary(m, out)


def test_the_contrast_rewards_normalised_loss_is_one(synth, tmp_path):
    """The rude preset given on a polite expert's run loses what policy_loss_ref_rude says,
    so its normalised loss is 1; and on a rude expert's run, the polite preset's is."""
    run_dir, m, _ = synth
    rude, out = run_in_process(tmp_path / "rude", "birl=fixed", _weights([*RUDE, 0.0]),
                               "graph=small", "stages=[birl,evaluate]", f"from_run={run_dir}")
    assert rude["policy_loss_ref"] > 0
    assert rude["policy_loss_ref"] == pytest.approx(m["policy_loss_ref_rude"], rel=1e-12)
    assert rude["policy_loss_norm"] == pytest.approx(1.0, rel=1e-12)
    check_summary(rude, out)  # one iteration: final = initial, no warning of it
    polite, out = run_in_process(tmp_path / "polite", "reward=rude", "graph=small",
                                 "birl=fixed", _weights([*POLITE, 0.0]))
    assert "policy_loss_ref_rude" not in polite and polite["policy_loss_ref_polite"] > 0
    assert polite["policy_loss_norm"] == pytest.approx(1.0, rel=1e-12)
    check_summary(polite, out)


def test_a_transfer_to_the_runs_own_scene_repeats_its_roadmap_numbers(losing):
    """Same scene, same roadmap, same weights: every transfer_* metric is the run's own
    (with weights that lose, so the normalised loss is no 0 = 0)."""
    _, m, out = losing
    assert m["policy_loss_ref"] > 0.05
    assert m["transfer_metropolis_policy_loss"] == m["policy_loss_ref"]
    assert m["transfer_metropolis_policy_loss_norm"] == pytest.approx(m["policy_loss_norm"],
                                                                      rel=1e-12)
    for key in ("relation_crossings", "intimate_intrusion_m", "personal_intrusion_m",
                "min_distance_to_person", "path_length", "success"):
        assert m[f"transfer_metropolis_{key}"] == pytest.approx(m[f"ref_{key}"], rel=1e-12)
    assert "transfer_metropolis_time_to_goal" not in m  # DESIGN §9: not a transfer metric
    check_summary(m, out)


def test_path_metrics_are_those_of_eval_mcaps_paths(synth):
    """The learned paths in eval.mcap: one per start of each graph, from that start; each
    one's time to the goal its length over the speed (straight edges, 1 m/s); the run's
    numbers their mean (time, length) or sum (crossings)."""
    run_dir, m, _ = synth
    scene = codec.decode_scene(read_artefact(run_dir / "scene.mcap"))
    paths = read_artefact(run_dir / "eval.mcap").all(topics.EVAL_PATHS)
    for where, prefix in (("graph", ""), ("ref", "ref_")):
        mine = [p for p in paths if p["graph"] == where]
        assert [p["start"] for p in mine] == list(range(len(scene.starts)))
        for p in mine:
            pts = np.asarray(p["points"], float)
            assert np.linalg.norm(pts[0] - scene.starts[p["start"]]) < 0.5
            length = np.linalg.norm(np.diff(pts, axis=0), axis=1).sum()
            assert len(pts) > 2 and p["time_to_goal"] == pytest.approx(length, rel=1e-9)
            assert p["path_length"] == pytest.approx(length, rel=1e-9)
        assert m[prefix + "time_to_goal"] == pytest.approx(
            np.mean([p["time_to_goal"] for p in mine]), rel=1e-12)
        assert m[prefix + "relation_crossings"] == sum(p["relation_crossings"] for p in mine)
        assert m[prefix + "success"] == 1.0


def test_the_demo_node_share_is_graph_mcaps(synth, subjects_run):
    for run_dir, m, _ in (synth, subjects_run):
        kinds = codec.decode_nodes(read_artefact(run_dir / "graph.mcap")).kind
        assert m["graph_demo_node_share"] == pytest.approx(
            np.count_nonzero(kinds == "demo") / len(kinds), rel=1e-12)
    assert subjects_run[1]["graph_demo_node_share"] > 0


def test_a_synthetic_expert_reports_no_similarity_to_demonstrations(synth):
    m = synth[1]
    assert not {"frechet_to_demos", "frechet_to_demos_max", "demos_count",
                "demos_unreached"} & set(m)


def test_demonstration_metrics_count_only_what_learning_saw(subjects_run):
    """demos_* and frechet_to_demos: over the training demonstrations (held-out ones never
    enter learning), against the learned graph path from each one's start; the smallest
    distance to a person over every demonstration (docs/inputs.md)."""
    run_dir, m, out = subjects_run
    demos = read_artefact(run_dir / "demos.mcap").all(topics.DEMOS)
    kept = [d for d in demos if not d["heldout"]]
    assert 0 < len(kept) < len(demos)
    assert m["demos_count"] == len(kept)
    assert m["demos_unreached"] == sum(not d["reached"] for d in kept)
    scene = codec.decode_scene(read_artefact(run_dir / "scene.mcap"))
    learned = {p["start"]: np.asarray(p["points"], float)
               for p in read_artefact(run_dir / "eval.mcap").all(topics.EVAL_PATHS)
               if p["graph"] == "graph"}
    dists = [frechet(learned[d["start_index"]], np.asarray(d["points"], float)) for d in kept]
    assert np.ptp(dists) > 0.01  # mean, median and largest differ
    assert m["frechet_to_demos"] == pytest.approx(np.mean(dists), rel=1e-12)
    assert m["frechet_to_demos_max"] == pytest.approx(np.max(dists), rel=1e-12)
    assert m["demos_min_distance_to_person"] == pytest.approx(min(
        min_distance_to_person(np.asarray(d["points"], float), scene.person_xy)
        for d in demos), rel=1e-12)
    check_summary(m, out)


def test_the_held_out_lines_say_the_held_out_metrics(subjects_run):
    _, m, out = subjects_run
    # in the column of the other lines' values, whatever the count's digits
    assert ("  " + f"held out ({m['heldout_count']:.0f})".ljust(17)
            + f"Fréchet {m['heldout_frechet_m']:.2f} m "
            f"(shortest path {m['heldout_frechet_m_shortest']:.2f} m), min-distance error "
            f"{m['heldout_min_distance_error_m']:.2f} m (shortest "
            f"{m['heldout_min_distance_error_m_shortest']:.2f} m)") in out
    assert (f"worst held-out Fréchet {m['heldout_frechet_m_max']:.2f} m (shortest path "
            f"{m['heldout_frechet_m_shortest_max']:.2f} m)") in out
    assert (f"log likelihood per demonstration {m['heldout_log_likelihood']:.2f} "
            f"(shortest path's reward {m['heldout_log_likelihood_shortest']:.2f})") in out
    # the shortest-path baselines differ from the learned ones (else no baseline)
    assert m["heldout_frechet_m_shortest_max"] != m["heldout_frechet_m_shortest"]
    assert m["heldout_min_distance_error_m_shortest"] > 0


def test_a_weight_that_rounds_to_zero_is_shown_without_a_sign(synth, tmp_path):
    _, out = run_in_process(tmp_path, "birl=fixed", _weights([*POLITE, -1e-4]),
                            "graph=small", "stages=[birl,evaluate]", f"from_run={synth[0]}")
    assert "crossing 0.000" in out and "-0.000" not in out


def test_the_demonstrations_artefact_describes_its_expert(subjects_run, tmp_path):
    """demos.mcap of an expert without a true reward carries none; every demonstration's
    duration is its length at the run's speed; the MDP and features are the run's."""
    run_dir = subjects_run[0]
    art = read_artefact(run_dir / "demos.mcap")
    cfg = yaml.safe_load(art.config_yaml)
    expert = art.one(topics.DEMOS_EXPERT)
    assert expert["true_weights"] is None and expert["reward"] is None
    assert expert["feature_names"] == list(cfg["reward"]["features"])
    assert (expert["gamma"], expert["time_cost"], expert["speed"]) == (
        cfg["mdp"]["gamma"], cfg["mdp"]["time_cost"], cfg["mdp"]["speed"])
    assert art.one(topics.DEMOS_ROADMAP)["true_values"] is None
    scene = codec.decode_scene(read_artefact(run_dir / "scene.mcap"))
    for d in art.all(topics.DEMOS):
        pts = np.asarray(d["points"], float)
        assert d["value_true"] is None
        assert d["duration"] == pytest.approx(
            np.linalg.norm(np.diff(pts, axis=0), axis=1).sum() / cfg["mdp"]["speed"], rel=1e-9)
        # its start index names the scene start it begins at
        assert np.argmin(np.linalg.norm(scene.starts - pts[0], axis=1)) == d["start_index"]
    # a Boltzmann expert's β, the paper's discounting: γ^T of each demonstration
    run_in_process(tmp_path, "expert=boltzmann", "expert.beta=7", "mdp=paper",
                   "stages=[scene,demos]")
    art = read_artefact(tmp_path / "demos.mcap")
    assert art.one(topics.DEMOS_EXPERT)["beta"] == 7
    for d in art.all(topics.DEMOS):
        assert d["end_discount"] == pytest.approx(0.95 ** d["duration"], rel=1e-9)


def test_n_starts_keeps_the_first_starts_demonstrations(tmp_path):
    run_in_process(tmp_path, "expert.n_starts=2", "stages=[scene,demos]")
    demos = read_artefact(tmp_path / "demos.mcap").all(topics.DEMOS)
    assert sorted(d["start_index"] for d in demos) == [0, 1]


def test_the_closest_demonstration_counts_even_when_held_out(tmp_path):
    """demos_min_distance_to_person: the smallest distance from any demonstration to a
    person (docs/inputs.md), held-out ones too. Subject a keeps 1.49 m from the person at
    (5, 2), subject b (held out) passes (5, 3): 1 m exactly."""
    scene = {"name": "round", "room": {"x_min": 0, "y_min": 0, "x_max": 10, "y_max": 6},
             "persons": [{"id": 1, "x": 5.0, "y": 2.0, "theta": 1.57}], "relations": [],
             "starts": [[1.0, 2.0]], "goal": [9.0, 2.0]}
    far = [[1.0, 2.0], [3.0, 3.3], [5.0, 3.5], [7.0, 3.3], [9.0, 2.0]]
    near = [[1.0, 2.0], [3.0, 3.0], [5.0, 3.0], [7.0, 3.0], [9.0, 2.0]]
    (tmp_path / "scene.json").write_text(json.dumps(scene))
    (tmp_path / "demos.json").write_text(json.dumps({"trajectories": [far, near],
                                                     "subjects": ["a", "b"]}))
    m, out = run_in_process(tmp_path / "run", "graph=small", "scene=file",
                            f"scene.path={tmp_path / 'scene.json'}", "expert=file",
                            f"expert.path={tmp_path / 'demos.json'}", "evaluate.holdout=[b]",
                            "birl=fixed", "birl.features=[social@2.0,length]",
                            "birl.weights=[-1,-1]")
    assert m["demos_count"] == 1 and m["heldout_count"] == 1
    assert m["demos_min_distance_to_person"] == pytest.approx(1.0, abs=1e-9)
    check_summary(m, out)


# -- the second round of the audit: the held-out likelihood's β, the ruder warning's edges,
# eval.mcap's metrics, the summary's naming of short roadmap paths and of two short chains

# A hall with one person beside the way from the start to the goal: the learned reward is
# length alone (w = -1), so the straight walk is better than the detour under every reward
# the held-out likelihood weighs (w, and w = 0: the cost per second alone).
HALL = {"name": "hall", "room": {"x_min": 0, "y_min": 0, "x_max": 8, "y_max": 4},
        "persons": [{"id": 1, "x": 4.0, "y": 0.6, "theta": 1.57}], "relations": [],
        "starts": [[1.0, 2.0]], "goal": [7.0, 2.0]}
STRAIGHT = [[1.0, 2.0], [3.0, 2.3], [5.0, 2.3], [7.0, 2.0]]
DETOUR = [[1.0, 2.0], [2.0, 3.3], [4.0, 3.5], [6.0, 3.3], [7.0, 2.0]]


def _hall_run(root, name: str, trajectories: list, subjects: list, held: str):
    (root / "scene.json").write_text(json.dumps(HALL))
    demos = root / f"{name}.json"
    demos.write_text(json.dumps({"trajectories": trajectories, "subjects": subjects}))
    run_dir = root / name
    m, out = run_in_process(run_dir, "graph=small", "graph.max_nodes=40", "scene=file",
                            f"scene.path={root / 'scene.json'}", "expert=file",
                            f"expert.path={demos}", f"evaluate.holdout=[{held}]",
                            "birl=fixed", "birl.features=[length]", "birl.weights=[-1]")
    return run_dir, m, out


@pytest.fixture(scope="module")
def hall(tmp_path_factory):
    """Three runs of the hall, one demonstration learned from and one held out: the detour
    learned from and the straight walk held out; the detour learned from and held out (a
    copy); the straight walk learned from and the detour held out."""
    root = tmp_path_factory.mktemp("hall")
    return {"straight_held": _hall_run(root, "straight_held", [DETOUR, STRAIGHT], ["a", "b"], "b"),
            "copy_held": _hall_run(root, "copy_held", [DETOUR, DETOUR], ["a", "c"], "c"),
            "detour_held": _hall_run(root, "detour_held", [DETOUR, STRAIGHT], ["a", "b"], "a")}


@pytest.mark.parametrize("key", ["heldout_log_likelihood", "heldout_log_likelihood_shortest"])
def test_the_held_out_likelihood_is_at_the_beta_fitted_to_the_training_demonstrations(hall,
                                                                                      key):
    """DESIGN §9: the mean log likelihood of the held-out demonstrations at the β that makes
    the training ones most likely. Per demonstration the Boltzmann model's log dP/dμ is
    β·R(ξ) − V_β(start) (pipeline.irl.robust), so from one start, at every β, a walk of higher
    reward is the likelier by β·ΔR: the straight walk held out is likelier than a copy of the
    detour learned from, at the detour's β. And the detour's own β is its best: the straight
    walk's (larger, its reward being higher) explains the detour worse, strictly (the log
    likelihood is concave in β, the detour's best β inside [0.1, 1000])."""
    straight_on_detour = hall["straight_held"][1][key]  # held out: straight; β: the detour's
    detour_on_detour = hall["copy_held"][1][key]        # held out: the detour's copy
    detour_on_straight = hall["detour_held"][1][key]    # held out: the detour; β: straight's
    assert straight_on_detour > detour_on_detour
    assert detour_on_detour > detour_on_straight + 1e-6  # by more than the fit's round-off
    for _, m, out in hall.values():
        assert m["heldout_count"] == m["demos_count"] == 1
        check_summary(m, out)


def test_eval_mcaps_metrics_are_metrics_json_but_the_wall_clock_times(synth):
    """eval.mcap's /eval/metrics: every metric of metrics.json but the stages' wall-clock
    times (time_<what>_s: the same seed makes the same bytes); the mean time to the goal of
    the learned paths is a metric, not a wall-clock time."""
    run_dir, m, _ = synth
    stored = read_artefact(run_dir / "eval.mcap").one(topics.EVAL_METRICS)
    clock = {k for k in m if k.startswith("time_") and k.endswith("_s")}
    assert {"time_evaluate_s", "time_graph_s"} <= clock and "time_to_goal" in m
    assert stored == {k: v for k, v in m.items() if k not in clock}


def test_a_graph_that_loses_what_the_roadmap_loses_gets_no_ruder_warning(tmp_path):
    """The true (rude) weights given: the learned paths are the optimal ones on both graphs,
    policy loss 0 on each, so the graph's paths lose nothing more than the roadmap's however
    they differ (here: further into intimate zones), and no warning says they are ruder."""
    m, out = run_in_process(tmp_path, "reward=rude", "graph=small", "birl=fixed",
                            _weights([*RUDE, 0.0]))
    assert m["policy_loss"] == m["policy_loss_ref"] == 0.0
    assert (m["relation_crossings"] > m["ref_relation_crossings"]  # the case: they differ
            or m["intimate_intrusion_m"] > m["ref_intimate_intrusion_m"] + 1e-9)
    assert "ruder than the roadmap's" not in out
    check_summary(m, out)


def test_a_graph_whose_paths_only_go_much_further_into_personal_zones_is_ruder(tmp_path):
    """No true reward (expert=none): the small graph of metropolis' seed 0 crosses no link,
    enters no intimate zone and passes people as closely as the roadmap's paths (within
    5 cm), but its paths go about twice as far into personal zones: they are ruder, and the
    deployment is told to take the roadmap's paths (a walker's scene, 3.22 m against
    0.90 m, was not)."""
    m, out = run_in_process(tmp_path, "graph=small", "expert=none", "seed=0", "birl=fixed",
                            _weights([*POLITE, -0.5]))
    assert m["relation_crossings"] == m["ref_relation_crossings"]  # the case
    assert m["intimate_intrusion_m"] == m["ref_intimate_intrusion_m"]
    assert m["min_distance_to_person"] >= m["ref_min_distance_to_person"] - 0.05
    assert m["personal_intrusion_m"] > 1.5 * m["ref_personal_intrusion_m"] + 1.0
    warning = [x for x in out.splitlines() if "ruder than the roadmap's" in x]
    assert len(warning) == 1
    assert (f"(personal {m['personal_intrusion_m']:.2f} m against "
            f"{m['ref_personal_intrusion_m']:.2f} m): " in warning[0])
    assert "deploy the roadmap's paths" in warning[0]
    check_summary(m, out)


def test_a_graph_whose_paths_only_go_further_into_intimate_zones_is_ruder(tmp_path):
    """No social link to cross (metropolis without its relations) and no true reward (no
    demonstrations, expert=none): the graph's paths are ruder when they intrude further into
    intimate zones alone. Without its medial-axis nodes the small graph of seed 0 lacks the
    roadmap's detour round a person."""
    data = json.loads(METROPOLIS.read_text())
    data.update(name="unlinked", relations=[])
    (tmp_path / "scene.json").write_text(json.dumps(data))
    m, out = run_in_process(tmp_path / "run", "graph=small", "scene=file",
                            f"scene.path={tmp_path / 'scene.json'}", "expert=none",
                            "graph.medial_axis=false", "seed=0", "birl=fixed",
                            _weights([*POLITE, -0.5]))
    assert m["relation_crossings"] == m["ref_relation_crossings"] == 0  # no link to cross
    assert m["intimate_intrusion_m"] > m["ref_intimate_intrusion_m"]  # the case
    # and they pass a person closer, by more than the 5 cm a path follows a distance to
    assert m["min_distance_to_person"] < m["ref_min_distance_to_person"] - 0.05
    warning = [x for x in out.splitlines() if "ruder than the roadmap's" in x]
    assert len(warning) == 1
    assert (f"(intimate {m['intimate_intrusion_m']:.2f} m against "
            f"{m['ref_intimate_intrusion_m']:.2f} m, min distance "
            f"{m['min_distance_to_person']:.2f} m against "
            f"{m['ref_min_distance_to_person']:.2f} m, personal "
            f"{m['personal_intrusion_m']:.2f} m against "
            f"{m['ref_personal_intrusion_m']:.2f} m)") in warning[0]
    check_summary(m, out)


def test_roadmap_paths_that_stop_short_are_named_in_the_warning(tmp_path):
    """mdp=paper (discounted, R_goal 1) and a reward that pays for being near a person: the
    learned paths stay by the person rather than arrive, on the roadmap too, and the
    warning names the roadmap's success beside the graph's."""
    (tmp_path / "scene.json").write_text(json.dumps(HALL))
    m, out = run_in_process(tmp_path / "run", "graph=small", "graph.max_nodes=40", "scene=file",
                            f"scene.path={tmp_path / 'scene.json'}", "mdp=paper", "expert=none",
                            "birl=fixed", "birl.features=[social@2.0]", "birl.weights=[0.5]",
                            "birl.upper=[1]")
    assert m["ref_success"] < 1  # the case
    short = [f"roadmap {m['ref_success']:.2f}"] + (
        [f"graph {m['success']:.2f}"] if m["success"] < 1 else [])
    assert f"learned paths stop short of the goal (success {', '.join(short)})" in out
    check_summary(m, out)


def test_two_chains_too_short_for_r_hat_are_not_called_one_chain(tmp_path):
    """Two chains (the fewest R-hat compares) of three samples each have no R-hat: too few
    samples per chain, not one chain."""
    m, out = run_in_process(tmp_path, "birl=mcmc", "birl.n_chains=2", "birl.n_samples=3",
                            "birl.max_samples=3", "birl.n_iterations=2", "graph=small",
                            "graph.max_nodes=70")
    assert "mcmc_rhat_max" not in m and m["mcmc_chains"] == 2
    assert "too few samples per chain" in out and "one chain" not in out


def _hall_demos(tmp_path, trajectories: list, subjects: list, *overrides: str):
    """The scene and demos stages alone on the hall with two starts (1, 2) and (1, 3)."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    (tmp_path / "scene.json").write_text(json.dumps({**HALL, "starts": [[1.0, 2.0], [1.0, 3.0]]}))
    (tmp_path / "demos.json").write_text(json.dumps({"trajectories": trajectories,
                                                     "subjects": subjects}))
    return run_in_process(tmp_path / "run", "scene=file", f"scene.path={tmp_path / 'scene.json'}",
                          "expert=file", f"expert.path={tmp_path / 'demos.json'}",
                          "stages=[scene,demos]", *overrides)


def test_n_starts_that_keeps_no_demonstration_is_refused(tmp_path):
    """Every demonstration begins at start 1: expert.n_starts=1 keeps none of them."""
    from_second = [[1.0, 3.0], [4.0, 3.2], [7.0, 2.0]]
    with pytest.raises(PipelineError, match=r"expert\.n_starts=1 leaves no demonstration"):
        _hall_demos(tmp_path, [from_second, from_second], ["a", "b"], "expert.n_starts=1")


def test_holding_out_every_subject_is_refused_but_holdout_all_is_not(tmp_path):
    """evaluate.holdout naming every subject leaves nothing to learn from: refused. "all"
    says so on purpose (a given reward judged on demonstrations it never saw, birl=fixed):
    every demonstration held out."""
    with pytest.raises(PipelineError, match=r"holds out every demonstration; keep some"):
        _hall_demos(tmp_path / "named", [DETOUR, STRAIGHT], ["a", "b"], "evaluate.holdout=[a,b]")
    _hall_demos(tmp_path / "all", [DETOUR, STRAIGHT], ["a", "b"], "evaluate.holdout=all",
                "birl=fixed", "birl.features=[length]", "birl.weights=[-1]")
    demos = read_artefact(tmp_path / "all" / "run" / "demos.mcap").all(topics.DEMOS)
    assert [d["heldout"] for d in demos] == [True, True]


def test_roadmap_paths_ruder_than_every_demonstrator_are_not_offered_for_deployment(tmp_path):
    """Weights that pass people closely, judged against the polite demonstrations
    (evaluate.holdout=all) on a small graph without its medial-axis nodes: the graph's
    paths are ruder than the roadmap's, and the roadmap's are ruder than every
    demonstrator. The first warning no longer tells the user to deploy the roadmap's
    paths that the second one says are too rude."""
    m, out = run_in_process(tmp_path, "expert=file", f"expert.path={POLITE_DEMOS}",
                            "evaluate.holdout=all", "birl=fixed", "graph=small",
                            "graph.medial_axis=false", "seed=0", _weights([0, -0.1, 0, -1, 0]))
    lines = out.splitlines()
    first = next(k for k, x in enumerate(lines) if "ruder than the roadmap's" in x)
    assert "closer than any demonstration" in lines[first + 1]  # the case, and its order
    assert "/birlg/learned_paths_ref) are the better ones, but see the next line" in lines[first]
    assert "deploy the roadmap's paths" not in out
    check_summary(m, out)


def test_expert_select_walks_reaches_the_reader_through_the_config(tmp_path):
    """The demos stage gives expert.select_walks to the reader: of a walk, a track that came
    into view mid-room and one bound elsewhere, the walk alone is learned from; without it
    the file is refused, naming the option."""
    late, elsewhere = [[3.0, 3.0], [5.0, 2.5], [7.0, 2.0]], [[1.0, 2.0], [1.0, 3.5], [3.0, 3.7]]
    with pytest.raises(PipelineError, match=r"expert\.select_walks=true"):
        _hall_demos(tmp_path / "strict", [DETOUR, late, elsewhere], ["a", "b", "c"])
    _hall_demos(tmp_path / "select", [DETOUR, late, elsewhere], ["a", "b", "c"],
                "expert.select_walks=true")
    demos = read_artefact(tmp_path / "select" / "run" / "demos.mcap").all(topics.DEMOS)
    assert [d["subject"] for d in demos] == ["a"]
    np.testing.assert_allclose(demos[0]["points"][:-1], DETOUR[:-1])


def test_a_deployment_ruder_than_the_demonstrators_it_was_learned_from_is_said(tmp_path):
    """Demonstrators who kept 2.5 m from the one person in a hall, a learner whose hinge
    (1.2 m) cannot say more: its roadmap paths pass 1.2 m from the person. Deployed without
    demonstrations (expert=none), the summary still says the reward is ruder than the
    demonstrators it was learned from (the learning run's metrics.json)."""
    hall = {**HALL, "room": {"x_min": 0, "y_min": 0, "x_max": 8, "y_max": 6},
            "persons": [{"id": 1, "x": 4.0, "y": 2.0, "theta": 1.57}]}
    (tmp_path / "hall.json").write_text(json.dumps(hall))
    wide = [[[1.0, 2.0], [2.0, 4.2], [4.0, 4.6], [6.0, 4.2], [7.0, 2.0]],
            [[1.0, 2.0], [2.2, 4.3], [4.0, 4.7], [6.1, 4.1], [7.0, 2.0]]]
    (tmp_path / "wide.json").write_text(json.dumps({"trajectories": wide}))
    scene = ("scene=file", f"scene.path={tmp_path / 'hall.json'}", "graph=small")
    learned, _ = run_in_process(tmp_path / "learn", *scene, "expert=file",
                                f"expert.path={tmp_path / 'wide.json'}")
    assert learned["ref_min_distance_to_person"] < \
        learned["demos_min_distance_to_person"] - 0.05  # the case
    m, out = run_in_process(tmp_path / "deploy", *scene, "expert=none", "birl=fixed",
                            f"birl.from_run={tmp_path / 'learn'}")
    assert (f"the roadmap paths pass {m['ref_min_distance_to_person']:.2f} m from a person; "
            "the demonstrations the weights were learned from kept "
            f"{learned['demos_min_distance_to_person']:.2f} m or more") in out
    assert "learn again with social_squared" in out  # and what to do about it
    check_summary(m, out, learned["demos_min_distance_to_person"])
    # judged against new walks, the run's own demonstrations say it (closer_than_demos)
    m, out = run_in_process(tmp_path / "judged", *scene, "expert=file",
                            f"expert.path={tmp_path / 'wide.json'}", "evaluate.holdout=all",
                            "birl=fixed", f"birl.from_run={tmp_path / 'learn'}")
    assert "closer than any demonstration" in out
    assert "the weights were learned from kept" not in out


def test_roadmap_paths_kept_from_people_by_the_lattice_alone_are_said(tmp_path):
    """Weights on length alone, a person 0.75 m off the straight line from start 1 to the
    goal: the lattice's shortest staircase happens to pass it at 1.4 m; pulled taut, as a
    planner off the lattice would drive, the path passes at about 0.72 m. The summary says
    that the distance is the lattice's, not the reward's."""
    hall = {"name": "hall", "room": {"x_min": 0, "y_min": 0, "x_max": 10, "y_max": 9},
            "persons": [{"id": 1, "x": 3.0, "y": 5.6, "theta": 0.0}], "relations": [],
            "starts": [[1.0, 1.0], [1.0, 7.0]], "goal": [9.0, 4.5]}
    (tmp_path / "hall.json").write_text(json.dumps(hall))
    m, out = run_in_process(tmp_path / "run", "scene=file", f"scene.path={tmp_path / 'hall.json'}",
                            "expert=none", "graph=small", "birl=fixed",
                            _weights([0, 0, 0, -1, 0]))
    straight = np.array([[1.0, 7.0], [8.7, 4.6]])  # about the taut path from start 1
    assert m["ref_min_distance_to_person_taut"] == pytest.approx(
        min_distance_to_person(straight, np.array([[3.0, 5.6]])), abs=0.05)
    assert m["ref_min_distance_to_person"] > m["ref_min_distance_to_person_taut"] + 0.5
    assert (f"the roadmap paths pass {m['ref_min_distance_to_person_taut']:.2f} m from a "
            f"person, not {m['ref_min_distance_to_person']:.2f} m") in out
    check_summary(m, out)
    # judged on walks that keep about 1.1 m from the person: the lattice paths (1.4 m) look
    # polite, the taut ones (0.7 m) are closer than any of them, which the line says
    walks = {"trajectories": [[[1.0, 1.0], [9.0, 4.5]], [[1.0, 7.0], [3.0, 6.8], [9.0, 4.5]]]}
    (tmp_path / "walks.json").write_text(json.dumps(walks))
    m, out = run_in_process(tmp_path / "judged", "scene=file",
                            f"scene.path={tmp_path / 'hall.json'}", "expert=file",
                            f"expert.path={tmp_path / 'walks.json'}", "evaluate.holdout=all",
                            "graph=small", "birl=fixed", _weights([0, 0, 0, -1, 0]))
    assert m["ref_min_distance_to_person_taut"] < m["demos_min_distance_to_person"] - 0.05 \
        <= m["ref_min_distance_to_person"]  # the case
    assert (f"not the learned reward's, closer than any demonstration "
            f"({m['demos_min_distance_to_person']:.2f} m); learn again with") in out
    check_summary(m, out)
