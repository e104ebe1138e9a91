"""Stage 1: scene generation -> scene.mcap (topic /scene, DESIGN §3)."""

from __future__ import annotations

import logging

from pipeline.app import build
from pipeline.app.context import RunContext
from pipeline.artefacts import codec, foxglove, topics
from pipeline.errors import listed

log = logging.getLogger(__name__)


def run(ctx: RunContext) -> None:
    scene = build.scene(ctx.cfg, lambda seed: ctx.rng("scene", seed))
    log.info("scene '%s': %d persons, %d relations, %d starts, goal (%g, %g)", scene.name,
             len(scene.persons), len(scene.relations), len(scene.starts), *scene.goal)
    guessed = [p.id for p in scene.persons if not p.heading_given]
    front = [f for f in (*ctx.cfg.reward.features, *ctx.cfg.learner_features)
             if f.split("@")[0] == "front"]
    if guessed and front:
        log.warning("persons %s give neither theta nor a velocity: %s takes them to face +x "
                    "(theta 0); give each its theta", listed(guessed, 8), front[0])
    if scene.obstacles is not None:
        log.info("obstacles: %d polygons%s, robot_radius %g m", len(scene.polygons),
                 f", map {scene.map_source}" if scene.map_grid is not None else "",
                 scene.robot_radius)
    with ctx.writer("scene") as w:
        w.add(topics.SCENE, "Scene", scene.to_dict(), log_time=0)
        foxglove.add_scene(w, scene.to_dict())
        if scene.map_grid is not None:
            w.add(topics.SCENE_MAP, "OccupancyGrid", codec.grid_record(scene.map_grid),
                  log_time=0)
            foxglove.add_map(w, codec.grid_record(scene.map_grid))
