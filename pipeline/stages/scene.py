"""Stage 1: scene generation -> scene.mcap (topic /scene, DESIGN §3)."""

from __future__ import annotations

import logging

from pipeline.app import build
from pipeline.app.context import RunContext
from pipeline.artefacts import topics

log = logging.getLogger(__name__)


def run(ctx: RunContext) -> None:
    scene = build.scene(ctx.cfg, lambda seed: ctx.rng("scene", seed))
    log.info("scene '%s': %d persons, %d relations, %d starts, goal (%g, %g)", scene.name,
             len(scene.persons), len(scene.relations), len(scene.starts), *scene.goal)
    with ctx.writer("scene") as w:
        w.add(topics.SCENE, "Scene", scene.to_dict(), log_time=0)
