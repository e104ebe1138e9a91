"""The pipeline from Python (a notebook, a script): run it, open earlier runs and sweeps, and
learn a reward from Python objects without files.

    from pipeline import api
    run = api.run(["scene=random", "seed=3", "graph=small"], run_dir="outputs/nb/seed3")
    run.metrics["policy_loss_norm"]                       # metrics.json as a dict
    curve = run.messages("evaluate", "/eval/policy_loss")  # DataFrame, arrays as numpy arrays
    paths = run.paths()                                    # {start index: (K, 2) learned path}
    run.plot().figure.savefig("outputs/nb/seed3.png")      # scene, demos and learned paths
    earlier = api.open_run("outputs/nb/seed3")             # the same handle for a run dir
    table = api.sweep("multirun/quick/2025-01-01_12-00")   # one row per job, as summary.csv

    scene = earlier.scene()                                # a pipeline.core.world.Scene
    demos = earlier.messages("demos", "/demos").to_dict("records")  # or Demonstrations, arrays
    learned = api.learn(scene, demos, method="maxent", overrides=["graph=small"],
                        n_iterations=5)
    learned.weights, learned.feature_names, learned.trace  # final weights, per-iteration table

`run` composes the same typed Hydra config as `birlg` and runs the same stages in this
process (errors are `PipelineError`s with the same one-line messages). `learn` grows the
adaptive graph and calls the IRL method as the graph and birl stages do, with the same
seeds, so the same scene, demonstrations and settings give the same weights; it writes
nothing.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from hydra.errors import HydraException
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException
from threadpoolctl import threadpool_limits

from pipeline.app import build
from pipeline.app.config import Config, compose_config, load_settings, register_configs
from pipeline.app.context import stage_rng
from pipeline.app.figure_style import paper_style
from pipeline.app.figures import SCENE_SIZE_IN, draw_scene
from pipeline.app.rundir import RunStatus, read_status
from pipeline.app.summary import summary_table
from pipeline.artefacts import codec, topics
from pipeline.artefacts.store import Artefact, read_artefact
from pipeline.artefacts.topics import ARTEFACT_FILE, STAGES
from pipeline.core.adaptive_graph import AdaptiveGraph
from pipeline.core.experts import Demonstration
from pipeline.core.features import FeatureModel
from pipeline.core.graph_mdp import SpatialGraph
from pipeline.core.world import Scene
from pipeline.errors import PipelineError
from pipeline.irl import methods
from pipeline.irl.base import IRLProblem, IRLResult, Iteration
from pipeline.irl.environment import GraphEnvironment, GrowingGraphEnvironment, spatial_graph
from pipeline.stages import run_pipeline

register_configs()

PATH_GRAPHS = ("graph", "ref")  # where /eval/paths were planned: adaptive graph, roadmap


# -- runs ----------------------------------------------------------------------------------

@dataclass(frozen=True)
class Run:
    """A run dir, read back: its config, metrics, artefacts and messages (read from the files
    on every access, so a handle sees a re-run)."""
    dir: Path

    @property
    def config(self) -> DictConfig:
        """The resolved config the run used: the one attached to its latest stage's artefact
        (`.hydra/config.yaml` for a CLI run without artefacts)."""
        for stage in reversed(STAGES):
            if (self.dir / ARTEFACT_FILE[stage]).exists():
                cfg = OmegaConf.create(self.artefact(stage).config_yaml)
                assert isinstance(cfg, DictConfig)
                return cfg
        hydra = self.dir / ".hydra" / "config.yaml"
        if hydra.exists():
            cfg = OmegaConf.load(hydra)
            assert isinstance(cfg, DictConfig)
            return cfg
        raise PipelineError(f"run dir {self.dir} holds no artefact and no .hydra/config.yaml")

    @property
    def metrics(self) -> dict[str, float]:
        """metrics.json as a dict; empty when the evaluate stage has not run."""
        path = self.dir / "metrics.json"
        return json.loads(path.read_text()) if path.exists() else {}

    @property
    def status(self) -> RunStatus:
        """How far the run got (status.json): `.state`, `.stage`, `.error`, `.complete`."""
        return read_status(self.dir)

    def artefact(self, stage: str) -> Artefact:
        """The artefact a stage wrote (checked whole before it is returned)."""
        if stage not in ARTEFACT_FILE:
            raise ValueError(f"unknown stage '{stage}' (one of {', '.join(ARTEFACT_FILE)})")
        return read_artefact(self.dir / ARTEFACT_FILE[stage], producer_stage=stage)

    def messages(self, stage: str, topic: str) -> pd.DataFrame:
        """The messages of one topic: one row per message (in log-time order), one named
        column per field; numeric arrays are numpy arrays in their cells (lists of records,
        e.g. a scene's persons, stay lists of dicts)."""
        rows = self.artefact(stage).all(topic)
        return pd.DataFrame([{k: _cell(v) for k, v in row.items()} for row in rows])

    def paths(self, graph: str = "graph") -> dict[int, np.ndarray]:
        """The greedy paths under the final learned weights (eval.mcap /eval/paths): start
        index -> (K, 2) points; `graph="ref"`: those planned on the reference roadmap."""
        if graph not in PATH_GRAPHS:
            raise ValueError(f"graph='{graph}': one of {', '.join(PATH_GRAPHS)}")
        return {int(p["start"]): np.asarray(p["points"], float)
                for p in self.artefact("evaluate").all(topics.EVAL_PATHS) if p["graph"] == graph}

    def scene(self) -> Scene:
        """The run's scene as the stages use it (with its map, when it has one)."""
        return codec.decode_scene(self.artefact("scene"))

    def plot(self, ax: Any = None, paths: str = "graph") -> Any:
        """The scene (room, map, persons, social links, starts, goal) with the graph's nodes,
        the demonstrations and the learned paths (`paths`: "graph" or "ref"), as far as the
        run has them, drawn on `ax` (a new figure when None); returns the Axes. The backend
        is the caller's (inline in a notebook; `matplotlib.use("Agg")` in scripts)."""
        if paths not in PATH_GRAPHS:
            raise ValueError(f"paths='{paths}': one of {', '.join(PATH_GRAPHS)}")
        if ax is not None:
            from matplotlib.axes import Axes

            if not isinstance(ax, Axes):  # else matplotlib's AttributeError, deep inside
                raise TypeError(f"ax={ax!r}: a matplotlib Axes, or None for a new figure")
            return draw_scene(ax, self.dir, paths)
        import matplotlib.pyplot as plt

        with paper_style():  # as the sweep's scene.png
            _, ax = plt.subplots(figsize=SCENE_SIZE_IN, layout="constrained")
            return draw_scene(ax, self.dir, paths)


def _cell(value: Any) -> Any:
    """A message field for a DataFrame cell: numeric (nested) lists as numpy arrays."""
    if not isinstance(value, list):
        return value
    try:
        array = np.asarray(value)
    except ValueError:  # ragged
        return value
    return array if array.dtype.kind in "biuf" else value


def run(overrides: Sequence[str] = (), run_dir: str | Path | None = None) -> Run:
    """Run the pipeline with command-line style overrides (as `birlg` takes them) and return
    the run's handle. `run_dir` defaults to a new `outputs/api/<date-time-microseconds>` dir
    under the current directory."""
    cfg = _compose(overrides)
    if run_dir is None:
        run_dir = Path("outputs") / "api" / datetime.now().strftime("%Y-%m-%d_%H-%M-%S-%f")
    run_pipeline(cfg, Path(run_dir))
    return Run(Path(run_dir))


def _compose(overrides: Sequence[str]) -> DictConfig:
    """`compose_config`, with Hydra's errors as one-line PipelineErrors (as `birlg` says
    them) and one string refused: it would be read one character at a time."""
    try:
        return compose_config(_overrides_list(overrides))
    except (HydraException, OmegaConfBaseException) as e:
        lines = [ln.strip() for ln in str(e).splitlines() if ln.strip()]
        raise PipelineError(f"config error: {lines[0] if lines else type(e).__name__}") \
            from None


def open_run(run_dir: str | Path) -> Run:
    """The handle of an existing run dir (made by `birlg`, `run` or a sweep job)."""
    path = Path(run_dir)
    if not path.is_dir():
        raise PipelineError(f"run dir {path} not found")
    return Run(path)


def sweep(sweep_dir: str | Path) -> pd.DataFrame:
    """The table of a Hydra multirun dir, as `make aggregate` writes it to summary.csv: one
    row per job with its overrides, status, error and every metric (writes nothing)."""
    path = Path(sweep_dir)
    if not path.is_dir():
        raise PipelineError(f"sweep dir {path} not found")
    return summary_table(path)


# Backwards compatible helpers of the first API (a run dir instead of a handle).
def artefact(run_dir: str | Path, stage: str) -> Artefact:
    """The artefact a stage wrote into `run_dir`: `Run(run_dir).artefact(stage)`."""
    return Run(Path(run_dir)).artefact(stage)


def messages(run_dir: str | Path, stage: str, topic: str) -> pd.DataFrame:
    """The messages of one topic as a DataFrame: `Run(run_dir).messages(stage, topic)`."""
    return Run(Path(run_dir)).messages(stage, topic)


# -- learning in memory --------------------------------------------------------------------

@dataclass(frozen=True, eq=False)
class Learned:
    """What `learn` returns: the IRL method's result with the names of its weights, the
    graph it learned on and the settings it ran with."""
    result: IRLResult
    feature_names: list[str]
    graph: SpatialGraph  # the adaptive graph at the end (it grows with birl.grow_nodes)
    settings: Config

    @property
    def weights(self) -> np.ndarray:
        """The final weights (d,), in the order of `feature_names`."""
        return self.result.weights

    @property
    def iterations(self) -> list[Iteration]:
        return self.result.iterations

    @property
    def trace(self) -> pd.DataFrame:
        """One row per iteration: weights (numpy array), log likelihood, log prior, MDP
        solves spent so far."""
        return pd.DataFrame([{"iteration": it.index, "weights": it.weights,
                              "log_likelihood": it.log_likelihood, "log_prior": it.log_prior,
                              "mdp_solves": int(n)}
                             for it, n in zip(self.result.iterations, self.result.mdp_solves,
                                              strict=True)])


DemoLike = Demonstration | Mapping[str, Any] | np.ndarray | Sequence[Sequence[float]]


def learn(scene: Scene, demos: Sequence[DemoLike], method: str = "map", *, seed: int = 0,
          overrides: Sequence[str] = (), **config: Any) -> Learned:
    """Learn reward weights for `scene` from `demos` with the IRL method `method` (map, mcmc,
    policywalk, maxent, fixed), in memory: grow the adaptive graph, then fit, as the graph
    and birl stages do (same seeds: the same inputs and settings give the same weights).

    demos: Demonstration objects, /demos rows (dicts with "points" and optionally
    "start_index", "reached"), or (K, 2) polylines; a missing start index is the nearest
    scene start to the first point, `reached` whether the last point is within the goal
    tolerance. Their features are computed on the learner's features.
    config: the method's settings (birl.* without the prefix, e.g. n_iterations=5, beta=10);
    overrides: any other setting, as command-line overrides (e.g. "graph=small",
    "mdp=paper", "reward=rude" for the feature constants). The scene settings are unused.
    """
    if method not in methods():
        raise PipelineError(f"unknown method '{method}' (one of {', '.join(methods())})")
    if not isinstance(scene, Scene):
        raise PipelineError(f"scene must be a pipeline.core.world.Scene (e.g. Run.scene()), "
                            f"not {type(scene).__name__}")
    if isinstance(demos, str | np.ndarray) or not len(demos):
        raise PipelineError("demos must be a non-empty list of demonstrations (polylines, "
                            "/demos rows or Demonstration objects)")
    cfg = settings_for_learning(method, seed, overrides, config)
    features = build.learner_feature_model(cfg, scene)
    demonstrations = [as_demonstration(d, scene, features, cfg.mdp.speed) for d in demos]
    with threadpool_limits(1):  # as the stages run (and one thread is faster here)
        graph_weights, _ = build.growth_weights(cfg, None)
        graph = AdaptiveGraph(scene, features, build.controller(cfg), graph_weights, cfg.graph,
                              stage_rng(cfg.seed, "graph"), cfg.mdp)
        graph.initialise(list(demonstrations))
        graph.grow()
        rng = stage_rng(cfg.seed, "birl")
        w0 = build.initial_weights(cfg, rng)
        env = learning_environment(cfg, scene, graph, graph_weights)

        @functools.cache
        def roadmap() -> SpatialGraph:
            r = build.reference_roadmap(cfg, scene, build.learner_feature_model(cfg, scene))
            return r.spatial(r.mdp(cfg.mdp))

        problem = IRLProblem([d.stats(cfg.mdp) for d in demonstrations],
                             [d.points for d in demonstrations], env, build.prior(cfg), w0, rng,
                             roadmap, lattice=build.alternatives_lattice(cfg, scene))
        result = build.irl_method(cfg).fit(problem, cfg.birl)
    return Learned(result, cfg.learner_features, env.graph, cfg)


def settings_for_learning(method: str, seed: int, overrides: Sequence[str],
                          birl: Mapping[str, Any]) -> Config:
    """The checked settings of `learn`: the app's config with `birl=method`, `seed`, the
    overrides and the method's settings `birl`."""
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer):
        raise PipelineError(f"seed must be an integer, not {seed!r}")
    dc = _compose([f"birl={method}", f"seed={seed}", *_overrides_list(overrides)])
    for key, value in birl.items():
        try:
            dc.birl[key] = value.tolist() if isinstance(value, np.ndarray) else value
        except OmegaConfBaseException as e:
            reason = str(e).splitlines()[0]
            raise PipelineError(f"config error: birl.{key}={value!r}: {reason}") from None
    return load_settings(dc)


def _overrides_list(overrides: Sequence[str]) -> list[str]:
    if isinstance(overrides, str):
        raise PipelineError(f"overrides must be a list of 'key=value' strings, e.g. "
                            f"[{overrides!r}], not one string")
    return list(overrides)


def as_demonstration(demo: DemoLike, scene: Scene, features: FeatureModel,
                     speed: float) -> Demonstration:
    """One demonstration of `learn` with the features of its own segments."""
    start = reached = subject = None
    if isinstance(demo, Demonstration):
        points: Any = demo.points
        start, reached, subject = demo.start_index, demo.reached, demo.subject
    elif isinstance(demo, Mapping):
        if "points" not in demo:
            raise PipelineError(f"a demonstration given as a dict needs 'points' (has "
                                f"{', '.join(map(repr, demo)) or 'no keys'})")
        points = demo["points"]
        start, reached, subject = (demo.get("start_index"), demo.get("reached"),
                                   demo.get("subject"))
    else:
        points = demo
    pts = np.asarray(points, float)
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2 or not np.isfinite(pts).all():
        raise PipelineError(f"a demonstration must be a polyline of at least two finite (x, y) "
                            f"points, got an array of shape {pts.shape}")
    if start is None:
        start = int(np.argmin(np.linalg.norm(np.asarray(scene.starts) - pts[0], axis=1)))
    elif isinstance(start, bool) or not isinstance(start, int | np.integer) \
            or not 0 <= start < len(scene.starts):  # -1 would silently be the last start
        raise PipelineError(f"start_index={start!r} is not a start of the scene (0 to "
                            f"{len(scene.starts) - 1})")
    if reached is None:
        reached = bool(np.linalg.norm(pts[-1] - scene.goal) <= scene.goal_tolerance)
    return Demonstration.from_points(int(start), pts, features, speed, bool(reached),
                                     None if subject is None else str(subject))


def learning_environment(cfg: Config, scene: Scene, graph: AdaptiveGraph,
                         graph_weights: np.ndarray) -> GraphEnvironment:
    """The grown graph as the birl stage sees it (as graph.mcap's tables hold it)."""
    grow_nodes = build.learning_growth(cfg, scene)
    if grow_nodes <= 0:
        return GraphEnvironment(spatial_graph(graph), cfg.mdp)
    adaptive = build.regrowable_graph(cfg, scene, graph_weights, graph.min_separation,
                                      graph.node_table(), graph.edge_table(),
                                      graph.start_nodes.tolist(),
                                      stage_rng(cfg.seed, "birl", 1))
    return GrowingGraphEnvironment(adaptive, cfg.mdp, grow_nodes)
