"""Transfer (DESIGN §9): `birl=fixed` and `evaluate.transfer_scenes`, checked against runs
whose answer is known exactly."""

import pytest

from pipeline.app.metric_keys import is_metric_key
from pipeline.artefacts import read_artefact
from pipeline.errors import PipelineError
from pipeline.tools.viewer import build_recording
from tests.conftest import METROPOLIS, POLITE, run_in_process
from tests.pipeline.conftest import FAST

SMALL = ("graph=small",)


def test_fixed_true_weights_have_zero_loss_and_full_artefacts(tmp_path):
    true_on_learner = [*POLITE.tolist(), 0.0]  # the true reward has no crossing weight
    weights = "[" + ",".join(str(x) for x in true_on_learner) + "]"
    m, _ = run_in_process(tmp_path, "birl=fixed", f"birl.weights={weights}", *SMALL)
    assert m["policy_loss_ref"] == 0.0 and m["policy_loss"] == 0.0  # w = w*: the optimal policy
    its = read_artefact(tmp_path / "birl.mcap").all("/birl/iteration")
    assert [it["index"] for it in its] == [0] and its[0]["method"] == "fixed"
    assert its[0]["weights"] == true_on_learner
    solution = read_artefact(tmp_path / "graph.mcap").one("/graph/solution")
    assert solution["weights_source"] == "fixed"  # the graph grows under the given reward
    assert build_recording(tmp_path).stat().st_size > 0  # `make view` works on it


def test_fixed_from_run_reuses_the_final_weights(tmp_path, default_run):
    run_dir, learned, _ = default_run
    m, _ = run_in_process(tmp_path, "birl=fixed", f"birl.from_run={run_dir}", *SMALL)
    names = ("relation", "social", "goal_deviation", "length")
    assert [m[f"weight_{n}"] for n in names] == [learned[f"weight_{n}"] for n in names]
    # Same scene, same reference roadmap, same weights: the same roadmap loss, up to how
    # policy iteration breaks near-ties (the learning run warm-starts each iteration's solve
    # from the previous one; the fixed run solves cold).
    assert m["policy_loss_ref"] == pytest.approx(learned["policy_loss_ref"], rel=0.02)


def test_fixed_from_run_refuses_other_feature_constants(tmp_path, default_run):
    """Weights learned with ρ_p = 1.2 m are another reward at 0.8 m: refused, naming the value
    to set."""
    run_dir, _, _ = default_run
    with pytest.raises(PipelineError, match=r"learned its weights with reward\.rho_personal=1\.2"
                                            r", this run has 0\.8.*set reward\.rho_personal=1\.2"):
        run_in_process(tmp_path, "birl=fixed", f"birl.from_run={run_dir}",
                       "reward.rho_personal=0.8", *SMALL)


@pytest.mark.parametrize("features", [
    (),
    # a learner feature before the reward's (the README's wall set): the transfer roadmap's
    # learner view was built from the wrong columns, an IndexError
    ("birl.features=[relation,social,wall,goal_deviation,length,crossing]",)])
def test_transfer_to_the_same_scene_repeats_the_run_metrics(tmp_path, features):
    m, printed = run_in_process(tmp_path, *SMALL, "birl.n_iterations=3", *features,
                                f"evaluate.transfer_scenes=[{METROPOLIS}]")
    # the one screen shows it, the same numbers as the run's own roadmap line
    ref_line = next(x for x in printed.splitlines() if x.startswith("  roadmap paths"))
    transfer_line = next(x for x in printed.splitlines() if x.startswith("  transfer "))
    assert transfer_line.endswith(ref_line.removeprefix("  roadmap paths    "))
    assert "metropolis (roadmap): normalised loss" in transfer_line
    assert m["transfer_metropolis_policy_loss"] == m["policy_loss_ref"]
    assert all(is_metric_key(k) for k in m)  # every key can be a sweep's objective
    assert m["transfer_metropolis_policy_loss_norm"] == pytest.approx(m["policy_loss_norm"])
    for key in ("relation_crossings", "intimate_intrusion_m", "min_distance_to_person",
                "success"):
        assert m[f"transfer_metropolis_{key}"] == pytest.approx(m[f"ref_{key}"])


@pytest.mark.parametrize("overrides, fragment", [
    (["birl=fixed"], "birl.weights"),
    (["birl=fixed", "birl.weights=[-1,-1,-1,-1]", "birl.from_run=x"], "birl.weights"),
    (["birl=fixed", "birl.weights=[-1,-1]"], "needs 5 numbers"),
    (["birl=fixed", "birl.weights=[-5,-1,-1,-1,-1]"], "outside [birl.lower, birl.upper]"),
    (["birl=fixed", "birl.n_iterations=3", "birl.weights=[-1,-1,-1,-1]"], "birl.n_iterations"),
])
def test_bad_fixed_settings_are_one_line(tmp_path, overrides, fragment):
    with pytest.raises(PipelineError) as err:
        run_in_process(tmp_path, *overrides, *SMALL)
    assert fragment in str(err.value) and "\n" not in str(err.value)


def test_from_run_without_birl_artefact_names_the_file(tmp_path):
    with pytest.raises(PipelineError, match="birl.mcap"):
        run_in_process(tmp_path / "run", "birl=fixed", f"birl.from_run={tmp_path}", *SMALL)


def test_a_missing_transfer_scene_is_one_line(tmp_path):
    with pytest.raises(PipelineError) as err:
        run_in_process(tmp_path, *SMALL, "birl.n_iterations=1",
                       f"evaluate.transfer_scenes=[{tmp_path}/nowhere.json]")
    assert "nowhere.json" in str(err.value) and "\n" not in str(err.value)


def test_a_missing_map_for_a_random_scene_is_one_line(tmp_path):
    with pytest.raises(PipelineError) as err:
        run_in_process(tmp_path, "scene=random", f"scene.map={tmp_path}/nowhere.yaml",
                       "stages=[scene]")
    assert "nowhere.yaml" in str(err.value) and "\n" not in str(err.value)


def test_fixed_deployment_equals_the_transfer_score(tmp_path):
    office = "data/scenes/office.json"
    # learned on metropolis (the default scene), scored on the office map
    learned, _ = run_in_process(tmp_path / "learn", *FAST, f"evaluate.transfer_scenes=[{office}]")
    deployed, _ = run_in_process(tmp_path / "deploy", "scene=office", "graph=small",
                                 "birl=fixed", f"birl.from_run={tmp_path / 'learn'}")
    assert deployed["policy_loss_ref"] == learned["transfer_office_policy_loss"]
    assert deployed["policy_loss_norm"] == learned["transfer_office_policy_loss_norm"]
    assert deployed["ref_success"] == learned["transfer_office_success"]
