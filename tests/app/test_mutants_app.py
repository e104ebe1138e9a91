"""What a mutation audit of pipeline/app (config, preflight, limits, summary, outcome, build,
context) found untested: each test pins one behaviour a changed comparison, a dropped check or
a wrong constant there would alter (a refusal and its one line, an estimate, a row of the
sweep table, a derived value)."""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf

from pipeline.app import build, limits, preflight, rundir
from pipeline.app.config import (
    check_boolean_overrides,
    config_error,
    learned_feature_names,
    load_settings,
    one_job_of_a_sweep,
)
from pipeline.app.context import (
    PACKAGE_ROOT,
    RunContext,
    input_path_exists,
    resolve_path,
    stage_rng,
)
from pipeline.app.outcome import (
    SweepOutcome,
    SweepRefused,
    _sweeps,
    check_subdir_template,
    failed_jobs,
)
from pipeline.app.provenance import files_digest
from pipeline.app.summary import Unreadable, job_row, parse_overrides, read_metrics, summary_rows
from pipeline.artefacts import topics
from pipeline.artefacts.store import ArtefactWriter, write_artefact
from pipeline.artefacts.topics import STAGES
from pipeline.core.adaptive_graph import GraphParams
from pipeline.core.roadmap import RoadmapParams
from pipeline.errors import PipelineError
from tests.conftest import (
    METROPOLIS,
    OFFICE_SCENE,
    ROOT,
    compose_config,
    one_line,
    run_in_process,
    walled_metropolis,
    write_json,
)

FIVE = "[-1,-1,-1,-1,-1]"  # weights on the default learner's five features


def settings(*overrides: str):
    return load_settings(compose_config(*overrides))


def refused(*overrides: str) -> str:
    with pytest.raises(PipelineError) as err:
        settings(*overrides)
    return one_line(err)


# -- config: refusals and their one line -------------------------------------------------------

def test_a_random_rooms_size_is_free_without_a_map_and_refused_with_one():
    assert (settings("scene=random", "scene.width=30", "scene.height=20").scene.width) == 30
    assert refused("scene=random", "scene.map=data/maps/office.yaml", "scene.width=30") \
        .startswith("config error: scene.width=30.0 is not allowed (allowed: unset (10) with "
                    "scene.map")


def test_a_true_weight_that_is_no_finite_number_is_refused():
    assert refused("reward.weights=[-1,nan,-1,-1]").startswith("config error: reward.weights=")


def test_an_expert_without_demonstrations_takes_no_n_starts():
    assert refused("expert=none", "birl=fixed", f"birl.weights={FIVE}", "expert.n_starts=2") \
        == ("config error: expert.n_starts=2 is not allowed (allowed: null with expert=none "
            "(there are no demonstrations to select))")


def test_only_the_synthetic_experts_know_the_true_reward():
    knows = {kind: settings(f"expert={kind}", *extra).expert.knows_true_reward
             for kind, extra in (("optimal", ()), ("boltzmann", ()), ("planner", ()),
                                 ("file", ("expert.path=x.json",)),
                                 ("none", ("birl=fixed", f"birl.weights={FIVE}")))}
    assert knows == {"optimal": True, "boltzmann": True, "planner": False, "file": False,
                     "none": False}


def test_a_derived_graph_size_stays_null_in_the_settings():
    """graph.max_nodes=null is checked as the paper's 460 but left null: start-up derives it
    from the scene."""
    assert settings().graph.max_nodes is None
    assert settings("graph.max_nodes=600").graph.max_nodes == 600


@pytest.mark.parametrize("holdout", ["0", "1", "[]"])
def test_a_holdout_fraction_lies_strictly_between_0_and_1(holdout):
    assert refused(f"evaluate.holdout={holdout}").startswith(
        "config error: evaluate.holdout=")
    assert settings("evaluate.holdout=0.5").evaluate.holdout == 0.5


def test_a_blank_transfer_scene_path_is_refused():
    assert refused("evaluate.transfer_scenes=[' ']").startswith(
        "config error: evaluate.transfer_scenes=")


def test_a_reward_that_has_crossing_already_is_not_given_it_twice():
    cfg = settings("reward.features=[relation,social,crossing,length]",
                   "reward.weights=[-1,-1,-1,-1]")
    assert cfg.learner_features == ["relation", "social", "crossing", "length"]
    assert cfg.n_features == 4


def test_the_true_weights_on_the_learners_features_are_0_where_the_reward_lacks_one():
    cfg = settings()  # polite on 4 features, learned on them and crossing
    assert cfg.on_learner_features([-1.0, -0.7, -0.85, -0.1]) == [-1.0, -0.7, -0.85, -0.1, 0.0]
    fewer = settings("birl.features=[relation,social]")
    assert fewer.on_learner_features([-1.0, -0.7, -0.85, -0.1]) is None
    assert refused("birl.features=[relation,social]", "graph.weights=true").startswith(
        "config error: graph.weights=True is not allowed (allowed: null or numbers: the true "
        "weights are on reward.features=")


def _birl_artefact(run: Path, names: list[str], weights: list[list[float]],
                   config_yaml: str = "reward:\n  rho_personal: 1.2\n") -> Path:
    """A run dir holding a birl.mcap as the birl stage writes its topics: the learner's
    feature names and one message per iteration with its weights."""
    run.mkdir(parents=True, exist_ok=True)
    records = [(topics.BIRL_EXPERT, "BirlExpert", {"feature_names": names}, 0)]
    records += [(topics.BIRL_ITERATION, "BirlIteration", {"iteration": k, "weights": w}, k)
                for k, w in enumerate(weights)]
    return write_artefact(run / "birl.mcap", records, config_yaml=config_yaml, metadata={})


def test_a_deployment_learns_on_the_features_its_run_learned_on_as_the_file_is_now(tmp_path):
    run = tmp_path / "run"
    _birl_artefact(run, ["relation", "length"], [[-1.0, -0.5]])
    deployed = settings("expert=none", "birl=fixed", f"birl.from_run={run}")
    assert deployed.learner_features == ["relation", "length"]
    # the file replaced by another run's (another size): its names, not the first one's
    _birl_artefact(run, ["relation", "social", "length"], [[-1.0, -0.2, -0.5]])
    assert learned_feature_names(str(run)) == ("relation", "social", "length")
    assert settings("expert=none", "birl=fixed",
                    f"birl.from_run={run}").learner_features == ["relation", "social", "length"]


def test_one_job_of_a_sweep_warns_only_when_something_is_swept():
    assert one_job_of_a_sweep({}, "run it with -m") is None
    assert one_job_of_a_sweep(None, "run it with -m") is None
    assert one_job_of_a_sweep({"seed": "0,1", "birl": "map,mcmc"}, "run it with -m") == (
        "the config sweeps seed: 0,1; birl: map,mcmc (its experiment preset's sweep), but this "
        "is one run, with the config's own values of those settings; run it with -m")


def test_a_misspelt_objective_is_shown_the_closest_key():
    assert refused("objective=policy_los") == ("config error: objective=policy_los is not "
                                               "allowed (allowed: a metrics.json key, e.g. "
                                               "policy_loss)")
    assert refused("objective=zzz").endswith("e.g. policy_loss_norm)")


def test_a_held_out_objective_needs_held_out_demonstrations():
    assert refused("objective=heldout_frechet_m").startswith(
        "config error: objective=heldout_frechet_m is not allowed (allowed: a metric this run "
        "writes: the heldout_* keys need held-out demonstrations")
    assert settings("objective=heldout_frechet_m", "evaluate.holdout=0.3").objective == \
        "heldout_frechet_m"


def test_a_boolean_override_takes_true_false_a_sweep_or_an_interpolation():
    file_expert = ("expert=file", "expert.path=x.json")
    cfg = compose_config(*file_expert)
    for said in ("expert.denoise=true", "expert.denoise=False", "expert.denoise=true,false",
                 "expert.denoise=${expert.denoise}", "~expert.denoise"):
        check_boolean_overrides(cfg, [said])
    with pytest.raises(PipelineError) as err:
        check_boolean_overrides(cfg, ["expert.denoise=yes"])
    assert one_line(err) == ("config error: expert.denoise=yes is not allowed (allowed: true "
                             "or false)")
    check_boolean_overrides(cfg, ["expert.path=yes"])  # a string setting takes any word
    with pytest.raises(PipelineError) as err:  # the option added for a tracker's files
        check_boolean_overrides(cfg, ["expert.select_walks=on"])
    assert one_line(err) == ("config error: expert.select_walks=on is not allowed (allowed: "
                             "true or false)")


def test_a_long_value_is_cut_from_101_characters_on():
    assert str(config_error("k", "x" * 100, "y")) == \
        f"config error: k={'x' * 100} is not allowed (allowed: y)"
    assert str(config_error("k", "x" * 101, "y")) == \
        f"config error: k={'x' * 80}... (101 characters) is not allowed (allowed: y)"


def test_a_key_added_to_a_section_or_the_top_is_refused_naming_it():
    assert refused("+scene.colour=1").startswith(
        "config error: scene.colour is not a setting of scene (known: ")
    assert refused("+colour=1").startswith("config error: colour is not a setting (known: ")


def test_a_missing_value_is_shown_how_to_set_it():
    assert refused("scene=file") == \
        "config error: scene.path is missing (set it: scene=file scene.path=PATH)"


@pytest.mark.parametrize("section, other, chosen", [
    ("scene", "random", "file scene.path=data/scenes/metropolis.json"),
    ("expert", "boltzmann", "optimal"),
])
def test_a_kind_other_than_the_chosen_schemas_is_refused(section, other, chosen):
    overrides = f"{section}={chosen}".split() + [f"{section}.kind={other}"]
    assert refused(*overrides).startswith(
        f"config error: {section}.kind={other} is not allowed (allowed: "
        f"'{chosen.split()[0]}' (choose another with {section}=NAME))")


def test_a_deleted_setting_is_refused():
    assert refused("~seed").startswith("config error: seed is missing (deleted with ~seed?)")


@pytest.mark.parametrize("override, message", [
    ("stages=[]", "config error: stages=[] is not allowed"),
    ("seed=-1", "config error: seed=-1 is not allowed (allowed: an integer >= 0)"),
    ("from_run=' '", "config error: from_run=  is not allowed (allowed: a run dir)"),
    ("birl.init_weights=[5,5,5,5,5]", "config error: birl.init_weights=[5.0, 5.0, 5.0, 5.0, 5.0] "
                                      "is not allowed"),
    ("graph.weights=[-1,-1,-1,-1,-1,-1]", "config error: graph.weights=[-1, -1, -1, -1, -1, -1]"),
])
def test_top_level_and_cross_section_values_are_refused(override, message):
    assert refused(override).startswith(message)


def test_undiscounted_runs_refuse_positive_weights_and_take_zero():
    assert settings("mdp.gamma=1", "birl.upper=[0]").mdp.gamma == 1
    assert refused("mdp.gamma=1", "graph.weights=[1,-1,-1,-1,-1]").startswith(
        "config error: graph.weights=[1, -1, -1, -1, -1] is not allowed (allowed: <= 0 with "
        "mdp.gamma=1")


@pytest.mark.parametrize("overrides, message", [
    (["evaluate.holdout=all"], "config error: evaluate.holdout=all is not allowed (allowed: a "
                               "fraction or subject ids, unless birl=fixed"),
    (["evaluate.holdout=[s1]"], "config error: evaluate.holdout=['s1'] is not allowed (allowed: "
                                "a fraction or null with expert=optimal"),
    (["expert=none"], "config error: birl=map is not allowed (allowed: fixed with expert=none"),
    (["expert=planner", "graph.weights=true"], "config error: graph.weights=True is not allowed "
                                               "(allowed: null or numbers: graph.weights=true "
                                               "needs true weights, but the demonstrations have "
                                               "none (expert=planner)"),
    (["expert=planner", "graph.weights='true'"], "config error: graph.weights=true is not "
                                                 "allowed (allowed: null or numbers"),
])
def test_what_the_demonstrator_does_not_allow_is_refused(overrides, message):
    assert refused(*overrides).startswith(message)


# -- preflight ---------------------------------------------------------------------------------

def _preflight(run_dir: Path, *overrides: str, from_run: Path | None = None):
    return preflight.preflight(settings(*overrides), run_dir, from_run)


def test_maxent_is_refused_only_for_demonstrations_that_are_no_roadmap_paths(tmp_path):
    _preflight(tmp_path / "a", "birl=maxent", "expert=boltzmann", "stages=[scene,demos]")
    # the birl stage does not run: nothing learns from the file's demonstrations here
    _preflight(tmp_path / "b", "birl=maxent", "expert=file",
               "expert.path=data/demos/metropolis_handdrawn.json", "stages=[scene,demos]")


def test_weights_from_this_runs_own_dir_are_refused_also_given_relative(tmp_path, monkeypatch):
    run = tmp_path / "run"
    run.mkdir()
    monkeypatch.chdir(tmp_path)
    with pytest.raises(PipelineError, match=r"birl\.from_run=run is this run's own dir"):
        _preflight(run, "birl=fixed", "birl.from_run=run", "stages=[birl]", "birl.features="
                   "[relation,social,goal_deviation,length,crossing]")
    # the birl stage does not run: the birl.mcap is only read (here: there is none)
    with pytest.raises(PipelineError) as err:
        _preflight(run, "birl=fixed", "birl.from_run=run", "stages=[graph]", "birl.features="
                   "[relation,social,goal_deviation,length,crossing]")
    assert "own dir" not in str(err.value)


def test_an_artefact_given_as_the_demonstration_file_is_refused(tmp_path):
    made = write_artefact(tmp_path / "demos.mcap", [("/x", "X", {"a": 1}, 0)], config_yaml="",
                          metadata={})
    with pytest.raises(PipelineError, match=r"is an artefact of this pipeline \(a run's "
                                            r"demos\.mcap\), not a recording"):
        _preflight(tmp_path / "run", "expert=file", f"expert.path={made}")


@pytest.fixture(scope="module")
def scene_run(tmp_path_factory) -> Path:
    """A run dir holding only the default scene.mcap (metropolis)."""
    run = tmp_path_factory.mktemp("scene_run")
    run_in_process(run, "stages=[scene]")
    return run


def test_evaluate_alone_derives_the_graph_size_and_growth_its_inputs_were_made_with(
        tmp_path, scene_run):
    checked = _preflight(tmp_path / "run", "stages=[evaluate]", from_run=scene_run)
    assert checked.derived == {"graph.max_nodes": 460, "birl.grow_nodes": 0}
    checked = _preflight(tmp_path / "run", "stages=[birl]", from_run=scene_run)
    assert checked.derived == {"graph.max_nodes": 460, "birl.grow_nodes": 0}


def test_no_growth_on_an_open_room_is_said_only_at_debug_level(tmp_path, caplog):
    with caplog.at_level(logging.INFO, logger="pipeline"):
        _preflight(tmp_path / "run")
    assert not [r for r in caplog.records if "birl.grow_nodes=" in r.getMessage()]
    with caplog.at_level(logging.DEBUG, logger="pipeline"):
        _preflight(tmp_path / "run")
    assert [r.levelno for r in caplog.records if "birl.grow_nodes=0" in r.getMessage()] \
        == [logging.DEBUG]


def test_the_default_robot_radius_in_an_open_room_is_no_warning(tmp_path, caplog):
    with caplog.at_level(logging.WARNING, logger="pipeline"):
        _preflight(tmp_path / "run")
    assert [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING] == []


def test_later_stages_without_a_scene_artefact_are_left_to_the_stage(tmp_path):
    """No scene.mcap to size from: nothing is derived and the stage says what is missing."""
    assert _preflight(tmp_path / "run", "stages=[graph]").derived == {}


def _tiny_memory(monkeypatch, have: float = 1e3) -> None:
    monkeypatch.setattr(limits, "available_memory", lambda: have)


def test_the_size_checks_count_what_each_stage_builds(tmp_path, monkeypatch):
    """The element counts of each refusal: the reference roadmap's edges (16-connected at
    0.25 m over metropolis' 100 m²), the demonstrations of its 7 starts, the planner's
    lattice (0.1 m over 100 m²), one expansion's candidates."""
    cfg = settings()
    metropolis = preflight.scene_facts(cfg, tmp_path / "run", None)
    _tiny_memory(monkeypatch)
    with pytest.raises(PipelineError, match=r"^the reference roadmap of scene 'metropolis' "
                                            r"would need about .* \(25,600 elements\)"):
        preflight.check_roadmap_size(cfg, metropolis)
    with pytest.raises(PipelineError, match=r"^7 starts × expert\.demos_per_start=3 "
                                            r"demonstrations would need .* \(21 elements\)"):
        preflight.check_demonstrations_size(settings("expert=boltzmann",
                                                     "expert.demos_per_start=3"), 7)
    facts = preflight.SceneFacts("metropolis", 100.0, 9, False, lambda: 100.0)
    with pytest.raises(PipelineError, match=r"^the planner's lattice over scene 'metropolis' "
                                            r"would need .* \(10,000 elements\)"):
        preflight.check_planner_lattice_size(settings("expert=planner"), facts)


def test_the_roadmap_estimate_counts_persons_and_obstacles(monkeypatch):
    """BYTES_FIXED + edges × (500 + 1 per person + 150 with obstacles): on the edge of the
    memory share, the persons and the obstacles make the difference."""
    edges = limits.lattice_edges(100.0, 0.25, 16)
    assert edges == 25_600
    cfg = settings()
    for n_persons, obstacles in ((40, False), (0, True)):
        need = limits.BYTES_FIXED + edges * limits.bytes_per_lattice_edge(n_persons, obstacles)
        _tiny_memory(monkeypatch, (need - 1) / limits.MEMORY_SHARE)
        facts = preflight.SceneFacts("s", 100.0, n_persons, obstacles, lambda: 100.0)
        with pytest.raises(PipelineError, match="reference roadmap of scene 's'"):
            preflight.check_roadmap_size(cfg, facts)
        _tiny_memory(monkeypatch, need / limits.MEMORY_SHARE)
        preflight.check_roadmap_size(cfg, facts)


def test_the_birl_stage_alone_checks_one_expansions_candidates(tmp_path, scene_run):
    with pytest.raises(PipelineError, match=r"graph\.n_new=99999999999 candidates"):
        _preflight(tmp_path / "run", "stages=[birl]", "graph.n_new=99999999999",
                   from_run=scene_run)


def test_demonstration_sizes_are_checked_only_where_demonstrations_are_made(tmp_path):
    many = ("expert=boltzmann", "expert.demos_per_start=99999999999")
    _preflight(tmp_path / "run", "stages=[scene,graph]", *many)
    with pytest.raises(PipelineError, match="demonstrations would need"):
        _preflight(tmp_path / "run", "stages=[scene,demos]", *many)


def test_transfer_scenes_are_checked_where_evaluate_runs(tmp_path):
    bad = "evaluate.transfer_scenes=[/nonexistent/hall.json]"
    _preflight(tmp_path / "run", "stages=[scene]", bad)
    with pytest.raises(PipelineError, match=r"transfer_scenes\[0\].*not found"):
        _preflight(tmp_path / "run", "stages=[evaluate]", bad)


def test_a_bad_transfer_scene_is_named_by_its_place_and_two_of_one_name_are_refused(tmp_path):
    with pytest.raises(PipelineError, match=r"^evaluate\.transfer_scenes\[1\]: .*not found"):
        preflight.check_transfer_scenes(settings(
            f"evaluate.transfer_scenes=[{METROPOLIS},/nonexistent/hall.json]"))
    twin = write_json(tmp_path / "twin.json", json.loads(METROPOLIS.read_text()))
    with pytest.raises(PipelineError, match=r"names two scenes called 'metropolis' \(.*"
                                            r"metropolis\.json and .*twin\.json\)"):
        preflight.check_transfer_scenes(settings(
            f"evaluate.transfer_scenes=[{METROPOLIS},{twin}]"))


# The walled room's 1 m gap is missed by an 8-connected lattice 2 m apart: every start is cut
# off from the goal on that reference roadmap (a valid scene: on a 0.25 m one, none is).
COARSE = ("roadmap.spacing=2", "roadmap.connectivity=8")


def test_a_transfer_scene_whose_goal_the_roadmap_cannot_reach_is_refused(tmp_path):
    path = write_json(tmp_path / "walled.json", walled_metropolis())
    preflight.check_transfer_scenes(settings(f"evaluate.transfer_scenes=[{path}]"))
    with pytest.raises(PipelineError, match=r"^evaluate\.transfer_scenes\[0\]: scene 'walled': "
                                            r"the goal cannot be reached from start\(s\) "
                                            r"\[0, 1, 2, 3\] on the reference roadmap \(spacing "
                                            r"2 m\)"):
        preflight.check_transfer_scenes(settings(f"evaluate.transfer_scenes=[{path}]", *COARSE))


def test_the_scene_files_are_recorded_by_digest_and_an_edit_since_is_refused(tmp_path):
    scene = write_json(tmp_path / "s.json", json.loads(METROPOLIS.read_text()))
    own = ("scene=file", f"scene.path={scene}")
    checked = _preflight(tmp_path / "run", *own, "stages=[scene]")
    assert checked.source_digests == {"scene.path": files_digest([scene])}
    run_in_process(tmp_path / "run", *own, "stages=[scene]")
    _preflight(tmp_path / "run", *own, "stages=[demos]")
    data = json.loads(scene.read_text())
    data["persons"][0]["x"] += 0.5
    write_json(scene, data)
    with pytest.raises(PipelineError, match="scene.path"):
        _preflight(tmp_path / "run", *own, "stages=[demos]")


def test_a_scene_on_a_map_is_read_from_the_file_the_map_and_its_image():
    key, files = preflight.scene_source(settings("scene=office"))
    assert key == "scene.path"
    assert [p.name for p in files] == ["office.json", "office.yaml", "office.pgm"]


def test_what_the_size_checks_know_of_a_scene(tmp_path):
    random = preflight.scene_facts(settings("scene=random", "scene.seed=7"), tmp_path, None)
    assert (random.name, random.area, random.n_persons, random.obstacles) == \
        ("random-7", 100.0, 3 + 3 * 4, False)  # 3 singles, 3 groups of at most 4
    assert preflight.facts_of(build.scene_file(str(OFFICE_SCENE))).obstacles is True
    assert preflight.facts_of(build.scene_file(str(METROPOLIS))).obstacles is False


def test_the_edited_demonstration_file_is_refused_also_for_evaluate_alone(tmp_path):
    demos = write_json(tmp_path / "d.json", json.loads(
        (ROOT / "data" / "demos" / "metropolis_handdrawn.json").read_text()))
    own = ("expert=file", f"expert.path={demos}")
    run_in_process(tmp_path / "run", *own, "stages=[scene,demos]")
    _preflight(tmp_path / "run", *own, "stages=[evaluate]")
    demos.write_text(demos.read_text() + "\n ")
    with pytest.raises(PipelineError, match="expert.path"):
        _preflight(tmp_path / "run", *own, "stages=[evaluate]")


# -- limits ------------------------------------------------------------------------------------

def test_bytes_per_lattice_edge_adds_persons_and_obstacles():
    assert limits.bytes_per_lattice_edge(0, False) == limits.BYTES_PER_LATTICE_EDGE == 500
    assert limits.bytes_per_lattice_edge(3, True) == 500 + 3 * 1.0 + 150


def _meminfo_available() -> float:
    for line in Path("/proc/meminfo").read_text().splitlines():
        if line.startswith("MemAvailable:"):
            return float(line.split()[1]) * 1024  # kB
    pytest.skip("no MemAvailable in /proc/meminfo")


def test_available_memory_is_memavailable_in_bytes():
    before = _meminfo_available()
    have = limits.available_memory()
    after = _meminfo_available()
    assert min(before, after) * 0.995 <= have <= max(before, after) * 1.005


@pytest.mark.parametrize("n_bytes, shown", [
    (1e9, "1.0 GB"), (999e6, "999.0 MB"), (1e6, "1.0 MB"), (5e5, "0.50 MB"),
    (2.5e12, "2.5 TB"), (1234e9, "1.2 TB")])
def test_sizes_are_shown_in_the_largest_unit_they_reach(n_bytes, shown):
    assert limits._size(n_bytes) == shown


def test_memory_is_refused_beyond_the_share_of_what_is_available(monkeypatch):
    _tiny_memory(monkeypatch, 1e9)  # share 0.8: 800 MB, of which 150 MB are fixed
    limits.check_memory("x", 650, 1e6, "fix it")
    with pytest.raises(PipelineError) as err:
        limits.check_memory("x", 651, 1e6, "fix it")
    assert one_line(err) == "x would need about 801.0 MB (651 elements) but 1.0 GB are " \
                            "available: fix it"


@pytest.mark.parametrize("rates, nodes, total, seconds", [
    ([(200, 0.01)], 200, 400, 0.01 * 200),  # one window: a constant rate
    ([(100, 0.01), (200, 0.02)], 200, 400, 0.02 * 200 / 2 * (2**2 - 1)),  # rate ∝ n: power 1
    ([(100, 0.01), (200, 0.04)], 200, 400, 0.04 * 200 / 3 * (2**3 - 1)),  # power 2
    ([(100, 0.01), (200, 0.16)], 200, 400, 0.16 * 200 / 3 * (2**3 - 1)),  # power 4, clipped to 2
    ([(100, 0.02), (200, 0.01)], 200, 400, 0.01 * 200),  # falling: clipped to 0
    ([(100, 0.01), (200, 0.02)], 300, 400, 0.02 * 200 / 2 * (2**2 - 1.5**2)),  # from 300 on
    ([(50, 0.0), (100, 0.01), (200, 0.02)], 200, 400, 0.02 * 200 / 2 * 3),  # a zero rate left out
])
def test_growth_time_left_integrates_the_last_rate_grown_as_a_power(rates, nodes, total,
                                                                    seconds):
    assert limits.growth_seconds_left(rates, nodes, total) == pytest.approx(seconds)


def test_a_graph_of_exactly_the_nodes_that_resolve_personal_space_is_enough():
    assert limits.nodes_to_resolve(100.0, 1.2) == 70  # 69.4 rounded up
    limits.check_graph_resolution(70, 100.0, 1.2, "x")
    with pytest.raises(PipelineError, match=r"graph\.max_nodes=69 is too few .* >= 70"):
        limits.check_graph_resolution(69, 100.0, 1.2, "x")


def test_a_learner_that_does_not_learn_on_the_graph_grows_nothing_even_on_a_map():
    grow, why = limits.learning_growth(True, "office", learns_on_the_graph=False)
    assert grow == 0 and "birl.alternatives=lattice" in why
    assert limits.learning_growth(True, "office")[0] == limits.GROW_ON_MAPS


def test_an_alternatives_lattice_of_exactly_the_most_nodes_keeps_its_spacing():
    area = limits.ALTERNATIVES_MAX_NODES * 0.5**2
    assert limits.alternatives_spacing(area, 0.5, "x") == (0.5, "")
    spacing, why = limits.alternatives_spacing(4 * area, 0.5, "x")
    assert spacing == pytest.approx(1.0) and "1.00 m apart, not 0.5 m" in why


def test_the_derived_graph_size_is_twice_the_resolving_nodes_but_at_least_the_papers():
    assert limits.graph_size(100.0, 1.2, "x")[0] == GraphParams.max_nodes == 460
    assert limits.graph_size(810.0, 1.2, "x")[0] == 2 * 563


# -- summary -----------------------------------------------------------------------------------

def _job(sweep: Path, name: str, overrides_yaml: str, status: dict | None = None,
         metrics: str | None = None) -> Path:
    job = sweep / name
    (job / ".hydra").mkdir(parents=True)
    (job / ".hydra" / "overrides.yaml").write_text(overrides_yaml)
    if status is not None:
        (job / "status.json").write_text(json.dumps(status))
    if metrics is not None:
        (job / "metrics.json").write_text(metrics)
    return job


@pytest.mark.parametrize("text, error", [
    ("", None), ("[]\n", None),
    ("a: b\n", "overrides.yaml is not a list of overrides"),
    ("- seed\n", 'overrides.yaml: "seed" is not an override (key=value)'),
])
def test_a_jobs_overrides_are_a_list_of_key_value_lines(tmp_path, text, error):
    job = _job(tmp_path, "0", text)
    if error is None:
        assert parse_overrides(job) == {}
    else:
        with pytest.raises(Unreadable) as err:
            parse_overrides(job)
        assert str(err.value) == error


def test_metrics_that_are_no_object_are_unreadable(tmp_path):
    path = tmp_path / "metrics.json"
    path.write_text("[1, 2]")
    with pytest.raises(Unreadable, match="^metrics.json is not an object of metrics$"):
        read_metrics(path)


@pytest.mark.parametrize("status, error", [
    ({"state": "failed", "error": "boom"}, "boom"),
    ({"state": "failed"}, "failed"),
    ({"state": "failed", "stage": "graph"}, "stage graph: failed"),
])
def test_a_failed_jobs_error_says_what_its_status_says(tmp_path, status, error):
    job = _job(tmp_path, "0", "- seed=0\n", status)
    assert job_row(job, tmp_path) == {"job": "0", "seed": "0", "status": "failed",
                                      "error": error}


def test_a_run_dir_or_an_empty_dir_is_no_sweep(tmp_path):
    run = _job(tmp_path, "run", "- seed=0\n", {"state": "complete"})
    with pytest.raises(PipelineError, match="is a run dir"):
        summary_rows(run)
    (tmp_path / "empty").mkdir()
    with pytest.raises(PipelineError, match="holds no Hydra jobs"):
        summary_rows(tmp_path / "empty")


# -- outcome -----------------------------------------------------------------------------------

def _sweep_config(sweep_dir: Path, task: list[str], params: dict | None = None,
                  objective: str = "policy_loss_norm", subdir: str = "${hydra.job.num}",
                  launcher: str = "hydra._internal.core_plugins.basic_launcher.BasicLauncher"):
    return OmegaConf.create({
        "objective": objective, "evaluate": {"holdout": None},
        "hydra": {"overrides": {"task": task},
                  "sweeper": {"_target_": "hydra._internal.core_plugins.basic_sweeper."
                                          "BasicSweeper", "params": params or {}},
                  "launcher": {"_target_": launcher},
                  "sweep": {"dir": str(sweep_dir), "subdir": subdir}}})


def test_a_setting_is_swept_by_a_sweep_override_or_a_sweeper_parameter(tmp_path):
    cfg = _sweep_config(tmp_path, ["seed=1", "evaluate.holdout=0.1,0.3"],
                        {"birl.beta": "range(1,3)"})
    assert _sweeps(cfg, "evaluate.holdout") and _sweeps(cfg, "birl.beta")
    assert not _sweeps(cfg, "seed")


@pytest.mark.parametrize("subdir", ["/abs/${hydra.job.num}", "../${hydra.job.num}", "", ".",
                                    "a/../../${hydra.job.num}"])
def test_a_subdir_outside_the_sweep_dir_is_refused(subdir):
    with pytest.raises(PipelineError, match="outside the sweep dir, or in it"):
        check_subdir_template(subdir)


def test_a_subdir_without_an_interpolation_is_one_dir_for_every_job():
    with pytest.raises(PipelineError, match="is one run dir that every job of the sweep would "
                                            "share"):
        check_subdir_template("same")
    check_subdir_template("${hydra.job.num}")
    check_subdir_template("seed_${seed}/${hydra.job.num}")


def test_failed_jobs_are_those_not_complete_and_those_no_status_could_name(tmp_path,
                                                                          monkeypatch):
    number, _ = rundir.begin_sweep(tmp_path)
    for name, state in (("0", "complete"), ("1", "failed"), ("2", "interrupted")):
        _job(tmp_path, name, f"- seed={name}\n", {"state": state, "sweep": number})
    monkeypatch.setattr(SweepOutcome, "unrecorded", {str(tmp_path / "1"): "x",
                                                     str(tmp_path / "3"): "could not start"})
    assert failed_jobs(tmp_path) == [str(tmp_path / "1"), str(tmp_path / "2"),
                                     str(tmp_path / "3")]


@pytest.fixture
def sweep_state(monkeypatch):
    """The callback's class state, put back after the test."""
    for name in ("sweep_dir", "unrecorded", "ended", "_lock_fd", "_previous", "_number",
                 "_versions", "_read_only"):
        monkeypatch.setattr(SweepOutcome, name, getattr(SweepOutcome, name))
    yield
    SweepOutcome.release()


def test_a_held_out_objective_of_a_sweep_that_sweeps_the_holdout_is_not_refused(tmp_path,
                                                                               sweep_state):
    swept = _sweep_config(tmp_path / "a", ["evaluate.holdout=0.1,0.3"],
                          objective="heldout_frechet_m")
    SweepOutcome().on_multirun_start(swept)
    SweepOutcome.release()
    with pytest.raises(SweepRefused):
        SweepOutcome().on_multirun_start(_sweep_config(tmp_path / "b", ["seed=0,1"],
                                                       objective="heldout_frechet_m"))


def test_only_the_pool_launcher_checks_the_subdirs_itself(tmp_path, sweep_state):
    pool = "pipeline.pool_launcher.PoolLauncher"
    SweepOutcome().on_multirun_start(_sweep_config(tmp_path / "a", ["seed=0,1"], subdir="same",
                                                   launcher=pool))
    SweepOutcome.release()
    with pytest.raises(SweepRefused):
        SweepOutcome().on_multirun_start(_sweep_config(tmp_path / "b", ["seed=0,1"],
                                                       subdir="same"))


# -- build -------------------------------------------------------------------------------------

def test_a_preset_weighs_only_its_own_features():
    assert build.preset_weights("polite", ["length", "crossing", "relation"]).tolist() == \
        [-0.1, 0.0, -1.0]


def test_a_random_scene_is_drawn_with_its_own_seed(tmp_path):
    seeds = []

    def rng_for_seed(seed):
        seeds.append(seed)
        return np.random.default_rng(seed)

    scene = build.scene(settings("scene=random", "scene.seed=5", "seed=2"), rng_for_seed)
    assert scene.name == "random-5" and seeds == [5]


def test_one_scene_file_with_other_sizes_is_another_scene():
    build.forget_scene_files()
    plain = build.scene_file(str(METROPOLIS))
    wider = build.scene_file(str(METROPOLIS), robot_radius=0.4)
    assert wider.robot_radius == 0.4 != plain.robot_radius
    assert build.scene_file(str(METROPOLIS)) is plain


def test_growth_while_learning_is_derived_from_the_scenes_obstacles():
    paper = settings("birl.likelihood=paper")
    assert build.learning_growth(paper, build.scene_file(str(OFFICE_SCENE))) == \
        limits.GROW_ON_MAPS
    assert build.learning_growth(paper, build.scene_file(str(METROPOLIS))) == 0


@pytest.mark.parametrize("name, path, key", [
    ("my hall", "x/h.json", "my_hall"), ("-hall-", "x/h.json", "hall"), ("!!!", "x/h.json", "h")])
def test_a_transfer_scenes_key_is_its_name_in_word_characters(name, path, key):
    assert build.transfer_name(name, path) == key


LEARNER = ["relation", "social", "goal_deviation", "length", "crossing"]


def _fixed_from(run: Path, *extra: str):
    return settings("expert=none", "birl=fixed", f"birl.from_run={run}", *extra)


def test_fixed_weights_are_the_last_iterations_of_the_run(tmp_path):
    run = tmp_path / "run"
    _birl_artefact(run, LEARNER, [[-1.0] * 5, [-0.5, -0.4, -0.3, -0.2, -0.1]])
    weights, digest = build._fixed(_fixed_from(run))
    assert weights.tolist() == [-0.5, -0.4, -0.3, -0.2, -0.1]
    assert digest is not None
    assert build.learned_feature_params(
        build.read_artefact(run / "birl.mcap"), ["relation", "length"]).features == \
        ["relation", "length"]


def test_fixed_weights_of_a_run_with_other_features_or_counts_are_refused(tmp_path):
    run = tmp_path / "run"
    _birl_artefact(run, LEARNER, [[-1.0] * 4])  # one weight short of its features
    with pytest.raises(PipelineError, match=r"birl\.weights=\[-1\.0, -1\.0, -1\.0, -1\.0\] "
                                            r"needs 5 numbers"):
        build.fixed_weights(_fixed_from(run))
    with pytest.raises(PipelineError, match=r"learned weights on \['relation', 'social', "
                                            r"'goal_deviation', 'length', 'crossing'\]; set "
                                            r"birl\.features="):
        build.fixed_weights(_fixed_from(run, "birl.features=[relation,length]"))


def test_fixed_weights_need_the_reward_constants_they_were_learned_with(tmp_path):
    run = tmp_path / "run"
    _birl_artefact(run, LEARNER, [[-1.0] * 5], config_yaml="seed: 0\n")
    with pytest.raises(PipelineError, match=r"\(attachment config\.yaml\) has no 'reward' "
                                            r"section"):
        build.fixed_weights(_fixed_from(run))
    _birl_artefact(run, LEARNER, [[-1.0] * 5], config_yaml="reward:\n  rho_personal: 0.8\n")
    with pytest.raises(PipelineError, match=r"learned its weights with reward\.rho_personal=0\.8,"
                                            r" this run has 1\.2"):
        build.fixed_weights(_fixed_from(run))


def test_a_deployment_whose_reward_has_crossing_grows_under_its_crossing_weight():
    features = "[relation,social,goal_deviation,length,crossing]"
    deployed = settings("expert=none", "birl=fixed", f"reward.features={features}",
                        "reward.weights=[-1,-1,-1,-1,-1]",
                        "birl.weights=[-1,-0.5,-0.4,-0.3,-0.2]")
    w, source = build.growth_weights(deployed, None)
    assert source == "fixed" and w.tolist() == [-1, -0.5, -0.4, -0.3, -0.2]


def test_the_starts_cut_off_from_the_goal_are_named_by_their_index(tmp_path):
    scene = build.scene_file(str(write_json(tmp_path / "walled.json", walled_metropolis())))
    assert build.roadmap_cut_off(scene, RoadmapParams(spacing=2.0, connectivity=8)) == \
        [0, 1, 2, 3]
    assert build.roadmap_cut_off(scene, RoadmapParams()) == []


def test_learning_starts_from_the_given_initial_weights():
    w, what = build.initial_weights(settings("birl.init_weights=[-0.5,-0.5,-0.5,-0.5,-0.5]"),
                                    np.random.default_rng(0))
    assert what == "birl.init_weights" and w.tolist() == [-0.5] * 5


# -- context -----------------------------------------------------------------------------------

def test_an_input_path_in_the_cwd_wins_over_the_packages(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    given = "data/scenes/metropolis.json"
    assert resolve_path(given) == PACKAGE_ROOT / given  # only the package has it
    (tmp_path / "data" / "scenes").mkdir(parents=True)
    (tmp_path / given).write_text("{}")
    assert resolve_path(given) == Path(given)
    assert resolve_path("nowhere/x.json") == Path("nowhere/x.json")  # the stage says not found


def test_a_path_through_a_file_does_not_exist(tmp_path):
    (tmp_path / "f.json").write_text("{}")
    assert input_path_exists(tmp_path / "f.json" / "x", "f.json/x") is False


def test_a_path_that_cannot_be_looked_up_is_shown_whole_up_to_80_characters(tmp_path):
    for length, shown_whole in ((80, True), (81, False)):
        loop = tmp_path / ("l" * (length - len(str(tmp_path)) - 1))
        given = str(loop)
        assert len(given) == length
        os.symlink(loop.name, loop)  # a link to itself: ELOOP on lookup
        with pytest.raises(PipelineError) as err:
            input_path_exists(loop, given)
        message = one_line(err)
        assert (given in message) is shown_whole
        if not shown_whole:
            assert f"{given[:60]}... (81 characters)" in message
        loop.unlink()


def test_each_stage_draws_from_its_own_generator():
    draws = {stage: stage_rng(3, stage).random() for stage in STAGES}
    assert len(set(draws.values())) == len(STAGES)
    assert draws["graph"] == np.random.default_rng([3, STAGES.index("graph")]).random()


def _context(run_dir: Path, cfg=None) -> RunContext:
    return RunContext(cfg if cfg is not None else settings("seed=4"), run_dir, None, {}, "", {})


def test_a_stages_generator_takes_the_seed_given_else_the_runs(tmp_path):
    ctx = _context(tmp_path)
    assert ctx.rng("birl").random() == stage_rng(4, "birl").random()
    assert ctx.rng("birl", 9).random() == stage_rng(9, "birl").random()


def test_a_replaced_artefact_is_read_again(tmp_path):
    ctx = _context(tmp_path)
    path = tmp_path / "scene.mcap"
    with ArtefactWriter(path, config_yaml="", metadata={}) as w:
        w.add("/a", "A", {"v": 1}, 0)
    assert ctx._read_cached(path, ["/a"], "scene").one("/a") == {"v": 1}
    with ArtefactWriter(path, config_yaml="", metadata={}) as w:
        w.add("/a", "A", {"v": 22}, 0)
    assert ctx._read_cached(path, ["/a"], "scene").one("/a") == {"v": 22}



def test_a_stage_this_run_makes_is_read_from_this_run_the_others_from_from_run(tmp_path):
    run, earlier = tmp_path / "run", tmp_path / "earlier"
    for d, v in ((run, 1), (earlier, 2)):
        d.mkdir()
        write_artefact(d / "scene.mcap", [("/a", "A", {"v": v}, 0)], config_yaml="",
                       metadata={})
    ctx = RunContext(settings(), run, earlier, {}, "", {})  # every stage runs
    assert ctx.read("scene", ["/a"]).one("/a") == {"v": 1}
    ctx = RunContext(settings("stages=[demos]"), run, earlier, {}, "", {})
    assert ctx.read("scene", ["/a"]).one("/a") == {"v": 2}
    assert os.path.samefile(run / "scene.mcap", earlier / "scene.mcap")  # linked in


def test_a_run_that_makes_demonstrations_checks_the_planners_lattice(tmp_path, monkeypatch):
    """Between the reference roadmap's need (150 MB + 25,600 edges × 509 B, 163.0 MB) and the
    planner lattice's (150 MB + 10,000 points × 2.7 kB, 177.0 MB): only the lattice is
    refused, by the run's start-up checks."""
    _tiny_memory(monkeypatch, 170e6 / limits.MEMORY_SHARE)
    with pytest.raises(PipelineError) as err:
        _preflight(tmp_path / "run", "expert=planner", "stages=[scene,demos]")
    assert one_line(err) == (
        "the planner's lattice over scene 'metropolis' would need about 177.0 MB (10,000 "
        "elements) but 212.5 MB are available: raise expert.spacing (now 0.1 m) or lower "
        "expert.max_lattice_nodes (now 40000)")
    _preflight(tmp_path / "run", "expert=planner", "stages=[scene,graph]")  # no demos made


def test_a_given_graph_size_too_few_to_resolve_personal_space_is_refused_at_start_up(tmp_path):
    """metropolis: 100 m² of free space, one node per 1.2 m × 1.2 m square: 70 nodes (the
    stages would otherwise grow a graph that cannot route around people)."""
    _preflight(tmp_path / "run", "graph.max_nodes=70")
    with pytest.raises(PipelineError) as err:
        _preflight(tmp_path / "run", "graph.max_nodes=69")
    assert one_line(err) == (
        "config error: graph.max_nodes=69 is too few for scene 'metropolis': 100 m² of free "
        "space at one node per 1.2 m × 1.2 m (reward.rho_personal) needs graph.max_nodes >= 70")


def test_an_artefact_made_before_a_key_was_added_is_read_while_the_key_keeps_its_default(
        tmp_path):
    """demos.mcap made by a pipeline without expert.select_walks (its config and digests lack
    the key): a run at the key's default reads it; a run that sets the key otherwise, or
    changes a key the artefact has, is refused naming the key."""
    from pipeline.app.provenance import check_config, provenance_metadata
    from pipeline.artefacts.store import read_artefact

    def config(*overrides: str) -> tuple[dict, object]:
        composed = compose_config("expert=file", "expert.path=walks.csv", *overrides)
        return OmegaConf.to_container(composed, resolve=True), load_settings(composed)

    now, typed = config()
    older = json.loads(json.dumps(now))
    del older["expert"]["select_walks"]
    made = write_artefact(tmp_path / "demos.mcap", [("/x", "X", {"a": 1}, 0)],
                          config_yaml=OmegaConf.to_yaml(older),
                          metadata=provenance_metadata("demos", older, {}))
    artefact = read_artefact(made)
    check_config("demos", artefact, now, typed)  # the default: the old behaviour
    with pytest.raises(PipelineError, match=r"expert\.select_walks=<unset> but this run has "
                                            r"expert\.select_walks=true"):
        check_config("demos", artefact, *config("expert.select_walks=true"))
    with pytest.raises(PipelineError, match=r"expert\.start_radius=1\.0? but this run has "
                                            r"expert\.start_radius=0\.5"):
        check_config("demos", artefact, *config("expert.start_radius=0.5"))
