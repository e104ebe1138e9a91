"""The Python API (pipeline/api.py): runs started from Python and read back through a `Run`
handle, earlier runs and sweeps opened, and learning from Python objects in memory."""

import dataclasses
import json
import os
import shutil
import signal
import threading
import time
from pathlib import Path

import matplotlib
import numpy as np
import pytest
from omegaconf import OmegaConf

from pipeline import api
from pipeline.app import build
from pipeline.app.config import load_settings
from pipeline.app.rundir import read_status
from pipeline.artefacts import codec, topics
from pipeline.artefacts.store import ArtefactError, read_artefact
from pipeline.core.experts import optimal_demos
from pipeline.errors import PipelineError
from tests.conftest import ROOT, run_app
from tests.pipeline.conftest import FAST

matplotlib.use("Agg")  # before pyplot: no window in tests
import matplotlib.pyplot as plt  # noqa: E402


@pytest.fixture(scope="module")
def fast_run(tmp_path_factory):
    """One real run of the default experiment with the quick settings, through api.run."""
    run_dir = tmp_path_factory.mktemp("api_run")
    return api.run(list(FAST), run_dir=run_dir)


def raw(run_dir, stage, topic):
    """The messages as the artefact holds them (plain JSON values)."""
    return read_artefact(run_dir / topics.ARTEFACT_FILE[stage]).all(topic)


def test_python_api_runs_and_reads_tables(tmp_path):
    run = api.run(["graph=small", "birl.n_iterations=3", "stages=[scene,demos,graph,birl,"
                   "evaluate]"], run_dir=tmp_path)
    assert isinstance(run, api.Run) and run.dir == tmp_path
    assert run.metrics["policy_loss_norm"] >= 0
    curve = run.messages("evaluate", "/eval/policy_loss")
    assert len(curve) == 4 and {"iteration", "weights", "ref"} <= set(curve.columns)
    assert list(curve["iteration"]) == [0, 1, 2, 3]
    persons = run.messages("scene", "/scene")["persons"].iloc[0]
    assert len(persons) == 12  # metropolis
    with pytest.raises(PipelineError, match="unknown stage"):
        run.artefact("nope")
    # the run-dir helpers of the first API still answer
    assert api.messages(tmp_path, "evaluate", "/eval/policy_loss")["iteration"].tolist() == \
        [0, 1, 2, 3]
    with pytest.raises(PipelineError, match="unknown stage"):
        api.artefact(tmp_path, "nope")


def test_run_handle_fields_match_the_files(fast_run):
    d = fast_run.dir
    assert fast_run.metrics == json.loads((d / "metrics.json").read_text())
    assert fast_run.status.complete
    cfg = fast_run.config
    assert cfg.graph.max_nodes == 200 and cfg.birl.n_iterations == 3 and cfg.seed == 0
    attached = read_artefact(d / "eval.mcap").config_yaml
    assert OmegaConf.to_container(cfg) == OmegaConf.to_container(OmegaConf.create(attached))


def test_messages_have_named_columns_and_numpy_arrays(fast_run):
    d = fast_run.dir
    its = fast_run.messages("birl", topics.BIRL_ITERATION)
    stored = raw(d, "birl", topics.BIRL_ITERATION)
    assert list(its.columns) == list(stored[0])  # every field, named
    for cell, msg in zip(its["weights"], stored, strict=True):
        assert isinstance(cell, np.ndarray) and cell.dtype == float and cell.shape == (5,)
        assert cell.tolist() == msg["weights"]
    assert isinstance(its["generated"].iloc[0], list)  # records stay dicts
    demos = fast_run.messages("demos", topics.DEMOS)
    points = demos["points"].iloc[0]
    assert isinstance(points, np.ndarray) and points.ndim == 2 and points.shape[1] == 2
    assert points.tolist() == raw(d, "demos", topics.DEMOS)[0]["points"]
    scene = fast_run.messages("scene", topics.SCENE).iloc[0]
    assert isinstance(scene["starts"], np.ndarray) and scene["starts"].shape == (7, 2)
    assert isinstance(scene["persons"], list) and isinstance(scene["persons"][0], dict)


def test_paths_are_the_learned_paths_of_eval_mcap(fast_run):
    stored = raw(fast_run.dir, "evaluate", topics.EVAL_PATHS)
    for graph in ("graph", "ref"):
        paths = fast_run.paths(graph)
        expected = {p["start"]: p["points"] for p in stored if p["graph"] == graph}
        assert sorted(paths) == sorted(expected) == list(range(7))  # metropolis: 7 starts
        for start, pts in paths.items():
            assert isinstance(pts, np.ndarray) and pts.shape[1] == 2
            assert pts.tolist() == expected[start]
    assert not np.array_equal(fast_run.paths("graph")[0], fast_run.paths("ref")[0])
    with pytest.raises(PipelineError, match="one of graph, ref"):
        fast_run.paths("roadmap")


def test_plot_on_something_that_is_not_axes_is_one_clear_error(fast_run):
    with pytest.raises(TypeError, match=r"ax='x': a matplotlib Axes, or None for a new figure"):
        fast_run.plot(ax="x")


def drawn_lines(ax):
    return [np.column_stack(line.get_data()) for line in ax.lines]


@pytest.mark.parametrize("paths", ["graph", "ref"])
def test_plot_draws_scene_demonstrations_and_learned_paths(fast_run, paths):
    scene = raw(fast_run.dir, "scene", topics.SCENE)[0]
    n_demos = len(raw(fast_run.dir, "demos", topics.DEMOS))
    learned = fast_run.paths(paths)
    try:
        ax = fast_run.plot(paths=paths)
        assert isinstance(ax, matplotlib.axes.Axes)
        # graph nodes, room, one line per social link, demonstration and learned path,
        # starts, goal
        assert len(ax.lines) == 1 + 1 + len(scene["relations"]) + n_demos + len(learned) + 2
        # per person: personal zone, body disk, heading arrow
        assert len(ax.patches) == 3 * len(scene["persons"])
        lines = drawn_lines(ax)
        for pts in learned.values():
            assert any(line.shape == pts.shape and np.array_equal(line, pts) for line in lines)
        assert np.array_equal(lines[-2], np.asarray(scene["starts"]))
        _, ax2 = plt.subplots()
        assert fast_run.plot(ax=ax2) is ax2  # drawn onto the caller's Axes
    finally:
        plt.close("all")


def test_a_refused_api_run_leaves_a_complete_dir_as_it_was(fast_run, tmp_path):
    """Nothing of an API run reached the dir (unlike Hydra's .hydra/ files), so a config
    error says so and the complete run there stays complete."""
    before = (fast_run.dir / "status.json").read_bytes()
    with pytest.raises(PipelineError, match="scene.body_radius"):
        api.run(["scene.body_radius=-1"], run_dir=fast_run.dir)
    assert (fast_run.dir / "status.json").read_bytes() == before
    assert api.open_run(fast_run.dir).status.complete


def test_an_api_re_run_failing_in_a_stage_before_any_artefact_changed_keeps_the_run(
        fast_run, tmp_path):
    """The birl stage refuses the graph the run made (other MDP settings): no artefact of
    the dir changed, so the earlier run stays complete, timings and all, and can still be
    learned from or deployed, as after the same failure from the command line (it said
    `failed`: an API run writes no .hydra/ files, and only those were looked for)."""
    earlier = shutil.copytree(fast_run.dir, tmp_path / "run")
    before = {name: (earlier / name).read_bytes() for name in ("status.json", "timings.json")}
    with pytest.raises(PipelineError, match="gamma"):
        api.run([*FAST, "stages=[birl,evaluate]", "mdp.gamma=0.5"], run_dir=earlier)
    assert {name: (earlier / name).read_bytes() for name in before} == before
    assert api.open_run(earlier).status.complete


def signal_once_running(run_dir: Path, signum: int) -> None:
    """Send this process `signum` from a thread as soon as the run in `run_dir` has begun
    its stages (status.json says running, at a stage: it says running before the first
    stage begins, and a signal there stops the run "before the first stage")."""
    def send() -> None:
        for _ in range(6000):
            status = read_status(run_dir)
            if status.state == "running" and status.stage is not None:
                os.kill(os.getpid(), signum)
                return
            time.sleep(0.005)

    threading.Thread(target=send, daemon=True).start()


def test_ctrl_c_during_an_api_run_is_a_keyboard_interrupt_naming_the_stage(tmp_path):
    """A notebook's interrupt (SIGINT) once the run has begun its stages: KeyboardInterrupt,
    which `except KeyboardInterrupt` catches, saying where it stopped, as status.json does
    (it was the pipeline's own exception, printed as "(2, None, None)")."""
    run_dir = tmp_path / "run"
    signal_once_running(run_dir, signal.SIGINT)
    with pytest.raises(KeyboardInterrupt, match=r"^interrupted by the user at stage \w+$") \
            as stopped:
        # a graph that takes far longer to grow than the signal to come: under load the
        # quick run once finished before it did
        api.run([*FAST, "graph.max_nodes=5000"], run_dir=run_dir)
    status = read_status(run_dir)
    assert status.state == "interrupted" and str(stopped.value) == status.error


def test_an_api_run_under_nohup_is_not_stopped_by_a_hangup(tmp_path):
    """A process that ignores SIGHUP (`nohup python script.py`, so that closing the terminal
    does not stop it) keeps ignoring it during a run: it stopped the run `interrupted`."""
    run_dir = tmp_path / "run"
    previous = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        signal_once_running(run_dir, signal.SIGHUP)
        run = api.run(list(FAST), run_dir=run_dir)
        assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGHUP, previous)
    assert run.status.complete


def test_an_api_run_inside_the_callers_own_hydra(tmp_path):
    """A notebook's own `hydra.initialize()` (or a script under `@hydra.main`) holds Hydra's
    one global state: api.run composes its config beside it and gives it back (it raised
    Hydra's "ValueError: GlobalHydra is already initialized")."""
    from hydra import compose, initialize_config_dir

    conf = tmp_path / "conf"
    conf.mkdir()
    (conf / "mine.yaml").write_text("x: 1\n")
    with initialize_config_dir(config_dir=str(conf), version_base="1.3"):
        run = api.run(["stages=[scene]"], run_dir=tmp_path / "run")
        assert compose(config_name="mine").x == 1  # the caller's Hydra, as it was
    assert run.status.complete


def test_api_runs_in_threads_each_get_their_own_run(tmp_path):
    """Hydra keeps one global state per process: runs started together in threads take
    turns composing their configs (two of three raised Hydra's ValueError)."""
    start = threading.Barrier(3)
    outcome: dict[int, object] = {}

    def job(seed: int) -> None:
        start.wait()
        try:
            outcome[seed] = api.run([f"seed={seed}", "stages=[scene]"],
                                    run_dir=tmp_path / str(seed)).config.seed
        except Exception as e:  # noqa: BLE001 - the test reports it
            outcome[seed] = e

    threads = [threading.Thread(target=job, args=(seed,)) for seed in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert outcome == {0: 0, 1: 1, 2: 2}


def test_an_api_run_of_a_sweep_preset_warns_that_it_is_one_job(tmp_path, caplog):
    """api.run(["experiment=quick"]) runs one job: its sweep over seed and reward was dropped
    without a word."""
    run = api.run(["experiment=quick", "stages=[scene]"], run_dir=tmp_path / "run")
    assert run.status.complete and run.config.seed == 0
    warned = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len(warned) == 1 and "the config sweeps seed: 0,1; reward: polite,rude" in \
        warned[0] and "pipeline.api.sweep()" in warned[0], warned
    assert "hydra" not in run.config  # the job's config, as birlg's


def test_an_api_run_writes_the_artefacts_birlg_writes(tmp_path):
    """The same overrides give the same artefact bytes from pipeline.api and from birlg (the
    config each artefact records included)."""
    overrides = ["graph=small", "stages=[scene,demos]", "seed=4"]
    cli = run_app(*overrides, f"hydra.run.dir={tmp_path / 'cli'}")
    assert cli.returncode == 0, cli.stderr
    api.run(overrides, run_dir=tmp_path / "api")
    for name in ("scene.mcap", "demos.mcap"):
        assert (tmp_path / "api" / name).read_bytes() == (tmp_path / "cli" / name).read_bytes()


def test_load_scene_reads_a_scene_file_from_any_directory(tmp_path, monkeypatch):
    """api.load_scene looks a relative path up as scene.path does: the current directory
    first, then the package's data/ (the docs' example failed outside the repository)."""
    monkeypatch.chdir(tmp_path)
    shipped = api.load_scene("data/scenes/metropolis.json")
    assert shipped.persons == build.scene_file(str(ROOT / "data/scenes/metropolis.json")).persons
    assert len(shipped.persons) == 12
    mine = tmp_path / "data" / "scenes" / "metropolis.json"  # a user's own file of that name
    mine.parent.mkdir(parents=True)
    text = json.loads((ROOT / "data/scenes/metropolis.json").read_text())
    text["persons"] = text["persons"][:1]
    text["relations"] = []
    mine.write_text(json.dumps(text))
    assert len(api.load_scene("data/scenes/metropolis.json").persons) == 1
    with pytest.raises(PipelineError, match="scene file nope.json not found"):
        api.load_scene("nope.json")


def test_open_run_reads_an_existing_dir(fast_run, tmp_path):
    again = api.open_run(str(fast_run.dir))
    assert again == fast_run and again.metrics == fast_run.metrics
    assert all(np.array_equal(a, b) for a, b in
               zip(again.paths().values(), fast_run.paths().values(), strict=True))
    with pytest.raises(PipelineError, match="not found"):
        api.open_run(tmp_path / "missing")
    only_scene = api.run(["stages=[scene]"], run_dir=tmp_path / "only_scene")
    assert only_scene.metrics == {} and api.open_run(tmp_path / "only_scene").metrics == {}
    assert only_scene.config.stages == ["scene"]
    with pytest.raises(ArtefactError, match="eval.mcap not found"):
        only_scene.paths()
    scene = raw(only_scene.dir, "scene", topics.SCENE)[0]
    try:  # the scene alone: room, links, starts, goal
        assert len(only_scene.plot().lines) == 1 + len(scene["relations"]) + 2
    finally:
        plt.close("all")


def test_a_run_dir_under_home_is_read_as_a_shell_reads_it(fast_run, tmp_path, monkeypatch):
    """"~/runs/x" was a dir named "~" in the working directory."""
    monkeypatch.setenv("HOME", str(fast_run.dir.parent))
    monkeypatch.chdir(tmp_path)
    assert api.open_run(f"~/{fast_run.dir.name}").dir == fast_run.dir
    assert api.Run(f"~/{fast_run.dir.name}").metrics == fast_run.metrics


def test_sweep_reads_a_multirun_with_a_failed_job(tmp_path):
    result = run_app("-m", "graph=small", "birl.n_iterations=2", "scene.body_radius=0.25,-1",
                     f"hydra.sweep.dir={tmp_path}")
    assert result.returncode == 1, result.stderr[-2000:]  # the second job fails
    table = api.sweep(tmp_path)
    # the job, its outcome, the overrides alphabetically, then the metrics
    assert list(table.columns[:6]) == ["job", "status", "error", "birl.n_iterations", "graph",
                                       "scene.body_radius"]
    # as pd.read_csv reads summary.csv: numbers as numbers (strings made `seed == 0` match
    # no row), a missing value NaN
    assert table["scene.body_radius"].tolist() == [0.25, -1.0]
    assert table.columns[6] == "policy_loss_norm"  # every metric after the settings
    assert table["job"].tolist() == [0, 1] and table.status.tolist() == ["ok", "failed"]
    assert np.isnan(table.error.iloc[0])
    assert "scene.body_radius=-1" in table.error.iloc[1]
    metrics = api.open_run(tmp_path / "0").metrics
    row = table.iloc[0]
    assert all(row[k] == v for k, v in metrics.items())
    assert np.isnan(table.policy_loss_norm.iloc[1])
    with pytest.raises(PipelineError, match="holds no Hydra jobs"):
        api.sweep(tmp_path / "0" / ".hydra")
    with pytest.raises(PipelineError, match="not found"):
        api.sweep(tmp_path / "missing")
    # the sweep dir is no run (its metrics read as {}, "not evaluated yet")
    with pytest.raises(PipelineError, match="is a sweep dir, not a run dir"):
        api.open_run(tmp_path)
    # a job whose metrics.json went missing since it completed, and a job dir deleted after
    # the sweep, are failed rows (the deleted one was no row at all)
    (tmp_path / "0" / "metrics.json").rename(tmp_path / "metrics.json.kept")
    with pytest.raises(PipelineError, match="its run completed but metrics.json is gone"):
        _ = api.open_run(tmp_path / "0").metrics
    (tmp_path / "1" / ".hydra" / "overrides.yaml").unlink()
    assert api.sweep(tmp_path).error.tolist() == [
        "no metrics.json (stage evaluate was not run)",
        "its .hydra/overrides.yaml is gone (deleted after the sweep)"]
    shutil.rmtree(tmp_path / "1")
    table = api.sweep(tmp_path)
    assert table["job"].tolist() == [0, 1] and table.status.tolist() == ["failed", "failed"]
    assert table.error.tolist() == ["no metrics.json (stage evaluate was not run)",
                                    "its job dir is gone (deleted or moved after the sweep)"]
    # a run into the sweep's dir would make it a run dir, whose jobs no table could list
    result = run_app("graph=small", "stages=[scene]", f"hydra.run.dir={tmp_path}")
    assert result.returncode == 2
    assert f"{tmp_path} is a sweep's dir (it has sweep.json" in result.stderr.splitlines()[-1]
    with pytest.raises(PipelineError, match="is a sweep's dir"):
        api.run(["graph=small", "stages=[scene]"], run_dir=tmp_path)
    assert not (tmp_path / ".hydra").exists() and not (tmp_path / "scene.mcap").exists()
    # and a sweep into a run's dir is refused too (an API run: no .hydra/)
    single = api.run(["graph=small", "stages=[scene]"], run_dir=tmp_path / "single")
    result = run_app("-m", "graph=small", "seed=0,1", f"hydra.sweep.dir={single.dir}")
    assert result.returncode == 2
    assert f"{single.dir} is a run dir (it has status.json)" in result.stderr.splitlines()[-1]
    assert not (single.dir / "0").exists()


def optimal_expert(scene, overrides=()):
    """The default expert's demonstrations, made in memory: greedy paths under the true
    weights on the reference roadmap (what the demos stage writes)."""
    cfg = load_settings(api.compose_config(list(overrides)))
    roadmap = build.reference_roadmap(cfg, scene, build.feature_model(cfg, scene))
    mdp = roadmap.mdp(cfg.mdp)
    return optimal_demos(mdp, roadmap.positions, roadmap.start_nodes,
                         mdp.solve(np.asarray(cfg.reward.weights, float)))


def birl_weights(run_dir):
    return [np.asarray(m["weights"]) for m in raw(run_dir, "birl", topics.BIRL_ITERATION)]


@pytest.mark.parametrize("method, settings", [("map", {}), ("maxent", {}),
                                              ("map", {"grow_nodes": 10})])
def test_learn_in_memory_gives_the_weights_of_the_pipeline(fast_run, metropolis, tmp_path,
                                                           method, settings):
    # The pipeline: the fast run itself; its birl stage again with grown nodes; MaxEnt (its
    # own weight box: the graph grows under another prior mean) from the start.
    run_dir = fast_run.dir
    if method != "map":
        run_dir = api.run([*FAST, f"birl={method}"], run_dir=tmp_path).dir
    elif settings:
        run_dir = api.run([*FAST, *(f"birl.{k}={v}" for k, v in settings.items()),
                           "stages=[birl]", f"from_run={fast_run.dir}"], run_dir=tmp_path).dir
    # In memory: the scene file's Scene and the optimal expert's demonstrations.
    learned = api.learn(metropolis, optimal_expert(metropolis), method=method,
                        overrides=["graph=small"], n_iterations=3, **settings)
    expected = birl_weights(run_dir)
    # the birl stage alone from an earlier run left a complete run dir (graph.mcap linked)
    assert {"scene.mcap", "demos.mcap", "graph.mcap", "birl.mcap"} <= \
        {p.name for p in run_dir.iterdir()}
    assert np.array_equal(learned.weights, expected[-1])  # to the bit
    assert all(np.array_equal(a, b) for a, b in
               zip(learned.trace["weights"], expected, strict=True))
    assert learned.feature_names == ["relation", "social", "goal_deviation", "length", "crossing"]
    assert learned.trace["iteration"].tolist() == [0, 1, 2, 3]
    n_graph = len(codec.graph_tables(api.artefact(run_dir, "graph"),
                                     api.artefact(run_dir, "birl") if settings else None)[0])
    assert learned.graph.mdp.n_nodes == n_graph


def test_learn_takes_polylines_and_rows_of_an_earlier_run(fast_run):
    scene = fast_run.scene()
    rows = fast_run.messages("demos", topics.DEMOS).to_dict("records")
    from_rows = api.learn(scene, rows, overrides=["graph=small"], n_iterations=3)
    expected = birl_weights(fast_run.dir)[-1]
    assert np.array_equal(from_rows.weights, expected)
    # bare polylines: start index and goal reached found from the scene
    polylines = [r["points"] for r in rows]
    assert np.array_equal(api.learn(scene, polylines, overrides=["graph=small"],
                                    n_iterations=3).weights, expected)
    # another seed draws other initial weights
    other = api.learn(scene, polylines, seed=1, overrides=["graph=small"], n_iterations=3)
    assert not np.array_equal(other.iterations[0].weights, from_rows.iterations[0].weights)


def test_learn_refuses_bad_input(metropolis):
    walk = [[0.5, 0.5], [1.0, 8.0], [5.5, 9.0]]
    with pytest.raises(PipelineError, match="unknown method 'nope'"):
        api.learn(metropolis, [walk], method="nope")
    with pytest.raises(PipelineError, match="config error: birl.nope"):
        api.learn(metropolis, [walk], nope=1)
    with pytest.raises(PipelineError, match="graph.medial_axis=2 is not allowed .*true or false"):
        api.learn(metropolis, [walk], overrides=["graph.medial_axis=2"])  # (omegaconf: true)
    with pytest.raises(PipelineError, match="polyline of at least two"):
        api.learn(metropolis, [np.zeros((1, 2))], overrides=["graph=small"])
    # every mistake is one PipelineError line, not an error from deep inside
    for demos, says in (([], "non-empty list"), ([{"x": 1}], "needs 'points'"),
                        ([{"points": walk, "start_index": -1}], "start_index=-1 is not a start"),
                        ([{"points": walk, "start_index": 99}], "start_index=99 is not a start"),
                        ([{"points": walk, "start_index": 0.0}],  # a wrong type, not a range
                         "demonstration 0: start_index=0.0 must be an integer, not float")):
        with pytest.raises(PipelineError, match=says):
            api.learn(metropolis, demos, overrides=["graph=small"])
    with pytest.raises(PipelineError, match="scene must be a pipeline.core.world.Scene"):
        api.learn(None, [walk])
    with pytest.raises(PipelineError, match=r"overrides must be a list .* not one string"):
        api.learn(metropolis, [walk], overrides="graph=small")
    with pytest.raises(PipelineError, match="seed must be an integer"):
        api.learn(metropolis, [walk], seed="x")
    # a keyword is Python: a number given as a string is refused, as the seed is
    with pytest.raises(PipelineError, match="n_iterations='5' must be an integer, not a string"):
        api.learn(metropolis, [walk], n_iterations="5")


def test_run_refuses_bad_overrides_in_one_line(tmp_path):
    with pytest.raises(PipelineError, match=r"\['seed=1'\], not one string"):
        api.run("seed=1", run_dir=tmp_path)
    with pytest.raises(PipelineError, match="config error: .*nokey"):
        api.run(["nokey=1"], run_dir=tmp_path)


def test_learn_leaves_out_the_rows_a_run_held_out(fast_run):
    """/demos rows marked heldout (evaluate.holdout) never enter learning, as in the run
    (they used to: learn() trained on the test demonstrations)."""
    scene = fast_run.scene()
    rows = fast_run.messages("demos", topics.DEMOS).to_dict("records")
    marked = [dict(r, heldout=k in (1, 4)) for k, r in enumerate(rows)]
    kept = [r for k, r in enumerate(rows) if k not in (1, 4)]
    settings = {"overrides": ["graph=small"], "n_iterations": 2}
    from_marked = api.learn(scene, marked, **settings)
    assert np.array_equal(from_marked.weights, api.learn(scene, kept, **settings).weights)
    assert not np.array_equal(from_marked.weights, api.learn(scene, rows, **settings).weights)
    with pytest.raises(PipelineError, match="all 7 demonstrations are held out"):
        api.learn(scene, [dict(r, heldout=True) for r in rows], **settings)
    # a flag that is no bool is refused, not read as "not held out" (1 and "yes" were)
    for flag in (1, "yes"):
        with pytest.raises(PipelineError, match=rf"demonstration 1: heldout={flag!r} must be "
                                                r"true or false"):
            api.learn(scene, [dict(r, heldout=flag if k == 1 else False)
                              for k, r in enumerate(rows)], **settings)


def test_learn_checks_demonstrations_as_a_demonstration_file_is_checked(metropolis, fast_run):
    """What the file reader refuses or cuts, learn() refuses or cuts (it learned nonsense
    from them, or failed with 'no edge (48, 7)')."""
    walk = [[0.5, 0.5], [1.0, 8.0], [5.5, 9.0]]
    o = ["graph=small"]
    for demos, says in (
            ([[[0.5, 0.5], [0.5, 0.5]]], "demonstration 0 never moves"),
            ([[[-50, -50], [-40, -40], [5.5, 9]]], r"demonstration 0 leaves the room .* at "
                                                   r"\(-50\.00, -50\.00\)"),
            ([[[1e300, 1e300], [5.5, 9]]], r"leaves the room .* at \(1e\+300, 1e\+300\)"),
            ([[[3.0, 5.0], [5.5, 9.0]]], r"demonstration 0: trajectory 0 starts 2.24 m from "
                                         r"the nearest start"),
            ([{"points": walk, "start_index": 3}], "begins at start 0, not at its "
                                                   "start_index=3"),
            ([{"points": walk, "reached": "False"}], "reached='False' must be true or false"),
            ([[[0.5, 0.5], [1.0]]], "demonstration 0 must be a polyline of"),
            (fast_run.messages("demos", topics.DEMOS), "demos is a DataFrame"),
            ({"points": walk}, "not dict"), (None, "not NoneType")):
        with pytest.raises(PipelineError, match=says):
            api.learn(metropolis, demos, overrides=o)
    # a recording that runs on past the goal is cut at the goal disk, as a file's is: it ends
    # at its first point inside the disk, here the run's last roadmap node
    rows = fast_run.messages("demos", topics.DEMOS).to_dict("records")
    ran_on = [np.vstack([r["points"], [[5.52, 9.01], [5.6, 9.2]]]) for r in rows]
    cut = [np.asarray(r["points"], float) for r in rows]
    assert np.array_equal(api.learn(metropolis, ran_on, overrides=o, n_iterations=2).weights,
                          api.learn(metropolis, cut, overrides=o, n_iterations=2).weights)


def test_a_runs_own_demonstrations_in_a_file_learn_the_runs_weights(fast_run, tmp_path):
    """The optimal expert's roadmap paths, saved as a demonstration file (docs/inputs.md) and
    learned from with expert=file and its defaults, give the run's weights bit for bit. They
    learned other weights when the reader ended each path at the goal's centre (0.25 m past
    its last node, a piece no path compared with it has) and read the lattice paths' corners
    as tracking noise and smoothed them."""
    rows = fast_run.messages("demos", topics.DEMOS).to_dict("records")
    path = tmp_path / "own.json"
    path.write_text(json.dumps({"trajectories": [np.asarray(r["points"]).tolist()
                                                 for r in rows]}))
    run = api.run([*FAST, "expert=file", f"expert.path={path}"], run_dir=tmp_path / "run")
    read = run.messages("demos", topics.DEMOS).to_dict("records")
    assert all(np.array_equal(a["points"], b["points"]) for a, b in zip(read, rows, strict=True))
    assert np.array_equal(birl_weights(run.dir)[-1], birl_weights(fast_run.dir)[-1])


def test_learn_with_denoise_reads_noisy_tracks_as_a_demonstration_file(fast_run, tmp_path):
    """With denoise=True, tracked walks learn what the same walks in a file learn with
    expert=file (smoothed of their noise; one ending 2 cm outside the goal disk reaches
    the goal); without, they are taken as given."""
    scene = fast_run.scene()
    rng = np.random.default_rng(0)
    walks = []
    for row in fast_run.messages("demos", topics.DEMOS).to_dict("records"):
        points = np.asarray(row["points"], float)
        length = np.r_[0, np.cumsum(np.hypot(*np.diff(points, axis=0).T))]
        s = np.arange(0.0, length[-1], 0.12)
        dense = np.column_stack([np.interp(s, length, points[:, 0]),
                                 np.interp(s, length, points[:, 1])])
        walks.append(dense + rng.normal(0, 0.02, dense.shape))
    outward = walks[0][-1] - scene.goal  # the first stops 2 cm outside the goal disk
    walks[0] = np.vstack([walks[0][np.linalg.norm(walks[0] - scene.goal, axis=1) >
                                   scene.goal_tolerance + 0.02],
                          scene.goal + outward / np.linalg.norm(outward)
                          * (scene.goal_tolerance + 0.02)])
    walks = [np.round(w, 6) for w in walks]
    path = tmp_path / "walks.json"
    path.write_text(json.dumps({"scene": scene.name,
                                "trajectories": [w.tolist() for w in walks]}))
    o = ["graph=small", "birl.n_iterations=2"]
    run = api.run([*o, "expert=file", f"expert.path={path}"], run_dir=tmp_path / "run")
    from_file = run.messages("demos", topics.DEMOS).to_dict("records")
    # it reaches the goal at the disk's edge, where a path into the disk would end (its
    # coordinates rounded to the nanometre)
    edge_gap = np.linalg.norm(np.asarray(from_file[0]["points"][-1]) - scene.goal)
    assert from_file[0]["reached"] and abs(edge_gap - scene.goal_tolerance) < 1e-9
    denoised = api.learn(scene, walks, overrides=["graph=small"], denoise=True,
                         n_iterations=2)
    assert np.array_equal(denoised.weights, birl_weights(run.dir)[-1])
    as_given = api.learn(scene, walks, overrides=["graph=small"], n_iterations=2)
    assert not np.array_equal(as_given.weights, denoised.weights)
    with pytest.raises(PipelineError, match="denoise='yes' must be true or false"):
        api.learn(scene, walks, denoise="yes")


def test_a_walk_that_stops_short_is_learned_from_as_one_whose_end_was_not_recorded(
        metropolis):
    """One of the 21 hand-drawn walks cut 0.8 m short: read as a walk that gives the goal
    up, it moved the social weight from -0.78 to the box's edge (-1.0, the largest change
    0.26); read as the beginning of a walk to the goal, the weights barely move."""
    walks = [np.asarray(w, float) for w in json.loads(
        (ROOT / "data" / "demos" / "metropolis_handdrawn.json").read_text())["trajectories"]]
    cut = [*walks[:2], walks[2][:-8], *walks[3:]]
    o = ["graph=small"]
    full = api.learn(metropolis, walks, overrides=o, n_iterations=2).weights
    short = api.learn(metropolis, cut, overrides=o, n_iterations=2)
    # the case: that walk ends well outside the goal disk
    assert np.linalg.norm(cut[2][-1] - metropolis.goal) > metropolis.goal_tolerance + 0.5
    assert np.abs(short.weights - full).max() < 0.01


def test_messages_of_the_graph_and_the_roadmap_are_arrays_not_base64(fast_run):
    """Run.messages promised numpy arrays in its cells; the columnar topics' came as base64
    strings of thousands of characters. Each cell now holds its message's values, the same
    as the codec reads."""
    nodes_art = fast_run.artefact("graph")
    nodes = fast_run.messages("graph", topics.GRAPH_NODES)
    table, edge_table = codec.graph_tables(nodes_art)
    assert all(isinstance(x, np.ndarray) and len(x) == n
               for x, n in zip(nodes["x"], nodes["count"], strict=True))
    assert np.array_equal(np.concatenate(list(nodes["x"])), table.pose[:, 0])
    edges = fast_run.messages("graph", topics.GRAPH_EDGES)
    features = np.vstack(list(edges["features"]))
    assert np.array_equal(features, edge_table.features)
    assert np.array_equal(np.vstack(list(edges["waypoints"])), edge_table.waypoints.points)
    roadmap = fast_run.messages("demos", topics.DEMOS_ROADMAP).iloc[0]
    assert roadmap["positions"].shape == (roadmap["n_nodes"], 2)
    assert roadmap["features"].shape == (roadmap["n_edges"], roadmap["n_features"])


def test_learn_refuses_what_run_refuses(metropolis):
    walk = [[0.5, 0.5], [1.0, 8.0], [5.5, 9.0]]
    for kwargs, says in (
            ({"scene": dataclasses.replace(metropolis, relations=((1, 99),))},
             "relation \\[1, 99\\] names unknown person id 99"),
            ({"overrides": ["graph.max_nodes=3"]}, "graph.max_nodes=3 is too few"),
            ({"overrides": ["birl=mcmc"]}, "give it as learn\\(\\)'s method argument"),
            ({"overrides": ["seed=5"]}, "give it as learn\\(\\)'s seed argument"),
            # the keyword won silently over the override
            ({"overrides": ["birl.n_iterations=5"], "n_iterations": 2},
             "birl.n_iterations is given twice, as learn\\(\\)'s keyword n_iterations= and "
             "in overrides")):
        with pytest.raises(PipelineError, match=says):
            api.learn(**{"scene": metropolis, "demos": [walk], **kwargs})


@pytest.mark.parametrize("call, says", [
    (lambda d: api.run([3], run_dir=d), "overrides must be 'key=value' strings: 3 is a int"),
    (lambda d: api.run(["seed=${nope.x}"], run_dir=d), "Interpolation key 'nope.x' not found"),
    # a top-level key interpolating another section's (omegaconf's InterpolationKeyError, from
    # deep inside it) or a number (re's TypeError)
    (lambda d: api.run(["objective=${mdp.gamma}"], run_dir=d),
     "config error: objective=1.0 is not allowed \\(allowed: a metrics.json key"),
    (lambda d: api.run(["objective=${seed}"], run_dir=d),
     "config error: objective=0 is not allowed \\(allowed: a metrics.json key"),
    (lambda d: api.run(["~seed"], run_dir=d), "seed is missing \\(deleted with ~seed\\?\\)"),
    (lambda d: api.run(["hydra.run.dir=/x"], run_dir=d), "hydra.run.dir=/x: Hydra's own settings"),
    # a Hydra config group: `hydra/job_logging=disabled` ran without a word
    (lambda d: api.run(["hydra/job_logging=disabled"], run_dir=d),
     "hydra/job_logging=disabled: Hydra's own settings \\(hydra.\\*, hydra/...\\) have no effect"),
    # said as birlg says it: what was wrong with the value too (its cause), not only where
    (lambda d: api.run(["birl.beta=abc"], run_dir=d), "config error: Error merging override "
     "birl.beta=abc \\(Value 'abc' of type 'str' could not be converted to Float\\)"),
    (lambda d: api.run([], run_dir=""), "run_dir='': a path to a dir"),
    (lambda d: api.open_run(None), "run_dir=None: a path to a dir"),
    (lambda d: api.open_run(Path(__file__)), "is not a dir"),
    # a mistyped path read as a run without metrics; an empty dir opened as a run
    (lambda d: api.Run(d).metrics, "run dir .*run not found"),
    (lambda d: api.Run(d).status, "run dir .*run not found"),
    (lambda d: api.artefact(d, "scene"), "run dir .*run not found"),
    (lambda d: api.open_run(d.parent), "holds no run \\(no status.json, artefact or "
     "\\.hydra/config.yaml\\)"),
])
def test_bad_api_arguments_are_one_line_naming_them(tmp_path, call, says):
    with pytest.raises(PipelineError, match=says):
        call(tmp_path / "run")
    assert not (tmp_path / "run").exists()  # refused before anything was written


def test_a_run_dirs_damaged_config_or_metrics_is_one_line(tmp_path):
    (tmp_path / ".hydra").mkdir()
    (tmp_path / ".hydra" / "config.yaml").write_text("seed: [")
    (tmp_path / "metrics.json").write_text('{"a": 1,')
    handle = api.Run(str(tmp_path))  # a str, as the docstrings write it
    with pytest.raises(PipelineError, match="config.yaml cannot be read"):
        _ = handle.config
    with pytest.raises(PipelineError, match="metrics.json cannot be read"):
        _ = handle.metrics
    (tmp_path / ".hydra" / "config.yaml").write_text("- 1\n- 2\n")
    (tmp_path / "metrics.json").write_text("[1, 2]")
    with pytest.raises(PipelineError, match="is not a config"):
        _ = handle.config
    with pytest.raises(PipelineError, match="is not an object of metrics"):
        _ = handle.metrics


def test_another_stages_artefact_under_a_stages_file_name_is_refused(fast_run, tmp_path):
    """scene.mcap copied over eval.mcap was read as the evaluate stage's artefact."""
    shutil.copytree(fast_run.dir, tmp_path / "run")
    shutil.copy(tmp_path / "run" / "scene.mcap", tmp_path / "run" / "eval.mcap")
    mixed = api.open_run(tmp_path / "run")
    with pytest.raises(ArtefactError, match="eval.mcap has no topic '/eval/metrics'"):
        mixed.paths()
    assert mixed.artefact("scene").one(topics.SCENE) == fast_run.artefact("scene").one(topics.SCENE)


def test_learn_with_the_default_graph_size_gives_the_default_runs_weights(default_run):
    """graph.max_nodes is null by default (derived from the scene at start-up); learn() took
    it as given and failed with a TypeError unless an override set a size."""
    run = api.open_run(default_run[0])
    rows = run.messages("demos", topics.DEMOS).to_dict("records")
    learned = api.learn(run.scene(), rows)
    assert learned.graph.mdp.n_nodes == run.config.graph.max_nodes == 460
    assert np.array_equal(learned.weights, birl_weights(run.dir)[-1])


def test_learning_from_a_held_out_runs_rows_gives_its_weights(tmp_path):
    settings = ["graph=small", "birl.alternatives=graph", "evaluate.holdout=0.5",
                "expert=boltzmann", "expert.demos_per_start=2"]
    run = api.run([*settings, "birl.n_iterations=3"], run_dir=tmp_path)
    rows = run.messages("demos", topics.DEMOS).to_dict("records")
    assert 0 < sum(r["heldout"] for r in rows) < len(rows)
    learned = api.learn(run.scene(), rows, overrides=settings, n_iterations=3)
    assert np.array_equal(learned.weights, birl_weights(run.dir)[-1])


def test_plot_of_a_wide_room_is_page_wide_and_shows_held_out_walks_apart(tmp_path):
    """A 12 x 3 m hallway is drawn page wide, about as high as its shape (in a column's
    portrait figure it was a thin strip), a square room a column wide; held-out
    demonstrations are dotted in their own colour with their own legend entry."""
    from pipeline.app.figure_style import COLUMN_IN, PAGE_IN
    from pipeline.app.figures import AROUND_IN, BESIDE_IN, SCENE_COLOURS

    hall = api.run(["stages=[scene,demos]", "scene=hallway", "expert=planner",
                    "expert.n_subjects=2", "evaluate.holdout=[s1]"], run_dir=tmp_path / "hall")
    demos = raw(hall.dir, "demos", topics.DEMOS)
    held = [d for d in demos if d["heldout"]]
    assert held and len(held) < len(demos)
    try:
        ax = hall.plot()
        width, height = ax.figure.get_size_inches()
        assert width == PAGE_IN
        assert height == pytest.approx((PAGE_IN - BESIDE_IN) * 3 / 12 + AROUND_IN)
        dotted = [line for line in ax.lines if line.get_linestyle() == ":"]
        assert len(dotted) == len(held)
        assert {matplotlib.colors.to_hex(line.get_color()) for line in dotted} == \
            {SCENE_COLOURS["heldout"].lower()}
        assert [t.get_text() for t in ax.get_legend().get_texts()].count("held out") == 1
        square = api.run(["stages=[scene]"], run_dir=tmp_path / "square").plot()
        assert square.figure.get_size_inches()[0] == COLUMN_IN
    finally:
        plt.close("all")
