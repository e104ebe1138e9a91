"""The offline viewer: a real run turned into an .rrd, read back with rerun's own reader."""

import os
import subprocess
import sys
from collections import defaultdict

import numpy as np
import pytest
from rerun.chunk import RrdReader
from rerun.error_utils import RerunWarning

from pipeline.artefacts import ArtefactError, codec, read_artefact
from pipeline.errors import PipelineError
from pipeline.tools.viewer import build_recording
from tests.conftest import ROOT, run_in_process

SPATIAL = ["/scene/room", "/scene/persons", "/scene/person_heading", "/scene/links",
           "/scene/starts", "/scene/goal", "/demos/trajectories", "/graph/nodes",
           "/graph/edges", "/graph/best_paths", "/birl/learned_paths", "/eval/paths"]
STATIC = ["/scene/room", "/scene/persons", "/scene/person_heading", "/scene/links",
          "/scene/starts", "/scene/goal", "/demos/trajectories", "/eval/paths"]


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("viewer_run")
    run_in_process(d, "graph=small", "birl.n_iterations=4")
    return d


@pytest.fixture(scope="module")
def rrd(run_dir):
    import warnings
    with warnings.catch_warnings():  # rerun reports bad data as warnings unless strict
        warnings.simplefilter("error", RerunWarning)
        return build_recording(run_dir)


def chunks_by_entity(path, store=None):
    """entity path -> list of (is_static, arrow record batch), one per chunk."""
    reader = RrdReader(path)
    out = defaultdict(list)
    for ch in reader.stream(store=store):
        out[ch.entity_path].append((ch.is_static, ch.to_record_batch()))
    return out


def column(chunks, name):
    """Values of a column over the chunks that have it (a curve's static style chunk has
    no timeline column)."""
    return [v for _, rb in chunks if name in rb.schema.names for v in rb.column(name).to_pylist()]


def test_rrd_has_the_entities_timelines_and_no_temp_file(run_dir, rrd):
    assert rrd == run_dir / "run.rrd" and rrd.stat().st_size > 0
    assert not list(run_dir.glob("*.tmp"))
    reader = RrdReader(rrd)
    (rec,) = reader.recordings()
    assert rec.application_id == "birlg"
    schema = reader.store().schema()
    paths = set(schema.entity_paths())
    assert set(SPATIAL) <= paths
    assert {"/curves/policy_loss/graph", "/curves/policy_loss/ref", "/curves/policy_loss/norm",
            "/curves/log_posterior"} <= paths
    assert {c.name for c in schema.index_columns()} >= {"iteration", "birl_iteration"}
    chunks = chunks_by_entity(rrd)
    for p in STATIC:
        assert all(static for static, _ in chunks[p]), p
    persons = read_artefact(run_dir / "scene.mcap").one("/scene")["persons"]
    assert column(chunks["/scene/persons"], "Points2D:labels")[0] == \
        [str(p["id"]) for p in persons]


def test_graph_growth_replays_one_step_per_best_paths_message(run_dir, rrd):
    graph = read_artefact(run_dir / "graph.mcap")
    nodes, edges = codec.decode_nodes(graph), codec.decode_edges(graph)
    chunks = chunks_by_entity(rrd)
    best = graph.all("/graph/best_paths")
    steps = column(chunks["/graph/best_paths"], "iteration")
    assert len(set(steps)) == len(steps) == len(best)
    # nodes are cumulative: each step shows the nodes added up to its iteration
    logged = column(chunks["/graph/nodes"], "Points2D:positions")
    at = column(chunks["/graph/nodes"], "iteration")
    assert len(logged[-1]) == len(nodes)
    for k, points in zip(at, logged, strict=True):
        np.testing.assert_allclose(points, nodes.positions[nodes.added_at <= k] * [1, -1],
                                   rtol=1e-6)
    # edges are logged once each, at the iteration that added them
    strips = column(chunks["/graph/edges"], "LineStrips2D:strips")
    edge_steps = column(chunks["/graph/edges"], "iteration")
    assert sum(len(s) for s in strips) == len(edges)
    assert [len(s) for s in strips] == [np.count_nonzero(edges.added_at == k) for k in edge_steps]


def test_curves_have_one_value_per_birl_iteration(run_dir, rrd):
    birl = read_artefact(run_dir / "birl.mcap")
    its = birl.all("/birl/iteration")
    names = birl.one("/birl/expert")["feature_names"]
    chunks = chunks_by_entity(rrd)
    for i, name in enumerate(names):
        series = chunks[f"/curves/weights/{name}"]
        assert column(series, "birl_iteration") == [it["index"] for it in its]
        got = [v[0] for v in column(series, "Scalars:scalars")]
        np.testing.assert_allclose(got, [it["weights"][i] for it in its])
    assert len(column(chunks["/curves/log_posterior"], "Scalars:scalars")) == len(its)
    assert len(column(chunks["/birl/learned_paths"], "birl_iteration")) == len(its)
    losses = read_artefact(run_dir / "eval.mcap").all("/eval/policy_loss")
    got = [v[0] for v in column(chunks["/curves/policy_loss/graph"], "Scalars:scalars")]
    np.testing.assert_allclose(got, [m["graph"] for m in losses])


def test_blueprint_has_a_2d_view_beside_time_series(rrd):
    reader = RrdReader(rrd)
    (bp,) = reader.blueprints()
    views, queries = {}, {}
    for path, chunks in chunks_by_entity(rrd, store=bp).items():
        names = chunks[0][1].schema.names
        if "ViewBlueprint:class_identifier" in names:
            views[path] = (column(chunks, "ViewBlueprint:class_identifier")[0][0],
                           column(chunks, "ViewBlueprint:space_origin")[0][0])
        if "ViewContents:query" in names:
            queries[path.removesuffix("/ViewContents")] = column(chunks, "ViewContents:query")[0]
    kinds = sorted(views.values())
    assert kinds == [("2D", "/"), ("2D", "/"), ("TextDocument", "/legend"),
                     ("TimeSeries", "/curves/log_posterior"),
                     ("TimeSeries", "/curves/policy_loss"), ("TimeSeries", "/curves/weights")]
    learning, growth = sorted((p for p, v in views.items() if v[0] == "2D"),
                              key=lambda p: "- /curves/**" not in queries[p])
    # One view shows scene, final graph, BIRL paths and (beside it) curves on one timeline;
    # the growth replay has its own view.
    assert "- /curves/**" in queries[learning] and "- /graph/nodes" in queries[learning]
    assert "+ /graph/nodes" in queries[growth] and "+ /scene/**" in queries[growth]
    timelines = [v for chunks in chunks_by_entity(rrd, store=bp).values()
                 for _, rb in chunks for name in rb.schema.names if name.endswith(":timeline")
                 for v in rb.column(name).to_pylist()]
    assert timelines == [["birl_iteration"]]  # the time panel opens on the BIRL timeline


def test_scene_is_drawn_y_up_and_the_final_graph_is_static(run_dir, rrd):
    chunks = chunks_by_entity(rrd)
    persons = read_artefact(run_dir / "scene.mcap").one("/scene")["persons"]
    logged = np.array(column(chunks["/scene/persons"], "Points2D:positions")[0])
    # rerun's 2-D views draw y down: y is logged negated so the goal is at the top
    np.testing.assert_allclose(logged, [(p["x"], -p["y"]) for p in persons], rtol=1e-6)
    graph = read_artefact(run_dir / "graph.mcap")
    assert all(static for static, _ in chunks["/graph/final/nodes"])
    final = column(chunks["/graph/final/nodes"], "Points2D:positions")[0]
    assert len(final) == len(codec.decode_nodes(graph))


def test_curves_have_distinct_colours(rrd):
    chunks = chunks_by_entity(rrd)
    colours = {p: column(c, "SeriesLines:colors")[0][0] for p, c in chunks.items()
               if p.startswith("/curves/")}
    losses = [colours[f"/curves/policy_loss/{k}"] for k in ("graph", "ref", "norm")]
    weights = [c for p, c in colours.items() if p.startswith("/curves/weights/")]
    assert len(set(losses)) == 3 and len(set(weights)) == len(weights) == 5


def test_only_the_scene_is_required_and_what_is_missing_is_said(run_dir, tmp_path, capsys):
    (tmp_path / "scene.mcap").write_bytes((run_dir / "scene.mcap").read_bytes())
    out = build_recording(tmp_path, tmp_path / "only_scene.rrd")
    paths = set(RrdReader(out).store().schema().entity_paths())
    assert "/scene/persons" in paths and "/graph/nodes" not in paths
    note = capsys.readouterr().err
    assert "has no demos.mcap, graph.mcap, birl.mcap, eval.mcap (stages not run)" in note


def test_missing_scene_is_an_error_and_a_truncated_artefact_is_left_out(run_dir, tmp_path,
                                                                        capsys):
    with pytest.raises(ArtefactError, match="scene.mcap"):
        build_recording(tmp_path)
    with pytest.raises(PipelineError, match="run dir .*nope not found"):
        build_recording(tmp_path / "nope")
    assert not list(tmp_path.glob("*.rrd*"))
    for name in ("scene.mcap", "demos.mcap", "birl.mcap", "eval.mcap"):
        (tmp_path / name).write_bytes((run_dir / name).read_bytes())
    data = (run_dir / "graph.mcap").read_bytes()
    (tmp_path / "graph.mcap").write_bytes(data[: len(data) // 2])
    out = build_recording(tmp_path)  # the rest is shown, the truncated one named
    warning = capsys.readouterr().err
    assert "graph.mcap" in warning and "truncated" in warning and "leaves it out" in warning
    paths = set(RrdReader(out).store().schema().entity_paths())
    assert "/graph/nodes" not in paths
    assert {"/scene/persons", "/demos/trajectories", "/eval/paths"} <= paths


def _cli(*args):
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    return subprocess.run([sys.executable, "-m", "pipeline.tools.viewer", *map(str, args)],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=120,
                          check=False)


def test_cli_writes_the_rrd_and_says_how_to_open_it(run_dir, tmp_path):
    out = tmp_path / "cli.rrd"
    res = _cli(run_dir, "--out", out, "--no-open")
    assert res.returncode == 0, res.stderr
    assert out.stat().st_size > 0
    assert f"wrote {out}; open it with: " in res.stdout and str(out) in res.stdout.splitlines()[-1]


@pytest.mark.skipif(sys.platform == "darwin", reason="macOS always counts as having a display")
def test_cli_without_a_display_only_writes_the_file(run_dir, tmp_path):
    out = tmp_path / "nodisplay.rrd"
    res = _cli(run_dir, "--out", out)
    assert res.returncode == 0, res.stderr
    assert out.exists() and "open it with: " in res.stdout


def test_cli_error_is_one_line_and_exit_2(tmp_path):
    res = _cli(tmp_path, "--no-open")
    assert res.returncode == 2
    assert res.stderr.startswith("error: ") and "scene.mcap" in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1 and "Traceback" not in res.stderr


def test_a_map_scene_draws_the_obstacle_outlines(tmp_path):
    run_in_process(tmp_path, "scene=office", "stages=[scene]")
    rrd = build_recording(tmp_path)
    outlines = chunks_by_entity(rrd)["/scene/obstacles"]
    (strips,) = column(outlines, "LineStrips2D:strips")  # one row holding every strip
    assert len(strips) > 10  # outer walls, room walls, furniture
    # every outline point lies on the map (20 x 14 m, outlines half a cell outside at most)
    points = np.array([p for strip in strips for p in strip]) * [1, -1]  # logged y-up
    assert points.min() >= -0.05 and points[:, 0].max() <= 20.05 and points[:, 1].max() <= 14.05


def test_an_interrupted_run_is_shown_with_a_warning(run_dir, tmp_path):
    import shutil

    from pipeline.artefacts.store import write_json_atomic

    copy = tmp_path / "copy"
    shutil.copytree(run_dir, copy)
    write_json_atomic(copy / "status.json", {"state": "running", "stage": "birl"})
    res = _cli(copy, "--out", tmp_path / "x.rrd", "--no-open")
    assert res.returncode == 0, res.stderr
    assert res.stderr.startswith("warning: ") and "interrupted at stage birl" in res.stderr
    clean = _cli(run_dir, "--out", tmp_path / "y.rrd", "--no-open")
    assert "warning" not in clean.stderr
    (copy / "status.json").write_text("{x")  # damaged: said, not taken as complete
    res = _cli(copy, "--out", tmp_path / "z.rrd", "--no-open")
    assert res.returncode == 0 and res.stderr.startswith(
        f"warning: run dir {copy} has an unreadable status.json"), res.stderr


def test_a_viewer_that_dies_is_reported(tmp_path):
    from pipeline.tools.viewer import open_viewer

    rrd = tmp_path / "x.rrd"
    rrd.write_bytes(b"")
    crash = [sys.executable, "-c", "import sys; sys.exit('no display server found')"]
    assert open_viewer(crash, rrd, grace_s=60) == 1  # (returns when it dies: a loaded machine)
    assert "no display server found" in (tmp_path / "x.viewer.log").read_text()
    stays = [sys.executable, "-c", "import time; time.sleep(3)"]
    assert open_viewer(stays, rrd, grace_s=0.5) == 0


def test_mcmc_run_shows_paths_under_posterior_samples(tmp_path):
    run_in_process(tmp_path, "graph=small", "birl=mcmc", "birl.n_iterations=2",
                   "birl.n_samples=40", "birl.burn_in=20", "birl.n_chains=2")
    chunks = chunks_by_entity(build_recording(tmp_path))
    assert "/birl/posterior_paths" in chunks
    strips = column(chunks["/birl/posterior_paths"], "LineStrips2D:strips")
    assert len(strips) == 1 and len(strips[0]) == 6 * 7  # 6 posterior samples x 7 starts
    # above the wide final paths, which hid them entirely
    assert column(chunks["/birl/posterior_paths"], "LineStrips2D:draw_order")[0][0] > \
        column(chunks["/eval/paths"], "LineStrips2D:draw_order")[0][0]


def rgb(packed: int) -> tuple[int, int, int]:
    """An arrow-stored colour (0xRRGGBBAA) as (r, g, b)."""
    return (packed >> 24) & 255, (packed >> 16) & 255, (packed >> 8) & 255


def blueprint_views(rrd) -> dict[str, dict[str, list]]:
    """Each view's space origin -> its blueprint components (column -> first row's value),
    the view's own and those of its properties (axes, legend)."""
    reader = RrdReader(rrd)
    (bp,) = reader.blueprints()
    by_view: dict[str, dict[str, list]] = defaultdict(dict)
    for path, chunks in chunks_by_entity(rrd, store=bp).items():
        if path.startswith("/view/"):
            view = path.split("/")[2]
            for name in chunks[0][1].schema.names:
                if ":" in name:
                    by_view[view][name] = column(chunks, name)[0]
    return {v["ViewBlueprint:space_origin"][0]: v for v in by_view.values()
            if "ViewBlueprint:space_origin" in v and v["ViewBlueprint:class_identifier"][0]
            != "2D"}


def test_the_legend_names_every_kind_of_entity(rrd):
    chunks = chunks_by_entity(rrd)
    (text,) = column(chunks["/legend"], "TextDocument:text")
    assert all(static for static, _ in chunks["/legend"])
    assert column(chunks["/legend"], "TextDocument:media_type") == [["text/markdown"]]
    for thing in ("persons", "heading", "social links", "obstacles", "starts", "goal",
                  "demonstrations", "held-out", "final learned paths",
                  "learned paths at the BIRL iteration",
                  "posterior", "nodes and edges"):
        assert thing in text[0], thing
    assert "/legend" in blueprint_views(rrd)


def test_labels_are_light_and_below_their_discs(run_dir, rrd):
    from pipeline.tools.viewer import LABEL, LABEL_GAP, START_RADIUS

    scene = read_artefact(run_dir / "scene.mcap").one("/scene")
    chunks = chunks_by_entity(rrd)
    # The discs keep their labels (hover) but do not draw them: their colour on their colour.
    for disc in ("/scene/persons", "/scene/starts", "/scene/goal"):
        assert column(chunks[disc], "Points2D:show_labels") == [[False]], disc
    persons = scene["persons"]
    texts = column(chunks["/scene/labels"], "Points2D:labels")[0]
    assert texts == [str(p["id"]) for p in persons] + \
        [f"s{k}" for k in range(len(scene["starts"]))] + ["goal"]
    assert {rgb(c) for c in column(chunks["/scene/labels"], "Points2D:colors")[0]} == {LABEL}
    assert column(chunks["/scene/labels"], "Points2D:show_labels") == [[True]]
    below = [(p["x"], p["y"] - scene["body_radius"] - LABEL_GAP) for p in persons] + \
        [(x, y - START_RADIUS - LABEL_GAP) for x, y in scene["starts"]] + \
        [(scene["goal"][0], scene["goal"][1] - scene["goal_tolerance"] - LABEL_GAP)]
    np.testing.assert_allclose(column(chunks["/scene/labels"], "Points2D:positions")[0],
                               np.array(below) * [1, -1], rtol=1e-6)


def test_demonstrations_are_drawn_above_the_learned_paths(rrd):
    chunks = chunks_by_entity(rrd)

    def drawn(path):
        return (column(chunks[path], "LineStrips2D:draw_order")[0][0],
                column(chunks[path], "LineStrips2D:radii")[0][0])

    (demos, demo_radius), (learned, learned_radius), (final, final_radius) = (
        drawn(p) for p in ("/demos/trajectories", "/birl/learned_paths", "/eval/paths"))
    assert demos > learned > final  # the final paths widest and lowest, all three visible
    assert demo_radius < learned_radius < final_radius


def test_true_weights_are_reference_lines_beside_the_weights(run_dir, rrd):
    expert = read_artefact(run_dir / "demos.mcap").one("/demos/expert")
    true = dict(zip(expert["feature_names"], expert["true_weights"], strict=True))
    its = read_artefact(run_dir / "birl.mcap").all("/birl/iteration")
    chunks = chunks_by_entity(rrd)
    for name, w in true.items():
        series = chunks[f"/curves/weights_true/{name}"]
        assert column(series, "birl_iteration") == [it["index"] for it in its]
        np.testing.assert_allclose([v[0] for v in column(series, "Scalars:scalars")],
                                   [w] * len(its))
        assert column(series, "SeriesLines:names") == [[f"{name} (true)"]]
    weights = blueprint_views(rrd)["/curves/weights"]
    assert "+ /curves/weights_true/**" in weights["ViewContents:query"]


def test_a_run_without_true_weights_has_no_reference_lines(run_dir, tmp_path):
    for name in ("scene", "graph", "birl", "eval"):  # no demos.mcap: no expert, no w*
        (tmp_path / f"{name}.mcap").write_bytes((run_dir / f"{name}.mcap").read_bytes())
    paths = set(RrdReader(build_recording(tmp_path)).store().schema().entity_paths())
    assert "/curves/weights/relation" in paths
    assert not any(p.startswith("/curves/weights_true") for p in paths)


def test_curve_axes_span_every_iteration_and_leave_room_for_the_legend(run_dir, rrd):
    from pipeline.tools.viewer import LEGEND_ROW_SPAN

    its = read_artefact(run_dir / "birl.mcap").all("/birl/iteration")
    chunks = chunks_by_entity(rrd)
    views = blueprint_views(rrd)
    for origin, entities in (("/curves/policy_loss", ["/curves/policy_loss/"]),
                             ("/curves/weights", ["/curves/weights/", "/curves/weights_true/"]),
                             ("/curves/log_posterior", ["/curves/log_posterior"])):
        view = views[origin]
        series = [p for p in chunks if any(p.startswith(e) for e in entities)]
        values = [v[0] for p in series for v in column(chunks[p], "Scalars:scalars")]
        lo, hi = view["ScalarAxis:range"][0]
        # every value inside; above them a band for the legend's entries, top right
        assert lo < min(values) and hi - max(values) >= \
            LEGEND_ROW_SPAN * len(series) * (max(values) - min(values)), origin
        assert view["PlotLegend:corner"] == [2] and view["PlotLegend:visible"] == [True]
        assert view["TimeAxis:view_range"] == [{"start": 0, "end": its[-1]["index"]}], origin


def test_curve_range_by_hand():
    from pipeline.tools.viewer import curve_range

    # span 1: 5 % below, 0.1 + 0.2 per legend entry above
    np.testing.assert_allclose(curve_range([0.0, 1.0], 3), (-0.05, 1.7))
    np.testing.assert_allclose(curve_range([-2.0, -2.0], 1), (-2.1, -1.4))  # flat: span |v|
    np.testing.assert_allclose(curve_range([], 1), (-0.05, 1.3))  # no values: 0 to 1


def test_a_run_without_demonstrations_is_shown(tmp_path):
    """expert=none writes no /demos topic; the viewer refused every such run."""
    run_in_process(tmp_path, "graph=small", "expert=none", "birl=fixed",
                   "birl.weights=[-1,-0.5,-0.5,-0.1,-0.5]")
    out = build_recording(tmp_path)
    paths = set(RrdReader(out).store().schema().entity_paths())
    assert "/eval/paths" in paths and "/graph/nodes" in paths
    # One BIRL iteration (the fixed weights): a line through one point draws nothing, so
    # the deployed weights were invisible; markers show them.
    chunks = chunks_by_entity(out)
    weights = [p for p in chunks if p.startswith("/curves/weights/")]
    assert len(weights) == 5
    for p in weights:
        assert column(chunks[p], "SeriesPoints:names") and \
            not column(chunks[p], "SeriesLines:names"), p
    # No true reward, so no policy loss: no empty plot for it, no "thin: true" in a title
    views = blueprint_views(out)
    assert "/curves/policy_loss" not in views and "/curves/weights" in views
    assert views["/curves/weights"]["ViewBlueprint:display_name"] == ["weights"]


def test_an_output_that_is_not_an_rrd_file_is_refused_and_the_run_kept(run_dir, tmp_path):
    before = (run_dir / "scene.mcap").read_bytes()
    for out, says in ((run_dir / "scene.mcap", "must end in .rrd"), (tmp_path, "must end in"),
                      (tmp_path / "x.rrd", "is a directory")):
        if out.name == "x.rrd":
            out.mkdir()
        with pytest.raises(PipelineError, match=says):
            build_recording(run_dir, out)
    assert (run_dir / "scene.mcap").read_bytes() == before


def test_artefacts_of_different_runs_are_refused(run_dir, tmp_path):
    """As the stages and export refuse them; the viewer drew them together silently."""
    other = tmp_path / "other"
    run_in_process(other, "graph=small", "birl.n_iterations=4", "seed=1")
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    for name in ("scene", "demos", "eval"):
        (mixed / f"{name}.mcap").write_bytes((run_dir / f"{name}.mcap").read_bytes())
    for name in ("graph", "birl"):
        (mixed / f"{name}.mcap").write_bytes((other / f"{name}.mcap").read_bytes())
    with pytest.raises(PipelineError, match="they come from different runs"):
        build_recording(mixed)


def test_a_hand_edited_path_is_a_clear_error(run_dir, tmp_path):
    """Points that are no [x, y] pairs (a hand-edited artefact of the run's own provenance)
    are one line naming them, not numpy's reshape error."""
    import shutil

    from pipeline.artefacts import topics, write_artefact

    for name in ("scene.mcap", "demos.mcap", "graph.mcap", "birl.mcap"):
        shutil.copy(run_dir / name, tmp_path / name)
    ev = read_artefact(run_dir / "eval.mcap")
    records, k = [], 0
    for n, (topic, messages) in enumerate(ev.messages.items()):
        for msg in messages:
            if topic == topics.EVAL_PATHS and msg.get("graph") == "graph":
                msg = {**msg, "points": [[1.0, 2.0, 3.0]]}
            records.append((topic, f"Edited{n}", msg, k))
            k += 1
    write_artefact(tmp_path / "eval.mcap", records, config_yaml=ev.config_yaml,
                   metadata=ev.metadata)
    with pytest.raises(PipelineError, match=r"points that are not finite \[x, y\] pairs"):
        build_recording(tmp_path)


def test_rerun_switched_off_is_one_line(run_dir, tmp_path):
    """RERUN=off (rerun's own switch) gives our one line and nothing of rerun's."""
    env = {**os.environ, "RERUN": "off"}
    res = subprocess.run([sys.executable, "-m", "pipeline.tools.viewer", str(run_dir), "--out",
                          str(tmp_path / "x.rrd"), "--no-open"], cwd=ROOT, env=env,
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 2
    assert res.stderr.strip().splitlines() == [
        "error: rerun logging is disabled (RERUN=off in the environment)"]


@pytest.mark.parametrize("argv, says", [
    (["NOPE"], "error: run dir NOPE not found"),  # was "Xvfb not found" where it is missing
    (["RUN", "--out", "shot"], "--out shot: the screenshot is a PNG"),  # after the capture
    (["RUN", "--timeout", "-1"], "--timeout -1.0: seconds > 0"),
])
def test_the_screenshot_checks_its_arguments_before_it_needs_xvfb(argv, says, tmp_path, capsys):
    from pipeline.tools.screenshot import main
    names = {"NOPE": str(tmp_path / "nope"), "RUN": str(tmp_path)}
    try:
        status = main([names.get(a, a) for a in argv])
    except SystemExit as e:  # argparse's refusal
        status = e.code
    assert status == 2 and says.replace("NOPE", names["NOPE"]) in capsys.readouterr().err


def test_held_out_demonstrations_are_drawn_apart(tmp_path):
    """Held-out demonstrations are judged, never learned from: the viewer drew them in the
    learned ones' magenta, so a reader could not tell which the reward was learned from."""
    from pipeline.tools.viewer import DEMO, HELDOUT_DEMO

    run_in_process(tmp_path, "graph=small", "birl.n_iterations=2", "expert=planner",
                   "expert.n_subjects=3", "evaluate.holdout=[s2]", "stages=[scene,demos]")
    demos = read_artefact(tmp_path / "demos.mcap").all("/demos")
    held = [d["points"] for d in demos if d.get("heldout")]
    learned = [d["points"] for d in demos if not d.get("heldout")]
    assert held and learned
    chunks = chunks_by_entity(build_recording(tmp_path))
    for entity, want, colour in (("/demos/heldout", held, HELDOUT_DEMO),
                                 ("/demos/trajectories", learned, DEMO)):
        (strips,) = column(chunks[entity], "LineStrips2D:strips")
        assert len(strips) == len(want), entity
        for got, points in zip(strips, want, strict=True):
            np.testing.assert_allclose(got, np.asarray(points) * [1, -1], rtol=1e-6)
        assert {rgb(c) for c in column(chunks[entity], "LineStrips2D:colors")[0]} == {colour}


def test_mark_scale_by_hand():
    from pipeline.tools.viewer import mark_scale

    assert mark_scale({"x_min": 0, "x_max": 10, "y_min": 0, "y_max": 10}) == 1.0
    assert mark_scale({"x_min": 0, "x_max": 4, "y_min": -2, "y_max": 2}) == 1.0  # never smaller
    assert mark_scale({"x_min": -5, "x_max": 25, "y_min": 0, "y_max": 50}) == 5.0  # longest side


def test_marks_keep_their_size_on_screen_in_a_large_building(tmp_path):
    """On the 30 x 50 m warehouse the 0.12 m starts hid under their own labels and the
    person ids ran together: marks grow with the room, person ids go to hover."""
    from pipeline.tools.viewer import HEADING_LEN, START_RADIUS, mark_scale

    run_in_process(tmp_path, "scene=warehouse", "stages=[scene]")
    scene = read_artefact(tmp_path / "scene.mcap").one("/scene")
    scale = mark_scale(scene["room"])
    assert scale > 2
    chunks = chunks_by_entity(build_recording(tmp_path))
    assert column(chunks["/scene/starts"], "Points2D:radii")[0] == \
        pytest.approx([START_RADIUS * scale])  # one radius for every start
    labels = column(chunks["/scene/labels"], "Points2D:labels")[0]
    assert labels == [f"s{k}" for k in range(len(scene["starts"]))] + ["goal"]
    assert column(chunks["/scene/persons"], "Points2D:labels")[0] == \
        [str(p["id"]) for p in scene["persons"]]  # still on hover
    lengths = np.linalg.norm(column(chunks["/scene/person_heading"], "Arrows2D:vectors")[0],
                             axis=1)
    np.testing.assert_allclose(lengths, HEADING_LEN * scale, rtol=1e-6)


def test_headings_start_at_the_disc_edge_above_persons_and_links(run_dir, rrd):
    scene = read_artefact(run_dir / "scene.mcap").one("/scene")
    chunks = chunks_by_entity(rrd)
    r = scene["body_radius"]
    edge = [(p["x"] + r * np.cos(p["theta"]), -(p["y"] + r * np.sin(p["theta"])))
            for p in scene["persons"]]
    np.testing.assert_allclose(column(chunks["/scene/person_heading"], "Arrows2D:origins")[0],
                               edge, rtol=1e-6, atol=1e-9)

    def order(entity, kind):
        return column(chunks[entity], f"{kind}:draw_order")[0][0]

    assert order("/scene/person_heading", "Arrows2D") > order("/scene/persons", "Points2D") \
        > order("/scene/links", "LineStrips2D")
    assert order("/scene/persons", "Points2D") > order("/eval/paths", "LineStrips2D")


def test_graph_growth_is_drawn_under_the_scene_and_its_best_paths_above_it(rrd):
    chunks = chunks_by_entity(rrd)

    def order(entity, kind):
        return column(chunks[entity], f"{kind}:draw_order")[0][0]

    goal = order("/scene/goal", "Points2D")
    assert order("/graph/nodes", "Points2D") < goal and order("/graph/edges", "LineStrips2D") < goal
    assert order("/graph/best_paths", "LineStrips2D") > order("/scene/links", "LineStrips2D")
