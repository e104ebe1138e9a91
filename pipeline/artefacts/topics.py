"""The stable names of the artefact layout (DESIGN §2, §10): stages in pipeline order, the
file each writes, and every topic. Nothing else spells these strings."""

from __future__ import annotations

STAGES: tuple[str, ...] = ("scene", "demos", "graph", "birl", "evaluate")
ARTEFACT_FILE: dict[str, str] = {"scene": "scene.mcap", "demos": "demos.mcap",
                                 "graph": "graph.mcap", "birl": "birl.mcap",
                                 "evaluate": "eval.mcap"}

SCENE = "/scene"
SCENE_MAP = "/scene/map"  # the scene's occupancy map, when it has one (DESIGN §3)

DEMOS = "/demos"
DEMOS_EXPERT = "/demos/expert"
DEMOS_ROADMAP = "/demos/roadmap"

# The graph's nodes and edges as columns (one row per element, with the iteration it was
# added at): birlg.GraphNodes, birlg.GraphEdges.
GRAPH_NODES = "/graph/nodes"
GRAPH_EDGES = "/graph/edges"
GRAPH_BEST_PATHS = "/graph/best_paths"
GRAPH_SOLUTION = "/graph/solution"

BIRL_EXPERT = "/birl/expert"
BIRL_ITERATION = "/birl/iteration"
BIRL_POSTERIOR = "/birl/posterior"
BIRL_GRAPH_NODES = "/birl/graph_nodes"  # nodes grown during learning (birl.grow_nodes > 0)
BIRL_GRAPH_EDGES = "/birl/graph_edges"

EVAL_POLICY_LOSS = "/eval/policy_loss"
EVAL_PATHS = "/eval/paths"
EVAL_METRICS = "/eval/metrics"

# The topic every artefact of a stage holds: a file of another stage lacks it.
STAGE_TOPIC: dict[str, str] = {"scene": SCENE, "demos": DEMOS_EXPERT, "graph": GRAPH_NODES,
                               "birl": BIRL_ITERATION, "evaluate": EVAL_METRICS}

# Foxglove-native views (foxglove.SceneUpdate, pipeline/artefacts/foxglove.py): for other tools,
# never read back by the pipeline.
FOXGLOVE_SCENE = "/foxglove/scene"  # in scene.mcap
FOXGLOVE_MAP = "/foxglove/map"  # in scene.mcap, scenes with a map only (foxglove.Grid)
FOXGLOVE_DEMOS = "/foxglove/demos"  # in demos.mcap
FOXGLOVE_GRAPH = "/foxglove/graph"  # in graph.mcap
FOXGLOVE_PATHS = "/foxglove/paths"  # in eval.mcap
