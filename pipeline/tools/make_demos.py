"""Generate the shipped demonstration files: data/demos/metropolis_handdrawn.json.

    python -m pipeline.tools.make_demos handdrawn             # into the package's data/demos
    python -m pipeline.tools.make_demos handdrawn --out DIR   # DIR/demos

handdrawn: hand-drawn-like demonstrations on metropolis.

Not recorded human data: a stand-in with the defects of paths drawn by hand. For every start,
three drawings of the polite expert's route (the optimal path on the reference roadmap
under the polite weights): corner-cut (a moving average over about 1 m), resampled at
10 cm, with a slow sideways wobble (smoothed random walk, up to about 15 cm, pinned at both
ends) and a small per-point tremor (1 cm). A drawing that would enter a body disk (+5 cm)
is redrawn with less wobble. Deterministic (seeded). The learned paths should keep the
drawers' median distance to people and cross no social link (`handdrawn` in
results/bench/learning_summary.csv, docs/benchmarks/index.md).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from pipeline.app.build import preset_weights
from pipeline.app.context import PACKAGE_ROOT
from pipeline.artefacts.store import write_text_atomic
from pipeline.core.experts import optimal_demos
from pipeline.core.features import FEATURE_NAMES, FeatureModel
from pipeline.core.roadmap import build_roadmap
from pipeline.errors import PipelineError, report
from pipeline.inputs.scene_file import load_scene_file
from pipeline.tools import check_out_places, run_tool

DATA = PACKAGE_ROOT / "data"
DRAWINGS_PER_START = 3


def resample(p: np.ndarray, step: float) -> np.ndarray:
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    t = np.linspace(0.0, s[-1], max(int(s[-1] / step), 2) + 1)
    return np.column_stack([np.interp(t, s, p[:, 0]), np.interp(t, s, p[:, 1])])


def smooth(p: np.ndarray, window: int) -> np.ndarray:
    """Moving average with the ends held: cuts corners like a quick hand stroke."""
    pad = np.concatenate([np.repeat(p[:1], window, 0), p, np.repeat(p[-1:], window, 0)])
    kernel = np.ones(2 * window + 1) / (2 * window + 1)
    return np.column_stack([np.convolve(pad[:, i], kernel, "valid") for i in range(2)])


def drawing(route: np.ndarray, rng: np.random.Generator, wobble: float) -> np.ndarray:
    p = smooth(resample(route, 0.1), 5)
    normal = np.gradient(p, axis=0)[:, ::-1] * [1, -1]
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-9)
    walk = smooth(np.cumsum(rng.normal(0, 1, (len(p), 2)), axis=0), 8)[:, 0]
    walk -= np.linspace(walk[0], walk[-1], len(walk))  # pinned at start and goal
    walk *= wobble / max(np.abs(walk).max(), 1e-9)
    p = p + walk[:, None] * normal + rng.normal(0, 0.01, p.shape)
    p[0], p[-1] = route[0], route[-1]
    return p


def write_handdrawn(root: Path) -> None:
    scene = load_scene_file(DATA / "scenes" / "metropolis.json")
    fm = FeatureModel.from_scene(scene)
    roadmap = build_roadmap(scene, fm)
    mdp = roadmap.mdp()
    demos = optimal_demos(mdp, roadmap.positions, roadmap.start_nodes,
                          mdp.solve(preset_weights("polite", list(FEATURE_NAMES))))
    out = root / "demos" / "metropolis_handdrawn.json"
    check_out_places(root, [out.relative_to(root)], "make_demos")  # before the drawings
    rng = np.random.default_rng(11)
    persons, limit = scene.person_xy, scene.body_radius + 0.05
    trajectories = []
    for d in demos:
        for _ in range(DRAWINGS_PER_START):
            wobble = 0.15
            while True:
                p = drawing(d.points, rng, wobble)
                if np.linalg.norm(p[:, None] - persons[None], axis=2).min() > limit:
                    break
                wobble *= 0.7
            trajectories.append(np.round(p, 3).tolist())
    (root / "demos").mkdir(parents=True, exist_ok=True)
    # atomic: a stop or a full disk leaves the shipped file as it was, never cut short
    write_text_atomic(out, json.dumps({"scene": "metropolis",
                                       "trajectories": trajectories}) + "\n")
    print(f"wrote {out}: {len(trajectories)} drawings")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m pipeline.tools.make_demos",
                                     description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("name", choices=["handdrawn"])
    parser.add_argument("--out", type=Path, default=DATA,
                        help="data directory to write into (default: the package's data/)")
    args = parser.parse_args(argv)
    try:
        write_handdrawn(args.out)
    except (PipelineError, OSError) as e:
        raise SystemExit(report(e, "the hand-drawn demonstrations")) from None


if __name__ == "__main__":
    run_tool(main)
