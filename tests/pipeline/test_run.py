"""The real Hydra app: config composition, artefacts, errors, determinism, stage subsets."""

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from hydra.errors import ConfigCompositionException

from pipeline.app.config import load_settings as validate
from pipeline.artefacts import read_artefact
from pipeline.errors import PipelineError
from tests.conftest import ROOT, compose_config, run_app, run_in_process


@pytest.mark.parametrize("overrides", [
    [], ["scene=random"], ["scene=file", "scene.path=data/scenes/metropolis.json"],
    ["reward=rude"], ["expert=boltzmann"], ["expert=file", "expert.path=x.json"],
    ["graph=small"], ["graph.controller.kind=posq"], ["graph.weights=true"],
    ["graph.weights=[-1,-1,-1,-1]"], ["birl=mcmc"],
])
def test_every_config_group_option_composes_and_validates(overrides):
    validate(compose_config(*overrides))


@pytest.mark.parametrize("override, key", [
    ("scene.body_radius=-0.1", "scene.body_radius"),
    ("reward.weights=[-1,-1]", "reward.weights"),
    ("stages=[scene,dance]", "stages"),
    ("mdp.gamma=1.5", "mdp.gamma"),
    ("scene=file", "scene.path"),
    ("graph.p_best=1.5", "graph.p_best"),
    ("graph.weights=[1,2]", "graph.weights"),
    ("graph.controller.kind=spline", "graph.controller.kind"),
    ("birl.prior.kind=cauchy", "birl.prior.kind"),
    ("birl.lower=[0,0,0,0]", "birl.lower"),
    ("birl.beta=-1", "birl.beta"),
    ("scene.robot_radius=-0.1", "scene.robot_radius"),
    ("scene=random scene.robot_radius=0", "scene.robot_radius"),
    ("expert=file expert.path=x.json expert.start_radius=0", "expert.start_radius"),
    ("graph.controller.max_speed=-1", "graph.controller.max_speed"),
    ("graph.controller.k_rho=0", "graph.controller.k_rho"),
    ("reward.features=[social,dance]", "reward.features"),
    ("reward.features=[social,length]", "reward.weights"),  # 4 weights for 2 features
])
def test_out_of_range_values_name_the_key(override, key):
    with pytest.raises(PipelineError) as err:
        validate(compose_config(*override.split()))
    message = str(err.value)
    assert message.startswith((f"config error: {key}=", f"config error: {key} is missing"))
    assert "\n" not in message


@pytest.mark.parametrize("overrides, key", [
    (["birl=maxent", "birl.alpha=3"], "birl.alpha"),  # a PolicyWalk key on MaxEnt
    (["birl=map", "birl.n_samples=10"], "birl.n_samples"),  # an MCMC key on the MAP method
    (["expert=optimal", "expert.beta=5"], "expert.beta"),  # a Boltzmann key on the optimal one
])
def test_a_key_of_another_method_is_refused(overrides, key):
    with pytest.raises(ConfigCompositionException, match=f"override '{key}'"):
        compose_config(*overrides)


def test_a_subset_of_the_features_runs_end_to_end(tmp_path):
    metrics, _ = run_in_process(tmp_path, "reward.features=[social,length]",
                                "reward.weights=[-0.7,-0.1]", "graph=small", "birl.n_iterations=3")
    assert {k for k in metrics if k.startswith("weight_")} == {"weight_social", "weight_length"}
    assert metrics["policy_loss"] >= 0
    assert read_artefact(tmp_path / "graph.mcap").one("/graph/solution")["n_nodes"] > 0


@pytest.fixture(scope="module")
def default_dir(default_run):
    return default_run[0]


def test_default_experiment_writes_artefacts(default_dir):
    scene = read_artefact(default_dir / "scene.mcap", required_topics=["/scene"])
    assert scene.one("/scene")["name"] == "metropolis"
    assert "reward:" in scene.config_yaml and "seed: 0" in scene.config_yaml
    assert scene.metadata["seed"] == "0" and "version.numpy" in scene.metadata
    demos = read_artefact(default_dir / "demos.mcap",
                          required_topics=["/demos", "/demos/expert", "/demos/roadmap"])
    assert len(demos.all("/demos")) == 7
    assert demos.one("/demos/expert")["true_weights"] == [-1.0, -0.7, -0.85, -0.1]
    assert all(d["reached"] for d in demos.all("/demos"))
    graph = read_artefact(default_dir / "graph.mcap", required_topics=[
        "/graph/node", "/graph/edge", "/graph/best_paths", "/graph/solution"])
    nodes, edges = graph.all("/graph/node"), graph.all("/graph/edge")
    solution = graph.one("/graph/solution")
    assert len(nodes) == 460 and solution["n_nodes"] == 460 and len(edges) == solution["n_edges"]
    assert solution["weights_source"] == "prior_mean"
    # Growth replays in order: nodes and edges appear no earlier than their iteration.
    assert [n["iteration"] for n in nodes] == sorted(n["iteration"] for n in nodes)
    added = {n["id"]: n["iteration"] for n in nodes}
    assert all(e["iteration"] == max(added[e["src"]], added[e["dst"]]) for e in edges)
    assert all(n["parent"] >= 0 for n in nodes if n["kind"] == "sampled")
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


def _fails_with_one_line(result, *fragments):
    assert result.returncode != 0
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    for f in fragments:
        assert f in lines[0]
    assert "Traceback" not in result.stderr + result.stdout


def test_typo_and_wrong_type_fail_at_start_up(tmp_path):
    typo = run_app(f"hydra.run.dir={tmp_path}", "scene.n_persns=3")
    assert typo.returncode != 0 and "n_persns" in typo.stderr
    wrong_type = run_app(f"hydra.run.dir={tmp_path}", "seed=abc")
    assert wrong_type.returncode != 0 and "seed" in wrong_type.stderr
    assert not (tmp_path / "scene.mcap").exists()


def test_out_of_range_value_exits_with_one_line(tmp_path):
    _fails_with_one_line(run_app(f"hydra.run.dir={tmp_path}", "scene.body_radius=-1"),
                         "scene.body_radius=-1")


def _refused_with_one_line(run_dir, overrides, *fragments):
    """In-process twin of _fails_with_one_line: the PipelineError the CLI prints as one line."""
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


def test_help_lists_groups_and_options_without_schemas():
    result = run_app("--help")
    assert result.returncode == 0, result.stderr
    text = result.stdout
    assert text.startswith("birlg: BIRL-G")
    assert "scene: file, metropolis, office, random" in text
    assert "base_" not in text and "__main__" not in text and "powered by Hydra" not in text
    assert len(text.splitlines()) < 40  # groups and options, not the whole config


def test_python_api_runs_and_reads_tables(tmp_path):
    from pipeline import api

    metrics = api.run(["graph=small", "birl.n_iterations=3", "stages=[scene,demos,graph,birl,"
                       "evaluate]"], run_dir=tmp_path)
    assert metrics["policy_loss_norm"] >= 0
    curve = api.messages(tmp_path, "evaluate", "/eval/policy_loss")
    assert len(curve) == 4 and {"iteration", "weights", "ref"} <= set(curve.columns)
    assert list(curve["iteration"]) == [0, 1, 2, 3]
    persons = api.messages(tmp_path, "scene", "/scene")["persons"].iloc[0]
    assert len(persons) == 12  # metropolis
    with pytest.raises(ValueError, match="unknown stage"):
        api.artefact(tmp_path, "nope")
    assert api.run(["stages=[scene]"], run_dir=tmp_path / "only_scene") == {}


def test_the_birlg_console_script_completes_keys_and_options():
    import os

    birlg = Path(sys.executable).parent / "birlg"
    assert birlg.exists(), "pip install -e . creates the console script"
    env = {**os.environ, "COMP_LINE": "birlg scene=ra", "COMP_POINT": "14"}
    done = subprocess.run([str(birlg), "-sc", "query=bash"], env=env, capture_output=True,
                          text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert "scene=random" in done.stdout.split()
