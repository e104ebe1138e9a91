"""The JSON Schemas of the artefact messages (DESIGN §10), one per message type.

`ArtefactWriter.add` stores `SCHEMAS[type]` in the MCAP file as schema `birlg.<type>`
(encoding `jsonschema`, draft 2020-12), so an artefact describes itself to any MCAP reader:
types, array shapes, units and meanings. Conventions used by every schema: lengths are
metres, angles radians, times seconds, all in the scene's frame; a point is `[x, y]`; a
feature vector has one entry per reward feature in the order of `feature_names` (default
relation, social, goal_deviation, length). Extra keys are allowed everywhere (no
`additionalProperties: false`), so adding a field never breaks a reader; removing or
retyping one does. docs/artefacts.md is the human-readable form of this module.
"""

from __future__ import annotations

from typing import Any

Schema = dict[str, Any]
DRAFT = "https://json-schema.org/draft/2020-12/schema"


def _num(desc: str, **kw: Any) -> Schema:
    return {"type": "number", "description": desc, **kw}


def _int(desc: str, **kw: Any) -> Schema:
    return {"type": "integer", "description": desc, **kw}


def _str(desc: str, **kw: Any) -> Schema:
    return {"type": "string", "description": desc, **kw}


def _bool(desc: str) -> Schema:
    return {"type": "boolean", "description": desc}


def _array(items: Schema, desc: str, n: int | None = None, min_items: int = 0) -> Schema:
    """An array of `items`; exactly `n` long when n is given, else at least `min_items`."""
    shape = {"minItems": n, "maxItems": n} if n is not None else \
        ({"minItems": min_items} if min_items else {})
    return {"type": "array", "description": desc, "items": items, **shape}


def _nullable(schema: Schema, when: str) -> Schema:
    return {**schema, "type": [schema["type"], "null"],
            "description": f"{schema['description']} null {when}."}


def _obj(desc: str, props: dict[str, Schema], optional: tuple[str, ...] = ()) -> Schema:
    """An object whose properties are all required except `optional` ones."""
    return {"type": "object", "description": desc, "properties": props,
            "required": [k for k in props if k not in optional]}


def _point(desc: str) -> Schema:
    return _array({"type": "number"}, f"{desc} [x, y], metres.", n=2)


def _polyline(desc: str) -> Schema:
    return _array(_point("A waypoint"), f"{desc}: a polyline of [x, y] points (metres), in "
                  "order of travel.")


def _features(desc: str) -> Schema:
    return _array({"type": "number"}, f"{desc}. One entry per reward feature, in the order "
                  "of feature_names.", min_items=1)


def _ids(desc: str) -> Schema:
    return _array({"type": "integer", "minimum": 0}, desc)


def _message(title: str, desc: str, props: dict[str, Schema],
             optional: tuple[str, ...] = ()) -> Schema:
    return {"$schema": DRAFT, "title": f"birlg.{title}", **_obj(desc, props, optional)}




def _node(desc: str) -> Schema:
    return _int(f"{desc} (node id: index into the graph's node list).", minimum=0)

FEATURE_NAMES = _array({"type": "string"}, "Names of the features, in the order of the "
                       "feature vectors that follow them: in demos.mcap (/demos/expert) the "
                       "true reward's; in birl.mcap (/birl/expert) the learner's, which "
                       "graph.mcap's (its /graph/edges names them too) and eval.mcap's "
                       "feature and weight vectors follow.",
                       min_items=1)
GAMMA_T = _num("Discount at the end of the path, γ^T with T its duration in seconds "
               "(0 < γ^T ≤ 1).", minimum=0, maximum=1)
PHI = _features("Discounted feature counts Φ(ξ) = Σ_t γ^{T_t} φ(e_t) of the path")
REACHED = _bool("Whether the path ends within goal_tolerance of the goal.")
OFFSET = _num("The part of the path's return no weight changes: −c·Σ_t γ^{T_t} τ_t (c the "
              "cost per second, τ_t the edges' durations) plus γ^T R_goal if it reaches the "
              "goal; Q(ξ; w) = w·Φ + offset.")

SCENE = _message("Scene", "The scene: room, persons, relations, starts, goal, "
                 "obstacles. Written once, log_time 0.", {
    "name": _str("Name of the scene (its file stem, or 'random-<seed>')."),
    "room": _obj("The room, an axis-aligned rectangle (metres).", {
        k: _num(f"{desc} of the room, metres.") for k, desc in (
            ("x_min", "Left edge"), ("y_min", "Bottom edge"), ("x_max", "Right edge"),
            ("y_max", "Top edge"))}),
    "persons": _array(_obj("A person: a static pose with an optional velocity.", {
        "id": _int("Person id, referred to by relations."),
        "x": _num("Position x, metres."), "y": _num("Position y, metres."),
        "theta": _num("Heading, radians, counter-clockwise from +x."),
        "vx": _num("Velocity x, m/s (0 for a standing person)."),
        "vy": _num("Velocity y, m/s (0 for a standing person).")}), "The persons."),
    "relations": _array(_array({"type": "integer"}, "A social link: the ids of two persons; "
                               "the link is the segment between them.", n=2),
                        "Social relations (unordered pairs of person ids)."),
    "starts": _array(_point("A robot start"), "Robot start positions.", min_items=1),
    "goal": _point("The goal (a state within goal_tolerance of it is terminal),"),
    "body_radius": _num("Radius of each person's body disk, metres; no path may enter it.",
                        exclusiveMinimum=0),
    "goal_tolerance": _num("Distance to the goal within which a state is terminal, metres.",
                           exclusiveMinimum=0),
    "robot_radius": _num("Clearance the robot needs from obstacles, metres.", minimum=0),
    "obstacles": _array(_array(_point("A vertex"), "A polygon (closed implicitly).",
                               min_items=3), "Static obstacle polygons (none: empty list)."),
    "map": _str("Path of the ROS map_server YAML the scene's map came from (relative to the "
                "scene file); the raster itself is on /scene/map."),
}, optional=("map",))

OCCUPANCY_GRID = _message("OccupancyGrid", "The scene's occupancy map (only for scenes with a "
                          "map). Cell (row r, col c) covers x in origin_x + [c, c+1]·resolution "
                          "and y in origin_y + [r, r+1]·resolution: row 0 is the bottom row.", {
    "origin": _point("Lower-left corner of cell (0, 0),"),
    "resolution": _num("Cell size, metres per cell.", exclusiveMinimum=0),
    "width": _int("Number of columns.", minimum=1),
    "height": _int("Number of rows.", minimum=1),
    "occupied": _str("The (height, width) occupancy raster, row-major (row 0 = lowest y), "
                     "1 = obstacle (occupied or unknown), bit-packed with numpy.packbits "
                     "(big-endian bit order) and base64-encoded.", contentEncoding="base64"),
})

EXPERT = _message("Expert", "Who demonstrated, under which true reward.", {
    "kind": _str("Expert kind: optimal, boltzmann, file, planner, or none (a deployment "
                 "without demonstrations)."),
    "reward": _nullable(_str("Name of the true reward preset (polite, rude, ...)."),
                        "for file, planner and none demonstrations"),
    "true_weights": _nullable(_features("The true reward weights w*"),
                              "for file, planner and none demonstrations (no w* known)"),
    "feature_names": FEATURE_NAMES,
    "beta": _nullable(_num("Boltzmann rationality β_E of the expert."),
                      "unless kind is boltzmann"),
    "gamma": _num("Discount per second, γ (1: undiscounted goal reaching).",
                  exclusiveMinimum=0, maximum=1),
    "time_cost": _num("Cost per second c: every edge's reward has −c·τ (mdp.time_cost).",
                      minimum=0),
    "r_goal": _num("Terminal reward of the goal, R_goal."),
    "speed": _num("Robot speed used for edge durations, m/s.", exclusiveMinimum=0),
})

DEMONSTRATION = _message("Demonstration", "One expert demonstration (log_time = its index).", {
    "start_index": _int("Index of the start (into Scene.starts) it begins at.", minimum=0),
    "points": _polyline("The demonstrated path"),
    "features": _features("Feature integrals φ of the whole path (undiscounted)"),
    "discounted_features": PHI,
    "end_discount": GAMMA_T,
    "offset": OFFSET,
    "duration": _num("Duration of the path at the robot speed, seconds.", minimum=0),
    "reached": REACHED,
    "subject": _nullable(_str("Who demonstrated it (a demonstration file's `subjects`, or a "
                              "synthetic subject)."), "when unknown"),
    "source": _nullable(_str("Where it came from in the demonstration file: its trajectory's "
                             "number there, from 0, and its id (`17 (id '117')`; `17/2` for "
                             "the second walk expert.select_walks cut from it), behind the "
                             "recording's name in a folder (`ben.bag: 3`)."),
                        "for synthetic demonstrations (absent in artefacts written before it)"),
    "heldout": _bool("Held out of learning (evaluate.holdout): never in the graph nor in the "
                     "likelihood, only compared with the learned paths."),
    "value_true": _nullable(_num("Quality of the path under w*: w*·Φ + offset."),
                            "for file, planner and none demonstrations"),
}, optional=("source",))

def _column(dtype: str, desc: str, per: str = "node") -> Schema:
    """A column of a columnar message: one value per row, as the base64 of a little-endian
    binary array (numpy: np.frombuffer(base64.b64decode(s), dtype))."""
    return {"type": "string", "contentEncoding": "base64",
            "contentMediaType": "application/octet-stream",
            "description": f"{desc} Column: base64 of one little-endian {dtype} per {per}."}


_COLUMNAR = ("Columns, one row per {per}: row i is {per} first_id + i. Each numeric column "
             "is the base64 of a little-endian binary array (dtype in its description). "
             "Several messages on one topic hold consecutive rows (each starts at the id after "
             "the previous one's last); log_time = the last growth iteration among the rows.")

GRAPH_NODES = _message("GraphNodes", "Nodes of the adaptive state graph. "
                       + _COLUMNAR.format(per="node"), {
    "first_id": _int("Node id (index into the graph's node list) of the first row.",
                     minimum=0),
    "count": _int("Number of nodes (rows) in this message.", minimum=0),
    "x": _column("float64", "Position x, metres."),
    "y": _column("float64", "Position y, metres."),
    "theta": _column("float64", "Heading of the robot state, radians."),
    "kind": _array(_str("start, goal, voronoi, demo, medial (on the medial axis of the "
                        "free space: between obstacles in scenes with obstacles, and between "
                        "obstacles, people and social links in a graph without "
                        "demonstrations) or sampled."),
                   "How each node was made (count strings)."),
    "parent": _column("int32", "Node it was sampled from; −1 for initial nodes."),
    "iteration": _column("int32", "Growth iteration it was added (0 = initial nodes): "
                         "growth replays from this."),
    "gp_mean": _column("float64", "GP-regression estimate of its value at sampling time; "
                       "NaN for initial nodes."),
    "gp_std": _column("float64", "GP-regression standard deviation at sampling time; NaN "
                      "for initial nodes."),
    "score": _column("float64", "Exploration score ES it was picked with; NaN for initial "
                     "nodes."),
    "terminal": _column("uint8", "1 if the node is terminal, else 0 (only on "
                        "/birl/graph_nodes; graph.mcap's are in /graph/solution)."),
}, optional=("terminal",))

GRAPH_EDGES = _message("GraphEdges", "Directed edges (local-controller runs) of the adaptive "
                       "graph. " + _COLUMNAR.format(per="edge"), {
    "first_id": _int("Edge id (index into the graph's edge list) of the first row.",
                     minimum=0),
    "count": _int("Number of edges (rows) in this message.", minimum=0),
    "n_features": _int("Entries of each edge's feature vector (len(feature_names)).",
                       minimum=0),
    "feature_names": _array({"type": "string"}, "Names of the features of `features`' "
                            "columns, in order (the learner's)."),
    "src": _column("int32", "Source node id.", "edge"),
    "dst": _column("int32", "Destination node id.", "edge"),
    "duration": _column("float64", "Duration τ(e) of the controller run, seconds (> 0).",
                        "edge"),
    "features": _column("float64", "Feature integrals φ(e): count × n_features values, "
                        "row-major (edge by edge), in the order of feature_names.",
                        "feature entry"),
    "n_waypoints": _column("int32", "Number of points (≥ 2) of the edge's path in "
                           "`waypoints`.", "edge"),
    "waypoints": _column("float64", "The controller's path of every edge, edge after edge "
                         "(n_waypoints points each, from src to dst), each point x then y, "
                         "metres.", "coordinate"),
    "demo": _column("uint8", "1 if the edge is a segment of a demonstration (carries its "
                    "features), else 0.", "edge"),
    "iteration": _column("int32", "Growth iteration it was added (the later of its ends).",
                         "edge"),
})

ROADMAP = _message("Roadmap", "The reference roadmap with its exact solution under w*, as "
                   "columns (like birlg.GraphNodes and birlg.GraphEdges, in one message): a "
                   "roadmap has 10^4-10^6 edges, which as JSON arrays took longer to write and "
                   "read than to build.", {
    "spacing": _num("Lattice spacing, metres.", exclusiveMinimum=0),
    "connectivity": _int("Lattice connectivity: 8 (king moves) or 16 (plus knight moves)."),
    "n_nodes": _int("Number of nodes.", minimum=1),
    "n_edges": _int("Number of edges.", minimum=0),
    "n_features": _int("Entries of each edge's feature vector (len(feature_names)).",
                       minimum=0),
    "positions": _column("float64", "Node positions: x then y of every node, metres.",
                         "coordinate"),
    "src": _column("int32", "Source node of every edge.", "edge"),
    "dst": _column("int32", "Destination node of every edge.", "edge"),
    "duration": _column("float64", "Duration of every edge, seconds.", "edge"),
    "features": _column("float64", "Feature integrals of every edge: n_edges × n_features "
                        "values, row-major (edge by edge), in the order of feature_names.",
                        "feature entry"),
    "terminal": _column("uint8", "1 if the node is terminal, else 0."),
    "start_nodes": _ids("Node of every start, in the order of Scene.starts."),
    "goal_node": _node("The goal's node"),
    "true_values": _nullable(_column("float64", "Optimal values V* under w*."),
                             "for file, planner and none demonstrations"),
    "true_policy": _nullable(_column("int32", "Optimal policy under w*: the edge index taken "
                                     "at each node, −1 for none."),
                             "for file, planner and none demonstrations"),
})

BEST_PATHS = _message("BestPaths", "The greedy best trajectories after one growth iteration.", {
    "iteration": _int("Growth iteration.", minimum=0),
    "n_nodes": _int("Number of nodes at that iteration.", minimum=0),
    "paths": _array(_ids("The node ids of the best path from one start."),
                    "Best path per start, in the order of Scene.starts."),
    "values": _array({"type": "number"}, "Value V of every start."),
    "reached": _array({"type": "boolean"}, "Whether each best path reaches the goal."),
})

GRAPH_SOLUTION = _message("GraphSolution", "The final graph's MDP solution under the weights "
                          "that grew it (arrays over nodes have n_nodes entries).", {
    "weights": _features("The weights the graph grew under"),
    "weights_source": _str("Where they came from: prior_mean, fixed, true or given."),
    "values": _array({"type": "number"}, "Value V of every node."),
    "policy_dst": _array({"type": "integer", "minimum": -1}, "Successor node of every node under "
                         "the greedy policy, −1 for none."),
    "terminal": _array({"type": "boolean"}, "Whether each node is terminal."),
    "start_nodes": _ids("Node of every start, in the order of Scene.starts."),
    "goal_node": _node("The goal's node"),
    "n_nodes": _int("Number of nodes.", minimum=0),
    "n_edges": _int("Number of edges.", minimum=0),
    "iterations": _int("Number of growth iterations.", minimum=0),
    "min_separation": _num("Minimum distance between nodes, metres.", minimum=0),
})

BIRL_EXPERT = _message("BirlExpert", "The demonstrations as the likelihood sees them.", {
    "feature_names": FEATURE_NAMES,
    "beta": _nullable(_num("The likelihood's temperature β at the estimate: learned by the "
                           "Boltzmann forms (the MAP's; with birl=mcmc the posterior mean's), "
                           "birl.beta for eq. (2)."), "for methods without one"),
    "prior": _str("Prior kind: gaussian, laplace or uniform."),
    "trajectories": _array(_obj("One demonstration.", {
        "start": _int("Start index.", minimum=0), "phi": PHI, "offset": OFFSET,
        "end_discount": GAMMA_T, "reached": REACHED}), "One entry per demonstration."),
})

BIRL_ITERATION = _message("BirlIteration", "One learning iteration (log_time = index; 0 = the "
                          "initial weights).", {
    "index": _int("Iteration index.", minimum=0),
    "method": _str("IRL method (map, mcmc, policywalk, maxent, fixed)."),
    "mdp_solves": _int("MDP solves used so far.", minimum=0),
    "weights": _features("Reward weights w_n of this iteration"),
    "log_likelihood": _num("Log likelihood of the demonstrations under w_n."),
    "log_prior": _num("Log prior density of w_n."),
    "log_posterior": _num("log_likelihood + log_prior."),
    "generated": _array(_obj("The greedy trajectory from one start under w_n.", {
        "start": _int("Start index.", minimum=0),
        "nodes": _ids("Graph node ids along the path."),
        "points": _polyline("The path"),
        "phi": PHI, "offset": OFFSET, "end_discount": GAMMA_T, "reached": REACHED,
        "quality": _num("Q(ξ; w_n) = w_n·Φ + offset.")}),
        "Greedy trajectory per start, in the order of Scene.starts."),
})

BIRL_POSTERIOR = _message("BirlPosterior", "Posterior samples of one sampling iteration "
                          "(birl=mcmc; log_time = iteration: with eq. (2) iterations 1..n; "
                          "with the Boltzmann forms the last, whose weights are its mean).", {
    "iteration": _int("The iteration whose weights are this posterior's mean (from 1).",
                      minimum=1),
    "mean": _features("Posterior mean of the weights"),
    "std": _features("Posterior standard deviation of the weights"),
    "acceptance_rate": _num("Metropolis–Hastings acceptance rate over the steps taken with "
                            "the kept proposal: the sampling steps, and a fixed-step burn-in "
                            "(an adapting burn-in's steps are not counted: its rate is the "
                            "target by construction).", minimum=0, maximum=1),
    "samples": _array(_features("One kept sample"), "Kept samples (n_kept × n_features)."),
    "n_chains": _int("Chains sampled; `samples` holds them one after the other.", minimum=1),
    "step": _num("The proposal step the chains kept after burn-in (adapted).", minimum=0),
    "rhat": _nullable(_array(_nullable(_num("Split R-hat (ArviZ)."), "where not finite"),
                             "Per weight, in the order of feature_names."),
                      "for one chain"),
    "ess": _nullable(_array(_nullable(_num("Bulk effective sample size (ArviZ)."),
                                      "where not finite"),
                            "Per weight, in the order of feature_names."), "for one chain"),
})

POLICY_LOSS = _message("PolicyLoss", "Policy loss of one iteration's weights ("
                       "log_time = iteration). Losses only when w* is known.", {
    "iteration": _int("BIRL iteration.", minimum=0),
    "weights": _features("The learned weights of that iteration"),
    "graph": _nullable(_num("Policy loss on the adaptive graph, in value units (≥ 0)."),
                       "when it cannot be computed"),
    "ref": _nullable(_num("Policy loss on the reference roadmap (≥ 0)."),
                     "when it cannot be computed"),
    "norm": _nullable(_num("Roadmap loss divided by the loss of the contrasting preset."),
                      "when that loss is 0"),
}, optional=("graph", "ref", "norm"))

LEARNED_PATH = _message("LearnedPath", "The greedy path from one start under the final learned "
                        "weights, with its social metrics (log_time = start index).", {
    "graph": _str("Where it was planned: graph (adaptive graph) or ref (reference roadmap).",
                  enum=["graph", "ref"]),
    "start": _int("Start index.", minimum=0),
    "points": _polyline("The path"),
    "relation_crossings": _int("Number of social links the path crosses.", minimum=0),
    "intimate_intrusion_m": _num("Path length inside intimate zones (< 0.45 m), metres.",
                                 minimum=0),
    "personal_intrusion_m": _num("Path length inside personal zones (< 1.2 m), metres.",
                                 minimum=0),
    "min_distance_to_person": _num("Smallest distance to a person, metres (scenes with "
                                   "persons only).", minimum=0),
    "path_length": _num("Length, metres.", minimum=0),
    "time_to_goal": _num("Duration at the robot speed, seconds.", minimum=0),
    "success": _num("1 if it reaches the goal, else 0.", minimum=0, maximum=1),
    "min_distance_to_obstacle": _num("Smallest clearance to an obstacle, metres (scenes "
                                     "with obstacles only)."),
    "obstacle_collisions": _num("1 if closer than robot_radius to an obstacle, else 0 "
                                "(scenes with obstacles only).", minimum=0, maximum=1),
}, optional=("min_distance_to_person", "min_distance_to_obstacle", "obstacle_collisions"))

METRICS = {
    **_message("Metrics", "The run's metrics (metrics.json without wall-clock timings): flat "
               "keys, numbers only; a metric that cannot be computed is left out. Besides "
               "the keys below: policy_loss_iter_NN / policy_loss_ref_iter_NN per "
               "iteration, policy_loss_initial / policy_loss_ref_initial (iteration 0), "
               "policy_loss_ref_<preset> (the contrasting preset's loss), weight_<feature> "
               "(weight_std_<feature> and mcmc_acceptance_rate for mcmc), ref_<metric> for "
               "the roadmap's paths, obstacle_collisions / min_distance_to_obstacle (scenes "
               "with obstacles), frechet_to_demos(_max) (file demos, metres), "
               "transfer_<scene>_<metric>; every key is in the metrics reference "
               "(docs/reference/metrics.md): held-out, demonstration-count, MCMC-diagnostic "
               "and graph keys among them.", {
        "policy_loss": _num("Final policy loss on the adaptive graph."),
        "policy_loss_ref": _num("Final policy loss on the reference roadmap."),
        "policy_loss_norm": _num("policy_loss_ref normalised by the contrasting preset's."),
        "relation_crossings": _num("Social links crossed, summed over starts."),
        "intimate_intrusion_m": _num("Intimate-zone intrusion, metres, summed over starts."),
        "personal_intrusion_m": _num("Personal-zone intrusion, metres, summed over starts."),
        "min_distance_to_person": _num("Smallest distance to a person over all paths, m "
                                       "(scenes with persons only)."),
        "path_length": _num("Mean path length, metres."),
        "time_to_goal": _num("Mean time to goal, seconds."),
        "success": _num("Share of starts whose path reaches the goal.", minimum=0, maximum=1),
    }, optional=("policy_loss", "policy_loss_ref", "policy_loss_norm",
                 "min_distance_to_person")),
    "additionalProperties": {"type": "number"},
}

# Message type name (without the `birlg.` prefix) -> its schema.
SCHEMAS: dict[str, Schema] = {s["title"].removeprefix("birlg."): s for s in (
    SCENE, OCCUPANCY_GRID, EXPERT, DEMONSTRATION, ROADMAP, GRAPH_NODES, GRAPH_EDGES, BEST_PATHS,
    GRAPH_SOLUTION, BIRL_EXPERT, BIRL_ITERATION, BIRL_POSTERIOR, POLICY_LOSS, LEARNED_PATH,
    METRICS)}


# --- foxglove.SceneUpdate and foxglove.Grid: Foxglove's own schemas (https://docs.foxglove.dev/
# docs/visualization/message-schemas/scene-update, .../grid), written out from their field
# definitions, so that Foxglove's 3D panel draws the /foxglove/* topics without plugins. Field
# names must match Foxglove's.

def _fg(title: str, desc: str, props: dict[str, Schema]) -> Schema:
    return {"title": f"foxglove.{title}", "description": desc, "type": "object",
            "properties": props, "required": list(props)}


def _xyz(title: str, desc: str, names: str = "xyz") -> Schema:
    return _fg(title, desc, {k: _num(f"{k} coordinate") for k in names})


def _enum(title: str, desc: str, values: tuple[tuple[str, str], ...]) -> Schema:
    return {"title": f"foxglove.{title}", "description": desc,
            "oneOf": [{"title": name, "const": i, "description": d}
                      for i, (name, d) in enumerate(values)]}


def _time(desc: str, signed: bool = False) -> Schema:
    sec = {"type": "integer"} if signed else {"type": "integer", "minimum": 0}
    return {"type": "object", "title": "duration" if signed else "time", "description": desc,
            "properties": {"sec": sec,
                           "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}},
            "required": ["sec", "nsec"]}


_COLOR = _fg("Color", "A color in RGBA format", {
    k: _num(f"{name} value between 0 and 1") for k, name in
    (("r", "Red"), ("g", "Green"), ("b", "Blue"), ("a", "Alpha"))})
_POSE = _fg("Pose", "A position and orientation for an object or reference frame in 3D space", {
    "position": _xyz("Vector3", "Point denoting position in 3D space"),
    "orientation": _xyz("Quaternion", "Quaternion denoting orientation in 3D space", "xyzw")})
_POINT3 = _xyz("Point3", "A point representing a position in 3D space")
_SIZE = _xyz("Vector3", "Size along each axis")
_INDICES = _array({"type": "integer", "minimum": 0}, "Indices into `points` and `colors`; "
                  "empty: [0, 1, ..., N-1]")
_COLORS = _array(_COLOR, "Per-point colors (empty, or as long as `points`)")


def _primitive(title: str, desc: str, **props: Schema) -> Schema:
    return _array(_fg(title, desc, props), f"{title} primitives")


SCENE_UPDATE: Schema = _fg("SceneUpdate", "An update to the entities displayed in a 3D scene", {
    "deletions": _array(_fg("SceneEntityDeletion", "Command to remove previously published "
                            "entities", {
        "timestamp": _time("Only matching entities earlier than this timestamp are deleted"),
        "type": _enum("SceneEntityDeletionType", "Type of deletion action to perform", (
            ("MATCHING_ID", "Delete the existing entity on the same topic with the given `id`"),
            ("ALL", "Delete all existing entities on the same topic"))),
        "id": _str("Identifier which must match if `type` is `MATCHING_ID`")}),
        "Scene entities to delete"),
    "entities": _array(_fg("SceneEntity", "A visual element in a 3D scene, made of primitives "
                           "that share one frame of reference", {
        "timestamp": _time("Timestamp of the entity"),
        "frame_id": _str("Frame of reference"),
        "id": _str("Identifier; replaces any prior entity on the same topic with the same id"),
        "lifetime": _time("Time after `timestamp` when the entity is removed; 0: never",
                          signed=True),
        "frame_locked": _bool("Whether the entity follows `frame_id` (true) or keeps its "
                              "location in the fixed frame (false)"),
        "metadata": _array(_fg("KeyValuePair", "A key with its associated value", {
            "key": _str("Key"), "value": _str("Value")}), "Additional metadata (unique keys)"),
        "arrows": _primitive("ArrowPrimitive", "A primitive representing an arrow",
                             pose=_POSE, shaft_length=_num("Length of the arrow shaft"),
                             shaft_diameter=_num("Diameter of the arrow shaft"),
                             head_length=_num("Length of the arrow head"),
                             head_diameter=_num("Diameter of the arrow head"), color=_COLOR),
        "cubes": _primitive("CubePrimitive", "A primitive representing a cube or rectangular "
                            "prism", pose=_POSE, size=_SIZE, color=_COLOR),
        "spheres": _primitive("SpherePrimitive", "A primitive representing a sphere or "
                              "ellipsoid", pose=_POSE, size=_SIZE, color=_COLOR),
        "cylinders": _primitive("CylinderPrimitive", "A primitive representing a cylinder, "
                                "elliptic cylinder, or truncated cone", pose=_POSE, size=_SIZE,
                                bottom_scale=_num("0-1, ratio of the bottom face's diameter "
                                                  "to the bounding box"),
                                top_scale=_num("0-1, ratio of the top face's diameter to the "
                                               "bounding box"), color=_COLOR),
        "lines": _primitive("LinePrimitive", "A primitive representing a series of points "
                            "connected by lines",
                            type=_enum("LineType", "Drawing primitive to use for lines", (
                                ("LINE_STRIP", "Connected line segments: 0-1, 1-2, ..."),
                                ("LINE_LOOP", "Closed polygon: 0-1, 1-2, ..., (n-1)-n, n-0"),
                                ("LINE_LIST", "Individual line segments: 0-1, 2-3, ..."))),
                            pose=_POSE, thickness=_num("Line thickness"),
                            scale_invariant=_bool("Whether `thickness` is in screen pixels "
                                                  "(true) or world units (false)"),
                            points=_array(_POINT3, "Points along the line"), color=_COLOR,
                            colors=_COLORS, indices=_INDICES),
        "triangles": _primitive("TriangleListPrimitive", "A primitive representing a set of "
                                "triangles or a surface tiled by triangles", pose=_POSE,
                                points=_array(_POINT3, "Vertices, as triples"), color=_COLOR,
                                colors=_COLORS, indices=_INDICES),
        "texts": _primitive("TextPrimitive", "A primitive representing a text label",
                            pose=_POSE, billboard=_bool("Whether the text always faces the "
                                                        "camera"),
                            font_size=_num("Font size (height of one line of text)"),
                            scale_invariant=_bool("Whether `font_size` is in screen pixels "
                                                  "(true) or world units (false)"),
                            color=_COLOR, text=_str("Text")),
        "models": _primitive("ModelPrimitive", "A primitive representing a 3D model file",
                             pose=_POSE, scale=_SIZE, color=_COLOR,
                             override_color=_bool("Whether to use `color` instead of the "
                                                  "model's materials"),
                             url=_str("URL pointing to model file"),
                             media_type=_str("Media type of embedded model"),
                             data=_str("Embedded model", contentEncoding="base64")),
    }), "Scene entities to add or replace"),
})

_NUMERIC_TYPES = ("UNKNOWN", "UINT8", "INT8", "UINT16", "INT16", "UINT32", "INT32", "FLOAT32",
                  "FLOAT64")
GRID: Schema = _fg("Grid", "A 2D grid of data", {
    "timestamp": _time("Timestamp of grid"),
    "frame_id": _str("Frame of reference"),
    "pose": {**_POSE, "description": "Origin of the grid's corner relative to the frame of "
             "reference; the grid lies in the x-y plane of this pose"},
    "column_count": _int("Number of grid columns", minimum=0),
    "cell_size": _xyz("Vector2", "Size of a single grid cell along x and y, relative to `pose`",
                      "xy"),
    "row_stride": _int("Number of bytes between rows in `data`", minimum=0),
    "cell_stride": _int("Number of bytes between cells within a row in `data`", minimum=0),
    "fields": _array(_fg("PackedElementField", "A field present within each element in a byte "
                         "array of packed elements", {
        "name": _str("Name of the field"),
        "offset": _int("Byte offset from start of data buffer", minimum=0),
        "type": _enum("NumericType", "Type of data in the field (integers little-endian)",
                      tuple((name, name) for name in _NUMERIC_TYPES))}), "Fields in `data`"),
    "data": _str("Grid cell data, interpreted using `fields`, in row-major (y-major) order",
                 contentEncoding="base64"),
})

SCHEMAS["foxglove.SceneUpdate"] = SCENE_UPDATE
SCHEMAS["foxglove.Grid"] = GRID
