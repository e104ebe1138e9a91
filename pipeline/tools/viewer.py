"""Offline viewer: turn a run's MCAP artefacts into a rerun recording (.rrd) with a blueprint.

    python -m pipeline.tools.viewer RUN_DIR [--out FILE] [--no-open]

Static: the scene, the demonstrations (held-out ones in their own colour), the final graph,
the final learned paths (with
`birl=mcmc`, also the paths under a few posterior samples: its uncertainty). BIRL replays
on the `birl_iteration` timeline (learned paths and curves), which the layout selects, so
scene, final graph, learned paths and curves show together; graph growth replays on the
`iteration` timeline in its own view. rerun 0.41's 2-D views draw y downwards, so y is
logged negated and the scene appears y-up as in the figures (hover shows -y). A text view
under the scene (LEGEND) says what each colour is; labels are drawn light, below their discs;
the demonstrations above the learned paths; the weights plot has the true weights as thin
reference lines when the run knows them; each plot's y range leaves room above the curves for
its legend. Written against rerun-sdk 0.41 (pinned): its API changes between releases.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import uuid
from pathlib import Path

import contourpy  # ships with matplotlib
import numpy as np

from pipeline.app.provenance import check_inputs
from pipeline.app.rundir import COMPLETE, read_status
from pipeline.artefacts import Artefact, codec, read_artefact, topics, unique_tmp
from pipeline.core.world import Scene
from pipeline.errors import PipelineError, existing_dir, report
from pipeline.tools import run_tool

# rerun-sdk is the optional `viewer` extra (670 MB with pyarrow), out of the core install.
RERUN_MISSING = ("the viewer needs rerun-sdk, which is not installed: "
                 "pip install -e '.[viewer]' (make view and make screenshot install it)")
try:
    import rerun as rr
    import rerun.blueprint as rrb
except ModuleNotFoundError as e:
    if e.name != "rerun":
        raise
    if __name__ == "__main__":
        print(f"error: {RERUN_MISSING}", file=sys.stderr)
        sys.exit(2)
    raise ModuleNotFoundError(RERUN_MISSING, name="rerun") from None

APP_ID = "birlg"
# Marks (starts, arrows, line widths, label gaps) are sized for a room of this side and grow
# with larger ones, so that they keep their size on screen: on a 30 x 50 m map the starts
# were hidden under their own labels and the final paths were hair-thin.
MARK_ROOM_SIDE = 10.0  # m
HEADING_LEN = 0.3  # m, the person heading arrows, out from the disc's edge
START_RADIUS = 0.12  # m, the start discs
LABEL_GAP = 0.22  # m, from a disc's edge down to its label's anchor
# Above this mark scale (rooms over 20 m) person ids overlap one another and the discs of
# their group: they are then shown on hover only.
PERSON_LABELS_UP_TO_SCALE = 2.0
# What each thing is drawn in, on the viewer's near-black background; LEGEND names them.
PERSON, LINK = (235, 130, 40), (210, 40, 40)  # as in the figures: orange persons, red links
START, GOAL = (40, 180, 60), (240, 240, 240)
DEMO = (240, 70, 200)  # magenta: apart from the persons' orange and the paths' green and cyan
HELDOUT_DEMO = (255, 230, 90)  # pale yellow: held out of learning, only judged
FINAL_PATHS, BIRL_PATHS = (30, 200, 30), (0, 190, 190)
POSTERIOR_PATHS = (150, 150, 255)
GRAPH_NODES, GRAPH_EDGES = (150, 150, 150), (190, 200, 225)
OBSTACLE = (140, 140, 140)
LABEL = (225, 225, 225)  # label text, beside its disc: never red on red, green on green
KIND_COLORS = {"start": START, "goal": GOAL, "voronoi": (60, 110, 230), "demo": DEMO,
               "medial": (40, 160, 170), "sampled": GRAPH_NODES}
# Draw order, low to high: the demonstrations above the learned paths of the selected BIRL
# iteration, both above the wide final paths (at the last iteration all three coincide).
# Persons above the paths, their heading arrows above them (links passed over them); the graph
# growth under the scene (at 5000 nodes it buried the goal), its best paths above it; the
# posterior paths (MCMC) above the wide final paths they would otherwise lie under.
ORDER = {"obstacles": -10.0, "graph_edges": -5.0, "graph_nodes": -4.0, "links": 19.0,
         "final_paths": 20.0, "posterior_paths": 20.5, "birl_paths": 21.0, "demos": 22.0,
         "best_paths": 23.0, "persons": 30.0, "headings": 31.0, "labels": 40.0}
LEGEND = """\
**Scene** orange discs: persons (number below, or on hover in rooms over 20 m; arrow: \
heading) · red lines: social links (groups) · grey outlines: obstacles, map walls · green \
dots: starts s0, s1, … · white disc: goal

**Paths** magenta: demonstrations · pale yellow: held-out ones (judged only) · wide green: \
final learned paths · thin cyan: learned paths at the BIRL iteration selected below · \
lavender: paths under posterior samples (MCMC) · grey: the adaptive graph's nodes and edges

**Graph growth** (tab, on the `iteration` timeline) nodes: green start, white goal, magenta \
on a demonstration, blue Voronoi, teal medial axis, grey sampled · gold: best paths so far
"""
# Distinct series colours (matplotlib's tab10): curves that share a view never look alike.
TAB10 = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
         (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207)]
Y_UP = np.array([1.0, -1.0])  # rerun 2-D views draw y down: negate y to show the scene y-up


def _xy(points) -> np.ndarray:
    try:  # the readers check what they decode; a hand-edited message may still hold anything
        xy = np.asarray(points, dtype=float)
        if xy.size == 0:
            xy = xy.reshape(0, 2)
        if xy.ndim != 2 or xy.shape[1] != 2 or not np.isfinite(xy).all():
            raise ValueError
    except (TypeError, ValueError):
        raise PipelineError(f"an artefact message holds points that are not finite [x, y] "
                            f"pairs: {str(points)[:60]}") from None
    return xy * Y_UP


def _strips(polylines) -> list[np.ndarray]:
    return [_xy(p) for p in polylines]


def obstacle_outlines(scene: Scene) -> list[np.ndarray]:
    """Outlines (polylines (k, 2)) of the scene's obstacle raster, map and polygons, for
    drawing; empty without obstacles."""
    if scene.obstacles is None:
        return []
    grid = scene.obstacles.grid
    centres = grid.cell_centres()
    padded = np.pad(grid.occupied.astype(float), 1)  # close the outlines at the border
    res = grid.resolution
    x = np.concatenate([[centres[0, 0, 0] - res], centres[0, :, 0], [centres[0, -1, 0] + res]])
    y = np.concatenate([[centres[0, 0, 1] - res], centres[:, 0, 1], [centres[-1, 0, 1] + res]])
    lines = contourpy.contour_generator(x, y, padded).lines(0.5)
    return [np.asarray(line, float) for line in lines]


def mark_scale(room: dict) -> float:
    """How much larger than in a MARK_ROOM_SIDE room the marks are drawn (at least 1)."""
    side = max(room["x_max"] - room["x_min"], room["y_max"] - room["y_min"])
    return max(1.0, side / MARK_ROOM_SIDE)


def _log_obstacles(rec: rr.RecordingStream, outlines: list[np.ndarray], scale: float) -> None:
    """The obstacle raster's outlines (map walls, polygons), under everything else."""
    if outlines:
        rec.log("scene/obstacles", rr.LineStrips2D(_strips(outlines), radii=0.02 * scale,
                                                   colors=OBSTACLE,
                                                   draw_order=ORDER["obstacles"]),
                static=True, strict=True)


def _log_scene(rec: rr.RecordingStream, scene: dict, scale: float) -> None:
    r = scene["room"]
    room = [(r["x_min"], r["y_min"]), (r["x_max"], r["y_min"]), (r["x_max"], r["y_max"]),
            (r["x_min"], r["y_max"]), (r["x_min"], r["y_min"])]
    persons = scene["persons"]
    pos = {p["id"]: (p["x"], p["y"]) for p in persons}
    xy = np.array([pos[p["id"]] for p in persons], dtype=float).reshape(-1, 2)
    theta = np.array([p["theta"] for p in persons], dtype=float)
    rec.log("scene/room", rr.LineStrips2D(_strips([room]), radii=0.01 * scale,
                                          colors=(80, 80, 80)), static=True, strict=True)
    ids = [str(p["id"]) for p in persons]
    # Every label (shown on hover) is also drawn below its disc by _log_labels: rerun draws a
    # label in its point's colour, on the point, which is unreadable on a disc of that colour.
    rec.log("scene/persons", rr.Points2D(_xy(xy), radii=scene["body_radius"], colors=PERSON,
                                         labels=ids, show_labels=False,
                                         draw_order=ORDER["persons"]),
            static=True, strict=True)
    # From the disc's edge outwards: from the centre, only a stub showed beyond the disc.
    facing = np.stack([np.cos(theta), np.sin(theta)], axis=-1)
    # Light grey: the dark grey of the (white) figures is invisible on the viewer's black.
    rec.log("scene/person_heading", rr.Arrows2D(
        origins=_xy(xy + scene["body_radius"] * facing), vectors=_xy(HEADING_LEN * scale * facing),
        radii=0.025 * scale, colors=(200, 200, 200), draw_order=ORDER["headings"]),
        static=True, strict=True)
    links = [[pos[a], pos[b]] for a, b in scene["relations"]]
    rec.log("scene/links", rr.LineStrips2D(_strips(links), colors=LINK, radii=0.03 * scale,
                                           draw_order=ORDER["links"]),
            static=True, strict=True)
    starts = [f"s{k}" for k in range(len(scene["starts"]))]
    start_radius = START_RADIUS * scale
    rec.log("scene/starts", rr.Points2D(_xy(scene["starts"]), radii=start_radius, colors=START,
                                        labels=starts, show_labels=False,
                                        draw_order=ORDER["persons"]),
            static=True, strict=True)
    goal_radius = scene.get("goal_tolerance", 0.2)
    rec.log("scene/goal", rr.Points2D(_xy([scene["goal"]]), radii=goal_radius, colors=GOAL,
                                      labels=["goal"], show_labels=False,
                                      draw_order=ORDER["persons"]),
            static=True, strict=True)
    person_labels = [(xy, scene["body_radius"], ids)] if scale <= PERSON_LABELS_UP_TO_SCALE else []
    _log_labels(rec, [*person_labels,
                      (np.asarray(scene["starts"], float), start_radius, starts),
                      (np.asarray([scene["goal"]], float), goal_radius, ["goal"])],
                LABEL_GAP * scale)


def _log_labels(rec: rr.RecordingStream,
                groups: list[tuple[np.ndarray, float, list[str]]], gap: float) -> None:
    """The labels of discs (centres, radius, texts), light grey `gap` below each disc."""
    anchors = np.concatenate([np.asarray(xy, float).reshape(-1, 2) - [0.0, radius + gap]
                              for xy, radius, _ in groups])
    texts = [t for _, _, group in groups for t in group]
    rec.log("scene/labels", rr.Points2D(_xy(anchors), radii=0.001, colors=LABEL, labels=texts,
                                        show_labels=True, draw_order=ORDER["labels"]),
            static=True, strict=True)


def _log_graph(rec: rr.RecordingStream, graph: Artefact, scale: float) -> None:
    nodes, edges = codec.decode_nodes(graph), codec.decode_edges(graph)
    best = graph.all(topics.GRAPH_BEST_PATHS)
    pos = nodes.positions
    # The final graph, static: shown beside the BIRL timeline without switching timelines.
    rec.log("graph/final/nodes", rr.Points2D(_xy(pos), radii=0.03 * scale, colors=GRAPH_NODES,
                                             draw_order=ORDER["graph_nodes"]),
            static=True, strict=True)
    rec.log("graph/final/edges", rr.LineStrips2D(_strips(edges.waypoints), radii=0.005 * scale,
                                                 colors=GRAPH_EDGES,
                                                 draw_order=ORDER["graph_edges"]),
            static=True, strict=True)
    iterations = sorted(set(nodes.added_at.tolist()) | set(edges.added_at.tolist())
                        | {b["iteration"] for b in best})
    best_at = {b["iteration"]: b for b in best}
    colors = np.array([KIND_COLORS.get(str(k), (0, 0, 0)) for k in nodes.kind],
                      dtype=np.uint8).reshape(-1, 3)
    # Edges grouped by the iteration that added them (rows in iteration order within each).
    by_iteration = np.argsort(edges.added_at, kind="stable")
    bounds = np.searchsorted(edges.added_at[by_iteration], [iterations, np.add(iterations, 1)])
    for j, k in enumerate(iterations):
        rec.set_time("iteration", sequence=k)
        # Nodes cumulative (cheap); edges only the new ones, made cumulative in the view by a
        # visible-time-range override: cumulative edges would grow quadratically in the file.
        grown = nodes.added_at <= k
        rec.log("graph/nodes", rr.Points2D(_xy(pos[grown]), radii=0.05 * scale,
                                           colors=colors[grown],
                                           draw_order=ORDER["graph_nodes"]), strict=True)
        new = [edges.waypoints[e] for e in by_iteration[bounds[0, j]:bounds[1, j]]]
        if new:
            rec.log("graph/edges", rr.LineStrips2D(_strips(new), radii=0.01 * scale,
                                                   colors=(120, 140, 200),
                                                   draw_order=ORDER["graph_edges"]), strict=True)
        if k in best_at:  # one row per /graph/best_paths message, even if it has no paths
            paths = [pos[p] for p in best_at[k]["paths"] if p]
            rec.log("graph/best_paths", rr.LineStrips2D(_strips(paths), radii=0.04 * scale,
                                                        colors=(250, 200, 0),
                                                        draw_order=ORDER["best_paths"]),
                    strict=True)
    rec.reset_time()


LOSS_SERIES = {"graph": "adaptive graph", "ref": "reference roadmap", "norm": "normalised"}


def _tint(colour: tuple[int, int, int]) -> tuple[int, ...]:
    """The colour halfway to white: a true weight's line beside its learned weight's."""
    return tuple((c + 255) // 2 for c in colour)


def _log_series_styles(rec: rr.RecordingStream, names: list[str], true: dict[str, float],
                       one_iteration: bool) -> None:
    """Names and distinct colours of the curves (static, so every view shows them); a true
    weight thin, in its learned weight's colour lightened. With one BIRL iteration (e.g.
    `birl=fixed`) each curve is one point, which a line does not draw: markers then."""
    styles = {f"curves/policy_loss/{k}": (TAB10[i], label, 2.0)
              for i, (k, label) in enumerate(LOSS_SERIES.items())}
    for i, n in enumerate(names):
        styles[f"curves/weights/{n}"] = (TAB10[i % len(TAB10)], n, 2.0)
        if n in true:
            styles[f"curves/weights_true/{n}"] = (_tint(TAB10[i % len(TAB10)]), f"{n} (true)", 1.0)
    styles["curves/log_posterior"] = (TAB10[4], "log posterior", 2.0)
    for path, (color, label, width) in styles.items():
        style = rr.SeriesPoints(colors=[color], names=[label], marker_sizes=[3.0 * width]) \
            if one_iteration else rr.SeriesLines(colors=[color], names=[label], widths=[width])
        rec.log(path, style, static=True, strict=True)


def true_weights(arts: dict[str, Artefact], names: list[str]) -> dict[str, float]:
    """The demonstrator's true weight of each learned feature it has, when the run knows them
    (synthetic experts; not file or planner demonstrations)."""
    demos = arts.get("demos")
    expert = demos.one(topics.DEMOS_EXPERT) if demos is not None \
        and demos.messages.get(topics.DEMOS_EXPERT) else {}
    if expert.get("true_weights") is None:
        return {}
    true = dict(zip(expert["feature_names"], expert["true_weights"], strict=True))
    return {n: float(true[n]) for n in names if n in true}


def _log_birl(rec: rr.RecordingStream, birl: Artefact | None, ev: Artefact | None,
              names: list[str], true: dict[str, float], scale: float) -> None:
    iterations = birl.all(topics.BIRL_ITERATION) if birl else []
    _log_series_styles(rec, names, true, one_iteration=len(iterations) == 1)
    for it in iterations:
        rec.set_time("birl_iteration", sequence=it["index"])
        paths = [g["points"] for g in it["generated"] if g.get("points")]
        # Thinner than and above the final paths (eval/paths): at the last iteration they are
        # the same paths, which would hide them entirely.
        rec.log("birl/learned_paths", rr.LineStrips2D(_strips(paths), radii=0.03 * scale,
                                                      colors=BIRL_PATHS,
                                                      draw_order=ORDER["birl_paths"]),
                strict=True)
        for i, w in enumerate(it["weights"]):
            name = names[i] if i < len(names) else f"w{i}"
            rec.log(f"curves/weights/{name}", rr.Scalars(w), strict=True)
        for name, w in true.items():  # a flat reference line beside the learned weights
            rec.log(f"curves/weights_true/{name}", rr.Scalars(w), strict=True)
        if it.get("log_posterior") is not None:
            rec.log("curves/log_posterior", rr.Scalars(it["log_posterior"]), strict=True)
    for loss in ev.all(topics.EVAL_POLICY_LOSS) if ev else []:
        rec.set_time("birl_iteration", sequence=loss["iteration"])
        for key in LOSS_SERIES:
            if loss.get(key) is not None:
                rec.log(f"curves/policy_loss/{key}", rr.Scalars(loss[key]), strict=True)
    rec.reset_time()
    if birl is not None and birl.messages.get(topics.BIRL_GRAPH_NODES):  # birl.grow_nodes > 0
        grown = codec.decode_nodes(birl, topics.BIRL_GRAPH_NODES, first_id=None)
        rec.log("birl/grown_nodes", rr.Points2D(_xy(grown.positions), radii=0.05 * scale,
                                                colors=BIRL_PATHS), static=True, strict=True)
    if ev is not None and topics.EVAL_PATHS in ev.messages:
        final = [p for p in ev.all(topics.EVAL_PATHS) if p.get("graph") == "graph" and p["points"]]
        # No labels: the starts carry them (s0, s1, ...), path labels would overlap them.
        rec.log("eval/paths", rr.LineStrips2D(
            _strips([p["points"] for p in final]), radii=0.06 * scale, colors=FINAL_PATHS,
            draw_order=ORDER["final_paths"]), static=True, strict=True)


GROWTH = ["/graph/nodes", "/graph/edges", "/graph/best_paths"]  # on the `iteration` timeline


POSTERIOR_PATH_SAMPLES = 6


def _log_posterior_paths(rec: rr.RecordingStream, arts: dict[str, Artefact],
                         scale: float) -> None:
    """Posterior uncertainty (`birl=mcmc`): the greedy paths on the graph under a few
    samples of the last posterior, evenly spread over the kept samples."""
    birl, graph_art, demos = arts.get("birl"), arts.get("graph"), arts.get("demos")
    if birl is None or graph_art is None or demos is None \
            or not birl.messages.get(topics.BIRL_POSTERIOR):
        return
    graph = codec.decode_graph(graph_art, codec.decode_mdp_params(demos.one(topics.DEMOS_EXPERT)),
                               grown=birl)
    samples = np.asarray(birl.all(topics.BIRL_POSTERIOR)[-1]["samples"], float)
    picks = np.linspace(0, len(samples) - 1, min(POSTERIOR_PATH_SAMPLES, len(samples)))
    paths = []
    for w in samples[picks.astype(int)]:
        policy = graph.mdp.solve(w).policy
        paths += [graph.polyline(graph.mdp.follow(policy, int(s))) for s in graph.start_nodes]
    rec.log("birl/posterior_paths", rr.LineStrips2D(_strips(paths), radii=0.02 * scale,
                                                    colors=POSTERIOR_PATHS,
                                                    draw_order=ORDER["posterior_paths"]),
            static=True, strict=True)


# A curve view's y range leaves room above the curves for its legend (top right): this share
# of the curves' span per legend entry, and a little more.
LEGEND_ROW_SPAN, LEGEND_PAD_SPAN = 0.2, 0.1


def curve_range(values: list[float], legend_rows: int) -> tuple[float, float]:
    """The y range of a curve view: its values, a small margin below and room for its legend
    above (the legend then never covers a curve)."""
    lo, hi = (float(np.min(values)), float(np.max(values))) if values else (0.0, 1.0)
    span = hi - lo if hi > lo else max(abs(hi), 1.0)
    return lo - 0.05 * span, hi + span * (LEGEND_PAD_SPAN + LEGEND_ROW_SPAN * legend_rows)


def curve_ranges(birl: Artefact | None, ev: Artefact | None,
                 true: dict[str, float]) -> dict[str, tuple[float, float]]:
    """The y range of each curve view (by its entity under /curves), from the logged values."""
    its = birl.all(topics.BIRL_ITERATION) if birl else []
    losses = [v for loss in (ev.all(topics.EVAL_POLICY_LOSS) if ev else [])
              for k, v in loss.items() if k in LOSS_SERIES and v is not None]
    weights = [w for it in its for w in it["weights"]] + list(true.values())
    posterior = [it["log_posterior"] for it in its if it.get("log_posterior") is not None]
    n_weights = len(its[0]["weights"]) if its else 0
    return {"policy_loss": curve_range(losses, len(LOSS_SERIES)),
            "weights": curve_range(weights, n_weights + len(true)),
            "log_posterior": curve_range(posterior, 1)}


def _curve_view(name: str, entity: str, y_range: tuple[float, float], last_iteration: int,
                contents: list[str] | None = None) -> rrb.TimeSeriesView:
    """A time-series view over every BIRL iteration with its legend top right, above the
    curves (curve_range), and axes long enough for more than one labelled tick."""
    end = rrb.TimeRangeBoundary.absolute(seq=max(last_iteration, 1))
    return rrb.TimeSeriesView(
        name=name, origin=f"/curves/{entity}", contents=contents or "$origin/**",
        axis_x=rrb.TimeAxis(view_range=rrb.TimeRange(
            start=rrb.TimeRangeBoundary.absolute(seq=0), end=end)),
        axis_y=rrb.ScalarAxis(range=y_range),
        plot_legend=rrb.PlotLegend(rrb.Corner2D.RightTop, visible=True))


def _blueprint(room: dict, ranges: dict[str, tuple[float, float]], last_iteration: int,
               has_loss: bool, has_true: bool) -> rrb.Blueprint:
    """The layout; the policy-loss view only when the run has a loss (a true reward), the
    weights view titled for reference lines only when it has them."""
    margin = 0.5
    bounds = rrb.VisualBounds2D(  # y negated (Y_UP)
        x_range=[room["x_min"] - margin, room["x_max"] + margin],
        y_range=[-room["y_max"] - margin, -room["y_min"] + margin])
    # Scene, final graph, learned paths of the selected BIRL iteration and final paths.
    learning = rrb.Spatial2DView(
        name="scene and learning (BIRL timeline)", origin="/",
        contents=["+ /**", "- /curves/**", "- /legend", *[f"- {p}" for p in GROWTH]],
        visual_bounds=bounds)
    # Edges are logged once, at the iteration that added them: show all up to the cursor.
    grown = rrb.VisibleTimeRanges(timeline="iteration", start=rrb.TimeRangeBoundary.infinite(),
                                  end=rrb.TimeRangeBoundary.cursor_relative())
    growth = rrb.Spatial2DView(
        name="graph growth (iteration timeline)", origin="/",
        contents=["+ /scene/**", *[f"+ {p}" for p in GROWTH]],
        overrides={"graph/edges": grown}, visual_bounds=bounds)
    legend = rrb.TextDocumentView(name="legend", origin="/legend")
    views = [(2, _curve_view("policy loss", "policy_loss", ranges["policy_loss"],
                             last_iteration))] if has_loss else []
    views += [  # the weights' legend has up to twice as many entries: a larger share
        (3, _curve_view("weights (thin: true)" if has_true else "weights", "weights",
                        ranges["weights"], last_iteration,
                        ["+ /curves/weights/**", "+ /curves/weights_true/**"])),
        (2, _curve_view("log posterior", "log_posterior", ranges["log_posterior"],
                        last_iteration))]
    curves = rrb.Vertical(*(v for _, v in views), row_shares=[share for share, _ in views])
    return rrb.Blueprint(
        rrb.Horizontal(rrb.Vertical(rrb.Tabs(learning, growth), legend, row_shares=[4, 1]),
                       curves, column_shares=[3, 2]),
        # collapsed: the time controls only, the room goes to the views
        rrb.TimePanel(timeline="birl_iteration", state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),  # recording metadata: room for the plots
        collapse_panels=False)


def _log_run(rec: rr.RecordingStream, scene_art: Artefact, decoded: Scene,
             arts: dict[str, Artefact]) -> None:
    """The blueprint, the legend and every entity of the run's artefacts (`decoded`: the
    scene artefact as a checked Scene)."""
    scene = scene_art.one(topics.SCENE)
    names = next((a.messages[t][0]["feature_names"] for a, t in
                  ((arts.get("birl"), topics.BIRL_EXPERT), (arts.get("demos"), topics.DEMOS_EXPERT))
                  if a is not None and a.messages.get(t)), [])
    true = true_weights(arts, names)
    iterations = arts["birl"].all(topics.BIRL_ITERATION) if "birl" in arts else []
    has_loss = "evaluate" in arts and any(
        loss.get(k) is not None for loss in arts["evaluate"].all(topics.EVAL_POLICY_LOSS)
        for k in LOSS_SERIES)
    rec.send_blueprint(_blueprint(scene["room"],
                                  curve_ranges(arts.get("birl"), arts.get("evaluate"), true),
                                  iterations[-1]["index"] if iterations else 0,
                                  has_loss=has_loss, has_true=bool(true)))
    rec.log("legend", rr.TextDocument(LEGEND, media_type=rr.MediaType.MARKDOWN), static=True,
            strict=True)
    scale = mark_scale(scene["room"])
    _log_scene(rec, scene, scale)
    _log_obstacles(rec, obstacle_outlines(decoded), scale)
    if "demos" in arts:  # expert=none writes no /demos topic: nothing to draw
        for entity, demos, colour in (
                ("demos/trajectories", codec.training_demos(arts["demos"]), DEMO),
                ("demos/heldout", codec.heldout_demos(arts["demos"]), HELDOUT_DEMO)):
            if demos or entity == "demos/trajectories":
                rec.log(entity, rr.LineStrips2D(_strips([d["points"] for d in demos]),
                                                radii=0.025 * scale, colors=colour,
                                                draw_order=ORDER["demos"]),
                        static=True, strict=True)
    if "graph" in arts:
        _log_graph(rec, arts["graph"], scale)
    _log_birl(rec, arts.get("birl"), arts.get("evaluate"), names, true, scale)
    _log_posterior_paths(rec, arts, scale)


def _later_artefacts(run_dir: Path) -> dict[str, Artefact]:
    """The readable artefacts after the scene's, by stage. What is missing or unreadable is
    said on stderr (one line each) and left out of the recording, which shows the rest: a
    run of `stages=[scene,demos]` opened on empty learning views without a word, and one
    truncated eval.mcap kept the scene, graph and learning from being shown at all."""
    arts, missing = {}, []
    for stage in topics.STAGES[1:]:  # shown when present; the scene is not optional
        path = run_dir / topics.ARTEFACT_FILE[stage]
        if not path.exists():
            missing.append(path.name)
            continue
        try:
            arts[stage] = read_artefact(path)
        except PipelineError as e:
            print(f"warning: {e}; the recording leaves it out", file=sys.stderr)
    if missing:
        print(f"note: run dir {run_dir} has no {', '.join(missing)} (stages not run): the "
              "recording shows what it has", file=sys.stderr)
    return arts


def build_recording(run_dir: Path, rrd_path: Path | None = None) -> Path:
    """Read the artefacts present in run_dir (scene.mcap required) and write an .rrd."""
    run_dir = existing_dir(Path(run_dir), "run dir")
    rrd_path = Path(rrd_path) if rrd_path is not None else run_dir / "run.rrd"
    if rrd_path.suffix != ".rrd":  # e.g. --out RUN/scene.mcap replaced the run's own input
        raise PipelineError(f"--out {rrd_path}: the recording's file name must end in .rrd")
    if rrd_path.is_dir():
        raise PipelineError(f"--out {rrd_path} is a directory; give the .rrd file to write")
    scene_art = read_artefact(run_dir / topics.ARTEFACT_FILE["scene"],
                              required_topics=[topics.SCENE])
    scene = codec.decode_scene(scene_art)  # a malformed scene: one line, before any drawing
    arts = _later_artefacts(run_dir)
    # artefacts of different runs side by side are refused, as the stages and export do
    check_inputs({"scene": scene_art, **arts})
    # rerun's own off switch (its accepted values): said before a stream exists, which would
    # add two warnings of its own when dropped
    if os.environ.get("RERUN", "").strip().lower() in ("0", "off", "false"):
        raise PipelineError("rerun logging is disabled (RERUN=off in the environment)")
    tmp = unique_tmp(rrd_path)
    # Same run dir -> same recording id: a rebuilt .rrd is the same recording, not a new one.
    rec_id = uuid.uuid5(uuid.NAMESPACE_URL, f"birlg:{run_dir.resolve()}")
    rec = rr.RecordingStream(APP_ID, recording_id=rec_id)
    if not rec.is_enabled():
        raise PipelineError("rerun logging is disabled (RERUN=off in the environment)")
    rec.set_log_time_enabled(False)  # wall-clock log_time would add a meaningless timeline
    try:
        try:
            rec.save(tmp)
        except RuntimeError as e:  # the bindings report an unwritable path this way
            raise PipelineError(f"cannot write {rrd_path}: {e}") from None
        rec.send_recording_name(run_dir.resolve().name)
        _log_run(rec, scene_art, scene, arts)
        try:
            rec.flush()
        except RuntimeError as e:  # its file writer stopped, e.g. on a full disk
            raise PipelineError(f"cannot write {rrd_path}: {e}") from None
        rec.disconnect()  # closes the file sink, writing the footer
        os.replace(tmp, rrd_path)
    finally:
        rec.disconnect()  # idempotent; on failure, stop writing into the temp file
        tmp.unlink(missing_ok=True)
    return rrd_path


def viewer_command(rrd: Path) -> list[str]:
    exe = Path(sys.executable).parent / "rerun"
    if exe.exists():
        return [str(exe), str(rrd)]
    found = shutil.which("rerun")
    return [found, str(rrd)] if found else [sys.executable, "-m", "rerun", str(rrd)]


def _has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")) \
        or sys.platform == "darwin"


def warn_if_incomplete(run_dir: Path) -> None:
    """A warning line when the run failed or was interrupted (its artefacts are shown)."""
    status = read_status(run_dir)
    if status.state == "unknown" and status.error:  # damaged, not merely older than status.json
        print(f"warning: run dir {run_dir} has {status.error}: whether its run finished is not "
              "known; showing the artefacts it has", file=sys.stderr)
    elif status.state not in (COMPLETE, "unknown"):  # unknown: made before status.json existed
        print(f"warning: run dir {run_dir} is {status.describe()}; showing the artefacts "
              "it has", file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m pipeline.tools.viewer",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("run_dir", type=Path, help="a run directory holding the stage artefacts")
    ap.add_argument("--out", type=Path, default=None, help="the .rrd to write "
                    "(default RUN_DIR/run.rrd)")
    ap.add_argument("--no-open", action="store_true", help="only write the .rrd")
    args = ap.parse_args(argv)
    try:
        rrd = build_recording(args.run_dir, args.out)
    except (PipelineError, OSError) as e:  # OSError: e.g. a read-only run dir at the rename
        return report(e, f"the recording of {args.run_dir}")
    warn_if_incomplete(args.run_dir)  # after: a dir with nothing to show gets the error alone
    cmd = viewer_command(rrd)
    if args.no_open or not _has_display():
        print(f"wrote {rrd}; open it with: {' '.join(cmd)}")
        return 0
    return open_viewer(cmd, rrd)


def open_viewer(cmd: list[str], rrd: Path, grace_s: float = 3.0) -> int:
    """Start the viewer detached (it outlives this command); a viewer that dies within
    `grace_s` (no GPU, no display server, a broken install) is reported, not hidden."""
    log_path = rrd.with_suffix(".viewer.log")
    with open(log_path, "w") as log_file:
        proc = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.DEVNULL,
                                stderr=log_file)
    try:
        code = proc.wait(timeout=grace_s)
    except subprocess.TimeoutExpired:
        print(f"wrote {rrd}; opened it with: {' '.join(cmd)}")
        return 0
    if code == 0:  # a viewer that hands the file to an already open window exits at once
        print(f"wrote {rrd}; opened it with: {' '.join(cmd)}")
        return 0
    last = (log_path.read_text().strip().splitlines() or ["no output"])[-1]
    print(f"error: the viewer exited with status {code} ({last}); the recording is {rrd}, "
          f"full viewer output in {log_path}", file=sys.stderr)
    return 1


if __name__ == "__main__":
    run_tool(main)
