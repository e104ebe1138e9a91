"""Figures of a run dir drawn from its artefacts, onto a matplotlib Axes the caller owns (the
caller picks the backend and saves or shows it): `make aggregate`'s scene.png and
`api.Run.plot` draw the same picture."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from pipeline.app.figure_style import COLUMN_IN, OKABE_ITO, PAGE_IN
from pipeline.core.social import PERSONAL_ZONE

# What each thing of the scene is drawn in: the same in the sweep's scene.png and Run.plot.
SCENE_COLOURS = {"person": OKABE_ITO["orange"], "link": OKABE_ITO["vermillion"],
                 "demo": OKABE_ITO["green"], "heldout": OKABE_ITO["blue"],
                 "learned": OKABE_ITO["sky"], "start": OKABE_ITO["purple"],
                 "goal": OKABE_ITO["yellow"], "node": "0.65"}
# the room's plot is the figure less these (inches): the y axis' labels beside it; the
# title, the x axis' labels and the legend below it
BESIDE_IN, AROUND_IN = 0.55, 1.5


def scene_size_in(room: dict) -> tuple[float, float]:
    """A figure size (inches) for a scene with its legend below, shaped as its room (the
    scene message's): a column wide for a room about square or taller, the page wide for a
    wide one (a 30 x 14 m hall in a column's portrait figure was a thin strip)."""
    shape = (room["y_max"] - room["y_min"]) / (room["x_max"] - room["x_min"])
    width = COLUMN_IN if shape >= 0.75 else PAGE_IN
    return width, float(np.clip((width - BESIDE_IN) * shape, 1.0, 8.0)) + AROUND_IN


def draw_scene(ax: Any, run_dir: Path, paths: str = "graph", fit_figure: bool = False) -> Any:
    """The scene of `run_dir` (room, map, persons with their personal zones and headings,
    social links, starts, goal) with the graph's nodes, the demonstrations and the learned
    paths (`paths`: "graph" for the adaptive graph's, "ref" for the reference roadmap's)
    when the run has them; returns `ax`. `fit_figure`: the figure (the caller's new one) is
    sized to the room (`scene_size_in`)."""
    # Here, not at the top: the artefact readers import the run's modules (scipy, ...), which
    # the sweep table (make aggregate) does not need.
    from pipeline.artefacts import codec, read_artefact, topics
    from pipeline.artefacts.topics import ARTEFACT_FILE

    run_dir = Path(run_dir)
    art = read_artefact(run_dir / ARTEFACT_FILE["scene"], producer_stage="scene")
    scene = art.one(topics.SCENE)
    if fit_figure:
        ax.figure.set_size_inches(scene_size_in(scene["room"]))
    obstacles = codec.decode_scene(art).obstacles
    if obstacles is not None:  # the map and polygons under the scene
        x0, y0, x1, y1 = obstacles.grid.extent()
        ax.imshow(obstacles.grid.occupied, origin="lower", extent=(x0, x1, y0, y1),
                  cmap="Greys", vmin=0, vmax=1.5, interpolation="nearest")
    if (run_dir / ARTEFACT_FILE["graph"]).exists():  # the graph's samples (paper Fig. 1 left)
        nodes = codec.decode_nodes(read_artefact(run_dir / ARTEFACT_FILE["graph"])).positions
        ax.plot(nodes[:, 0], nodes[:, 1], ".", color=SCENE_COLOURS["node"], ms=1.5,
                label=f"graph nodes ({len(nodes)})", zorder=1)
    room = scene["room"]
    ax.plot([room["x_min"], room["x_max"], room["x_max"], room["x_min"], room["x_min"]],
            [room["y_min"], room["y_min"], room["y_max"], room["y_max"], room["y_min"]], "k-")
    _draw_people(ax, scene)
    # The learned paths wide and under the dashed demonstrations: where the two agree, both
    # stay visible.
    if (run_dir / ARTEFACT_FILE["evaluate"]).exists():
        learned = [p for p in read_artefact(run_dir / ARTEFACT_FILE["evaluate"])
                   .all(topics.EVAL_PATHS) if p["graph"] == paths]
        for i, p in enumerate(learned):
            pts = np.asarray(p["points"])
            ax.plot(pts[:, 0], pts[:, 1], color=SCENE_COLOURS["learned"], lw=2.4, zorder=3,
                    label="learned paths" if i == 0 else None)
    if (run_dir / ARTEFACT_FILE["demos"]).exists():
        demos = read_artefact(run_dir / ARTEFACT_FILE["demos"]).messages.get(topics.DEMOS, [])
        labelled = set()
        for d in demos:  # held out of learning (evaluate.holdout): dotted, in their colour
            kind = "heldout" if d.get("heldout") else "demo"
            pts = np.asarray(d["points"])
            ax.plot(pts[:, 0], pts[:, 1], ":" if kind == "heldout" else "--",
                    color=SCENE_COLOURS[kind], lw=1.1, zorder=4,
                    label=None if kind in labelled else
                    {"demo": "demonstrations", "heldout": "held out"}[kind])
            labelled.add(kind)
    starts = np.asarray(scene["starts"])
    ax.plot(starts[:, 0], starts[:, 1], "s", color=SCENE_COLOURS["start"], ms=4, zorder=5,
            label="starts")
    ax.plot(*scene["goal"], "*", color=SCENE_COLOURS["goal"], ms=11, mec="k", mew=0.6,
            zorder=5, label="goal")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"scene '{scene['name']}'")
    # Below the room, where it hides nothing; two columns keep it short.
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2)
    return ax


def _draw_people(ax: Any, scene: dict) -> None:
    """The social links, and every person's body, heading and personal zone (an outline:
    filled zones would overlap and darken)."""
    from matplotlib.patches import Circle

    pos = {p["id"]: (p["x"], p["y"]) for p in scene["persons"]}
    for i, (a, b) in enumerate(scene["relations"]):
        ax.plot(*zip(pos[a], pos[b], strict=True), color=SCENE_COLOURS["link"], lw=1.2,
                zorder=2, label="social links" if i == 0 else None)
    for i, p in enumerate(scene["persons"]):
        ax.add_patch(Circle((p["x"], p["y"]), PERSONAL_ZONE, fill=False, lw=0.6, ls=":",
                            ec=SCENE_COLOURS["person"], zorder=2,
                            label=f"personal zone ({PERSONAL_ZONE} m)" if i == 0 else None))
        ax.add_patch(Circle((p["x"], p["y"]), scene["body_radius"], color=SCENE_COLOURS["person"],
                            zorder=2.5, label="persons (arrow: heading)" if i == 0 else None))
        ax.arrow(p["x"], p["y"], 0.4 * np.cos(p["theta"]), 0.4 * np.sin(p["theta"]),
                 head_width=0.12, lw=0.6, color="k", zorder=2.6)
