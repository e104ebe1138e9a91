"""What a mutation audit of pipeline/artefacts/store.py found untested: the replace hook,
copies across filesystems, numpy keys and object arrays, the last valid log time, and the
one-line refusals of foreign MCAP files (an empty topic, a non-JSON channel, a message that
is no object, a directory, a short non-MCAP file)."""

import errno
import os
import struct

import numpy as np
import pytest
from mcap.writer import Writer

from pipeline.artefacts import store
from pipeline.artefacts.store import (
    _MAX_INDEX,
    LOG_TIME_NS,
    ArtefactError,
    ArtefactWriter,
    content_digest,
    link_or_copy,
    read_artefact,
    to_jsonable,
    write_artefact,
)


def _one_line(err, path) -> str:
    message = str(err.value)
    assert str(path) in message and "\n" not in message, message
    return message


def _foreign(path, encoding="json", data=b'{"a": 1}', messages=1):
    """An MCAP file written without ArtefactWriter: one channel '/x' of `encoding`."""
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("birlg.X", "jsonschema", b"{}")
        cid = w.register_channel("/x", encoding, sid)
        for k in range(messages):
            w.add_message(cid, log_time=k, data=data, publish_time=k)
        w.finish()
    return path


def test_the_replace_hook_gets_the_digest_before_the_new_file_lands(tmp_path):
    path = write_artefact(tmp_path / "a.mcap", [("/a", "A", {"v": 1}, 0)], config_yaml="",
                          metadata={})
    old = path.read_bytes()
    seen = []

    def before_replace(digest: str) -> None:
        seen.append((digest, path.read_bytes() == old))

    with ArtefactWriter(path, config_yaml="", metadata={}, before_replace=before_replace) as w:
        w.add("/a", "A", {"v": 2}, 0)
    assert seen == [(content_digest(path), True)]
    assert read_artefact(path).one("/a") == {"v": 2}


def test_an_artefact_is_copied_where_it_cannot_be_linked(tmp_path, monkeypatch):
    source = write_artefact(tmp_path / "a.mcap", [("/a", "A", {"v": 1}, 0)], config_yaml="",
                            metadata={})

    def cross_device(*_args):
        raise OSError(errno.EXDEV, "Invalid cross-device link")

    monkeypatch.setattr(os, "link", cross_device)
    (tmp_path / "run").mkdir()
    link_or_copy(source, tmp_path / "run" / "a.mcap")
    assert (tmp_path / "run" / "a.mcap").read_bytes() == source.read_bytes()
    assert not os.path.samefile(source, tmp_path / "run" / "a.mcap")
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == ["a.mcap"]


def test_an_artefact_put_into_a_missing_dir_is_one_line(tmp_path):
    source = write_artefact(tmp_path / "a.mcap", [], config_yaml="", metadata={})
    with pytest.raises(ArtefactError, match=r"^cannot put .*a\.mcap into .*nowhere: "):
        link_or_copy(source, tmp_path / "nowhere" / "a.mcap")


def test_numpy_keys_and_object_arrays_become_plain_values(tmp_path):
    out = to_jsonable({np.int64(3): np.array([np.float32(1.5), None], dtype=object)})
    assert out == {3: [1.5, None]}
    assert type(next(iter(out))) is int and type(out[3][0]) is float
    path = write_artefact(tmp_path / "a.mcap", [("/a", "A", {"m": {np.int64(3): 1}}, 0)],
                          config_yaml="", metadata={})
    assert read_artefact(path).one("/a") == {"m": {"3": 1}}  # JSON keys are strings


def test_every_missing_topic_is_named(tmp_path):
    art = read_artefact(write_artefact(tmp_path / "a.mcap", [("/a", "A", {"v": 1}, 0)],
                                       config_yaml="", metadata={}))
    with pytest.raises(ArtefactError, match=r"has no topic '/b', '/c'$"):
        art.require(["/a", "/b", "/c"])


def test_a_topic_without_messages_has_not_exactly_one(tmp_path):
    path = _foreign(tmp_path / "x.mcap", messages=0)
    art = read_artefact(path)
    assert art.all("/x") == []
    with pytest.raises(ArtefactError) as err:
        art.one("/x")
    assert _one_line(err, path).endswith("has 0 messages on topic '/x', expected exactly 1")


def test_metadata_values_must_be_strings(tmp_path):
    with pytest.raises(ValueError, match="str -> str"):
        ArtefactWriter(tmp_path / "a.mcap", config_yaml="", metadata={"seed": 3})


def test_an_artefact_in_a_missing_dir_cannot_be_written_in_one_line(tmp_path):
    path = tmp_path / "nowhere" / "a.mcap"
    with pytest.raises(ArtefactError) as err:
        with ArtefactWriter(path, config_yaml="", metadata={}):
            pass
    assert _one_line(err, path).startswith(f"cannot write artefact {path}: ")


def test_the_last_index_an_mcap_time_can_hold_is_a_valid_log_time(tmp_path):
    path = write_artefact(tmp_path / "a.mcap", [("/a", "A", {"k": "last"}, _MAX_INDEX),
                                                ("/a", "A", {"k": "first"}, 0)],
                          config_yaml="", metadata={})
    assert read_artefact(path).all("/a") == [{"k": "first"}, {"k": "last"}]
    assert _MAX_INDEX * LOG_TIME_NS <= 2**64 - 1 < (_MAX_INDEX + 1) * LOG_TIME_NS


def test_a_message_on_a_channel_that_is_not_json_is_refused(tmp_path):
    path = _foreign(tmp_path / "x.mcap", encoding="cdr")
    with pytest.raises(ArtefactError) as err:
        read_artefact(path)
    assert "has a message on channel 1 with no JSON channel/schema" in _one_line(err, path)


def test_a_message_that_is_no_json_object_is_refused(tmp_path):
    path = _foreign(tmp_path / "x.mcap", data=b"[1, 2]")
    with pytest.raises(ArtefactError) as err:
        read_artefact(path)
    assert _one_line(err, path).endswith("has a message on topic '/x' that is not a JSON object")


def test_a_directory_is_no_artefact(tmp_path):
    (tmp_path / "scene.mcap").mkdir()
    with pytest.raises(ArtefactError) as err:
        read_artefact(tmp_path / "scene.mcap")
    assert str(err.value) == f"artefact {tmp_path / 'scene.mcap'} is a directory, not an MCAP file"


@pytest.mark.parametrize("content, says", [
    (b"ab", "is not an MCAP file"), (b"", "is truncated or corrupt"),
    (store.MCAP0_MAGIC[:5], "is truncated or corrupt")])
def test_a_file_shorter_than_the_magic_is_cut_only_if_it_begins_as_mcap(tmp_path, content,
                                                                        says):
    path = tmp_path / "a.mcap"
    path.write_bytes(content)
    with pytest.raises(ArtefactError, match=says):
        read_artefact(path)


def test_a_file_cut_after_its_magic_says_the_file_ended(tmp_path):
    path = write_artefact(tmp_path / "a.mcap", [("/a", "A", {"v": 1}, 0)], config_yaml="",
                          metadata={})
    path.write_bytes(path.read_bytes()[:len(store.MCAP0_MAGIC)])  # no record after the magic
    with pytest.raises(ArtefactError) as err:
        read_artefact(path)
    assert _one_line(err, path).endswith("is truncated or corrupt (cannot read MCAP: "
                                         "unexpected end of file)")


def test_every_flipped_byte_of_the_summary_section_is_an_error(tmp_path):
    """The stream reader checks the data section's CRC, not the summary's (channels,
    schemas, statistics, metadata index): the footer's summary CRC is checked by hand."""
    path = write_artefact(tmp_path / "a.mcap", [("/a", "A", {"v": 1}, 0)], config_yaml="",
                          metadata={})
    data = path.read_bytes()
    footer = data[-len(store.MCAP0_MAGIC) - 29:-len(store.MCAP0_MAGIC)]  # opcode, length, 3 fields
    summary_start, summary_offset_start = struct.unpack("<QQ", footer[9:25])
    assert 0 < summary_start < summary_offset_start < len(data)
    for k in range(summary_start, summary_offset_start):
        path.write_bytes(data[:k] + bytes([data[k] ^ 0xFF]) + data[k + 1:])
        with pytest.raises(ArtefactError, match="truncated or corrupt"):
            read_artefact(path)
