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
    mine = api.load_scene("data/scenes/metropolis.json")   # a scene file, as scene.path reads it
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

import dataclasses
import functools
import logging
import os
import signal
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import yaml
from hydra.errors import HydraException
from omegaconf import DictConfig, OmegaConf, open_dict
from omegaconf.errors import OmegaConfBaseException
from threadpoolctl import threadpool_limits

from pipeline.app import build, limits
from pipeline.app.config import (
    Config,
    FileExpertConfig,
    check_boolean_overrides,
    compose_config,
    load_settings,
    one_job_of_a_sweep,
    register_configs,
)
from pipeline.app.context import stage_rng
from pipeline.app.figure_style import paper_style
from pipeline.app.figures import draw_scene
from pipeline.app.rundir import (
    HYDRA_FILES,
    METRICS_FILE,
    STATUS_FILE,
    Interrupted,
    RunStatus,
    is_sweep_dir,
    read_status,
)
from pipeline.app.summary import Unreadable, read_metrics, summary_table
from pipeline.artefacts import codec, topics
from pipeline.artefacts.store import Artefact, read_artefact
from pipeline.artefacts.topics import ARTEFACT_FILE, STAGES
from pipeline.core.adaptive_graph import AdaptiveGraph
from pipeline.core.experts import Demonstration
from pipeline.core.features import FeatureModel
from pipeline.core.graph_mdp import SpatialGraph
from pipeline.core.world import Scene, scene_from_dict
from pipeline.errors import PipelineError, existing_dir, first_line, one_line
from pipeline.inputs.demo_file import checked_demonstration
from pipeline.inputs.polylines import drop_repeats
from pipeline.inputs.recorded import clean_tracks, cut_trajectory, match_to_starts
from pipeline.irl import methods
from pipeline.irl.base import IRLProblem, IRLResult, Iteration
from pipeline.irl.environment import GraphEnvironment, GrowingGraphEnvironment, spatial_graph
from pipeline.stages import run_pipeline

log = logging.getLogger("pipeline")

register_configs()

PATH_GRAPHS = ("graph", "ref")  # where /eval/paths were planned: adaptive graph, roadmap


# -- runs ----------------------------------------------------------------------------------

@dataclass(frozen=True)
class Run:
    """A run dir, read back: its config, metrics, artefacts and messages (read from the files
    on every access, so a handle sees a re-run)."""
    dir: Path

    def __post_init__(self) -> None:  # Run("outputs/x") as the docstrings write it
        object.__setattr__(self, "dir", _path(self.dir, "run_dir"))

    def _existing_dir(self) -> Path:
        """The run dir, or one line where there is none (a mistyped path read as a run
        with no metrics and an unknown status)."""
        return existing_dir(self.dir, "run dir")

    @property
    def config(self) -> DictConfig:
        """The resolved config the run used: the one attached to its latest stage's artefact
        (`.hydra/config.yaml` for a CLI run without artefacts)."""
        self._existing_dir()
        for stage in reversed(STAGES):
            if (self.dir / ARTEFACT_FILE[stage]).exists():
                cfg = OmegaConf.create(self.artefact(stage).config_yaml)
                assert isinstance(cfg, DictConfig)
                return cfg
        hydra = self.dir / HYDRA_FILES[0]
        if hydra.exists():
            try:
                cfg = OmegaConf.load(hydra)
            except (OSError, ValueError, yaml.YAMLError) as e:
                raise PipelineError(f"{hydra} cannot be read: {first_line(e)}") from None
            if not isinstance(cfg, DictConfig):
                raise PipelineError(f"{hydra} is not a config (a mapping of settings)")
            return cfg
        raise PipelineError(f"run dir {self.dir} holds no artefact and no .hydra/config.yaml")

    @property
    def metrics(self) -> dict[str, float]:
        """metrics.json as a dict; empty when the evaluate stage has not run."""
        path = self._existing_dir() / METRICS_FILE
        if not path.exists():
            status = self.status  # deleted since: {} would read as "not evaluated yet"
            if status.complete and "evaluate" in status.done:
                raise PipelineError(f"{self.dir}: its run completed but metrics.json is gone")
            return {}
        try:
            return read_metrics(path)
        except Unreadable as e:
            raise PipelineError(f"{self.dir}: {e}") from None

    @property
    def status(self) -> RunStatus:
        """How far the run got (status.json): `.state`, `.stage`, `.error`, `.complete`."""
        return read_status(self._existing_dir())

    def artefact(self, stage: str) -> Artefact:
        """The artefact a stage wrote (checked whole before it is returned)."""
        if not isinstance(stage, str) or stage not in ARTEFACT_FILE:
            raise PipelineError(f"unknown stage {stage!r} (one of {', '.join(ARTEFACT_FILE)})")
        # its stage's topic: another stage's file copied in is refused, not read as this one
        return read_artefact(self._existing_dir() / ARTEFACT_FILE[stage], producer_stage=stage,
                             required_topics=[topics.STAGE_TOPIC[stage]])

    def messages(self, stage: str, topic: str) -> pd.DataFrame:
        """The messages of one topic: one row per message (in log-time order), one named
        column per field; numeric arrays are numpy arrays in their cells (lists of records,
        e.g. a scene's persons, stay lists of dicts), the graph's and the roadmap's columns
        too (stored as base64: a message's `count` values each, its features as
        rows × n_features, points as (k, 2))."""
        art = self.artefact(stage)
        rows = [codec.decoded_columns(art, topic, row) for row in art.all(topic)]
        return pd.DataFrame([{k: _cell(v) for k, v in row.items()} for row in rows])

    def paths(self, graph: str = "graph") -> dict[int, np.ndarray]:
        """The greedy paths under the final learned weights (eval.mcap /eval/paths): start
        index -> (K, 2) points; `graph="ref"`: those planned on the reference roadmap."""
        if graph not in PATH_GRAPHS:
            raise PipelineError(f"graph='{graph}': one of {', '.join(PATH_GRAPHS)}")
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
            raise PipelineError(f"paths='{paths}': one of {', '.join(PATH_GRAPHS)}")
        if ax is not None:
            from matplotlib.axes import Axes

            if not isinstance(ax, Axes):  # else matplotlib's AttributeError, deep inside
                raise TypeError(f"ax={ax!r}: a matplotlib Axes, or None for a new figure")
            return draw_scene(ax, self.dir, paths)
        import matplotlib.pyplot as plt

        with paper_style():  # as the sweep's scene.png
            _, ax = plt.subplots(layout="constrained")
            return draw_scene(ax, self.dir, paths, fit_figure=True)


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
    under the current directory. Ctrl-C (a notebook's interrupt) raises KeyboardInterrupt
    naming the stage it stopped, which the run dir's status.json records as `interrupted`."""
    cfg = _compose(overrides)
    if run_dir is None:
        run_dir = Path("outputs") / "api" / datetime.now().strftime("%Y-%m-%d_%H-%M-%S-%f")
    path = _path(run_dir, "run_dir")
    try:
        run_pipeline(cfg, path, config_files_replaced=False)
    except Interrupted as e:  # Ctrl-C (a notebook's "interrupt") is what Python makes of it
        if e.signum == signal.SIGINT:
            raise KeyboardInterrupt(e.describe()) from None
        raise
    return Run(path)


def _path(value: Any, name: str) -> Path:
    """A dir argument as a Path: a non-empty str or os.PathLike (an empty string would be the
    working directory, unsaid)."""
    if isinstance(value, bytes) or not isinstance(value, str | os.PathLike) \
            or not str(value).strip():
        raise PipelineError(f"{name}={value!r}: a path to a dir (a non-empty str or Path)")
    # "~/runs/x" as a shell reads it; absolute, so that a handle outlives a change of dir
    return Path(value).expanduser().absolute()


def _compose(overrides: Sequence[str]) -> DictConfig:
    """`compose_config`, with Hydra's errors as one-line PipelineErrors (as `birlg` says
    them) and one string refused: it would be read one character at a time."""
    overrides = _overrides_list(overrides)
    hydra = [o for o in overrides if o.lstrip("+~").startswith(("hydra.", "hydra/"))]
    if hydra:  # the API has no Hydra run: they would be ignored silently
        raise PipelineError(f"{hydra[0]}: Hydra's own settings (hydra.*, hydra/...) have no "
                            "effect in pipeline.api (give the run's dir as run_dir=...)")
    try:
        cfg = compose_config(overrides, with_hydra=True)
        if warning := one_job_of_a_sweep(OmegaConf.select(cfg, "hydra.sweeper.params"),
                                         "run the sweep with `birlg -m` and read its dir "
                                         "with pipeline.api.sweep()"):
            log.warning(warning)
        with open_dict(cfg):
            del cfg["hydra"]  # the run's config, as birlg's job sees it
        check_boolean_overrides(cfg, overrides)
        # interpolations resolved now, so a bad one is this one line, not a failure later
        OmegaConf.to_container(cfg, resolve=True, throw_on_missing=True)
    except (HydraException, OmegaConfBaseException) as e:  # said as `birlg` says it
        raise PipelineError(f"config error: {one_line(e)}") from None
    return cfg


def open_run(run_dir: str | Path) -> Run:
    """The handle of an existing run dir (made by `birlg`, `run` or a sweep job)."""
    handle = Run(run_dir)
    path = handle._existing_dir()
    if is_sweep_dir(path):
        raise PipelineError(f"{path} is a sweep dir, not a run dir: read it with "
                            "pipeline.api.sweep(), or open one of its jobs (e.g. its 0/)")
    if not any((path / name).exists()
               for name in (STATUS_FILE, HYDRA_FILES[0], *ARTEFACT_FILE.values())):
        raise PipelineError(f"{path} holds no run (no status.json, artefact or "
                            ".hydra/config.yaml)")
    return handle


def load_scene(path: str | Path) -> Scene:
    """A scene file (JSON, with its map), read and checked as `scene.path=...` reads it: a
    relative path from the current directory, else from the package's data/ (so
    `load_scene("data/scenes/metropolis.json")` works from any directory)."""
    return build.scene_file(os.fspath(path))


def sweep(sweep_dir: str | Path) -> pd.DataFrame:
    """The table of a Hydra multirun dir, as `make aggregate` writes it to summary.csv: one
    row per job with its overrides, status, error and every metric (writes nothing)."""
    return summary_table(existing_dir(_path(sweep_dir, "sweep_dir"), "sweep dir"))


# Backwards compatible helpers of the first API (a run dir instead of a handle).
def artefact(run_dir: str | Path, stage: str) -> Artefact:
    """The artefact a stage wrote into `run_dir`: `Run(run_dir).artefact(stage)`."""
    return Run(_path(run_dir, "run_dir")).artefact(stage)


def messages(run_dir: str | Path, stage: str, topic: str) -> pd.DataFrame:
    """The messages of one topic as a DataFrame: `Run(run_dir).messages(stage, topic)`."""
    return Run(_path(run_dir, "run_dir")).messages(stage, topic)


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
        """Every iteration's weights, log likelihood and log prior (`trace` as a table)."""
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
          overrides: Sequence[str] = (), denoise: bool = False, **config: Any) -> Learned:
    """Learn reward weights for `scene` from `demos` with the IRL method `method` (map, mcmc,
    policywalk, maxent, fixed), in memory: grow the adaptive graph, then fit, as the graph
    and birl stages do (same seeds: the same inputs and settings give the same weights).

    demos: Demonstration objects, /demos rows (dicts with "points" and optionally
    "start_index", "reached"), or (K, 2) polylines; a missing start index is the nearest
    scene start to the first point, `reached` whether the last point is within the goal
    tolerance. They are checked and cut as a demonstration file's trajectories are (in the
    room, clear of bodies and obstacles, beginning within 1 m of a start, cut where they
    run on past the goal disk); rows marked "heldout" (evaluate.holdout) are left out, as
    the run left them out. Their features are computed on the learner's features.
    denoise: read polylines as `expert=file` reads a file's trajectories (its default
    expert.denoise=true): smoothed of tracking noise, and straying a few centimetres out of
    the room or ending a few millimetres outside the goal disk taken as that noise. Off by
    default: polylines given here are often a run's own paths, whose corners on the
    roadmap the smoothing would round off. Rows and Demonstration objects are what a run
    learned from, taken as they are.
    config: the method's settings (birl.* without the prefix, e.g. n_iterations=5, beta=10);
    overrides: any other setting, as command-line overrides (e.g. "graph=small",
    "mdp=paper", "reward=rude" for the feature constants). The scene settings are unused.
    """
    if not isinstance(denoise, bool | np.bool_):
        raise PipelineError(f"denoise={denoise!r} must be true or false")
    if not isinstance(method, str) or method not in methods():
        raise PipelineError(f"unknown method {method!r} (one of {', '.join(methods())})")
    scene = checked_scene(scene)
    given = demo_list(demos)
    cfg = settings_for_learning(method, seed, overrides, config)
    cfg = sized_graph(cfg, scene)
    # held-out rows of a run's /demos (evaluate.holdout) never enter learning, as in the run;
    # a flag that is no bool (1, "yes") is refused rather than read as "not held out"
    for k, d in enumerate(given):
        flag = d.get("heldout", False) if isinstance(d, Mapping) else False
        if not isinstance(flag, bool | np.bool_):
            raise PipelineError(f"demonstration {k}: heldout={flag!r} must be true or false")
    training = [d for d in given if not (isinstance(d, Mapping) and d.get("heldout", False))]
    if not training:
        raise PipelineError(f"all {len(given)} demonstrations are held out (their 'heldout' "
                            "is true): nothing to learn from")
    features = build.learner_feature_model(cfg, scene)
    demonstrations = as_demonstrations(training, scene, features, cfg.mdp.speed, denoise)
    with threadpool_limits(1):  # as the stages run (and one thread is faster here)
        graph_weights, _ = build.growth_weights(cfg, None)
        graph = AdaptiveGraph(scene, features, build.controller(cfg), graph_weights, cfg.graph,
                              stage_rng(cfg.seed, "graph"), cfg.mdp)
        graph.initialise(list(demonstrations))
        graph.grow()
        rng = stage_rng(cfg.seed, "birl")
        w0, _ = build.initial_weights(cfg, rng)
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


def demo_list(demos: Any) -> list[DemoLike]:
    """`learn`'s demos as a list, or one line saying what was given instead."""
    if isinstance(demos, pd.DataFrame):
        raise PipelineError("demos is a DataFrame: give its rows, "
                            "run.messages('demos', '/demos').to_dict('records')")
    if isinstance(demos, str | bytes | np.ndarray | Mapping | Demonstration) \
            or not isinstance(demos, Iterable):
        raise PipelineError(f"demos must be a non-empty list of demonstrations (polylines, "
                            f"/demos rows or Demonstration objects), not "
                            f"{type(demos).__name__}")
    listed = list(demos)
    if not listed:
        raise PipelineError("demos must be a non-empty list of demonstrations (polylines, "
                            "/demos rows or Demonstration objects)")
    return listed


def checked_scene(scene: Any) -> Scene:
    """`scene` validated as a scene file is (a Scene made by hand, e.g. with
    dataclasses.replace, can hold what no scene file may)."""
    if not isinstance(scene, Scene):
        raise PipelineError(f"scene must be a pipeline.core.world.Scene (e.g. Run.scene()), "
                            f"not {type(scene).__name__}")
    try:
        data = scene.to_dict()
    except (AttributeError, TypeError, ValueError) as e:
        raise PipelineError(f"scene is not a valid Scene: {first_line(e)}") from None
    scene_from_dict(data, source="learn(): scene", map_grid=scene.map_grid)  # SceneError
    return scene


def sized_graph(cfg: Config, scene: Scene) -> Config:
    """`cfg` with graph.max_nodes derived from the scene where it is null, and the size
    checks, as `run` makes them before the graph stage (`pipeline.app.preflight`)."""
    max_nodes = cfg.graph.max_nodes
    if max_nodes is None:  # the default: derived from the scene (it was a TypeError here)
        max_nodes = limits.graph_size(scene.free_area, cfg.reward.rho_personal, scene.name)[0]
        cfg = dataclasses.replace(cfg, graph=dataclasses.replace(cfg.graph,
                                                                 max_nodes=max_nodes))
    limits.check_graph_size(max_nodes, scene.free_area, cfg.reward.rho_personal, scene.name)
    return cfg


def settings_for_learning(method: str, seed: int, overrides: Sequence[str],
                          birl: Mapping[str, Any]) -> Config:
    """The checked settings of `learn`: the app's config with `birl=method`, `seed`, the
    overrides and the method's settings `birl`."""
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer):
        raise PipelineError(f"seed must be an integer, not {seed!r}")
    listed = _overrides_list(overrides)
    given = {o.lstrip("+~").split("=")[0]: o for o in listed}  # key -> its override
    for key, argument in (("birl", "method"), ("seed", "seed")):
        if key in given:  # else the override won silently over the argument
            raise PipelineError(f"override {given[key]!r}: give it as learn()'s {argument} "
                                "argument instead")
    twice = [key for key in birl or {} if f"birl.{key}" in given]
    if twice:  # else the keyword won silently over the override
        raise PipelineError(f"birl.{twice[0]} is given twice, as learn()'s keyword {twice[0]}= "
                            "and in overrides: give it once")
    dc = _compose([f"birl={method}", f"seed={seed}", *listed])
    for key, value in (birl or {}).items():
        if isinstance(value, np.ndarray):
            value = value.tolist()
        elif isinstance(value, np.generic):  # numpy scalars, as plain numbers
            value = value.item()
        try:
            dc.birl[key] = value
        except OmegaConfBaseException as e:
            reason = str(e).splitlines()[0]
            raise PipelineError(f"config error: birl.{key}={value!r}: {reason}") from None
        if isinstance(value, str) and isinstance(dc.birl[key], bool | int | float):
            # a keyword is Python, not the command line: "5" is refused, as seed="1" is
            kind = {bool: "true or false", int: "an integer"}.get(type(dc.birl[key]), "a number")
            raise PipelineError(f"{key}={value!r} must be {kind}, not a string")
    return load_settings(dc)


def _overrides_list(overrides: Sequence[str]) -> list[str]:
    if isinstance(overrides, str):
        raise PipelineError(f"overrides must be a list of 'key=value' strings, e.g. "
                            f"[{overrides!r}], not one string")
    if overrides is None or isinstance(overrides, Mapping) \
            or not isinstance(overrides, Iterable):
        raise PipelineError(f"overrides must be a list of 'key=value' strings, not "
                            f"{type(overrides).__name__}")
    listed = list(overrides)
    bad = [o for o in listed if not isinstance(o, str)]
    if bad:
        raise PipelineError(f"overrides must be 'key=value' strings: {bad[0]!r} is a "
                            f"{type(bad[0]).__name__}")
    return listed


def as_demonstrations(demos: Sequence[DemoLike], scene: Scene, features: FeatureModel,
                      speed: float, denoise: bool = False) -> list[Demonstration]:
    """`learn`'s demonstrations, checked and cut at the goal disk as a demonstration file's
    trajectories are (`pipeline.inputs`), with the features of their own segments. With
    `denoise`, given polylines are read wholly as a file's trajectories are
    (`clean_tracks`: smoothed of tracking noise, moved onto the room's edge where they stray
    a few centimetres out, taken to reach the goal where they end outside its disk by less
    than their noise). Rows (a run's /demos: what it learned from) and Demonstration
    objects are taken as they are."""
    given = [demo_fields(d, scene, f"demonstration {k}") for k, d in enumerate(demos)]
    tracks = [points for points, *_ in given]
    read: dict[int, np.ndarray] = {}  # given polylines, as a file's trajectories are read
    raw = [k for k, d in enumerate(demos) if not isinstance(d, Demonstration | Mapping)]
    if denoise and raw:
        read = dict(zip(raw, clean_tracks([tracks[k] for k in raw], scene.goal,
                                          scene.goal_tolerance, scene.room, "learn(): demos",
                                          [f"demonstration {k}" for k in raw]), strict=True))
    out = []
    for k, (_, start, reached, subject) in enumerate(given):
        what = f"demonstration {k}"
        cut = read.get(k)
        if cut is None:  # as given, cut at the goal disk
            cut = cut_trajectory(tracks[k], scene.goal, scene.goal_tolerance, scene.room, what)
            whole = drop_repeats(tracks[k])
            if len(cut) == len(whole) and np.array_equal(cut[:-1], whole[:-1]):
                cut = whole  # it ends at its first point in the disk (a synthetic expert's node)
        nearest = match_to_starts([cut], scene.starts, scene.goal,
                                  FileExpertConfig.start_radius, scene.goal_tolerance, what)[0]
        if start is not None and start != nearest:
            raise PipelineError(f"{what} begins at start {nearest}, not at its "
                                f"start_index={start}")
        demo = checked_demonstration(nearest, cut, None if subject is None else str(subject),
                                     scene, features, speed, what)
        if reached is not None and bool(reached) != demo.reached:
            demo = dataclasses.replace(demo, reached=bool(reached))
        out.append(demo)
    return out


def demo_fields(demo: DemoLike, scene: Scene,
                what: str) -> tuple[np.ndarray, int | None, bool | None, Any]:
    """One of `learn`'s demonstrations as (points, start index, reached, subject), each
    None where not given; refused in one line when malformed."""
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
    try:
        pts = np.asarray(points, float)
    except (TypeError, ValueError):
        raise PipelineError(f"{what} must be a polyline of (x, y) numbers, got "
                            f"{type(points).__name__}") from None
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2 or not np.isfinite(pts).all():
        raise PipelineError(f"a demonstration must be a polyline of at least two finite (x, y) "
                            f"points, got an array of shape {pts.shape} ({what})")
    if start is not None and (isinstance(start, bool) or not isinstance(start, int | np.integer)):
        raise PipelineError(f"{what}: start_index={start!r} must be an integer, not "
                            f"{type(start).__name__}")
    if start is not None and not 0 <= start < len(scene.starts):  # -1: the last start
        raise PipelineError(f"start_index={start!r} is not a start of the scene (0 to "
                            f"{len(scene.starts) - 1})")
    if reached is not None and not isinstance(reached, bool | np.bool_):  # "no" is truthy
        raise PipelineError(f"{what}: reached={reached!r} must be true or false")
    return pts, start, reached, subject


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
