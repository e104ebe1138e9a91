"""Stage 1: scene generation -> scene.mcap (topic /scene, DESIGN §3)."""

from __future__ import annotations

import logging

from pipeline.run import RunContext, resolve_path
from pipeline.scenegen import RandomSceneSpec, random_scene
from pipeline.world import Scene, load_scene_file, scene_from_dict

log = logging.getLogger(__name__)


def make_scene(ctx: RunContext) -> Scene:
    sc = ctx.cfg.scene
    if sc.kind == "random":
        fields = {k: sc[k] for k in RandomSceneSpec.__dataclass_fields__}
        seed = ctx.cfg.seed if sc.seed is None else sc.seed
        return random_scene(RandomSceneSpec(**fields), ctx.rng("scene", seed),
                            name=f"random-{seed}")
    return load_scene_file(resolve_path(sc.path), body_radius=sc.body_radius,
                           goal_tolerance=sc.goal_tolerance)


def load_scene(ctx: RunContext) -> Scene:
    """The scene of this run, read back from scene.mcap (what later stages use)."""
    art = ctx.read("scene", required_topics=["/scene"])
    return scene_from_dict(art.one("/scene"), source=f"artefact {art.path}")


def run(ctx: RunContext) -> None:
    scene = make_scene(ctx)
    log.info("scene '%s': %d persons, %d relations, %d starts, goal (%g, %g)", scene.name,
             len(scene.persons), len(scene.relations), len(scene.starts), *scene.goal)
    with ctx.writer("scene") as w:
        w.add("/scene", "Scene", scene.to_dict(), log_time=0)
