"""Artefact MCAP files: round trip, determinism, atomic writes and clear read errors."""

import errno
import hashlib
import json
import os

import numpy as np
import pytest
from mcap.reader import make_reader

from pipeline.artefacts.schemas import SCHEMAS
from pipeline.artefacts.store import (
    LOG_TIME_NS,
    SCHEMA_PREFIX,
    ArtefactError,
    ArtefactWriter,
    content_digest,
    read_artefact,
    to_jsonable,
    write_artefact,
    write_json_atomic,
)
from pipeline.errors import PipelineError

CONFIG = "seed: 3\nscene:\n  size: [4, 5]\n"
META = {"seed": "3", "git": "abc123", "numpy": np.__version__}
SCENE_SCHEMA = {"type": "object", "title": "birlg.Scene", "properties": {"size": {"type": "array"}}}


def _records():
    return [
        ("/scene", "Scene", {"size": (4, 5), "grid": np.float32([[0, 1, 2], [3, 4, 5]])}, 0),
        ("/demos", "Demo", {"states": np.array([1, 2, 3]), "reward": np.float64(0.5)}, 2),
        ("/demos", "Demo", {"states": [np.int64(7)], "reward": 1.25}, 1),
        ("/params", "Params", {"lr": 0.1, "nested": {"w": np.ones(2), "ok": np.bool_(True)}}, 0),
    ]


def _write(path, records=None):
    return write_artefact(path, records or _records(), config_yaml=CONFIG, metadata=META)


def _assert_one_line_error(excinfo, path):
    msg = str(excinfo.value)
    assert str(path) in msg and "\n" not in msg, msg
    assert isinstance(excinfo.value, PipelineError)


def test_round_trip(tmp_path):
    path = _write(tmp_path / "scene.mcap")
    art = read_artefact(path, required_topics=["/scene", "/demos"])
    assert art.path == path and art.config_yaml == CONFIG and art.metadata == META
    assert art.one("/scene") == {"size": [4, 5], "grid": [[0.0, 1.0, 2.0], [3.0, 4.0, 5.0]]}
    # returned in log_time order, not write order
    assert art.all("/demos") == [{"states": [7], "reward": 1.25},
                                 {"states": [1, 2, 3], "reward": 0.5}]
    assert art.one("/params") == {"lr": 0.1, "nested": {"w": [1.0, 1.0], "ok": True}}
    with pytest.raises(ArtefactError, match="2 messages on topic '/demos'"):
        art.one("/demos")
    with pytest.raises(ArtefactError, match="has no topic '/nope'"):
        art.all("/nope")


def test_file_layout_with_plain_mcap_reader(tmp_path):
    path = tmp_path / "a.mcap"
    with ArtefactWriter(path, config_yaml=CONFIG, metadata=META) as w:
        w.add("/scene", "Scene", {"size": [1, 2]}, 0, schema=SCENE_SCHEMA)
        w.add("/demos", "Demo", {"b": 1, "a": 2}, 5)
        w.add("/graph/best_paths", "BestPaths", {"iteration": 0}, 0)  # a registered type
        w.add("/foxglove/x", "foxglove.SceneUpdate", {"entities": []}, 0)  # another tool's
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        schemas = {s.name: s for s in summary.schemas.values()}
        assert set(schemas) == {f"{SCHEMA_PREFIX}Scene", f"{SCHEMA_PREFIX}Demo",
                                "birlg.BestPaths", "foxglove.SceneUpdate"}
        assert all(s.encoding == "jsonschema" for s in schemas.values())
        assert json.loads(schemas["birlg.Scene"].data) == SCENE_SCHEMA
        assert json.loads(schemas["birlg.Demo"].data) == {
            "type": "object", "title": "birlg.Demo", "properties": {"a": {}, "b": {}},
            "required": ["a", "b"]}
        # no schema given: the registered one (pipeline.artefacts.schemas) is stored
        assert json.loads(schemas["birlg.BestPaths"].data) == SCHEMAS["BestPaths"]
        assert json.loads(schemas["foxglove.SceneUpdate"].data) == SCHEMAS["foxglove.SceneUpdate"]
        assert {c.message_encoding for c in summary.channels.values()} == {"json"}
        assert summary.chunk_indexes and {c.compression for c in summary.chunk_indexes} == {"zstd"}
        msgs = [(c.topic, m.log_time, m.publish_time, m.data)
                for _, c, m in reader.iter_messages(log_time_order=False)]  # in write order
        # canonical JSON; log_time = index × 1 s (Foxglove shows index 5 at 5 s); publish = log
        assert msgs[1] == ("/demos", 5 * LOG_TIME_NS, 5 * LOG_TIME_NS, b'{"a":2,"b":1}')
        (att,) = list(reader.iter_attachments())
        assert (att.name, att.media_type, att.data, att.create_time, att.log_time) == (
            "config.yaml", "application/yaml", CONFIG.encode(), 0, 0)
        run, content = list(reader.iter_metadata())
        assert run.name == "run" and run.metadata == META
        # The content digest covers topic, log_time and data of every message, in order.
        expected = hashlib.sha256(b"".join(b"%s\0%d\0%s\0" % (t.encode(), lt, d)
                                           for t, lt, _, d in msgs)).hexdigest()
        assert content.name == "content" and content.metadata == {"sha256": expected}
        assert content_digest(path) == expected == read_artefact(path).digest


def test_same_inputs_give_identical_bytes(tmp_path):
    a, b = _write(tmp_path / "a.mcap"), _write(tmp_path / "b.mcap")

    def payloads(p):
        with open(p, "rb") as f:
            return [m.data for _, _, m in make_reader(f).iter_messages(log_time_order=False)]

    assert payloads(a) == payloads(b)
    # Whole files are identical too: the writer embeds no wall-clock time or path, and
    # metadata is written with sorted keys so dict insertion order does not matter.
    assert a.read_bytes() == b.read_bytes()
    c = write_artefact(tmp_path / "c.mcap", _records(), config_yaml=CONFIG,
                       metadata=dict(reversed(list(META.items()))))
    assert c.read_bytes() == a.read_bytes()


@pytest.mark.parametrize("lazy", [False, True])
@pytest.mark.parametrize("fraction", [0.0, 0.002, 0.1, 0.5, 0.9, 0.99, "len-1", "len-8"])
def test_truncated_file_is_an_error(tmp_path, fraction, lazy):
    path = _write(tmp_path / "scene.mcap")
    data = path.read_bytes()
    cut = {"len-1": len(data) - 1, "len-8": len(data) - 8}.get(fraction)
    cut = int(len(data) * fraction) if cut is None else cut
    path.write_bytes(data[:cut])
    with pytest.raises(ArtefactError, match="truncated or corrupt") as excinfo:
        read_artefact(path, lazy=lazy)
    _assert_one_line_error(excinfo, path)


@pytest.mark.parametrize("lazy", [False, True])
def test_every_truncation_offset_is_detected(tmp_path, lazy):
    path = _write(tmp_path / "scene.mcap")
    data = path.read_bytes()
    for cut in range(len(data)):
        path.write_bytes(data[:cut])
        with pytest.raises(ArtefactError, match="truncated or corrupt"):
            read_artefact(path, lazy=lazy)


@pytest.mark.parametrize("lazy", [False, True])
def test_flipped_byte_or_trailing_garbage_is_an_error(tmp_path, lazy):
    path = _write(tmp_path / "scene.mcap")
    data = path.read_bytes()
    for bad in (data + b"junk", data[:40] + bytes([data[40] ^ 0xFF]) + data[41:],
                data[:-60] + bytes([data[-60] ^ 0xFF]) + data[-59:]):
        path.write_bytes(bad)
        with pytest.raises(ArtefactError, match="truncated or corrupt") as excinfo:
            read_artefact(path, lazy=lazy)
        _assert_one_line_error(excinfo, path)


def test_lazy_read_checks_the_whole_file_and_parses_a_topic_when_looked_up(tmp_path):
    path = _write(tmp_path / "scene.mcap")
    data = path.read_bytes()
    # a flipped byte inside the compressed chunk: caught by the data-section CRC at once,
    # although no topic is looked up
    chunk = data.index(b"(\xb5/\xfd")  # zstd frame magic
    path.write_bytes(data[:chunk + 20] + bytes([data[chunk + 20] ^ 0xFF]) + data[chunk + 21:])
    with pytest.raises(ArtefactError, match="truncated or corrupt"):
        read_artefact(path, lazy=True)
    path.write_bytes(data)
    lazy, eager = read_artefact(path, lazy=True), read_artefact(path)
    assert sorted(lazy.messages) == ["/demos", "/params", "/scene"] and "/demos" in lazy.messages
    assert lazy.messages == eager.messages and lazy.all("/demos") == eager.all("/demos")
    assert "/other" not in lazy.messages and lazy.messages.get("/other") is None


@pytest.mark.parametrize("content", [b'{"scene": 1}', b"hello world\n" * 10, b"\x89MC-not-mcap"])
def test_non_mcap_file(tmp_path, content):
    path = tmp_path / "scene.mcap"
    path.write_bytes(content)
    with pytest.raises(ArtefactError, match="is not an MCAP file") as excinfo:
        read_artefact(path)
    _assert_one_line_error(excinfo, path)


def test_missing_file(tmp_path):
    path = tmp_path / "scene.mcap"
    with pytest.raises(ArtefactError) as excinfo:
        read_artefact(path, producer_stage="scene")
    assert str(excinfo.value) == (
        f"artefact {path} not found (run the 'scene' stage first or pass from_run=...)")
    with pytest.raises(ArtefactError, match="not found$"):
        read_artefact(path)


def test_required_topic_absent(tmp_path):
    path = _write(tmp_path / "demos.mcap")
    with pytest.raises(ArtefactError) as excinfo:
        read_artefact(path, required_topics=["/scene", "/missing"])
    assert str(excinfo.value) == f"artefact {path} has no topic '/missing'"


def test_invalid_json_message(tmp_path):
    path = tmp_path / "x.mcap"
    # Write an otherwise valid MCAP whose message is not JSON, bypassing ArtefactWriter.
    from mcap.writer import Writer
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("birlg.X", "jsonschema", b"{}")
        cid = w.register_channel("/x", "json", sid)
        w.add_message(cid, log_time=0, data=b"{not json", publish_time=0)
        w.finish()
    with pytest.raises(ArtefactError, match="topic '/x' that is not valid JSON") as excinfo:
        read_artefact(path)
    _assert_one_line_error(excinfo, path)
    lazy = read_artefact(path, lazy=True)  # parsed on lookup: the error comes then
    assert "/x" in lazy.messages
    with pytest.raises(ArtefactError, match="topic '/x' that is not valid JSON") as excinfo:
        lazy.all("/x")
    _assert_one_line_error(excinfo, path)


@pytest.mark.parametrize("bad", [float("nan"), np.inf, np.array([1.0, np.nan])])
def test_nan_payload_names_topic_and_leaves_no_file(tmp_path, bad):
    path = tmp_path / "scene.mcap"
    with pytest.raises(ArtefactError, match="topic '/posterior'.*NaN or infinity"):
        write_artefact(path, [("/ok", "Ok", {"a": 1}, 0), ("/posterior", "Post", {"x": bad}, 1)],
                       config_yaml=CONFIG, metadata=META)
    assert list(tmp_path.iterdir()) == []


def test_exception_in_block_keeps_earlier_artefact(tmp_path):
    path = _write(tmp_path / "scene.mcap")
    before = path.read_bytes()
    with pytest.raises(RuntimeError, match="boom"):
        with ArtefactWriter(path, config_yaml="other", metadata={}) as w:
            w.add("/scene", "Scene", {"size": [9]}, 0)
            raise RuntimeError("boom")
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.mcap"]
    assert read_artefact(path).config_yaml == CONFIG


def test_writer_rejects_misuse(tmp_path):
    with pytest.raises(ValueError, match="already has type 'A'"):
        with ArtefactWriter(tmp_path / "a.mcap", config_yaml="", metadata={}) as w:
            w.add("/t", "A", {}, 0)
            w.add("/t", "B", {}, 1)
    for bad_time in (-1, 1.5, True, 2**64 // LOG_TIME_NS + 1):
        with pytest.raises(ValueError, match="non-negative int"):
            with ArtefactWriter(tmp_path / "a.mcap", config_yaml="", metadata={}) as w:
                w.add("/t", "A", {}, bad_time)
    assert list(tmp_path.iterdir()) == []
    # an empty artefact (no messages) is still valid
    art = read_artefact(write_artefact(tmp_path / "e.mcap", [], config_yaml="", metadata={}))
    assert (art.messages, art.config_yaml, art.metadata) == ({}, "", {})


def test_to_jsonable():
    out = to_jsonable({"a": (np.int32(1), np.float32(0.5)), "b": np.array([[True, False]]),
                       "c": [np.str_("s"), None]})
    assert out == {"a": [1, 0.5], "b": [[True, False]], "c": ["s", None]}
    assert type(out["a"][0]) is int and type(out["a"][1]) is float


def test_two_writers_of_one_file_do_not_share_a_temporary_file(tmp_path):
    # Two runs writing the same artefact name at once: each writes its own temporary file,
    # and the file that lands is one complete artefact (the last rename wins).
    path = tmp_path / "scene.mcap"
    first = ArtefactWriter(path, config_yaml="first", metadata={})
    second = ArtefactWriter(path, config_yaml="second", metadata={})
    with first as a, second as b:
        a.add("/scene", "Scene", {"size": [1]}, 0)
        b.add("/scene", "Scene", {"size": [2]}, 0)
        assert a.tmp_path != b.tmp_path and a.tmp_path.exists() and b.tmp_path.exists()
    assert read_artefact(path).config_yaml in ("first", "second")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.mcap"]


def _disk_full(*_args):
    raise OSError(errno.ENOSPC, "No space left on device")


def test_disk_full_is_one_line_and_leaves_the_old_file_and_no_temp_file(tmp_path, monkeypatch):
    path = _write(tmp_path / "a.mcap")
    before = path.read_bytes()
    monkeypatch.setattr(os, "fsync", _disk_full)  # the OS reports ENOSPC when flushing
    with pytest.raises(ArtefactError) as err:
        _write(path)
    assert str(err.value) == f"cannot write artefact {path}: the disk is full"
    with pytest.raises(OSError):
        write_json_atomic(tmp_path / "metrics.json", {"a": 1})
    monkeypatch.undo()
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.mcap"]


def test_an_atomic_write_onto_a_directory_names_the_target_and_leaves_no_temp(tmp_path):
    """The error named the temp file, which no longer existed when it was read."""
    from pipeline.artefacts.store import write_text_atomic

    (tmp_path / "summary.csv").mkdir()
    with pytest.raises(IsADirectoryError) as err:
        write_text_atomic(tmp_path / "summary.csv", "a,b\n")
    assert err.value.filename == str(tmp_path / "summary.csv")
    assert [p.name for p in tmp_path.iterdir()] == ["summary.csv"]
