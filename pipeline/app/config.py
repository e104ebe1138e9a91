"""Typed configuration: the Hydra schemas, built on the algorithms' own parameter classes.

Each parameter set is declared once, in the algorithm module that uses it (GraphParams,
PosqController, RandomSceneSpec, FeatureParams, MDPParams, RoadmapParams, BoltzmannParams,
each IRL method's config); the schemas here subclass them and add only what selects or
feeds them (`kind`, `path`, `seed`, `weights`). Hydra rejects unknown keys and wrong types
at start-up against these schemas; `load_settings` then instantiates every section, which
runs the same range checks a direct call would, and reports the first violation in one
line naming the full key.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import numpy as np
from hydra.core.config_store import ConfigStore
from omegaconf import MISSING, DictConfig, OmegaConf
from omegaconf.errors import MissingMandatoryValue, OmegaConfBaseException

from pipeline.app.metric_keys import is_metric_key
from pipeline.artefacts.store import read_artefact
from pipeline.artefacts.topics import ARTEFACT_FILE, BIRL_EXPERT, STAGES
from pipeline.core.adaptive_graph import GraphParams
from pipeline.core.controllers import CONTROLLERS, PosqController
from pipeline.core.experts import BoltzmannParams
from pipeline.core.features import FeatureParams
from pipeline.core.graph_mdp import MDPParams
from pipeline.core.params import (
    ParameterError,
    is_number,
    renamed,
    require,
    require_count,
    require_positive,
)
from pipeline.core.roadmap import RoadmapParams
from pipeline.core.scenegen import RandomSceneSpec
from pipeline.core.social_planner import SocialPlannerParams
from pipeline.errors import PipelineError
from pipeline.inputs.recorded import START_RADIUS
from pipeline.irl import methods
from pipeline.irl.base import IRLConfig
from pipeline.irl.fixed import FixedConfig
from pipeline.irl.prior import broadcast

# -- scene ---------------------------------------------------------------------------------


@dataclass
class FileSceneConfig:
    # BodyParams' sizes, in its order, but optional: no subclass of it (its sizes are floats)

    # null: the scene file's value (or the world model's default)
    body_radius: Optional[float] = None
    goal_tolerance: Optional[float] = None  # m, states this close to the goal are terminal
    robot_radius: Optional[float] = None  # m, closer than this to an obstacle is a collision
    kind: str = "file"
    path: str = MISSING  # scene JSON; relative paths: cwd, then the package data

    def __post_init__(self) -> None:
        require(bool(self.path.strip()), "path", self.path, "the path of a scene file")
        require_positive(self, *(k for k in ("body_radius", "goal_tolerance", "robot_radius")
                                 if getattr(self, k) is not None))


@dataclass
class RandomSceneConfig(RandomSceneSpec):
    kind: str = "random"
    seed: Optional[int] = None  # scene generator seed; null: the run seed
    # a map_server YAML: persons, starts and goal on that map, whose extent is the room
    # (width and height stay unset)
    map: Optional[str] = None

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.seed is not None:
            require_count(self, "seed", minimum=0)
        if self.map is not None:  # said, not silently ignored
            for name in ("width", "height"):
                unset = RandomSceneSpec.__dataclass_fields__[name].default
                require(getattr(self, name) == unset, name, getattr(self, name),
                        f"unset ({unset:g}) with scene.map: the room is the map's extent (a "
                        "part of a building: a scene file's \"room\" over the map)")


SCENES: dict[str, type] = {"file": FileSceneConfig, "random": RandomSceneConfig}


# -- reward and expert ---------------------------------------------------------------------


@dataclass
class RewardConfig(FeatureParams):
    name: str = MISSING
    weights: list[float] = MISSING  # true weights w* of the synthetic expert, one per feature

    def __post_init__(self) -> None:
        super().__post_init__()
        require(len(self.weights) == len(self.features)
                and all(is_number(w) for w in self.weights), "weights", list(self.weights),
                f"{len(self.features)} finite numbers, one per feature {list(self.features)}")


# the experts that act under the true reward on the reference roadmap (their
# demonstrations are its paths, and a policy loss can be scored)
SYNTHETIC_EXPERTS = ("optimal", "boltzmann")


@dataclass
class ExpertConfig:
    kind: str = MISSING  # optimal | boltzmann | file | planner | none
    n_starts: Optional[int] = None  # demonstrations from the first n starts only (null: all)
    n_demos: Optional[int] = None  # deprecated spelling of n_starts

    def __post_init__(self) -> None:
        with renamed(self, "n_demos", "n_starts", "expert"):
            if self.n_starts is not None:
                require_count(self, "n_starts")

    @property
    def knows_true_reward(self) -> bool:
        """Synthetic experts act under the true reward (reward.*), on the reference roadmap:
        their demonstrations are its paths. File, planner and none have no true reward, so
        there is no policy loss."""
        return self.kind in SYNTHETIC_EXPERTS


@dataclass
class OptimalExpertConfig(ExpertConfig):
    kind: str = "optimal"


@dataclass
class NoExpertConfig(ExpertConfig):
    """No demonstrations (deployment): the graph grows from the scene alone and a
    given reward is planned with (birl=fixed)."""
    kind: str = "none"

    def __post_init__(self) -> None:
        super().__post_init__()
        # no demonstrations to take from the first n starts: the run failed after the scene
        require(self.n_starts is None, "n_starts", self.n_starts,
                "null with expert=none (there are no demonstrations to select)")


@dataclass
class BoltzmannExpertConfig(ExpertConfig, BoltzmannParams):
    kind: str = "boltzmann"

    def __post_init__(self) -> None:
        ExpertConfig.__post_init__(self)
        BoltzmannParams.__post_init__(self)


@dataclass
class FileExpertConfig(ExpertConfig):
    kind: str = "file"
    path: str = MISSING  # demonstrations: .json, .csv, a ROS bag (dir, .mcap, .bag)
    topic: Optional[str] = None  # bag topic; null: the only usable one
    frame: Optional[str] = None  # required header.frame_id of bag messages; null: any
    start_radius: float = START_RADIUS  # m, a demonstration begins this close to a start
    denoise: bool = True  # smooth tracking noise that makes trajectories >3 % longer
    # keep only each trajectory's walks from a start to the goal (a tracker's tracks of
    # everyone in view; with times, broken tracks are joined and id switches undone);
    # false: a trajectory that is no such walk is refused
    select_walks: bool = False

    def __post_init__(self) -> None:
        super().__post_init__()
        require(bool(self.path.strip()), "path", self.path,
                "the path of a demonstration file or ROS bag")
        require_positive(self, "start_radius")


@dataclass
class PlannerExpertConfig(ExpertConfig, SocialPlannerParams):
    """A people-aware planner with a cost of its own (no true weights): a stand-in for
    human demonstrators."""
    kind: str = "planner"

    def __post_init__(self) -> None:
        ExpertConfig.__post_init__(self)
        SocialPlannerParams.__post_init__(self)


EXPERTS: dict[str, type] = {"optimal": OptimalExpertConfig, "boltzmann": BoltzmannExpertConfig,
                            "none": NoExpertConfig,
                            "file": FileExpertConfig, "planner": PlannerExpertConfig}


# -- graph ---------------------------------------------------------------------------------


@dataclass
class ControllerConfig(PosqController):
    """`kind` picks the controller; the other keys are POSQ's (the linear controller drives
    at mdp.speed)."""
    kind: str = "linear"

    def __post_init__(self) -> None:
        super().__post_init__()
        require(self.kind in CONTROLLERS, "kind", self.kind,
                " or ".join(repr(k) for k in CONTROLLERS))
        if self.kind == "linear":  # POSQ's keys were ignored silently here
            for f in dataclasses.fields(PosqController):
                require(getattr(self, f.name) == f.default, f.name, getattr(self, f.name),
                        "only with graph.controller.kind=posq (the linear controller drives "
                        "at mdp.speed)")


@dataclass
class GraphConfig(GraphParams):
    # null: derived from the scene at start-up (pipeline.app.limits.graph_size): the paper's
    # 460, or twice the nodes that resolve personal space on the scene's free space where
    # that is more; a number is used as given (and refused when it is too few)
    max_nodes: Optional[int] = None  # type: ignore[assignment]
    # Reward that drives the growth: null = the weight box's centre on reward.features and 0
    # on the learner's other features (birl=fixed: its weights); true = the expert's true
    # weights (oracle mode, as in the authors' experiments); or one number per feature.
    # Typed Any: `true`, a list or null.
    weights: Any = None
    controller: ControllerConfig = field(default_factory=ControllerConfig)

    def __post_init__(self) -> None:
        derived = self.max_nodes is None
        if derived:  # the other checks, as for a given number
            self.max_nodes = GraphParams.max_nodes
        super().__post_init__()
        if derived:
            self.max_nodes = None


@dataclass
class EvaluateConfig:
    # Transfer: scene files on which the learned reward is also planned with and
    # scored (reference roadmap of each), as transfer_<scene>_<metric> keys
    transfer_scenes: list[str] = field(default_factory=list)
    # Held-out demonstrations, kept out of the graph and the likelihood: null
    # (none), a fraction (e.g. 0.3, drawn with the run's seed per start that has several),
    # a list of subject ids of the demonstration file's `subjects`, or all (a deployed
    # reward, birl=fixed, judged on demonstrations it never saw). Typed Any: a number, a
    # list or a word.
    holdout: Any = None

    def __post_init__(self) -> None:
        require(all(isinstance(p, str) and p.strip() for p in self.transfer_scenes),
                "transfer_scenes", self.transfer_scenes, "a list of scene file paths")
        h = self.holdout
        require(h is None or h == "all" or (is_number(h) and 0 < h < 1) or (
            isinstance(h, list) and len(h) > 0 and all(isinstance(s, str | int) for s in h)),
            "holdout", h, "null, a fraction in (0, 1), a list of subject ids, or all"
            + (f" (one subject: 'evaluate.holdout=[{h}]')" if isinstance(h, str | int)
               and not isinstance(h, bool) and h != "all" and not is_number(h) else ""))


# -- the whole run -------------------------------------------------------------------------

# The features the learner has beyond the reward's, for every demonstrator: `crossing`
# tells cutting through a link from passing near it. People and synthetic experts graze
# links (relation > 0) but do not cut through them; with relation alone the two are one
# cost, and a learned reward that tolerates grazing can also cut through. No row of
# results/bench/learner_features.csv shows it costing anything (nor, since demonstration
# edges are costed whole, the hand-drawn rows its benefit).
LEARNER_EXTRA_FEATURES = ("crossing",)


OBJECTIVE_EXAMPLES = ("policy_loss_norm", "policy_loss", "policy_loss_ref", "success",
                      "relation_crossings", "path_length", "min_distance_to_person")


@dataclass
class Config:
    seed: int = 0  # the run seed: every random draw of every stage derives from it
    # the stages to run, always in pipeline order; the others' artefacts come from from_run
    stages: list[str] = field(default_factory=lambda: list(STAGES))
    from_run: Optional[str] = None  # run dir whose artefacts feed stages not run now
    objective: str = "policy_loss_norm"  # metric a sweep job returns to a sweeper (Optuna)
    # FileSceneConfig | RandomSceneConfig, each checked by its own schema (typed Any: the
    # file scene's sizes are optional, which a BodyParams-typed node would not accept)
    scene: Any = MISSING
    reward: RewardConfig = MISSING
    expert: ExpertConfig = MISSING
    mdp: MDPParams = MISSING
    roadmap: RoadmapParams = field(default_factory=RoadmapParams)
    graph: GraphConfig = MISSING
    birl: IRLConfig = MISSING
    evaluate: EvaluateConfig = field(default_factory=EvaluateConfig)

    @property
    def learner_features(self) -> list[str]:
        """The features the reward is learned on: birl.features; with birl=fixed
        birl.from_run=RUN, those RUN learned on; else reward.features and
        LEARNER_EXTRA_FEATURES (one learner for every demonstrator)."""
        if self.birl.features is not None:
            return list(self.birl.features)
        if isinstance(self.birl, FixedConfig) and self.birl.from_run is not None:
            learned = learned_feature_names(self.birl.from_run)
            if learned is not None:  # a deployment plans on the features it learned on
                return list(learned)
        names = list(self.reward.features)
        return names + [n for n in LEARNER_EXTRA_FEATURES if n not in names]

    def on_learner_features(self, true_weights: list[float]) -> list[float] | None:
        """The true weights (on reward.features) on the learner's features: 0 where the true
        reward lacks a feature; None when the learner lacks one of the reward's."""
        true = dict(zip(self.reward.features, true_weights, strict=True))
        if not set(true) <= set(self.learner_features):
            return None
        return [float(true.get(n, 0.0)) for n in self.learner_features]

    @property
    def n_features(self) -> int:
        """How many weights are learned."""
        return len(self.learner_features)


def learned_feature_names(run: str) -> tuple[str, ...] | None:
    """The features the reward of run dir `run` was learned on (its birl.mcap), or None
    while it cannot be read (preflight checks birl.from_run and says why)."""
    from pipeline.app.context import resolve_path  # context imports this module

    path = resolve_path(run) / ARTEFACT_FILE["birl"]
    try:
        stat = path.stat()
    except OSError:
        return None
    return _feature_names_in(path, stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=8)
def _feature_names_in(path: Path, mtime_ns: int, size: int) -> tuple[str, ...] | None:
    """birl.mcap's feature names, read once per version of the file (mtime, size)."""
    try:
        names = read_artefact(path, required_topics=[BIRL_EXPERT]).one(BIRL_EXPERT)[
            "feature_names"]
    except (PipelineError, KeyError, TypeError):
        return None
    return tuple(names) if isinstance(names, list) and all(
        isinstance(n, str) for n in names) else None


def config_groups_help() -> str:
    """The user-facing config groups and their options for `--help` (conf/<group>/*.yaml;
    the `base_*` schema entries stay hidden)."""
    conf = Path(__file__).resolve().parent.parent / "conf"
    lines = []
    for group in sorted(d for d in conf.iterdir() if d.is_dir() and d.name != "hydra"):
        options = sorted(f.stem for f in group.glob("*.yaml"))
        lines.append(f"{group.name}: {', '.join(options)}")
    return "\n".join(lines)


_COMPOSING = threading.Lock()  # Hydra's GlobalHydra is one per process


def compose_config(overrides: Sequence[str] = (), with_hydra: bool = False) -> DictConfig:
    """The app's config with command-line style overrides, as `birlg` composes it (with
    its `hydra` section too if `with_hydra`). Hydra keeps one global state per process:
    compositions in threads take turns, and a Hydra the caller had initialised (a
    notebook's `initialize()`, a script under `@hydra.main`) is put back afterwards (Hydra
    refused: "GlobalHydra is already initialized")."""
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.initialize import get_gh_backup, restore_gh_from_backup

    from pipeline.app.context import PACKAGE_ROOT

    register_configs()
    with _COMPOSING:
        callers = get_gh_backup() if GlobalHydra.instance().is_initialized() else None
        GlobalHydra.instance().clear()
        try:
            with initialize_config_dir(config_dir=str(PACKAGE_ROOT / "conf"),
                                       version_base="1.3"):
                return compose(config_name="config", overrides=list(overrides),
                               return_hydra_config=with_hydra)
        finally:
            if callers is not None:
                restore_gh_from_backup(callers)


def one_job_of_a_sweep(swept: Mapping | None, instead: str) -> str | None:
    """The warning for a config that sweeps settings (an experiment preset's
    hydra.sweeper.params) run as one job, which takes their values from the config alone;
    None when nothing is swept. `instead` says how to run the sweep."""
    if not swept:
        return None
    settings = "; ".join(f"{key}: {value}" for key, value in swept.items())
    return (f"the config sweeps {settings} (its experiment preset's sweep), but this is one "
            f"run, with the config's own values of those settings; {instead}")


SCHEMA_PREFIX = "base_"  # the typed schemas of a group's options, stored in the group


def check_group_choices(choices: Mapping[str, Any]) -> None:
    """A schema chosen as a group's option (`reward=glob(*)` picks base_reward too) is
    refused: it is what the options extend, with required values left unset."""
    for group, choice in choices.items():
        if isinstance(choice, str) and choice.startswith(SCHEMA_PREFIX) \
                and not group.startswith("hydra"):
            raise PipelineError(f"config error: {group}={choice} is the schema the {group} "
                                f"options extend, not an option of its own (a glob sweep "
                                f"leaves it out with '{group}=glob(*,exclude={SCHEMA_PREFIX}*)')")


def check_objective_name(objective: str) -> None:
    """The objective must name a metrics.json key (else every sweep trial would return NaN);
    checked by each run and, before any job, by a sweep."""
    if not is_metric_key(objective):
        close = difflib.get_close_matches(objective, OBJECTIVE_EXAMPLES, n=1)
        raise config_error("objective", objective,
                           f"a metrics.json key, e.g. {close[0] if close else 'policy_loss_norm'}")


def check_objective_is_written(objective: str, holdout: Any) -> None:
    """A heldout_* objective needs held-out demonstrations (evaluate.holdout); checked by
    each run and, before any job, by a sweep that does not set evaluate.holdout."""
    if objective.startswith("heldout_") and holdout is None:
        raise config_error("objective", objective,
                           "a metric this run writes: the heldout_* keys need held-out "
                           "demonstrations, e.g. evaluate.holdout=0.3")


def register_configs() -> None:
    if not OmegaConf.has_resolver("birlg_config_groups"):
        OmegaConf.register_new_resolver("birlg_config_groups", config_groups_help)
    cs = ConfigStore.instance()
    base = SCHEMA_PREFIX
    cs.store(name=f"{base}config", node=Config)
    for kind, node in SCENES.items():
        cs.store(group="scene", name=f"{base}{kind}", node=node)
    cs.store(group="reward", name=f"{base}reward", node=RewardConfig)
    for kind, node in EXPERTS.items():
        cs.store(group="expert", name=f"{base}{kind}", node=node)
    cs.store(group="graph", name=f"{base}graph", node=GraphConfig)
    cs.store(group="mdp", name=f"{base}mdp", node=MDPParams)
    for name, method in methods().items():
        cs.store(group="birl", name=f"{base}{name}", node=method.config)


# -- instantiation and checks --------------------------------------------------------------

_HINTS = {"scene.path": "scene=file scene.path=PATH", "expert.path": "expert=file expert.path=PATH",
          "reward.weights": "one number per feature", "reward.name": "a name"}


def check_boolean_overrides(cfg: DictConfig, overrides: Sequence[str]) -> None:
    """A boolean setting given on the command line takes true or false: omegaconf takes 2,
    `yes` or `on` for true, which a typed config should refuse, not guess."""
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from omegaconf.nodes import BooleanNode

    for override in OverridesParser.create().parse_overrides(list(overrides)):
        if override.is_delete() or override.is_sweep_override():
            continue
        key = override.key_or_group
        parent_key, _, leaf = key.rpartition(".")
        try:  # (a config group such as experiment=quick is no key of the config)
            parent = OmegaConf.select(cfg, parent_key) if parent_key else cfg
            node = parent._get_node(leaf) if isinstance(parent, DictConfig) else None
        except OmegaConfBaseException:
            continue
        value = override.value()
        said = isinstance(value, bool) or (isinstance(value, str) and (
            value.lower() in ("true", "false") or "${" in value))  # ('true', an interpolation)
        if isinstance(node, BooleanNode) and not said:
            raise config_error(key, value, "true or false")


def config_error(key: str, value: Any, allowed: str) -> PipelineError:
    if isinstance(value, (list, tuple, np.ndarray)):  # numbers as typed, not np.float64(1.0)
        value = [v.item() if isinstance(v, np.generic) else v for v in value]
    shown = str(value)
    if len(shown) > 100:  # a list can be thousands of numbers long: never echo it whole
        shown = f"{shown[:80]}... ({len(shown):,} characters)"
    return PipelineError(f"config error: {key}={shown} is not allowed (allowed: {allowed})")


def _instantiate(node: DictConfig, key: str) -> Any:
    """The node's dataclass instance, its children first so an error names the deepest key."""
    schema = OmegaConf.get_type(node)
    if dataclasses.is_dataclass(schema):  # `+section.key=...` adds keys Hydra would ignore
        known = {f.name for f in dataclasses.fields(schema)}
        unknown = [str(k) for k in node if k not in known]
        if unknown:
            raise PipelineError(f"config error: {key}.{unknown[0]} is not a setting of {key} "
                                f"(known: {', '.join(sorted(known))})")
    for child in node:
        sub = node._get_node(child)
        if isinstance(sub, DictConfig) and OmegaConf.get_type(sub) not in (dict, None):
            _instantiate(sub, f"{key}.{str(child)}")
    try:
        return OmegaConf.to_object(node)
    except ParameterError as e:
        raise config_error(f"{key}.{e.field}", e.value, e.allowed) from None
    except MissingMandatoryValue as e:
        full = f"{key}.{e.key}" if e.key else key
        hint = _HINTS.get(full, f"{full}=VALUE")
        raise PipelineError(f"config error: {full} is missing (set it: {hint})") from None


def _require_matching_kind(section: str, obj: Any, registry: dict[str, type]) -> None:
    """`section.kind` must name the schema in use (a kind is chosen with `section=NAME`)."""
    expected = next((k for k, cls in registry.items() if type(obj) is cls), None)
    if obj.kind != expected:
        raise config_error(f"{section}.kind", obj.kind,
                           f"'{expected}' (choose another with {section}=NAME)")


def load_settings(cfg: DictConfig) -> Config:
    """The composed config as checked, typed objects (a Config instance)."""
    known = {f.name for f in dataclasses.fields(Config)}
    unknown = [str(k) for k in cfg if k not in known]
    if unknown:
        raise PipelineError(f"config error: {unknown[0]} is not a setting (known: "
                            f"{', '.join(sorted(known))})")
    deleted = [k for k in known if k not in cfg]  # `~seed`: its default, unrecorded
    if deleted:
        raise PipelineError(f"config error: {deleted[0]} is missing (deleted with "
                            f"~{deleted[0]}?): every run records it; set it instead")
    sections = {}
    for key in ("scene", "reward", "expert", "mdp", "roadmap", "graph", "birl", "evaluate"):
        sections[key] = _instantiate(cfg[key], key)
    # resolved first: the masked copy has no other keys (objective=${mdp.gamma} failed there
    # with omegaconf's InterpolationKeyError) and no types (objective=${seed} was an int)
    resolved = cfg.copy()
    OmegaConf.resolve(resolved)
    top = OmegaConf.to_object(OmegaConf.masked_copy(resolved, ["seed", "stages", "from_run",
                                                               "objective"]))
    settings = Config(**top, **sections)  # type: ignore[arg-type]

    unknown = [s for s in settings.stages if s not in STAGES]
    if unknown or not settings.stages:
        raise config_error("stages", list(settings.stages), f"a non-empty subset of {list(STAGES)}")
    if settings.seed < 0:
        raise config_error("seed", settings.seed, "an integer >= 0")
    if settings.from_run is not None and not settings.from_run.strip():  # the cwd, unsaid
        raise config_error("from_run", settings.from_run, "a run dir")
    check_objective_name(settings.objective)
    check_objective_is_written(settings.objective, settings.evaluate.holdout)
    _require_matching_kind("scene", settings.scene, SCENES)
    _require_matching_kind("expert", settings.expert, EXPERTS)
    _require_matching_kind("birl", settings.birl, {n: m.config for n, m in methods().items()})

    d = settings.n_features
    try:
        prior = settings.birl.make_prior(d)
    except ParameterError as e:
        raise config_error(f"birl.{e.field}", e.value, e.allowed) from None
    w0 = settings.birl.init_weights
    if w0 is not None and not (len(w0) == d and all(is_number(x) for x in w0)
                               and prior.in_box(broadcast(w0, d, "init_weights"))):
        raise config_error("birl.init_weights", list(w0),
                           f"null or {d} numbers within [birl.lower, birl.upper]")
    w = settings.graph.weights
    ok = w is None or w is True or w == "true" or (
        isinstance(w, list) and len(w) == d and all(is_number(x) for x in w))
    if not ok:
        raise config_error("graph.weights", w, f"null (prior mean), true (oracle) or {d} numbers")
    if settings.mdp.undiscounted:  # every edge must cost, or a loop could pay
        why = "<= 0 with mdp.gamma=1 (features are costs; a positive weight can make a loop pay)"
        for key, values in (("birl.upper", prior.upper.tolist()),
                            ("reward.weights", list(settings.reward.weights)),
                            ("graph.weights", w if isinstance(w, list) else [])):
            if any(v > 0 for v in values):
                raise config_error(key, values, why)
    _check_demonstrator(settings)
    return settings


def _check_demonstrator(settings: Config) -> None:
    """What the expert kind allows: learning needs demonstrations, the oracle growth needs
    true weights on the learner's features."""
    if settings.evaluate.holdout == "all" and settings.birl.kind != "fixed":
        raise config_error("evaluate.holdout", "all", "a fraction or subject ids, unless "
                           "birl=fixed (holding out every demonstration leaves none to learn)")
    if settings.expert.kind == "none" and settings.evaluate.holdout is not None:
        raise config_error("evaluate.holdout", settings.evaluate.holdout,
                           "null with expert=none (it has no demonstrations to hold out; "
                           "held-out ones come from a file: expert=file expert.path=...)")
    if isinstance(settings.evaluate.holdout, list) and settings.expert.knows_true_reward:
        raise config_error("evaluate.holdout", settings.evaluate.holdout,
                           f"a fraction or null with expert={settings.expert.kind} (its "
                           "demonstrations have no subjects; subject ids come from a "
                           "file's `subjects` or expert=planner's subjects)")
    if settings.expert.kind == "none" and settings.birl.kind != "fixed":
        raise config_error("birl", settings.birl.kind,
                           "fixed with expert=none (nothing to learn from: birl=fixed "
                           "birl.weights=[...] or birl.from_run=RUN)")
    w = settings.graph.weights
    if not (w is True or w == "true"):
        return
    if not settings.expert.knows_true_reward:
        raise config_error("graph.weights", w, "null or numbers: graph.weights=true needs true "
                           f"weights, but the demonstrations have none "
                           f"(expert={settings.expert.kind})")
    if settings.on_learner_features(settings.reward.weights) is None:
        raise config_error("graph.weights", w, "null or numbers: the true weights are on "
                           f"reward.features={list(settings.reward.features)}, not all of "
                           f"them among the learner's {settings.learner_features}")

