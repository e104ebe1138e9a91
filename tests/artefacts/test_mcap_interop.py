"""Artefacts as other tools see them: every message matches the JSON Schema stored in its
own file, checked with the plain `mcap` reader and `jsonschema` only; the Foxglove
topics are `foxglove.SceneUpdate` messages that draw the scene, demos, graph and paths;
log_time is index × 1 s; `python -m pipeline.tools.mcapinfo` describes and checks a file."""

import ast
import base64
import copy
import errno
import json
import re
import time
from pathlib import Path

import pytest
from jsonschema import Draft202012Validator
from mcap.reader import make_reader

from pipeline.artefacts import codec, foxglove, read_artefact, topics
from pipeline.artefacts.schemas import SCHEMAS
from pipeline.artefacts.store import LOG_TIME_NS
from pipeline.tools import mcapinfo
from tests.conftest import ROOT, run_in_process

FILE_DEMOS = str(ROOT / "data" / "demos" / "metropolis_polite_smoothed.json")
RUNS = {  # between them, every message type and every optional or nullable field
    "default": ("graph=small", "birl.n_iterations=3"),
    "mcmc_file_grow": ("graph=small", "birl=mcmc", "birl.n_iterations=2", "birl.grow_nodes=3",
                       "expert=file", f"expert.path={FILE_DEMOS}"),
    "map": ("scene=office", "stages=[scene]"),
}


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, Path]:
    out = {}
    for name, overrides in RUNS.items():
        out[name] = tmp_path_factory.mktemp(name)
        run_in_process(out[name], *overrides)
    return out


def messages(path: Path):
    """(schema, channel, payload) of every message, read with the mcap library alone."""
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            yield schema, channel, json.loads(message.data)


def errors(schema: dict, payload: dict) -> list[str]:
    return [e.message for e in Draft202012Validator(schema).iter_errors(payload)]


def test_every_message_matches_the_schema_stored_in_its_file(runs):
    seen: dict[str, int] = {}
    for run_dir in runs.values():
        for path in sorted(run_dir.glob("*.mcap")):
            for schema, channel, payload in messages(path):
                assert (schema.encoding, channel.message_encoding) == ("jsonschema", "json")
                stored = json.loads(schema.data)
                assert errors(stored, payload) == [], f"{path.name} {channel.topic}"
                seen[schema.name] = seen.get(schema.name, 0) + 1
    # every registered type was written and checked, none fell back to the permissive schema
    assert set(seen) == {n if "." in n else f"birlg.{n}" for n in SCHEMAS}


def test_stored_schemas_are_the_registered_ones_and_describe_every_field(runs):
    for path in sorted(runs["default"].glob("*.mcap")):
        for schema, _, _ in messages(path):
            name = schema.name.removeprefix("birlg.")
            assert json.loads(schema.data) == SCHEMAS[name]
    for name, schema in SCHEMAS.items():
        Draft202012Validator.check_schema(schema)
        if "." in name:  # Foxglove's own: e.g. its times have undescribed sec, nsec
            continue
        undocumented = [f"{name}.{key}" for key, prop in _properties(schema)
                        if not prop.get("description") or not (prop.get("type") or
                                                               prop.get("oneOf"))]
        assert undocumented == []


def _properties(schema: dict, prefix: str = ""):
    """(dotted key, schema) of every property, nested objects and array items included."""
    for key, prop in schema.get("properties", {}).items():
        yield prefix + key, prop
        for sub in (prop, prop.get("items", {}), prop.get("items", {}).get("items", {})):
            yield from _properties(sub, f"{prefix}{key}.")


def test_every_type_the_stages_write_has_a_registered_schema():
    written = set()
    for path in (ROOT / "pipeline" / "stages").glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Call) and getattr(node.func, "attr", "") == "add" \
                    and len(node.args) >= 2 and isinstance(node.args[1], ast.Constant):
                written.add(node.args[1].value)
    assert written and written <= set(SCHEMAS)


def test_a_wrong_message_fails_its_schema(runs):
    scene = read_artefact(runs["default"] / "scene.mcap").one(topics.SCENE)
    assert errors(SCHEMAS["Scene"], scene) == []
    for breaks in (lambda s: s["persons"][0].update(x="2.0"),   # a string for a number
                   lambda s: s["starts"].append([1.0, 2.0, 3.0]),  # not an [x, y] point
                   lambda s: s.pop("goal"),                        # a required field
                   lambda s: s.update(starts=[]),                  # at least one start
                   lambda s: s["relations"].append([1])):          # a link has two ends
        bad = copy.deepcopy(scene)
        breaks(bad)
        assert errors(SCHEMAS["Scene"], bad) != []
    update = foxglove.scene_update(scene)
    assert errors(SCHEMAS[foxglove.SCENE_UPDATE], update) == []
    update["entities"][0]["lines"][0]["type"] = 7  # no such foxglove.LineType
    assert errors(SCHEMAS[foxglove.SCENE_UPDATE], update) != []
    update["entities"][0].pop("frame_id")
    assert len(errors(SCHEMAS[foxglove.SCENE_UPDATE], update)) == 2


def _foxglove(path: Path, topic: str) -> dict[str, dict]:
    """The entities of the one SceneUpdate on `topic`, by id, checked as Foxglove needs."""
    (found,) = [(s, c, p) for s, c, p in messages(path) if c.topic == topic]
    schema, channel, update = found
    assert (schema.name, schema.encoding, channel.message_encoding) == (
        "foxglove.SceneUpdate", "jsonschema", "json")
    assert errors(json.loads(schema.data), update) == [] and update["deletions"] == []
    assert all(e["frame_id"] == foxglove.FRAME for e in update["entities"])
    return {e["id"]: e for e in update["entities"]}


def test_foxglove_topics_draw_scene_demos_graph_and_paths(runs):
    run = runs["default"]
    scene = read_artefact(run / "scene.mcap").one(topics.SCENE)
    ents = _foxglove(run / "scene.mcap", topics.FOXGLOVE_SCENE)
    assert set(ents) == {"room", "persons", "relations", "starts", "goal"}
    persons = ents["persons"]
    assert len(persons["cylinders"]) == len(persons["arrows"]) == len(persons["texts"]) \
        == len(scene["persons"]) == 12
    assert [c["pose"]["position"]["x"] for c in persons["cylinders"]] == \
        [p["x"] for p in scene["persons"]]
    assert persons["cylinders"][0]["size"]["x"] == 2 * scene["body_radius"]
    assert len(ents["relations"]["lines"]) == len(scene["relations"]) == 10
    assert all(len(line["points"]) == 2 for line in ents["relations"]["lines"])
    assert len(ents["starts"]["spheres"]) == len(scene["starts"]) == 7
    (room,) = ents["room"]["lines"]
    assert room["type"] == foxglove.LINE_LOOP and len(room["points"]) == 4
    assert ents["goal"]["spheres"][0]["pose"]["position"]["y"] == scene["goal"][1]

    demos = read_artefact(run / "demos.mcap").all(topics.DEMOS)
    ents = _foxglove(run / "demos.mcap", topics.FOXGLOVE_DEMOS)
    assert [len(e["lines"][0]["points"]) for e in ents.values()] == \
        [len(d["points"]) for d in demos]

    graph = read_artefact(run / "graph.mcap")
    nodes, edges = codec.decode_nodes(graph), codec.decode_edges(graph)
    ents = _foxglove(run / "graph.mcap", topics.FOXGLOVE_GRAPH)
    assert len(ents["nodes"]["spheres"]) == len(nodes)
    (lines,) = ents["edges"]["lines"]
    pairs = {frozenset(pair) for pair in zip(edges.src.tolist(), edges.dst.tolist(), strict=True)}
    assert lines["type"] == foxglove.LINE_LIST and len(lines["points"]) == 2 * len(pairs)

    paths = read_artefact(run / "eval.mcap").all(topics.EVAL_PATHS)
    ents = _foxglove(run / "eval.mcap", topics.FOXGLOVE_PATHS)
    assert sorted(ents) == sorted(f"{p['graph']}/{p['start']}" for p in paths)
    assert len(ents) == 2 * 7
    first = ents["graph/0"]
    assert [[q["x"], q["y"]] for q in first["lines"][0]["points"]] == paths[0]["points"]
    assert {m["key"] for m in first["metadata"]} >= {"relation_crossings", "path_length"}


def test_the_occupancy_map_is_a_foxglove_grid(runs):
    art = read_artefact(runs["map"] / "scene.mcap")
    grid = art.one(topics.SCENE_MAP)
    (found,) = [(s, c, p) for s, c, p in messages(runs["map"] / "scene.mcap")
                if c.topic == topics.FOXGLOVE_MAP]
    schema, channel, msg = found
    assert (schema.name, schema.encoding, channel.message_encoding) == (
        "foxglove.Grid", "jsonschema", "json")
    assert errors(json.loads(schema.data), msg) == []
    cells = base64.b64decode(msg["data"])
    assert msg["column_count"] == grid["width"] == msg["row_stride"]
    assert len(cells) == grid["width"] * grid["height"] and set(cells) == {0, 100}
    assert msg["cell_size"]["x"] == grid["resolution"]
    occupied = codec.decode_grid(grid).occupied
    assert cells.count(100) == occupied.sum()
    row = 10  # row 0 is the bottom row in both
    assert [c == 100 for c in cells[row * grid["width"]:(row + 1) * grid["width"]]] == \
        occupied[row].tolist()


def test_obstacle_polygons_are_drawn():
    scene = {"room": {"x_min": 0, "y_min": 0, "x_max": 4, "y_max": 3}, "body_radius": 0.25,
             "goal_tolerance": 0.2, "persons": [], "relations": [], "starts": [[0.5, 0.5]],
             "goal": [3.5, 2.5], "obstacles": [[[1, 1], [2, 1], [2, 2]]]}
    update = foxglove.scene_update(scene)
    assert errors(SCHEMAS[foxglove.SCENE_UPDATE], update) == []
    room = next(e for e in update["entities"] if e["id"] == "room")
    assert [len(line["points"]) for line in room["lines"]] == [4, 3]


def test_log_time_is_the_index_in_seconds(runs):
    with open(runs["default"] / "graph.mcap", "rb") as f:
        best = [(m.log_time, json.loads(m.data)["iteration"])
                for _, c, m in make_reader(f).iter_messages() if c.topic == topics.GRAPH_BEST_PATHS]
    assert best and all(t == it * LOG_TIME_NS for t, it in best)
    assert best[-1][0] >= 10 * LOG_TIME_NS  # seconds on Foxglove's timeline, not nanoseconds
    # the package's reader returns messages in index order, as before
    iterations = [b["iteration"] for b in
                  read_artefact(runs["default"] / "graph.mcap").all(topics.GRAPH_BEST_PATHS)]
    assert iterations == sorted(iterations) == [it for _, it in best]


def test_mcapinfo_lists_topics_counts_and_metadata_and_checks_schemas(runs, capsys, tmp_path):
    path = runs["default"] / "eval.mcap"
    assert mcapinfo.main(["--check", str(path)]) == 0
    out = capsys.readouterr().out
    n_paths = len(read_artefact(path).all(topics.EVAL_PATHS))
    assert f"/eval/paths        birlg.LearnedPath     jsonschema/json  {n_paths}\n" in out
    assert "/foxglove/paths    foxglove.SceneUpdate  jsonschema/json  1\n" in out
    assert "attachment config.yaml  application/yaml" in out
    assert "    seed = 0\n" in out and "    input_digest.birl = " in out
    assert "    sha256 = " in out and "check: all " in out

    # A message that does not match its stored schema is reported, exit status 1.
    from mcap.writer import Writer
    bad = tmp_path / "bad.mcap"
    with open(bad, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("birlg.Scene", "jsonschema", json.dumps(SCHEMAS["Scene"]).encode())
        cid = w.register_channel("/scene", "json", sid)
        w.add_message(cid, log_time=0, data=b'{"name": 3}', publish_time=0)
        w.finish()
    assert mcapinfo.main(["--check", str(bad)]) == 1
    out = capsys.readouterr().out
    assert "INVALID /scene at log_time 0: .name: 3 is not of type 'string'" in out
    assert "INVALID /scene at log_time 0: (message): 'room' is a required property" in out

    # A message or a stored schema that is no JSON, or names a type JSON Schema does not know
    # (one flipped bit: 'number' -> 'oumber'), is an invalid message, not an unreadable file
    for name, schema, data in (("notjson", json.dumps(SCHEMAS["Scene"]).encode(), b"not json"),
                               ("badschema", b"{not a schema", b'{"name": "x"}'),
                               ("unknowntype", b'{"properties": {"name": {"type": "oumber"}}}',
                                b'{"name": "x"}')):
        with open(tmp_path / f"{name}.mcap", "wb") as f:
            w = Writer(f)
            w.start()
            cid = w.register_channel("/scene", "json",
                                     w.register_schema("birlg.Scene", "jsonschema", schema))
            w.add_message(cid, log_time=0, data=data, publish_time=0)
            w.finish()
        assert mcapinfo.main(["--check", str(tmp_path / f"{name}.mcap")]) == 1
        assert "INVALID /scene at log_time 0: (message): not checkable against schema " \
               "'birlg.Scene'" in capsys.readouterr().out

    # A channel without a schema is not checked, and said so (it was counted as matching)
    with open(tmp_path / "noschema.mcap", "wb") as f:
        w = Writer(f)
        w.start()
        cid = w.register_channel("/x", "json", 0)
        w.add_message(cid, log_time=0, data=b"not json", publish_time=0)
        w.finish()
    assert mcapinfo.main(["--check", str(tmp_path / "noschema.mcap")]) == 0
    out = capsys.readouterr().out
    assert "match their schemas" not in out
    assert "check: 1 messages have no JSON schema or are not JSON encoded: not checked" in out

    # A flipped byte that the lenient MCAP reader reads past is caught by --check's CRCs (it
    # said "all N messages match" of a file the pipeline refuses)
    data, caught = (runs["default"] / "scene.mcap").read_bytes(), 0
    for at in range(len(data) // 8, len(data) - 8, len(data) // 8):
        flipped = tmp_path / "flipped.mcap"
        flipped.write_bytes(data[:at] + bytes([data[at] ^ 0x01]) + data[at + 1:])
        if mcapinfo.main([str(flipped)]) != 0:
            capsys.readouterr()
            continue  # the flip broke the file's structure: "cannot be read", exit 2
        capsys.readouterr()
        assert mcapinfo.main(["--check", str(flipped)]) == 1
        assert "  INVALID file: " in capsys.readouterr().out
        caught += 1
    assert caught >= 1

    # A file that is not MCAP: one line on stderr, exit status 2.
    (tmp_path / "x.mcap").write_text("hello")
    assert mcapinfo.main([str(tmp_path / "x.mcap")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: {tmp_path / 'x.mcap'} cannot be read as MCAP") \
        and err.count("\n") == 1 and "truncated" not in err
    # One cut short (a copy that stopped): said so, not only as the record it misreads.
    (tmp_path / "cut.mcap").write_bytes(data[:len(data) // 2])
    assert mcapinfo.main([str(tmp_path / "cut.mcap")]) == 2
    err = capsys.readouterr().err
    assert "cannot be read as MCAP (truncated: it begins as MCAP but does not end" in err \
        and err.count("\n") == 1


DOC = ROOT / "docs" / "artefacts.md"


def test_the_format_doc_names_every_topic_type_and_field():
    doc = DOC.read_text()
    names = [v for k, v in vars(topics).items() if k.isupper() and isinstance(v, str)
             and v.startswith("/")]
    assert len(names) >= 20 and [t for t in names if f"`{t}`" not in doc] == []
    missing = [f"{name}.{key}" for name, schema in SCHEMAS.items() if "." not in name
               for key, _ in _properties(schema) if f"`{_doc_key(schema, key)}`" not in doc]
    assert [n for n in SCHEMAS if f"`{n if '.' in n else 'birlg.' + n}`" not in doc] == []
    assert missing == []


def _doc_key(schema: dict, key: str) -> str:
    """`a.b` as the doc writes it: `a[].b` when a is an array of objects."""
    head, _, rest = key.partition(".")
    prop = schema["properties"][head]
    return f"{head}[].{rest}" if rest and prop.get("type") == "array" else key


def test_the_python_snippets_of_the_format_doc_run(runs, capsys):
    code = "\n".join(re.findall(r"```python\n(.*?)```", DOC.read_text(), re.S))
    exec(code.replace("outputs/.../graph.mcap", str(runs["default"] / "graph.mcap")), {})
    out = capsys.readouterr().out
    assert "run {'config_digest." in out and "'config_digest.graph'" in out \
        and "content {'sha256'" in out
    assert "0 0 " in out and " sampled\n" in out


def test_mcapinfo_reads_a_pipe(runs):
    """`mcapinfo /dev/stdin` and `<(...)`: a stream that cannot seek (the reader reads the
    summary at the end first) is read whole, and reported as the file is."""
    import subprocess
    import sys

    path = runs["default"] / "scene.mcap"
    done = subprocess.run([sys.executable, "-m", "pipeline.tools.mcapinfo", "--check",
                           "/dev/stdin"], input=path.read_bytes(), cwd=ROOT,
                          capture_output=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert b"check: all 2 messages match their schemas" in done.stdout


def test_mcapinfo_on_a_named_pipe_of_a_cut_file_ends_in_one_line(runs, tmp_path):
    """A named pipe whose writer sent a truncated file and left: the error line, not a second
    open of the pipe (to see whether the file was cut short), which would wait for ever."""
    import os
    import subprocess
    import sys

    fifo = tmp_path / "scene.mcap"
    os.mkfifo(fifo)
    proc = subprocess.Popen([sys.executable, "-m", "pipeline.tools.mcapinfo", str(fifo)],
                            cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    data = (runs["default"] / "scene.mcap").read_bytes()
    # opened without blocking (ENXIO until the reader opens it): a command that died before
    # opening the pipe fails the test rather than leaving it waiting for ever
    deadline = time.monotonic() + 120
    while True:
        try:
            fd = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)
            break
        except OSError as e:
            assert e.errno == errno.ENXIO and proc.poll() is None \
                and time.monotonic() < deadline, (e, proc.poll())
            time.sleep(0.01)
    os.set_blocking(fd, True)
    with open(fd, "wb") as writer:
        writer.write(data[:len(data) // 2])
    err = proc.communicate(timeout=60)[1].decode()
    assert proc.returncode == 2 and "cannot be read as MCAP" in err and err.count("\n") == 1
