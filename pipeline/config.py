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

ALL_STAGES = ["scene", "demos"]  # in pipeline order; later issues append graph, birl, evaluate


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
class Config:
    seed: int = 0
    stages: list[str] = field(default_factory=lambda: list(ALL_STAGES))
    from_run: Optional[str] = None  # run dir whose artefacts feed stages not run now
    scene: SceneConfig = MISSING
    reward: RewardConfig = MISSING
    expert: ExpertConfig = MISSING
    mdp: MDPConfig = field(default_factory=MDPConfig)
    roadmap: RoadmapConfig = field(default_factory=RoadmapConfig)


def register_configs() -> None:
    cs = ConfigStore.instance()
    cs.store(name="base_config", node=Config)
    cs.store(group="scene", name="base_file", node=FileSceneConfig)
    cs.store(group="scene", name="base_random", node=RandomSceneConfig)
    cs.store(group="reward", name="base_reward", node=RewardConfig)
    cs.store(group="expert", name="base_expert", node=ExpertConfig)


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
    _require(ex.max_tries >= 1, "expert.max_tries", ex.max_tries, "an integer >= 1")

    md = cfg.mdp
    _require(0 < md.gamma < 1, "mdp.gamma", md.gamma, "0 < gamma < 1")
    _positive("mdp.v_max", md.v_max)
    _positive("mdp.speed", md.speed)

    rm = cfg.roadmap
    _positive("roadmap.spacing", rm.spacing)
    _require(rm.connectivity in (8, 16), "roadmap.connectivity", rm.connectivity, "8 or 16")
