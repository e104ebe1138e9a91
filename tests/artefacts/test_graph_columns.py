"""The graph as columns (/graph/nodes, /graph/edges and the BIRL stage's /birl/graph_*): every
field round-trips to the bit, growth replays from the iteration columns, chunked topics read
as one, and a garbled column is a one-line error naming the file, topic and field."""

import base64

import numpy as np
import pytest

from pipeline.artefacts import ArtefactError, codec, read_artefact, topics
from pipeline.artefacts.store import ArtefactWriter
from pipeline.core.adaptive_graph import AdaptiveGraph, GraphParams
from pipeline.core.controllers import LinearController, PosqController
from pipeline.core.experts import optimal_demos
from pipeline.core.features import FeatureModel
from pipeline.core.graph_mdp import MDPParams, Polylines
from pipeline.core.roadmap import RoadmapParams, build_roadmap
from pipeline.core.state_graph import EdgeTable, NodeTable
from tests.conftest import POLITE

PRIOR_MEAN = np.array([-0.5, -0.5, -0.5, -0.5])


@pytest.fixture(scope="module", params=["linear", "posq"])
def grown(request, metropolis):
    """A small adaptive graph (the PosQ controller's edges have many waypoints each) and the
    number of nodes after every growth iteration."""
    fm = FeatureModel.from_scene(metropolis)
    rm = build_roadmap(metropolis, fm)
    mdp = rm.mdp()
    demos = optimal_demos(mdp, rm.positions, rm.start_nodes, mdp.solve(POLITE))
    controller = LinearController() if request.param == "linear" else PosqController()
    g = AdaptiveGraph(metropolis, fm, controller, PRIOR_MEAN, GraphParams(max_nodes=120),
                      np.random.default_rng(1))
    g.initialise(demos)
    sizes = {g.iteration: g.n_nodes}
    g.grow(lambda graph: sizes.update({graph.iteration: graph.n_nodes}))
    return g, sizes


def _write(path, messages):
    """An artefact of (topic, type, payload, log_time)."""
    with ArtefactWriter(path, config_yaml="", metadata={}) as w:
        for topic, type_name, payload, log_time in messages:
            w.add(topic, type_name, payload, log_time=log_time)
    return path


def _graph_file(path, g, chunks=1):
    """graph.mcap's columns and solution for the graph g, each table in `chunks` messages."""
    nodes, edges = g.node_table(), g.edge_table()
    msgs = []
    for k in range(chunks):
        lo_n, hi_n = len(nodes) * k // chunks, len(nodes) * (k + 1) // chunks
        lo_e, hi_e = len(edges) * k // chunks, len(edges) * (k + 1) // chunks
        part_n, part_e = g.node_table(lo_n), g.edge_table(lo_e)
        part_n = NodeTable(*(None if v is None else v[:hi_n - lo_n] for v in
                             (part_n.pose, part_n.kind, part_n.parent, part_n.added_at,
                              part_n.gp_mean, part_n.gp_std, part_n.score, part_n.terminal)))
        part_e = EdgeTable(part_e.src[:hi_e - lo_e], part_e.dst[:hi_e - lo_e],
                           part_e.duration[:hi_e - lo_e], part_e.features[:hi_e - lo_e],
                           Polylines.from_list(part_e.waypoints[:hi_e - lo_e]),
                           part_e.demo[:hi_e - lo_e], part_e.added_at[:hi_e - lo_e])
        msgs += [(topics.GRAPH_NODES, "GraphNodes", codec.nodes_message(part_n, lo_n),
                  codec.last_iteration(part_n)),
                 (topics.GRAPH_EDGES, "GraphEdges", codec.edges_message(part_e, lo_e, g.fm.names),
                  codec.last_iteration(part_e))]
    msgs.append((topics.GRAPH_SOLUTION, "GraphSolution", {
        "terminal": g.terminal, "start_nodes": g.start_nodes, "min_separation": 0.1},
        g.iteration))
    return _write(path, msgs), nodes, edges


def _bits(a):
    """An array's bytes: equal to the bit (NaN payloads and −0.0 included)."""
    a = np.ascontiguousarray(a)
    return a.dtype.str if a.dtype.kind != "U" else "str", a.shape, a.tobytes()


def assert_same_nodes(got: NodeTable, want: NodeTable):
    for name in ("pose", "kind", "parent", "added_at", "gp_mean", "gp_std", "score"):
        assert _bits(getattr(got, name)) == _bits(getattr(want, name)), name


def assert_same_edges(got: EdgeTable, want: EdgeTable):
    for name in ("src", "dst", "duration", "features", "demo", "added_at"):
        assert _bits(getattr(got, name)) == _bits(getattr(want, name)), name
    assert _bits(got.waypoints.points) == _bits(want.waypoints.points)
    assert _bits(got.waypoints.offsets) == _bits(want.waypoints.offsets)


@pytest.mark.parametrize("lazy", [False, True])
@pytest.mark.parametrize("chunks", [1, 3])
def test_every_field_round_trips_to_the_bit(tmp_path, grown, chunks, lazy):
    g, _ = grown
    path, nodes, edges = _graph_file(tmp_path / "graph.mcap", g, chunks)
    art = read_artefact(path, lazy=lazy)
    assert len(art.all(topics.GRAPH_NODES)) == len(art.all(topics.GRAPH_EDGES)) == chunks
    assert_same_nodes(codec.decode_nodes(art), nodes)
    assert_same_edges(codec.decode_edges(art), edges)
    assert np.isnan(nodes.gp_mean[nodes.parent < 0]).all()  # initial nodes: no GP estimate
    assert len(set(edges.waypoints.counts.tolist())) > 1  # demo edges have more waypoints
    # every edge's polyline, as the graph drove it
    for e in range(0, len(edges), 7):
        assert _bits(edges.waypoints[e]) == _bits(np.asarray(g.waypoints[e], float))
    # and the typed graph the stages use
    graph = codec.decode_graph(art, MDPParams())
    want = g.mdp()
    assert np.array_equal(graph.mdp.src, want.src) and np.array_equal(graph.mdp.dst, want.dst)
    assert _bits(graph.mdp.features) == _bits(want.features)
    assert _bits(graph.positions) == _bits(g.positions)


def test_unusual_values_round_trip(tmp_path):
    weird = np.array([-0.0, 5e-324, 1.7976931348623157e308, np.nan, 0.1 + 0.2, -1e-300])
    nodes = NodeTable(np.stack([weird, weird[::-1], np.arange(6.0)], axis=1),
                      np.array(["start", "goal", "demo", "sampled", "voronoi", "sampled"]),
                      np.array([-1, -1, 0, 2**31 - 1, 3, 4]), np.array([0, 0, 0, 1, 2, 2]),
                      weird, np.abs(weird), weird[::-1], np.array([0, 1, 0, 0, 1, 0], bool))
    edges = EdgeTable(np.array([0, 1]), np.array([1, 0]), np.array([0.5, 1e-9]),
                      np.array([[0.0, -0.0, 1e300], [np.pi, 2.0, 3.0]]),
                      Polylines.from_list([[[0, 0], [1, 1]], [[1, 1], [0.5, 0.5], [0, 0]]]),
                      np.array([True, False]), np.array([0, 2]))
    empty_edges = EdgeTable(np.zeros(0, int), np.zeros(0, int), np.zeros(0), np.zeros((0, 3)),
                            Polylines.from_list([]), np.zeros(0, bool), np.zeros(0, int))
    path = _write(tmp_path / "x.mcap", [
        ("/n", "GraphNodes", codec.nodes_message(nodes, 10, with_terminal=True), 2),
        ("/e", "GraphEdges", codec.edges_message(edges, 4, ["a", "b", "c"]), 2),
        ("/none", "GraphEdges", codec.edges_message(empty_edges, 0, ["a", "b", "c"]), 0)])
    art = read_artefact(path)
    got = codec.decode_nodes(art, "/n", first_id=10)
    assert_same_nodes(got, nodes)
    assert got.terminal is not None and np.array_equal(got.terminal, nodes.terminal)
    assert_same_edges(codec.decode_edges(art, "/e", first_id=4), edges)
    none = codec.decode_edges(art, "/none")
    assert len(none) == 0 and none.features.shape == (0, 3) and len(none.waypoints) == 0
    with pytest.raises(ArtefactError, match="start at id 10, expected 0"):
        codec.decode_nodes(art, "/n")  # ids must continue where they are expected to
    with pytest.raises(ValueError, match="int32"):
        codec.nodes_message(NodeTable(*(v[:1] for v in (
            nodes.pose, nodes.kind, np.array([2**31]), nodes.added_at, nodes.gp_mean,
            nodes.gp_std, nodes.score))), 0)


def test_growth_replays_from_the_iteration_columns(tmp_path, grown):
    g, sizes = grown
    path, _, _ = _graph_file(tmp_path / "graph.mcap", g)
    art = read_artefact(path)
    nodes, edges = codec.decode_nodes(art), codec.decode_edges(art)
    # the graph as it stood after every iteration: as many nodes as it had then
    for k, n in sizes.items():
        assert np.count_nonzero(nodes.added_at <= k) == n, k
    # nodes in the order they were added; an edge from the iteration both its ends exist
    assert (np.diff(nodes.added_at) >= 0).all()
    assert np.array_equal(edges.added_at,
                          np.maximum(nodes.added_at[edges.src], nodes.added_at[edges.dst]))
    new = nodes.added_at > 0
    assert (nodes.parent[new] >= 0).all() and (nodes.parent[new] < np.flatnonzero(new)).all()
    # the file's log_time is the last iteration: the columns complete the growth
    assert max(sizes) == nodes.added_at.max() == g.iteration


def test_birl_growth_continues_the_graph(tmp_path, grown):
    g, _ = grown
    graph_path, _, _ = _graph_file(tmp_path / "graph.mcap", g)
    # restored from the columns, grown on under other weights (birl.grow_nodes)
    r = AdaptiveGraph(g.scene, g.fm, g.controller, PRIOR_MEAN, g.p, np.random.default_rng(2))
    r.restore(*codec.graph_tables(read_artefact(graph_path)), g.start_nodes)
    assert_same_nodes(r.node_table(), g.node_table())
    assert_same_edges(r.edge_table(), g.edge_table())
    base_nodes, base_edges = r.n_nodes, len(r.src)
    r.set_weights(POLITE)
    assert r.grow_by(6) >= 6
    more_nodes, more_edges = r.node_table(base_nodes), r.edge_table(base_edges)
    birl_path = _write(tmp_path / "birl.mcap", [
        (topics.BIRL_GRAPH_NODES, "GraphNodes",
         codec.nodes_message(more_nodes, base_nodes, with_terminal=True),
         codec.last_iteration(more_nodes)),
        (topics.BIRL_GRAPH_EDGES, "GraphEdges",
         codec.edges_message(more_edges, base_edges, r.fm.names),
         codec.last_iteration(more_edges))])
    nodes, edges = codec.graph_tables(read_artefact(graph_path), read_artefact(birl_path))
    assert_same_nodes(nodes, r.node_table())
    assert_same_edges(edges, r.edge_table())
    assert nodes.terminal is not None and np.array_equal(nodes.terminal, r.terminal)
    assert nodes.added_at[base_nodes:].min() > g.iteration  # growth replays on from there
    graph = codec.decode_graph(read_artefact(graph_path), MDPParams(), read_artefact(birl_path))
    assert graph.mdp.n_nodes == r.n_nodes and len(graph.waypoints) == len(r.src)


def _garble(msg: dict) -> None:
    msg["waypoints"] = msg["waypoints"][:-8]


def _pad(msg: dict) -> None:
    """Eight bytes too many at the end of the duration column."""
    msg["duration"] = base64.b64encode(base64.b64decode(msg["duration"]) + bytes(8)).decode()


def _negative_count(msg: dict) -> None:
    """The first edge's n_waypoints -1, the second's more by as many: the sum unchanged."""
    counts = np.frombuffer(base64.b64decode(msg["n_waypoints"]), "<i4").copy()
    counts[1] += counts[0] + 1
    counts[0] = -1
    msg["n_waypoints"] = codec.column(counts, "<i4")


@pytest.mark.parametrize("topic, garble, words", [
    (topics.GRAPH_EDGES, _garble, ["column 'waypoints' holds", "bytes"]),
    (topics.GRAPH_EDGES, lambda m: m.update(src="!!!"), ["column 'src'"]),
    (topics.GRAPH_EDGES, lambda m: m.update(dst=[1, 2]), ["column 'dst' is not a base64"]),
    (topics.GRAPH_EDGES, lambda m: m.pop("features"), ["without the field 'features'"]),
    (topics.GRAPH_EDGES, lambda m: m.update(count=-1), ["'count' is not a non-negative"]),
    (topics.GRAPH_EDGES, lambda m: m.update(count=True), ["'count' is not a non-negative",
                                                          "(True)"]),
    (topics.GRAPH_EDGES, _pad, ["column 'duration' holds", "bytes"]),
    (topics.GRAPH_EDGES, _negative_count, ["with a negative 'n_waypoints'"]),
    (topics.GRAPH_NODES, lambda m: m.update(kind=m["kind"][:-1]), ["'kind' is not a list"]),
    (topics.GRAPH_NODES, lambda m: m.update(first_id=3), ["start at id 3, expected 0"]),
    (topics.GRAPH_NODES, lambda m: m.update(x=m["x"][:-4] + "===="), ["column 'x'"]),
])
def test_a_garbled_column_is_a_one_line_error(tmp_path, grown, topic, garble, words):
    g, _ = grown
    path, _, _ = _graph_file(tmp_path / "graph.mcap", g)
    art = read_artefact(path)
    msgs = {t: [dict(m) for m in art.all(t)] for t in art.messages}
    garble(msgs[topic][0])
    types = {topics.GRAPH_NODES: "GraphNodes", topics.GRAPH_EDGES: "GraphEdges",
             topics.GRAPH_SOLUTION: "GraphSolution"}
    _write(path, [(t, types[t], m, 0) for t, ms in msgs.items() for m in ms])
    with pytest.raises(ArtefactError) as err:
        codec.decode_graph(read_artefact(path, lazy=True), MDPParams())
    text = str(err.value)
    assert str(path) in text and "\n" not in text and all(w in text for w in words), text


def test_a_truncated_graph_file_is_an_error_before_any_topic_is_read(tmp_path, grown):
    g, _ = grown
    path, _, _ = _graph_file(tmp_path / "graph.mcap", g)
    data = path.read_bytes()
    for cut in (len(data) // 3, len(data) // 2, len(data) - 20):
        path.write_bytes(data[:cut])
        with pytest.raises(ArtefactError, match="truncated or corrupt"):
            read_artefact(path, lazy=True)


@pytest.fixture(scope="module")
def roadmap(metropolis):
    """The metropolis reference roadmap and its solution under the polite reward."""
    rm = build_roadmap(metropolis, FeatureModel.from_scene(metropolis))
    mdp = rm.mdp()
    return rm, mdp, mdp.solve(POLITE)


def _roadmap_file(path, rm, mdp, solution):
    return _write(path, [(topics.DEMOS_ROADMAP, "Roadmap",
                          codec.roadmap_message(rm, RoadmapParams(), solution, mdp), 0)])


def test_the_roadmap_round_trips_to_the_bit(tmp_path, roadmap):
    rm, mdp, solution = roadmap
    art = read_artefact(_roadmap_file(tmp_path / "demos.mcap", rm, mdp, solution))
    graph = codec.decode_roadmap(art, MDPParams())
    assert np.array_equal(graph.positions, rm.positions)
    assert np.array_equal(graph.start_nodes, rm.start_nodes)
    m = graph.mdp  # the MDP orders edges its own way; caller order via edge_ids
    assert np.array_equal(m.src, mdp.src) and np.array_equal(m.dst, mdp.dst)
    assert np.array_equal(m.features, mdp.features) and np.array_equal(m.duration, mdp.duration)
    assert np.array_equal(m.terminal, rm.terminal)
    e = int(rm.src.size) // 2  # straight edges between the right nodes
    assert np.array_equal(graph.waypoints[e], rm.positions[[rm.src[e], rm.dst[e]]])
    msg = art.one(topics.DEMOS_ROADMAP)
    values = np.frombuffer(base64.b64decode(msg["true_values"]), "<f8")
    policy = np.frombuffer(base64.b64decode(msg["true_policy"]), "<i4")
    assert np.array_equal(values, solution.values)
    assert np.array_equal(policy, mdp.caller_edges(solution.policy))
    # and without a true reward: no solution
    art = read_artefact(_roadmap_file(tmp_path / "none.mcap", rm, mdp, None))
    assert art.one(topics.DEMOS_ROADMAP)["true_values"] is None


@pytest.mark.parametrize("garble, words", [
    (lambda m: m.update(features=m["features"][:-12]), ["column 'features' holds", "bytes"]),
    (lambda m: m.update(n_edges=m["n_edges"] + 1), ["column 'src' holds"]),
    (lambda m: m.update(src=[0, 1]), ["column 'src' is not a base64"]),
    (lambda m: m.pop("terminal"), ["without the field 'terminal'"]),
    (lambda m: m.update(n_nodes="9"), ["'n_nodes' is not a non-negative"]),
    (lambda m: m.update(positions=[[0.0, 0.0]]), ["JSON arrays", "add 'demos' to stages"]),
])
def test_a_garbled_roadmap_is_a_one_line_error(tmp_path, roadmap, garble, words):
    rm, mdp, solution = roadmap
    msg = codec.roadmap_message(rm, RoadmapParams(), solution, mdp)
    garble(msg)
    path = _write(tmp_path / "demos.mcap", [(topics.DEMOS_ROADMAP, "Roadmap", msg, 0)])
    with pytest.raises(ArtefactError) as err:
        codec.decode_roadmap(read_artefact(path), MDPParams())
    text = str(err.value)
    assert str(path) in text and "\n" not in text and all(w in text for w in words), text
