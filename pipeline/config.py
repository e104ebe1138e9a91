"""Typed configuration: dataclasses registered in Hydra's ConfigStore, plus range checks.

Hydra rejects unknown keys and wrong types at start-up against these schemas; `validate`
then checks value ranges and reports the first violation in one line naming the key.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Optional

from hydra.core.config_store import ConfigStore
from omegaconf import MISSING, OmegaConf

from pipeline.errors import PipelineError
from pipeline.features import FEATURE_NAMES

ALL_STAGES = ["scene", "demos", "graph", "birl", "evaluate"]  # in pipeline order


@dataclass
class SceneConfig:
    kind: str = MISSING
    body_radius: float = 0.25  # m, no robot path may enter a body disk
    goal_tolerance: float = 0.3  # m, states this close to the goal are terminal


@dataclass
class FileSceneConfig(SceneConfig):
    kind: str = "file"
    path: str = MISSING  # scene JSON (DESIGN §3); relative paths: cwd, then project root


@dataclass
class RandomSceneConfig(SceneConfig):
    kind: str = "random"
    seed: Optional[int] = None  # scene generator seed; null: the run seed
    width: float = 10.0
    height: float = 10.0
    n_singles: int = 3  # persons standing alone
    n_groups: int = 3  # F-formation groups
    group_size_min: int = 2
    group_size_max: int = 4
    formation_radius: float = 0.7  # m, distance of group members from the group centre
    min_person_gap: float = 0.7  # m, minimum distance between any two persons
    n_starts: int = 5
    border_margin: float = 0.3  # m, starts and goal this far inside the walls
    max_tries: int = 200  # resamples until every start reaches the goal


@dataclass
class RewardConfig:
    name: str = MISSING
    features: list[str] = field(default_factory=lambda: list(FEATURE_NAMES))
    weights: list[float] = MISSING  # true weights w* of the synthetic expert
    rho_relation: float = 0.6  # m, ρ_r
    rho_personal: float = 1.2  # m, ρ_p
    resolution: float = 0.05  # m, feature integration step


@dataclass
class ExpertConfig:
    kind: str = MISSING  # optimal | boltzmann | file
    beta: float = 50.0  # β_E of the boltzmann expert
    path: Optional[str] = None  # demonstration JSON for kind=file
    n_demos: Optional[int] = None  # learn from the demonstrations of the first n starts (null: all)
    max_steps: int = 2000  # boltzmann walks longer than this are resampled
    max_tries: int = 100


@dataclass
class MDPConfig:
    gamma: float = 0.95  # discount per second
    r_goal: float = 1.0  # terminal reward R_goal
    v_max: float = 10.0  # dead ends have V = −v_max
    speed: float = 1.0  # m/s, robot speed: edge duration = length / speed


@dataclass
class RoadmapConfig:
    spacing: float = 0.25  # m
    connectivity: int = 16  # 8 or 16


@dataclass
class ControllerConfig:
    kind: str = "linear"  # linear | posq (the linear controller drives at mdp.speed)
    k_v: float = 3.8  # POSQ gains (Palmieri & Arras 2014)
    k_rho: float = 1.0
    k_alpha: float = 6.0
    k_beta: float = -1.0
    wheel_base: float = 0.4  # m
    max_speed: float = 1.0  # m/s, wheel speed limit
    dt: float = 0.05  # s, integration step
    eps: float = 0.05  # m, arrival tolerance
    max_time: float = 10.0  # s, runs longer than this are dropped


@dataclass
class GraphConfig:
    max_nodes: int = 460  # the paper's Fig. 1
    radius: float = 1.2  # m, neighbourhood for edges, GP and concentration
    max_edges: int = 8  # nearest neighbours a new node connects to, each direction
    n_new: int = 8  # candidates per expansion
    n_add: int = 2  # candidates added per expansion
    p_best: float = 0.7  # probability of expanding a node of the best trajectories
    lambda_q: float = 0.6  # λ_q, weight of quality in the exploration score
    lambda_c: float = 0.4  # λ_c, weight of concentration
    t_min: float = 0.4  # s, candidate controller-run duration range [t_min, t_max],
    t_max: float = 1.6  # s, its upper end annealed to t_min as the graph fills
    min_separation: Optional[float] = None  # m, no two nodes closer; null: 0.35·√(area/max_nodes)
    gp_length_scale: float = 1.0  # m, RBF length scale of the value GP
    gp_signal_std: float = 1.0
    gp_noise: float = 1e-4
    gp_kappa: float = 1.0  # candidate value = GP mean + kappa · GP std
    gp_max_points: int = 40  # nearest nodes within radius the GP is fitted to
    max_stalls: int = 500  # stop early after this many expansions in a row add nothing
    # Reward that drives the growth: null = the learner's initial weights (the prior's
    # mean within the bounds); `true` = the expert's true weights (oracle mode); or a list.
    weights: Any = None
    controller: ControllerConfig = field(default_factory=ControllerConfig)


@dataclass
class PriorConfig:
    kind: str = "uniform"  # uniform (on the box) | gaussian | laplace
    scale: float = 0.5  # σ (gaussian) or b (laplace)
    mean: Optional[list[float]] = None  # default 0, clipped into the bounds


@dataclass
class BirlConfig:
    kind: str = "map"  # map | mcmc (BIRL-G) | policywalk | maxent (baselines)
    beta: float = 10.0  # expert optimality β
    prior: PriorConfig = field(default_factory=PriorConfig)
    lower: list[float] = field(default_factory=lambda: [-1.0] * len(FEATURE_NAMES))
    upper: list[float] = field(default_factory=lambda: [0.0] * len(FEATURE_NAMES))
    n_iterations: int = 20
    init_weights: Optional[list[float]] = None  # null: drawn from the prior with the seed
    # birl=mcmc: Metropolis–Hastings per iteration; the weights are the posterior mean
    n_samples: int = 2000
    burn_in: int = 500
    thin: int = 2
    step: float = 0.05  # random-walk proposal std (PolicyWalk: grid step)
    alpha: float = 10.0  # PolicyWalk: expert confidence in its Boltzmann likelihood
    learning_rate: float = 0.5  # MaxEnt: projected Adam step (decays as 1/sqrt(t))
    grow_nodes: int = 0  # BIRL-G: nodes the graph grows per iteration under the current weights


@dataclass
class Config:
    seed: int = 0
    stages: list[str] = field(default_factory=lambda: list(ALL_STAGES))
    from_run: Optional[str] = None  # run dir whose artefacts feed stages not run now
    scene: SceneConfig = MISSING
    reward: RewardConfig = MISSING
    expert: ExpertConfig = MISSING
    mdp: MDPConfig = field(default_factory=MDPConfig)
    roadmap: RoadmapConfig = field(default_factory=RoadmapConfig)
    graph: GraphConfig = MISSING
    birl: BirlConfig = MISSING


def register_configs() -> None:
    cs = ConfigStore.instance()
    cs.store(name="base_config", node=Config)
    cs.store(group="scene", name="base_file", node=FileSceneConfig)
    cs.store(group="scene", name="base_random", node=RandomSceneConfig)
    cs.store(group="reward", name="base_reward", node=RewardConfig)
    cs.store(group="expert", name="base_expert", node=ExpertConfig)
    cs.store(group="graph", name="base_graph", node=GraphConfig)
    cs.store(group="birl", name="base_birl", node=BirlConfig)


# -- range checks ------------------------------------------------------------------------

def _positive(key: str, value) -> None:
    if not value > 0:
        raise PipelineError(f"config error: {key}={value} is not allowed (allowed: > 0)")


def _require(ok: bool, key: str, value, allowed: str) -> None:
    if not ok:
        raise PipelineError(f"config error: {key}={value} is not allowed (allowed: {allowed})")


def validate(cfg: Any) -> None:
    """Range checks Hydra's type system cannot express; raises PipelineError (one line)."""
    unknown = [s for s in cfg.stages if s not in ALL_STAGES]
    _require(not unknown and len(cfg.stages) > 0, "stages", list(cfg.stages),
             f"a non-empty subset of {ALL_STAGES}")
    _require(cfg.seed >= 0, "seed", cfg.seed, "an integer >= 0")

    sc = cfg.scene
    _require(sc.kind in ("file", "random"), "scene.kind", sc.kind, "'file' or 'random'")
    _positive("scene.body_radius", sc.body_radius)
    _positive("scene.goal_tolerance", sc.goal_tolerance)
    if sc.kind == "file":
        _require(not OmegaConf.is_missing(sc, "path") and bool(sc.path), "scene.path", "???",
                 "a scene JSON file (scene=file scene.path=PATH)")
    if sc.kind == "random":
        for key in ("width", "height", "formation_radius", "min_person_gap"):
            _positive(f"scene.{key}", sc[key])
        for key in ("n_singles", "n_groups"):
            _require(sc[key] >= 0, f"scene.{key}", sc[key], "an integer >= 0")
        _require(sc.n_starts >= 1, "scene.n_starts", sc.n_starts, "an integer >= 1")
        _require(2 <= sc.group_size_min <= sc.group_size_max <= 4, "scene.group_size_min/max",
                 f"{sc.group_size_min}/{sc.group_size_max}", "2 <= min <= max <= 4")
        _require(sc.border_margin >= 0, "scene.border_margin", sc.border_margin, ">= 0")
        _require(sc.max_tries >= 1, "scene.max_tries", sc.max_tries, "an integer >= 1")

    rw = cfg.reward
    _require(list(rw.features) == list(FEATURE_NAMES), "reward.features", list(rw.features),
             f"exactly {list(FEATURE_NAMES)}")
    _require(len(rw.weights) == len(rw.features), "reward.weights", list(rw.weights),
             f"{len(rw.features)} numbers, one per feature {list(rw.features)}")
    for key in ("rho_relation", "rho_personal", "resolution"):
        _positive(f"reward.{key}", rw[key])

    ex = cfg.expert
    _require(ex.kind in ("optimal", "boltzmann", "file"), "expert.kind", ex.kind,
             "'optimal', 'boltzmann' or 'file'")
    _positive("expert.beta", ex.beta)
    _require(ex.kind != "file" or bool(ex.path), "expert.path", ex.path,
             "a demonstration JSON file when expert=file")
    _require(ex.max_steps >= 1, "expert.max_steps", ex.max_steps, "an integer >= 1")
    _require(ex.n_demos is None or ex.n_demos >= 1, "expert.n_demos", ex.n_demos,
             "null (all) or an integer >= 1")
    _require(ex.max_tries >= 1, "expert.max_tries", ex.max_tries, "an integer >= 1")

    md = cfg.mdp
    _require(0 < md.gamma < 1, "mdp.gamma", md.gamma, "0 < gamma < 1")
    _positive("mdp.v_max", md.v_max)
    _positive("mdp.speed", md.speed)

    rm = cfg.roadmap
    _positive("roadmap.spacing", rm.spacing)
    _require(rm.connectivity in (8, 16), "roadmap.connectivity", rm.connectivity, "8 or 16")

    validate_graph(cfg.graph)
    validate_birl(cfg.birl)


def validate_graph(g: Any) -> None:
    for key in ("radius", "t_min", "t_max", "gp_length_scale", "gp_signal_std", "gp_noise"):
        _positive(f"graph.{key}", g[key])
    if g.min_separation is not None:
        _positive("graph.min_separation", g.min_separation)
    for key in ("max_nodes", "max_edges", "n_new", "n_add", "max_stalls", "gp_max_points"):
        _require(g[key] >= 1, f"graph.{key}", g[key], "an integer >= 1")
    _require(g.n_add <= g.n_new, "graph.n_add", g.n_add, f"<= graph.n_new ({g.n_new})")
    _require(0 <= g.p_best <= 1, "graph.p_best", g.p_best, "0 <= p_best <= 1")
    _require(g.t_min <= g.t_max, "graph.t_min", g.t_min, f"<= graph.t_max ({g.t_max})")
    for key in ("lambda_q", "lambda_c", "gp_kappa"):
        _require(g[key] >= 0, f"graph.{key}", g[key], ">= 0")
    _require(g.lambda_q + g.lambda_c > 0, "graph.lambda_q", g.lambda_q,
             "lambda_q + lambda_c > 0")
    w = g.weights
    ok = w is None or w is True or w in ("true", "prior") or (
        OmegaConf.is_list(w) and len(w) == len(FEATURE_NAMES)
        and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in w))
    _require(ok, "graph.weights", w, f"null (prior mean), true (oracle) or {len(FEATURE_NAMES)} numbers")
    c = g.controller
    _require(c.kind in ("linear", "posq"), "graph.controller.kind", c.kind, "'linear' or 'posq'")
    for key in ("k_v", "k_rho", "k_alpha", "wheel_base", "max_speed", "dt", "eps", "max_time"):
        _positive(f"graph.controller.{key}", c[key])


def validate_birl(b: Any) -> None:
    d = len(FEATURE_NAMES)
    _require(b.kind in ("map", "mcmc", "policywalk", "maxent"), "birl.kind", b.kind,
             "'map', 'mcmc', 'policywalk' or 'maxent'")
    _positive("birl.alpha", b.alpha)
    _require(b.grow_nodes >= 0 and (b.grow_nodes == 0 or b.kind in ("map", "mcmc")),
             "birl.grow_nodes", b.grow_nodes, "an integer >= 0 (> 0 only for birl=map or mcmc)")
    _positive("birl.learning_rate", b.learning_rate)
    _positive("birl.beta", b.beta)
    _require(b.prior.kind in ("gaussian", "laplace", "uniform"), "birl.prior.kind",
             b.prior.kind, "'gaussian', 'laplace' or 'uniform'")
    _positive("birl.prior.scale", b.prior.scale)
    for key in ("lower", "upper"):
        _require(len(b[key]) == d, f"birl.{key}", list(b[key]), f"{d} numbers")
    _require(all(lo < hi for lo, hi in zip(b.lower, b.upper)), "birl.lower", list(b.lower),
             f"below birl.upper ({list(b.upper)}) in every entry")
    for key in ("init_weights",):
        v = b[key]
        _require(v is None or (len(v) == d and all(lo <= x <= hi for x, lo, hi in
                                                   zip(v, b.lower, b.upper))),
                 f"birl.{key}", None if v is None else list(v),
                 f"null or {d} numbers within [birl.lower, birl.upper]")
    _require(b.prior.mean is None or len(b.prior.mean) == d, "birl.prior.mean",
             b.prior.mean, f"null or {d} numbers")
    _require(b.n_iterations >= 1, "birl.n_iterations", b.n_iterations, "an integer >= 1")
    for key in ("n_samples", "thin"):
        _require(b[key] >= 1, f"birl.{key}", b[key], "an integer >= 1")
    _require(b.burn_in >= 0, "birl.burn_in", b.burn_in, "an integer >= 0")
    _positive("birl.step", b.step)
