"""Objects built from the settings: one factory per concept."""

from __future__ import annotations

import dataclasses

import numpy as np
from omegaconf import OmegaConf

from pipeline.app import limits
from pipeline.app.config import Config, RandomSceneConfig
from pipeline.app.context import PACKAGE_ROOT, resolve_path
from pipeline.artefacts import read_artefact, topics
from pipeline.artefacts.topics import ARTEFACT_FILE
from pipeline.core.controllers import Controller, PosqController, make_controller
from pipeline.core.features import FEATURE_NAMES, FeatureModel, FeatureParams
from pipeline.core.roadmap import Roadmap, build_roadmap
from pipeline.core.scenegen import REACHABILITY_SPACING, RandomSceneSpec, random_scene
from pipeline.core.world import Scene
from pipeline.errors import PipelineError
from pipeline.inputs.map_file import load_map
from pipeline.inputs.scene_file import load_scene_file
from pipeline.irl import methods
from pipeline.irl.base import Method
from pipeline.irl.fixed import FixedConfig
from pipeline.irl.prior import Prior


def preset_weights(name: str, feature_names: list[str]) -> np.ndarray:
    """The weights of a behaviour preset of conf/reward (`polite`, `rude`: the one source of
    those numbers) on the given features (a feature the preset does not weigh gets 0)."""
    preset = OmegaConf.load(PACKAGE_ROOT / "conf" / "reward" / f"{name}.yaml")
    by_name = dict(zip(preset.get("features", FEATURE_NAMES), preset.weights, strict=True))
    return np.array([float(by_name.get(n, 0.0)) for n in feature_names])


def scene(cfg: Config, rng_for_seed) -> Scene:
    """The configured scene: generated (`scene=random`) or read from a scene file."""
    sc = cfg.scene
    if isinstance(sc, RandomSceneConfig):
        seed = cfg.seed if sc.seed is None else sc.seed
        spec = RandomSceneSpec(**{f.name: getattr(sc, f.name)
                                  for f in dataclasses.fields(RandomSceneSpec)})
        map_grid = load_map(resolve_path(sc.map)) if sc.map else None
        if map_grid is None:  # the start-goal reachability check runs on a 0.2 m lattice
            limits.check_memory(
                f"the reachability lattice of a {spec.width:g} m × {spec.height:g} m room",
                limits.lattice_edges(spec.width * spec.height, REACHABILITY_SPACING, 8),
                limits.BYTES_PER_LATTICE_EDGE, "lower scene.width and scene.height")
        return random_scene(spec, rng_for_seed(seed), name=f"random-{seed}", map_grid=map_grid,
                            map_source=sc.map)
    return load_scene_file(resolve_path(sc.path), body_radius=sc.body_radius,
                           goal_tolerance=sc.goal_tolerance, robot_radius=sc.robot_radius)


def feature_model(cfg: Config, scene: Scene) -> FeatureModel:
    """The true reward's features (reward.features): the expert's and the policy loss's."""
    return FeatureModel.from_scene(scene, cfg.reward)


def learner_feature_model(cfg: Config, scene: Scene) -> FeatureModel:
    """The features the reward is learned on (Config.learner_features), with the reward's
    constants (ρ_r, ρ_p, σ, ...)."""
    params = FeatureParams(**{f.name: getattr(cfg.reward, f.name)
                              for f in dataclasses.fields(FeatureParams)})
    return FeatureModel.from_scene(scene, dataclasses.replace(params,
                                                              features=cfg.learner_features))


def reference_roadmap(cfg: Config, scene: Scene, features: FeatureModel) -> Roadmap:
    """The reference roadmap (roadmap.*) of `scene`, refused up front if it cannot fit."""
    rp = cfg.roadmap
    limits.check_memory(f"the reference roadmap of scene '{scene.name}'",
                        limits.lattice_edges(scene.room.area, rp.spacing, rp.connectivity),
                        limits.BYTES_PER_LATTICE_EDGE,
                        f"raise roadmap.spacing (now {rp.spacing:g} m) or use a smaller scene")
    return build_roadmap(scene, features, rp, cfg.mdp.speed)


def controller(cfg: Config) -> Controller:
    """graph.controller: linear at mdp.speed, or POSQ with its gains."""
    c = cfg.graph.controller
    if c.kind == "linear":
        return make_controller("linear", speed=cfg.mdp.speed)
    return make_controller(c.kind, **{f.name: getattr(c, f.name)
                                      for f in dataclasses.fields(PosqController)})


def prior(cfg: Config) -> Prior:
    return cfg.birl.make_prior(cfg.n_features)


def irl_method(cfg: Config) -> Method:
    return methods()[cfg.birl.kind]


def fixed_weights(cfg: Config) -> np.ndarray | None:
    """`birl=fixed`: its weights (given, or the final iteration of birl.from_run's
    birl.mcap, checked against this run's features); None for methods that learn."""
    b = cfg.birl
    if not isinstance(b, FixedConfig):
        return None
    d = cfg.n_features
    if b.weights is not None:
        w = np.asarray(b.weights, float)
        source = "birl.weights"
    else:
        run = resolve_path(b.from_run)
        art = read_artefact(run / ARTEFACT_FILE["birl"],
                            required_topics=[topics.BIRL_EXPERT, topics.BIRL_ITERATION])
        names = art.one(topics.BIRL_EXPERT)["feature_names"]
        if list(names) != cfg.learner_features:
            raise PipelineError(f"config error: birl.from_run={b.from_run} learned weights on "
                                f"{names}; set birl.features={list(names)}")
        w = np.asarray(art.all(topics.BIRL_ITERATION)[-1]["weights"], float)
        source = f"{run / ARTEFACT_FILE['birl']}"
    if len(w) != d:
        raise PipelineError(f"config error: birl.weights={w.tolist()} needs {d} numbers "
                            f"(the learner's features {cfg.learner_features})")
    if not prior(cfg).in_box(w):
        raise PipelineError(f"config error: the weights from {source} {w.tolist()} lie outside "
                            "[birl.lower, birl.upper]; widen them (e.g. birl.lower=[-100])")
    return w


def growth_weights(cfg: Config, true_weights: list[float] | None) -> tuple[np.ndarray, str]:
    """The reward that grows the graph: the learner's prior mean unless asked otherwise
    (with `birl=fixed`, its weights)."""
    w = cfg.graph.weights
    if w is None or w == "prior":
        fixed = fixed_weights(cfg)
        if fixed is not None:
            return fixed, "fixed"
        return prior(cfg).box_mean(), "prior_mean"
    if w is True or w == "true":
        if true_weights is None:
            raise PipelineError("config error: graph.weights=true needs true weights, but the "
                                "demonstrations have none (expert=file or expert=planner)")
        return np.asarray(true_weights, float), "true"
    return np.asarray(list(w), float), "given"
