"""Objects built from the settings: one factory per concept."""

from __future__ import annotations

import dataclasses
import functools
import logging
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import yaml
from omegaconf import DictConfig, OmegaConf

from pipeline.app import limits
from pipeline.app.config import LEARNER_EXTRA_FEATURES, Config, RandomSceneConfig
from pipeline.app.context import PACKAGE_ROOT, resolve_path
from pipeline.artefacts import Artefact, read_artefact, topics
from pipeline.artefacts.topics import ARTEFACT_FILE
from pipeline.core.adaptive_graph import AdaptiveGraph
from pipeline.core.controllers import Controller, PosqController, make_controller
from pipeline.core.experts import Demonstration
from pipeline.core.features import FEATURE_NAMES, PARAMETER_FIELD, FeatureModel, FeatureParams
from pipeline.core.graph_mdp import Polylines, SpatialGraph
from pipeline.core.obstacles import OccupancyGrid
from pipeline.core.params import ParameterError
from pipeline.core.roadmap import Roadmap, RoadmapParams, build_roadmap, lattice_graph
from pipeline.core.scenegen import REACHABILITY_SPACING, RandomSceneSpec, random_scene
from pipeline.core.state_graph import EdgeTable, NodeTable
from pipeline.core.world import OBSTACLE_RESOLUTION, Scene
from pipeline.errors import PipelineError
from pipeline.inputs.map_file import MapHeader, load_map
from pipeline.inputs.scene_file import SceneExtent, load_scene_file, read_scene_extent
from pipeline.irl import methods
from pipeline.irl.base import Method
from pipeline.irl.birl import BirlMapConfig
from pipeline.irl.fixed import FixedConfig
from pipeline.irl.prior import Prior, broadcast

log = logging.getLogger(__name__)


def preset_weights(name: str, feature_names: list[str]) -> np.ndarray:
    """The weights of a behaviour preset of conf/reward (`polite`, `rude`: the one source of
    those numbers) on the given features (a feature the preset does not weigh gets 0)."""
    preset = OmegaConf.load(PACKAGE_ROOT / "conf" / "reward" / f"{name}.yaml")
    assert isinstance(preset, DictConfig)  # a reward preset is a mapping (features, weights)
    by_name = dict(zip(preset.get("features", FEATURE_NAMES), preset.weights, strict=True))
    return np.array([float(by_name.get(n, 0.0)) for n in feature_names])


def scene(cfg: Config, rng_for_seed: Callable[[int], np.random.Generator]) -> Scene:
    """The configured scene: generated (`scene=random`) or read from a scene file."""
    sc = cfg.scene
    if isinstance(sc, RandomSceneConfig):
        seed = cfg.seed if sc.seed is None else sc.seed
        spec = RandomSceneSpec(**{f.name: getattr(sc, f.name)
                                  for f in dataclasses.fields(RandomSceneSpec)})
        map_grid = map_grid_of(sc.map) if sc.map else None
        if map_grid is None:  # the start-goal reachability check runs on a 0.2 m lattice
            check_reachability_lattice(spec.width * spec.height,
                                       spec.n_singles + spec.n_groups * spec.group_size_max,
                                       spec.width, spec.height)
        # On a map the generator checks reachability on the obstacle raster, finer than the
        # roadmap's lattice: a draw the roadmap cannot connect is drawn again, not refused.
        # (A room's own check runs on a lattice finer than the roadmap's already.)
        accept = None if map_grid is None else \
            (lambda s: not roadmap_cut_off(s, cfg.roadmap))
        return random_scene(spec, rng_for_seed(seed), name=f"random-{seed}", map_grid=map_grid,
                            map_source=sc.map, accept=accept)
    return scene_file(sc.path, body_radius=sc.body_radius, goal_tolerance=sc.goal_tolerance,
                      robot_radius=sc.robot_radius)


# Scene files and maps loaded in this run, by path, file identity and size overrides: the
# start-up checks load and validate them, the stages then use the same objects (scenes are
# immutable). Emptied when a run starts (`forget_scene_files`).
_SCENE_FILES: dict[tuple, Scene] = {}
_MAPS: dict[tuple, OccupancyGrid] = {}


def forget_scene_files() -> None:
    _SCENE_FILES.clear()
    _MAPS.clear()


def _identity(path: Path) -> tuple:
    try:
        st = path.stat()
    except OSError:
        return (str(path),)
    return str(path.resolve()), st.st_ino, st.st_size, st.st_mtime_ns


def scene_file(path: str, *, body_radius: float | None = None,
               goal_tolerance: float | None = None,
               robot_radius: float | None = None) -> Scene:
    """A scene file loaded and validated (once per run), refused up front when its obstacle
    raster cannot fit."""
    resolved = resolve_path(path)
    key = (_identity(resolved), body_radius, goal_tolerance, robot_radius)
    scene = _SCENE_FILES.get(key)  # one lookup: a run in another thread may empty the cache
    if scene is None:
        scene = _SCENE_FILES[key] = load_scene_file(resolved, body_radius=body_radius,
                                                    goal_tolerance=goal_tolerance,
                                                    robot_radius=robot_radius,
                                                    check=check_scene_extent)
    return scene


def scene_file_extent(path: str) -> SceneExtent:
    """A scene file's sizes from its JSON and its map's header (`read_scene_extent`),
    refused when its obstacle raster cannot fit."""
    extent = read_scene_extent(resolve_path(path))
    check_scene_extent(extent)
    return extent


def map_grid_of(path: str) -> OccupancyGrid:
    """A map_server map (once per run), refused before decoding when it cannot fit."""
    resolved = resolve_path(path)
    key = _identity(resolved)
    grid = _MAPS.get(key)  # one lookup, as scene_file's
    if grid is None:
        grid = _MAPS[key] = load_map(resolved, check_cells=check_map_size)
    return grid


def check_scene_extent(extent: SceneExtent) -> None:
    """The obstacle raster of a scene file must fit in memory (checked before it is made)."""
    if extent.map_header is not None:
        check_map_size(extent.map_header)
        return
    x0, y0, x1, y1 = extent.bounds
    limits.check_memory(
        f"{extent.source}: the obstacle raster of its {x1 - x0:g} m × {y1 - y0:g} m room at "
        f"{OBSTACLE_RESOLUTION:g} m", extent.raster_cells, limits.BYTES_PER_RASTER_CELL,
        "use a smaller room ('room' in the scene file)")


def check_map_size(header: MapHeader, per_cell: float = limits.BYTES_PER_RASTER_CELL,
                   use: str = "") -> None:
    """The map's raster must fit in memory (`use`: what else is done on it, said in the
    refusal, and `per_cell` its bytes per cell)."""
    limits.check_memory(
        f"map {header.path}: its {header.width:,} × {header.height:,} px image at "
        f"{header.resolution:g} m/px{use}", header.cells, per_cell,
        "use a smaller or coarser map (crop it, or scale it down and raise 'resolution')")


def check_reachability_lattice(area: float, n_persons: int, width: float,
                               height: float) -> None:
    limits.check_memory(
        f"the reachability lattice of a {width:g} m × {height:g} m room",
        limits.lattice_edges(area, REACHABILITY_SPACING, 8),
        limits.bytes_per_lattice_edge(n_persons, False), "lower scene.width and scene.height")


def feature_model(cfg: Config, scene: Scene) -> FeatureModel:
    """The true reward's features (reward.features): the expert's and the policy loss's."""
    return FeatureModel.from_scene(scene, cfg.reward)


def learner_feature_model(cfg: Config, scene: Scene,
                          names: list[str] | None = None) -> FeatureModel:
    """The features the reward is learned on (Config.learner_features), or `names`, with the
    reward's constants (ρ_r, ρ_p, σ, ...)."""
    chosen = cfg.learner_features if names is None else names
    return FeatureModel.from_scene(scene, feature_params(cfg, chosen))


def demonstrations(demo_msgs: list[dict], features: FeatureModel,
                   speed: float) -> list[Demonstration]:
    """demos.mcap's demonstrations (their messages) with the features of `features`, all
    integrated in one call (`Demonstration.from_polylines`)."""
    return Demonstration.from_polylines(
        [m["start_index"] for m in demo_msgs], [m["points"] for m in demo_msgs], features,
        speed, [m["reached"] for m in demo_msgs], [m.get("subject") for m in demo_msgs])


def feature_params(cfg: Config, names: list[str]) -> FeatureParams:
    """The features `names` with the reward's constants."""
    params = FeatureParams(**{f.name: getattr(cfg.reward, f.name)
                              for f in dataclasses.fields(FeatureParams)})
    return dataclasses.replace(params, features=list(names))


def with_named_features(cfg: Config, scene: Scene, graph: SpatialGraph, have: list[str],
                        want: list[str]) -> SpatialGraph:
    """`graph`, whose edge features are the features `have`, with the features `want`
    instead: the columns it holds are reused (the same name is the same feature: both sets
    take the reward's constants), the others integrated along its edges' driven paths."""
    if want == have:
        return graph
    missing = [n for n in want if n not in have]
    m = graph.mdp
    computed: dict[str, np.ndarray] = {}  # the column of each missing feature
    if missing:
        model, ways = learner_feature_model(cfg, scene, missing), graph.waypoints
        straight = (ways.counts == 2).all() if isinstance(ways, Polylines) \
            else all(len(w) == 2 for w in ways)
        if straight:  # the roadmap: one batch
            values = model.edge_features(graph.positions, m.src, m.dst)
        else:
            values = model.polylines(graph.internal_waypoints())
        computed = {n: values[:, i] for i, n in enumerate(missing)}
    features = m.features
    columns = [features[:, have.index(n)] if n in have else computed[n] for n in want]
    return graph.with_features(np.column_stack(columns).reshape(len(features), len(want)))


def learning_growth(cfg: Config, scene: Scene) -> int:
    """birl.grow_nodes, derived from the scene where it is null (start-up derives it for a
    run; this is for callers that skip start-up, as pipeline.api does); 0 for methods that
    do not learn on the graph."""
    b = cfg.birl
    if not isinstance(b, BirlMapConfig):  # the only methods with grow_nodes
        return 0
    if b.grow_nodes is None:
        return limits.learning_growth(scene.obstacles is not None, scene.name,
                                      b.learns_on_the_graph)[0]
    return int(b.grow_nodes)


def unreachable_message(scene: Scene, cut_off: list[int], spacing: float) -> str:
    return (f"scene '{scene.name}': the goal cannot be reached from start(s) {cut_off} on the "
            f"reference roadmap (spacing {spacing:g} m): the way is closed by "
            "persons' body disks or obstacles; move them or the start, or lower roadmap.spacing")


def roadmap_cut_off(scene: Scene, params: RoadmapParams) -> list[int]:
    """The starts that cannot reach the goal on the reference roadmap's lattice (its edges
    only, no features: what `reference_roadmap` would refuse, found without building it)."""
    positions, src, dst = lattice_graph(scene, params.spacing, params.connectivity)
    n = len(positions)
    n_starts = len(scene.starts)
    lattice = Roadmap(positions, src, dst, np.zeros(len(src)), np.zeros((len(src), 0)),
                      np.zeros(n, bool), np.arange(n - 1 - n_starts, n - 1), n - 1)
    return lattice.starts_without_path_to_goal()


def check_roadmap_reaches_goal(scene: Scene, params: RoadmapParams) -> None:
    """PipelineError when a start cannot reach the goal on the reference roadmap."""
    cut_off = roadmap_cut_off(scene, params)
    if cut_off:
        raise PipelineError(unreachable_message(scene, cut_off, params.spacing))


def fitting_lattice(cfg: Config, scene: Scene, features: FeatureModel, params: RoadmapParams,
                    what: str, fix: str) -> Roadmap:
    """A lattice roadmap of `scene` (`build_roadmap`), refused up front if it cannot fit in
    memory (`what` names it in the message, `fix` says which key to change)."""
    # Only the free space's lattice points get edges (a SLAM map's unknown margin, 99 % of
    # its extent, cost nothing but its points' free test): sized by the free area
    free = scene.free_area
    limits.check_memory(f"{what} of scene '{scene.name}'",
                        limits.lattice_edges(free, params.spacing, params.connectivity),
                        limits.bytes_per_lattice_edge(len(scene.persons),
                                                      scene.obstacles is not None), fix)
    seconds = limits.lattice_seconds(free, params.spacing)
    if seconds > limits.LONG_WORK_S:
        points = f"{free / params.spacing**2:,.0f}"
        log.info("building %s of scene '%s': %s lattice points %g m apart over %.0f m² of "
                 "free space, about %.0f s; for less, %s", what, scene.name, points,
                 params.spacing, free, seconds, fix)
    return build_roadmap(scene, features, params, cfg.mdp.speed)


def reference_roadmap(cfg: Config, scene: Scene, features: FeatureModel) -> Roadmap:
    """The reference roadmap (roadmap.*) of `scene`, refused up front if it cannot fit, and
    when a start cannot reach the goal on it."""
    rp = cfg.roadmap
    roadmap = fitting_lattice(cfg, scene, features, rp, "the reference roadmap",
                              f"raise roadmap.spacing (now {rp.spacing:g} m) or use a "
                              "smaller scene")
    cut_off = roadmap.starts_without_path_to_goal()
    if cut_off:  # nothing can be learned or scored from such a start: refuse, do not run on
        raise PipelineError(unreachable_message(scene, cut_off, rp.spacing))
    return roadmap


def alternatives_lattice(cfg: Config, scene: Scene, spacing: float | None = None
                         ) -> Callable[[], SpatialGraph | None] | None:
    """birl.alternatives=lattice: builds, once and on demand, a 16-connected lattice over the
    free space of `scene` on the learner's features, whose paths the demonstrations are
    compared with. The lattice is None (and the adaptive graph's paths serve) when a start
    cannot reach the goal on it; the factory is None for methods without the setting
    (birl.alternatives_spacing), unless `spacing` is given."""
    spacing = getattr(cfg.birl, "alternatives_spacing", spacing)
    if spacing is None:
        return None

    @functools.cache
    def lattice() -> SpatialGraph | None:
        chosen, why = limits.alternatives_spacing(scene.free_area, spacing, scene.name)
        if why:
            log.info("%s", why)
        built = fitting_lattice(cfg, scene, learner_feature_model(cfg, scene),
                                RoadmapParams(spacing=chosen), "the alternatives lattice",
                                "raise birl.alternatives_spacing or set "
                                "birl.alternatives=graph")
        if built.starts_without_path_to_goal():
            log.warning("a start cannot reach the goal on the %g m alternatives lattice of "
                        "scene '%s': the demonstrations are compared with the adaptive "
                        "graph's paths instead (birl.alternatives=graph)", chosen, scene.name)
            return None
        return built.spatial(built.mdp(cfg.mdp))
    return lattice


def transfer_name(scene_name: str, path: str) -> str:
    """How a transfer scene's metrics are keyed: transfer_<name>_<metric>."""
    return re.sub(r"\W+", "_", scene_name).strip("_") or Path(path).stem


def controller(cfg: Config) -> Controller:
    """graph.controller: linear at mdp.speed, or POSQ with its gains."""
    c = cfg.graph.controller
    if c.kind == "linear":
        return make_controller("linear", speed=cfg.mdp.speed)
    return make_controller(c.kind, **{f.name: getattr(c, f.name)
                                      for f in dataclasses.fields(PosqController)})


def prior(cfg: Config) -> Prior:
    return cfg.birl.make_prior(cfg.n_features)


def learned_weight_box(birl_cfg: dict, n: int) -> Prior:
    """The weight box a finished run's learner searched, from the `birl` part of its
    artefacts' config (its lower and upper bounds, for `n` weights): which of its weights
    lie at the box's bounds or middle (`Prior.at_box`). A KeyError, TypeError or
    ValueError where that config holds no such bounds."""
    return Prior("uniform", 1.0, broadcast(birl_cfg["lower"], n, "lower"),
                 broadcast(birl_cfg["upper"], n, "upper"))


def initial_weights(cfg: Config, rng: np.random.Generator) -> tuple[np.ndarray, str]:
    """The weights learning starts from: birl=fixed's, else birl.init_weights, else a draw
    from the prior with `rng` (the birl stage's generator); and which of them it is."""
    fixed = fixed_weights(cfg)
    if fixed is not None:
        return fixed, "the fixed weights"
    if cfg.birl.init_weights is not None:
        return np.asarray(cfg.birl.init_weights, float), "birl.init_weights"
    return prior(cfg).sample(rng), "a draw from the prior"


def regrowable_graph(cfg: Config, scene: Scene, weights: np.ndarray, min_separation: float,
                     nodes: NodeTable, edges: EdgeTable, start_nodes: list[int],
                     rng: np.random.Generator) -> AdaptiveGraph:
    """A grown adaptive graph (its node and edge tables, as graph.mcap holds them) rebuilt
    so that it can grow further under other weights (birl.grow_nodes), drawing from `rng`."""
    params = dataclasses.replace(cfg.graph, min_separation=min_separation)
    g = AdaptiveGraph(scene, learner_feature_model(cfg, scene), controller(cfg), weights,
                      params, rng, cfg.mdp)
    g.restore(nodes, edges, start_nodes)
    return g


def irl_method(cfg: Config) -> Method:
    return methods()[cfg.birl.kind]


def fixed_weights(cfg: Config) -> np.ndarray | None:
    """`birl=fixed`: its weights (given, or the final iteration of birl.from_run's
    birl.mcap, checked against this run's features); None for methods that learn."""
    found = _fixed(cfg)
    return None if found is None else found[0]


def fixed_weights_source(cfg: Config) -> str | None:
    """`birl=fixed birl.from_run=RUN`: the content digest of RUN's birl.mcap (checked as
    `fixed_weights` checks it), which the artefacts made with its weights record; None
    otherwise."""
    found = _fixed(cfg)
    return None if found is None else found[1]


def _fixed(cfg: Config) -> tuple[np.ndarray, str | None] | None:
    b = cfg.birl
    if not isinstance(b, FixedConfig):
        return None
    d = cfg.n_features
    digest = None
    if b.weights is not None:
        w = np.asarray(b.weights, float)
        source = "birl.weights"
    else:
        assert b.from_run is not None  # FixedConfig: exactly one of weights and from_run
        run = resolve_path(b.from_run)
        art = read_artefact(run / ARTEFACT_FILE["birl"],
                            required_topics=[topics.BIRL_EXPERT, topics.BIRL_ITERATION])
        names = art.one(topics.BIRL_EXPERT)["feature_names"]
        if list(names) != cfg.learner_features:
            raise PipelineError(f"config error: birl.from_run={b.from_run} learned weights on "
                                f"{names}; set birl.features={list(names)}")
        check_feature_constants(cfg, learned_feature_params(art, names), b.from_run)
        w = np.asarray(art.all(topics.BIRL_ITERATION)[-1]["weights"], float)
        source = f"{run / ARTEFACT_FILE['birl']}"
        digest = art.digest
    if len(w) != d:
        raise PipelineError(f"config error: birl.weights={w.tolist()} needs {d} numbers "
                            f"(the learner's features {cfg.learner_features})")
    if not prior(cfg).in_box(w):
        raise PipelineError(f"config error: the weights from {source} {w.tolist()} lie outside "
                            "[birl.lower, birl.upper]; widen them (e.g. birl.lower=[-100])")
    return w, digest


def config_section(art: Artefact, section: str) -> dict:
    """A section (`reward`, `birl`, ...) of the resolved config an artefact was made with (its
    config.yaml attachment); one line where that is not YAML or holds no such section."""
    where = f"artefact {art.path} (attachment config.yaml)"
    try:
        config = yaml.safe_load(art.config_yaml) or {}
    except yaml.YAMLError as e:
        raise PipelineError(f"{where} is not valid YAML ({' '.join(str(e).split())})") from None
    part = config.get(section) if isinstance(config, dict) else None
    if not isinstance(part, dict):
        raise PipelineError(f"{where} has no {section!r} section")
    return part


def learned_feature_params(birl: Artefact, names: list[str]) -> FeatureParams:
    """The learner's FeatureParams: the features the weights belong to (`names`, from
    /birl/expert) with the constants (ρ_r, ρ_p, σ, ...) of the `reward` section of
    birl.mcap's resolved config."""
    where = f"artefact {birl.path} (attachment config.yaml)"
    reward = config_section(birl, "reward")
    known = {f.name for f in dataclasses.fields(FeatureParams)}
    values = {k: v for k, v in reward.items() if k in known}
    values["features"] = list(names)
    try:
        return FeatureParams(**values)
    except (ParameterError, TypeError) as e:
        raise PipelineError(f"{where}: reward features: {e}") from None


def check_feature_constants(cfg: Config, learned: FeatureParams, from_run: str) -> None:
    """Weights mean what they meant only under the constants they were learned with (a
    social weight learned at ρ_p = 1.2 m is another reward at 0.8 m): refuse a deployment
    whose reward.* constants change one of the learner's features."""
    here = feature_params(cfg, learned.features)
    for then, now in zip(learned.selected(), here.selected(), strict=True):
        if then.value != now.value and not (np.isnan(then.value) and np.isnan(now.value)):
            key = f"reward.{PARAMETER_FIELD[then.kind]}"
            raise PipelineError(f"config error: birl.from_run={from_run} learned its weights "
                                f"with {key}={then.value:g}, this run has {now.value:g}: the "
                                f"{then.name} weight would mean another reward; set "
                                f"{key}={then.value:g}")


def growth_weights(cfg: Config, true_weights: list[float] | None) -> tuple[np.ndarray, str]:
    """The reward that grows the graph, unless graph.weights says otherwise: the learner's
    prior mean on the reward's features, 0 on the learner's other features; with
    `birl=fixed`, its weights, 0 on the learner's extras (LEARNER_EXTRA_FEATURES)."""
    w = cfg.graph.weights
    if w is None:
        # Learning: on the reward's features only. The learner's extras (crossing) leave
        # the graph as it is, so learners with other feature sets are compared on the same
        # graph. Growth is sensitive to its reward: grown with crossing as well, the
        # warehouse's optimal expert lost 0.48 and 0.13 in two seeds (0.017 on this graph),
        # and a metropolis deployment's graph lost the detours round a group (12 crossed
        # links, 0 here).
        fixed = fixed_weights(cfg)
        if fixed is not None:
            # A deployment grows under the reward it deploys, whatever this run's
            # reward.features (it has no true reward; often they are the defaults, and a
            # learned social@0.8, gaussian or wall weight was dropped from growth).
            extras = [n in LEARNER_EXTRA_FEATURES and n not in cfg.reward.features
                      for n in cfg.learner_features]
            return np.where(extras, 0.0, fixed), "fixed"
        beyond_reward = [n not in cfg.reward.features for n in cfg.learner_features]
        return np.where(beyond_reward, 0.0, prior(cfg).box_mean()), "prior_mean"
    if w is True or w == "true":
        if true_weights is None:
            raise PipelineError("config error: graph.weights=true needs true weights, but the "
                                "demonstrations have none (expert=file or expert=planner)")
        on_learner = cfg.on_learner_features(true_weights)
        assert on_learner is not None  # Config refuses graph.weights=true otherwise
        return np.asarray(on_learner, float), "true"
    return np.asarray(list(w), float), "given"
