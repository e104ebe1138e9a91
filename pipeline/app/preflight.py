"""Start-up checks: everything that can be refused before the first stage is refused here,
in one line naming the key or file and, for sizes, the estimate (`run_pipeline` calls
`preflight` before the run dir is touched).

In the order of the run: the input files of the stages that run (scene file and its map,
demonstration file, transfer scenes, the run dirs `from_run` and `birl.from_run` point to),
then the sizes of what will be built (the obstacle raster, a random room's reachability
lattice, the reference roadmap, the adaptive graph; `limits`) from the files' headers alone,
then the files themselves: the scene file and every transfer scene are loaded and validated
(transfer scenes also on their reference roadmap's lattice, and no two with one name),
`birl=fixed` gets its weights, and the graph's resolution is checked on the scene's free
space. Loaded scene files are kept for the stages (`build.scene_file`). `graph.max_nodes`
left null is derived from the scene's free space here (`limits.graph_size`, logged in one
line), `birl.grow_nodes` left null from whether it has obstacles and the learner learns on
the graph (`limits.learning_growth`);
`run_pipeline` puts the numbers into the settings and the recorded config.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from pipeline.app import build, limits
from pipeline.app.config import (
    SYNTHETIC_EXPERTS,
    BoltzmannExpertConfig,
    Config,
    FileExpertConfig,
    FileSceneConfig,
    PlannerExpertConfig,
    RandomSceneConfig,
)
from pipeline.app.context import resolve_path
from pipeline.app.provenance import check_source, file_digest, files_digest
from pipeline.app.rundir import check_from_run
from pipeline.artefacts import codec, topics
from pipeline.artefacts.store import content_digest, read_artefact
from pipeline.artefacts.topics import ARTEFACT_FILE
from pipeline.core import scenegen
from pipeline.core.obstacles import ObstacleMap
from pipeline.core.social_planner import spacing_over
from pipeline.core.world import BodyParams, Room, Scene
from pipeline.errors import PipelineError
from pipeline.inputs.map_file import MapHeader, read_map_header
from pipeline.inputs.recordings import check_readable
from pipeline.irl.birl import BirlMapConfig
from pipeline.irl.fixed import FixedConfig

log = logging.getLogger("pipeline")


@dataclass(frozen=True)
class SceneFacts:
    """What the size checks need to know of the scene the stages will work on, known before
    it is built; `load` builds and validates it (None: it is made by the scene stage)."""
    name: str
    area: float  # m² of the room
    n_persons: int
    obstacles: bool
    free_area: Callable[[], float]  # m² of free space for the graph (loads what it needs)
    load: Callable[[], Scene | None] = lambda: None
    map_header: MapHeader | None = None  # the scene's ROS map, if it has one


@dataclass
class Checked:
    """What the checks found that the run records: content digests of inputs that are no
    artefact of this run (`birl.from_run`'s birl.mcap), for the provenance; and the values
    derived from the scene for settings left null (`graph.max_nodes`, `birl.grow_nodes`), by
    full key."""
    source_digests: dict[str, str] = dataclasses.field(default_factory=dict)
    derived: dict[str, int] = dataclasses.field(default_factory=dict)



def preflight(cfg: Config, run_dir: Path, from_run: Path | None) -> Checked:
    """Run every start-up check for the stages `cfg.stages`; raises PipelineError."""
    build.forget_scene_files()
    checked = Checked()
    stages = set(cfg.stages)
    if cfg.birl.kind == "maxent" and "birl" in stages and \
            not cfg.expert.knows_true_reward:
        raise PipelineError(
            f"config error: birl=maxent learns on the reference roadmap, from demonstrations "
            f"that are its paths (expert={' or expert='.join(SYNTHETIC_EXPERTS)}); "
            f"expert={cfg.expert.kind} demonstrations are not: learn from them with the "
            "default birl=map (or birl=policywalk)")
    if isinstance(cfg.birl, FixedConfig) and cfg.birl.from_run and stages & {"graph", "birl"}:
        weights_from = resolve_path(cfg.birl.from_run)
        if "birl" in stages and weights_from.resolve() == Path(run_dir).resolve():
            raise PipelineError(f"config error: birl.from_run={cfg.birl.from_run} is this run's "
                                "own dir: its birl stage would replace the birl.mcap it takes "
                                "the weights from; write this run to another dir "
                                "(hydra.run.dir=...)")
        check_from_run(weights_from, cfg.birl.from_run, "birl.from_run", needs="birl")
    if isinstance(cfg.expert, FileExpertConfig) and "demos" in stages:
        if content_digest(resolve_path(cfg.expert.path)) is not None:  # ours, not a bag
            raise PipelineError(
                f"config error: expert.path={cfg.expert.path} is an artefact of this pipeline "
                "(a run's demos.mcap), not a recording: give the demonstrations' own file, or "
                "reuse the run's with from_run=RUN_DIR and stages without demos")
        check_readable(resolve_path(cfg.expert.path))
        checked.source_digests["expert.path"] = file_digest(resolve_path(cfg.expert.path))
    elif isinstance(cfg.expert, FileExpertConfig) and stages & {"graph", "birl", "evaluate"}:
        # the demonstrations come from an earlier run: from the file as it is now?
        made = (from_run or Path(run_dir)) / ARTEFACT_FILE["demos"]
        demos_file = resolve_path(cfg.expert.path)
        if made.is_file() and demos_file.exists():
            check_source(read_artefact(made, lazy=True), "expert.path", file_digest(demos_file))
    check_scene_source(cfg, run_dir, from_run, checked)
    # evaluate too: its inputs were made with the derived value, which it must match
    derive_graph = cfg.graph.max_nodes is None and bool(stages & {"graph", "birl", "evaluate"})
    # evaluate checks birl.mcap against the birl section, derived value included
    growing = cfg.birl if isinstance(cfg.birl, BirlMapConfig) else None  # has grow_nodes
    derive_growth = growing is not None and growing.grow_nodes is None and \
        bool(stages & {"birl", "evaluate"})
    facts = scene_facts(cfg, run_dir, from_run) \
        if stages - {"birl"} or derive_graph or derive_growth else None
    if growing is not None and derive_growth and facts is not None:
        grow_nodes, why = limits.learning_growth(facts.obstacles, facts.name,
                                                 growing.learns_on_the_graph)
        # said where it changes what runs (growth on a map); an open room runs as always
        log.log(logging.INFO if grow_nodes else logging.DEBUG, "birl.grow_nodes=%d: %s",
                grow_nodes, why)
        checked.derived["birl.grow_nodes"] = grow_nodes
    # the demos stage builds the reference roadmap, and so does a random scene on a map
    # (each draw must connect on it)
    builds_roadmap = "demos" in stages or ("scene" in stages and
                                           isinstance(cfg.scene, RandomSceneConfig) and
                                           bool(cfg.scene.map))
    if facts is not None and builds_roadmap:
        check_roadmap_size(cfg, facts)
    if facts is not None and "demos" in stages:
        check_planner_lattice_size(cfg, facts)
    if facts is not None:
        scene = facts.load()  # sizes are fine: the scene file is validated now, not at its stage
        if scene is not None and "demos" in stages:
            check_demonstrations_size(cfg, len(scene.starts))
        if scene is not None and scene.obstacles is None \
                and scene.robot_radius != BodyParams.robot_radius:
            log.warning("scene '%s' has no obstacles: robot_radius=%g m has no effect (it is "
                        "the clearance kept from obstacles; the room's edge is none)",
                        scene.name, scene.robot_radius)
    max_nodes = cfg.graph.max_nodes
    if derive_graph and facts is not None:
        max_nodes, why = limits.graph_size(facts.free_area(), cfg.reward.rho_personal,
                                           facts.name)
        log.info("graph.max_nodes=%d: %s", max_nodes, why)
        checked.derived["graph.max_nodes"] = max_nodes
    if stages & {"graph", "birl"}:  # the birl stage grows the graph on maps
        check_graph_candidates(cfg)
    if "graph" in stages and max_nodes is not None:
        limits.check_graph_size(max_nodes, facts.free_area() if facts is not None else None,
                                cfg.reward.rho_personal, facts.name if facts else "")
    if "evaluate" in stages:
        check_transfer_scenes(cfg)
    if isinstance(cfg.birl, FixedConfig) and stages & {"graph", "birl"}:
        digest = build.fixed_weights_source(cfg)
        if digest is not None:
            checked.source_digests["birl.from_run"] = digest
    return checked


# -- the scene -----------------------------------------------------------------------------

def check_scene_source(cfg: Config, run_dir: Path, from_run: Path | None,
                       checked: Checked) -> None:
    """The files a scene is read from (a scene file and its map, or a random scene's map):
    recorded by digest when the scene stage runs; without it, the scene artefact the stages
    will use must have been made from the files as they are now (edited since: refused, as an
    edited demonstration file is). Files that cannot be read now are not compared: the
    artefact is what the run uses."""
    if "scene" in cfg.stages:
        source = scene_source(cfg)
        if source is not None:
            checked.source_digests[source[0]] = files_digest(source[1])
        return
    made = (from_run or run_dir) / ARTEFACT_FILE["scene"]
    if not made.is_file():
        return
    try:
        source = scene_source(cfg)
        if source is None:
            return
        digest = files_digest(source[1])
    except (PipelineError, OSError):
        return
    check_source(read_artefact(made, lazy=True), source[0], digest)


def scene_source(cfg: Config) -> tuple[str, list[Path]] | None:
    """The outside files the scene stage reads, with the key that names them: a scene file
    and its map (`scene.path`), or the map of a random scene (`scene.map`); None for a random
    scene in an open room."""
    sc = cfg.scene
    if isinstance(sc, FileSceneConfig):
        header = build.scene_file_extent(sc.path).map_header
        return "scene.path", [resolve_path(sc.path)] + \
            ([header.path, header.image] if header is not None else [])
    if sc.map:
        header = read_map_header(resolve_path(sc.map))
        return "scene.map", [header.path, header.image]
    return None


def scene_facts(cfg: Config, run_dir: Path, from_run: Path | None) -> SceneFacts | None:
    """The scene the stages will use: the configured one when the scene stage runs (a scene
    file is loaded and validated now, after its size check), else the scene artefact the
    stages will read (None when there is none: the stage says so)."""
    sc = cfg.scene
    if "scene" not in cfg.stages:
        path = (from_run or run_dir) / ARTEFACT_FILE["scene"]
        if not path.exists():
            return None
        scene = codec.decode_scene(read_artefact(path, required_topics=[topics.SCENE]))
        return facts_of(scene)
    if isinstance(sc, FileSceneConfig):
        extent = build.scene_file_extent(sc.path)

        def load() -> Scene:
            return build.scene_file(sc.path, body_radius=sc.body_radius,
                                    goal_tolerance=sc.goal_tolerance,
                                    robot_radius=sc.robot_radius)

        return SceneFacts(extent.name, extent.area, extent.n_persons, extent.obstacles,
                          lambda: facts_of(load()).free_area(), load, extent.map_header)
    assert isinstance(sc, RandomSceneConfig)
    n_persons = sc.n_singles + sc.n_groups * sc.group_size_max
    if not sc.map:
        scenegen.check_fits(sc, Room(0.0, 0.0, sc.width, sc.height), on_map=False)
        build.check_reachability_lattice(sc.width * sc.height, n_persons, sc.width, sc.height)
        area = sc.width * sc.height
        return SceneFacts(f"random-{cfg.seed if sc.seed is None else sc.seed}", area,
                          n_persons, False, lambda: area)
    map_path = sc.map  # a str (checked above), also in free_area
    header = read_map_header(resolve_path(map_path))
    build.check_map_size(header, limits.BYTES_PER_RANDOM_MAP_CELL,
                         " with a random scene's draws on it")
    x0, y0, x1, y1 = header.extent()
    scenegen.check_fits(sc, Room(x0, y0, x1, y1), on_map=True)

    def free_area() -> float:  # the scene's goal will lie in the largest region (scenegen)
        obstacles = ObstacleMap(build.map_grid_of(map_path))
        return obstacles.free_area(sc.robot_radius,
                                   blocked=~obstacles.largest_free_region(sc.robot_radius))

    return SceneFacts(f"random on {sc.map}", (x1 - x0) * (y1 - y0), n_persons, True,
                      free_area, map_header=header)


def facts_of(scene: Scene) -> SceneFacts:
    return SceneFacts(scene.name, scene.room.area, len(scene.persons),
                      scene.obstacles is not None, lambda: scene.free_area)


def check_roadmap_size(cfg: Config, facts: SceneFacts) -> None:
    rp = cfg.roadmap
    limits.check_memory(f"the reference roadmap of scene '{facts.name}'",
                        limits.lattice_edges(facts.area, rp.spacing, rp.connectivity),
                        limits.bytes_per_lattice_edge(facts.n_persons, facts.obstacles),
                        f"raise roadmap.spacing (now {rp.spacing:g} m) or use a smaller scene"
                        + _map_extent_hint(facts.map_header))


def _map_extent_hint(header: MapHeader | None) -> str:
    """A map's size in metres, for a size refusal: a resolution typo (50 for 0.05 m/px)
    makes a building a thousand times larger than it is."""
    if header is None:
        return ""
    x0, y0, x1, y1 = header.extent()
    return (f" (map {header.path} spans {x1 - x0:,.0f} m × {y1 - y0:,.0f} m at "
            f"{header.resolution:g} m/px: if the building is smaller, its 'resolution' is wrong)")


def check_demonstrations_size(cfg: Config, n_starts: int) -> None:
    """A synthetic expert's demonstrations, from every start (expert.n_starts keeps some of
    them afterwards), must fit in memory."""
    key = "demos_per_start" if isinstance(cfg.expert, BoltzmannExpertConfig) else \
        "n_subjects" if isinstance(cfg.expert, PlannerExpertConfig) else None
    if key is not None:
        per_start = getattr(cfg.expert, key)
        limits.check_memory(f"{n_starts} starts × expert.{key}={per_start} demonstrations",
                            n_starts * per_start, limits.BYTES_PER_DEMONSTRATION,
                            f"lower expert.{key}")


def check_planner_lattice_size(cfg: Config, facts: SceneFacts) -> None:
    """The planner expert's lattice (expert.spacing, at most expert.max_lattice_nodes
    points) must fit in memory."""
    if not isinstance(cfg.expert, PlannerExpertConfig):
        return
    e = cfg.expert
    nodes = facts.area / spacing_over(facts.area, e) ** 2
    limits.check_memory(f"the planner's lattice over scene '{facts.name}'", nodes,
                        limits.BYTES_PER_PLANNER_NODE,
                        f"raise expert.spacing (now {e.spacing:g} m) or lower "
                        f"expert.max_lattice_nodes (now {e.max_lattice_nodes})")


def check_graph_candidates(cfg: Config) -> None:
    """One expansion's candidate runs (graph.n_new) must fit in memory."""
    limits.check_memory(f"graph.n_new={cfg.graph.n_new} candidates per expansion",
                        cfg.graph.n_new, limits.BYTES_PER_CANDIDATE, "lower graph.n_new")


# -- transfer scenes -----------------------------------------------------------------------


def check_transfer_scenes(cfg: Config) -> None:
    """Every evaluate.transfer_scenes file: found, small enough, valid, its goal reachable on
    the reference roadmap's lattice (the message the demos stage gives for the main scene),
    and no two with one name (their metrics.json keys would overwrite each other's)."""
    names: dict[str, str] = {}
    for i, path in enumerate(cfg.evaluate.transfer_scenes):
        try:
            extent = build.scene_file_extent(path)
            check_roadmap_size(cfg, SceneFacts(extent.name, extent.area, extent.n_persons,
                                               extent.obstacles, lambda: 0.0))
            scene = build.scene_file(path)
            build.check_roadmap_reaches_goal(scene, cfg.roadmap)
        except PipelineError as e:
            raise PipelineError(f"evaluate.transfer_scenes[{i}]: {e}") from None
        name = build.transfer_name(scene.name, path)
        if name in names:
            raise PipelineError(
                f"config error: evaluate.transfer_scenes names two scenes called '{name}' "
                f"({names[name]} and {path}): their transfer_{name}_* metrics would overwrite "
                "each other; give one another \"name\" in its file")
        names[name] = path
