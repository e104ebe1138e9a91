"""Stage artefacts: one MCAP file of JSON messages (JSON-schema typed) per pipeline stage.

Writes are atomic (temp file + os.replace) and deterministic (log_time is supplied by the
caller, JSON is canonical), so the same inputs give the same bytes. Each message type gets its
JSON Schema from pipeline.artefacts.schemas. The caller's log_time is an index (iteration,
start, ...); the file stores index × LOG_TIME_NS, i.e. one index step is one second on the
timeline of MCAP tools such as Foxglove. Reads validate the whole
file (magic, every CRC, footer) before returning anything, so a truncated or corrupt artefact
raises ArtefactError instead of silently yielding fewer messages.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
import uuid
import zlib
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import IO, Callable, Iterable, Iterator, Mapping

import numpy as np
from mcap.exceptions import EndOfFile
from mcap.reader import make_reader
from mcap.records import (
    Attachment,
    Channel,
    Chunk,
    Footer,
    McapRecord,
    Message,
    MessageIndex,
    Metadata,
    Schema,
)
from mcap.stream_reader import StreamReader, breakup_chunk
from mcap.writer import MCAP0_MAGIC, CompressionType, Writer

from pipeline.artefacts.schemas import SCHEMAS
from pipeline.errors import PipelineError, file_kind, os_error_reason

SCHEMA_PREFIX = "birlg."
LOG_TIME_NS = 1_000_000_000  # stored log_time = caller's index × this: index k at k seconds
_MAX_INDEX = (2**64 - 1) // LOG_TIME_NS  # MCAP times are uint64 nanoseconds
CONTENT_METADATA = "content"  # MCAP metadata record holding the content digest
_FOOTER_PREFIX_LEN = 1 + 8 + 8 + 8  # opcode, length, summary_start, summary_offset_start



def unique_tmp(path: Path) -> Path:
    """A temporary name beside `path` that no other writer uses (process id and a random
    part), so two runs writing into one dir never write into each other's file."""
    return path.with_name(f"{path.name}.{os.getpid()}-{uuid.uuid4().hex[:8]}.tmp")


def write_json_atomic(path: Path, obj: object) -> None:
    """`write_text_atomic` of `obj` as JSON."""
    write_text_atomic(path, json.dumps(to_jsonable(obj), indent=1, sort_keys=True))


def write_text_atomic(path: Path, text: str) -> None:
    """Write text to a unique temp file, fsync, rename: readers see the old or the new file,
    never a partial one (also when the disk fills up: the temp file is removed)."""
    tmp = unique_tmp(Path(path))
    try:
        with open(tmp, "w", newline="") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        try:
            os.replace(tmp, path)
        except OSError as e:  # else the error names the temp file, gone by then
            raise type(e)(e.errno, e.strerror, str(path)) from None
    finally:
        tmp.unlink(missing_ok=True)


def content_digest(path: Path) -> str | None:
    """The sha256 of an artefact's messages (topic, log_time, data), recorded by the writer.

    It identifies what an artefact says, not the file: the resolved config attached to every
    artefact changes with any key, the content only with what the stage made. Read from the
    summary section without reading the messages; None for a missing or unreadable file.
    """
    try:
        if not Path(path).is_file():  # a named pipe would wait for a writer
            return None
        with open(path, "rb") as f:
            for record in make_reader(f).iter_metadata():
                if record.name == CONTENT_METADATA:
                    return record.metadata.get("sha256")
    except Exception:  # noqa: BLE001 - missing, truncated, foreign: no digest to compare
        return None
    return None


def link_or_copy(source: Path, target: Path) -> None:
    """Put `source` at `target` as a hard link (artefacts are replaced, never modified, so
    sharing the inode is safe), or as a copy across filesystems; atomically either way."""
    if target.exists() and os.path.samefile(source, target):
        return
    tmp = unique_tmp(target)
    try:
        try:
            os.link(source, tmp)
        except OSError:
            shutil.copyfile(source, tmp)
        os.replace(tmp, target)
    except OSError as e:
        raise ArtefactError(f"cannot put {source} into {target.parent}: "
                            f"{os_error_reason(e)}") from None
    finally:
        tmp.unlink(missing_ok=True)


class ArtefactError(PipelineError):
    """A missing, corrupt or incomplete artefact file (message is one line naming the file)."""


def to_jsonable(obj: object) -> object:
    """Recursively turn numpy arrays/scalars and tuples into plain JSON-able Python values."""
    if isinstance(obj, np.ndarray):
        return obj.tolist() if obj.dtype != object else to_jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, dict):
        return {to_jsonable(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    return obj


def _numpy_default(obj: object) -> object:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    raise TypeError(f"Object of type {type(obj).__name__} is not JSON serializable")


# Canonical JSON: sorted keys, no spaces, no NaN. numpy values are converted as the C
# encoder meets them (no recursive copy of every payload first: graph.mcap has 10^5 messages).
_ENCODER = json.JSONEncoder(sort_keys=True, separators=(",", ":"), allow_nan=False,
                            default=_numpy_default)


def _canonical(obj: object) -> bytes:
    try:
        return _ENCODER.encode(obj).encode()
    except TypeError:  # e.g. numpy integer dict keys: convert the whole payload first
        return _ENCODER.encode(to_jsonable(obj)).encode()


@dataclass(frozen=True)
class Artefact:
    path: Path
    messages: Mapping[str, list[dict]]  # topic -> payloads in log_time order
    config_yaml: str
    metadata: dict[str, str]
    digest: str = ""  # content digest (see content_digest): what later artefacts record

    def require(self, topics: Iterable[str]) -> Artefact:
        """This artefact, if it has every topic in `topics`; else one line naming them."""
        missing = [t for t in topics if t not in self.messages]
        if missing:
            raise ArtefactError(f"artefact {self.path} has no topic "
                                + ", ".join(f"'{t}'" for t in missing))
        return self

    def all(self, topic: str) -> list[dict]:
        if topic not in self.messages:
            raise ArtefactError(f"artefact {self.path} has no topic '{topic}'")
        return self.messages[topic]

    def one(self, topic: str) -> dict:
        msgs = self.all(topic)
        if len(msgs) != 1:
            raise ArtefactError(f"artefact {self.path} has {len(msgs)} messages on topic "
                                f"'{topic}', expected exactly 1")
        return msgs[0]


class ArtefactWriter:
    """Context manager: with ArtefactWriter(path, config_yaml=..., metadata=...) as w: w.add(...)"""

    def __init__(self, path: str | os.PathLike[str], *, config_yaml: str,
                 metadata: dict[str, str], before_replace: Callable[[str], None] | None = None):
        self.path = Path(path)
        # Called with the content digest just before the new file replaces the old one.
        self._before_replace = before_replace
        self.tmp_path = unique_tmp(self.path)
        if not all(isinstance(k, str) and isinstance(v, str) for k, v in metadata.items()):
            raise ValueError("artefact metadata must be a str -> str dict")
        self._config_yaml, self._metadata = config_yaml, dict(sorted(metadata.items()))
        self._schemas: dict[str, int] = {}  # type_name -> schema id
        self._channels: dict[str, tuple[int, str]] = {}  # topic -> (channel id, type_name)
        self._file: IO[bytes] | None = None
        self._writer: Writer | None = None
        self._content = hashlib.sha256()  # of the messages only: see content_digest()

    def __enter__(self) -> ArtefactWriter:
        try:
            self._file = file = open(self.tmp_path, "wb")
        except OSError as e:
            raise self._os_error(e) from None
        try:
            # Data CRCs on too, so readers can check the whole data section, not only chunks.
            self._writer = writer = Writer(file, compression=CompressionType.ZSTD,
                                           enable_crcs=True, enable_data_crcs=True)
            writer.start()
            # Times fixed at 0: wall-clock would make files differ between identical runs.
            writer.add_attachment(0, 0, "config.yaml", "application/yaml",
                                  self._config_yaml.encode())
            writer.add_metadata("run", self._metadata)
        except BaseException:
            self.__exit__(*sys.exc_info())
            raise
        return self

    def add(self, topic: str, type_name: str, payload: dict, log_time: int,
            schema: dict | None = None) -> None:
        if self._writer is None:
            raise RuntimeError("ArtefactWriter.add() called outside its 'with' block")
        if isinstance(log_time, bool) or not isinstance(log_time, (int, np.integer)) \
                or not 0 <= log_time <= _MAX_INDEX:
            raise ValueError(f"log_time for topic '{topic}' must be a non-negative int "
                             f"(an index up to {_MAX_INDEX}), got {log_time!r}")
        topic_type = self._channels.get(topic, (0, type_name))[1]
        if topic_type != type_name:
            raise ValueError(f"topic '{topic}' already has type '{topic_type}', "
                             f"cannot add '{type_name}'")
        if not isinstance(payload, dict):
            raise TypeError(f"payload for topic '{topic}' must be a dict, "
                            f"got {type(payload).__name__}")
        try:
            data = _canonical(payload)
        except ValueError as e:  # allow_nan=False: NaN/inf would be invalid JSON
            raise ArtefactError(f"cannot write artefact {self.path}: payload on topic '{topic}' "
                                f"contains NaN or infinity ({e})") from None
        except TypeError as e:
            raise TypeError(f"payload for topic '{topic}' is not JSON-serialisable: {e}") from None
        # "Scene" -> birlg.Scene; a dotted name is another tool's type (foxglove.SceneUpdate).
        name = type_name if "." in type_name else SCHEMA_PREFIX + type_name
        if type_name not in self._schemas:
            schema = schema or SCHEMAS.get(type_name)
            if schema is None:  # an unregistered type: only pins the set of top-level keys
                schema = {"type": "object", "title": name, "properties": {k: {} for k in payload},
                          "required": sorted(payload)}
            self._schemas[type_name] = self._writer.register_schema(
                name, "jsonschema", _canonical(schema))
        if topic not in self._channels:
            self._channels[topic] = (
                self._writer.register_channel(topic, "json", self._schemas[type_name]), type_name)
        stamp = int(log_time) * LOG_TIME_NS
        self._content.update(b"%s\0%d\0%s\0" % (topic.encode(), stamp, data))
        try:
            self._writer.add_message(self._channels[topic][0], log_time=stamp, data=data,
                                     publish_time=stamp)
        except OSError as e:
            raise self._os_error(e) from None

    def _os_error(self, e: OSError) -> ArtefactError:
        e.filename = None  # the temp file's name would only confuse
        return ArtefactError(f"cannot write artefact {self.path}: {os_error_reason(e)}")

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        # Called after __enter__ opened the file (by `with`, or by __enter__ itself on a
        # failure after open); the writer exists too unless __enter__ failed (exc_type set).
        writer, file = self._writer, self._file
        assert file is not None
        done = False
        try:
            if exc_type is None:
                assert writer is not None
                try:
                    writer.add_metadata(CONTENT_METADATA, {"sha256": self._content.hexdigest()})
                    writer.finish()
                    file.flush()
                    os.fsync(file.fileno())  # durable before it gets the final name
                    file.close()
                    if self._before_replace is not None:
                        self._before_replace(self._content.hexdigest())
                    os.replace(self.tmp_path, self.path)
                except OSError as e:
                    raise self._os_error(e) from None
                done = True
        finally:  # on any failure (in the block or while finishing) drop the partial temp file
            self._writer = None
            try:
                file.close()  # flushes what is buffered: on a full disk it fails again
            except OSError as e:
                if done:
                    raise self._os_error(e) from None
            finally:
                if not done:
                    self.tmp_path.unlink(missing_ok=True)


def write_artefact(path: str | os.PathLike[str], records: Iterable[tuple[str, str, dict, int]],
                   *, config_yaml: str, metadata: dict[str, str]) -> Path:
    with ArtefactWriter(path, config_yaml=config_yaml, metadata=metadata) as w:
        for topic, type_name, payload, log_time in records:
            w.add(topic, type_name, payload, log_time)
    return w.path


def read_records(f: IO[bytes]) -> list[McapRecord]:
    """The top-level records of a complete MCAP, chunks still compressed; raises on
    truncation, a bad data-section or summary CRC, or trailing bytes. The data-section CRC
    covers every byte of every chunk, so a chunk that is never decompressed is checked too."""
    records = list(StreamReader(f, validate_crcs=True, emit_chunks=True).records)
    footer, end = records[-1], f.tell()
    assert isinstance(footer, Footer)  # the stream reader stops only after the footer
    if end != f.seek(0, os.SEEK_END):  # the file's size (a file in memory has no fstat)
        raise ValueError("trailing bytes after the MCAP end magic")
    if footer.summary_crc:  # the stream reader does not check the summary/footer CRC
        footer_start = end - len(MCAP0_MAGIC) - _FOOTER_PREFIX_LEN - 4
        f.seek(footer.summary_start or footer_start)
        if zlib.crc32(f.read(footer_start + _FOOTER_PREFIX_LEN - f.tell())) != footer.summary_crc:
            raise ValueError("summary CRC mismatch")
    return records


def _corrupt(path: Path, e: Exception) -> ArtefactError:
    detail = "unexpected end of file" if isinstance(e, EndOfFile) else str(e)
    detail = " ".join((detail or type(e).__name__).split())  # keep it on one line
    return ArtefactError(f"artefact {path} is truncated or corrupt (cannot read MCAP: {detail})")


class _Messages(Mapping[str, list[dict]]):
    """topic -> payloads in log_time order, of one artefact. A topic's chunks are
    decompressed (their CRCs checked) and its JSON parsed when it is first looked up, so a
    reader pays only for the topics it uses (graph.mcap's Foxglove view and best paths are
    most of the file); `load_all` does every topic at once."""

    def __init__(self, path: Path, channels: dict[int, Channel], schemas: dict[int, Schema],
                 chunks: list[tuple[Chunk, set[int] | None]],
                 loose: list[Message]) -> None:
        self._path, self._channels, self._schemas = path, channels, schemas
        # Chunks not yet broken up, with the channel ids of their messages (None: unknown).
        self._chunks = chunks
        self._raw: dict[int, list[Message]] = {}  # channel id -> messages of broken-up chunks
        self._topics: dict[str, list[int]] = {}  # topic -> its channel ids
        self._decoded: dict[str, list[dict]] = {}
        for m in loose:
            self._raw.setdefault(m.channel_id, []).append(m)
        for c in channels.values():
            self._topics.setdefault(c.topic, []).append(c.id)
        # Chunks that may hold channels the summary did not list: broken up now, so that
        # the set of topics is complete.
        self._break_up([i for i, (_, ids) in enumerate(chunks)
                        if ids is None or not ids <= channels.keys()])

    def _break_up(self, which: list[int]) -> None:
        for i in which:
            chunk, _ = self._chunks[i]
            self._chunks[i] = (chunk, set())  # nothing left in it
            try:
                records = breakup_chunk(chunk, validate_crc=True)
            except Exception as e:  # noqa: BLE001 - zstd, CRC, struct: one line
                raise _corrupt(self._path, e) from e
            for r in records:
                if isinstance(r, Channel) and r.id not in self._channels:
                    self._channels[r.id] = r
                    self._topics.setdefault(r.topic, []).append(r.id)
                elif isinstance(r, Schema):
                    self._schemas.setdefault(r.id, r)
                elif isinstance(r, Message):
                    self._raw.setdefault(r.channel_id, []).append(r)

    def _check_channels(self) -> None:
        for channel_id in self._raw:
            ch = self._channels.get(channel_id)
            if ch is None or ch.message_encoding != "json" or ch.schema_id not in self._schemas:
                raise ArtefactError(f"artefact {self._path} has a message on channel "
                                    f"{channel_id} with no JSON channel/schema")

    def _decode(self, topic: str) -> list[dict]:
        ids = set(self._topics[topic])
        self._break_up([i for i, (_, in_chunk) in enumerate(self._chunks)
                        if in_chunk is None or in_chunk & ids])
        self._check_channels()
        timed = []
        for channel_id in self._topics[topic]:
            for m in self._raw.pop(channel_id, []):
                try:
                    payload = json.loads(m.data)
                except ValueError as e:
                    raise ArtefactError(f"artefact {self._path} has a message on topic "
                                        f"'{topic}' that is not valid JSON ({e})") from None
                if not isinstance(payload, dict):
                    raise ArtefactError(f"artefact {self._path} has a message on topic "
                                        f"'{topic}' that is not a JSON object")
                # Only the order of log_time matters here (index × LOG_TIME_NS; in artefacts
                # written before that scale, the index itself), so no unscaling is needed.
                timed.append((m.log_time, payload))
        # sorted() is stable, so messages with equal log_time keep their file order.
        return [p for _, p in sorted(timed, key=lambda x: x[0])]

    def load_all(self) -> None:
        """Decompress and parse everything now (errors are raised here, not on lookup)."""
        self._break_up(list(range(len(self._chunks))))
        self._check_channels()
        for topic in self._topics:
            self[topic]

    def __getitem__(self, topic: str) -> list[dict]:
        if topic not in self._decoded:
            if topic not in self._topics:
                raise KeyError(topic)
            self._decoded[topic] = self._decode(topic)
        return self._decoded[topic]

    def __contains__(self, topic: object) -> bool:
        return topic in self._topics

    def __iter__(self) -> Iterator[str]:
        return iter(self._topics)

    def __len__(self) -> int:
        return len(self._topics)

    def __repr__(self) -> str:
        return f"<messages of {self._path}: {sorted(self._topics)}>"


def read_artefact(path: str | os.PathLike[str], *, required_topics: Iterable[str] = (),
                  producer_stage: str | None = None, lazy: bool = False) -> Artefact:
    """The artefact at `path`, after checking the whole file (magic, the data-section and
    summary CRCs, the footer). Every message is decompressed (chunk CRCs checked) and
    parsed now; with `lazy`, a topic's messages when it is first looked up (errors then)."""
    path = Path(path)

    def fail(what: str) -> ArtefactError:
        return ArtefactError(f"artefact {path} {what}")

    try:
        kind = file_kind(path)  # before open: opening a named pipe waits for a writer
        if kind is not None:
            raise fail(f"is {kind}, not an MCAP file")
        f = open(path, "rb")
    except FileNotFoundError:
        hint = f" (run the '{producer_stage}' stage first or pass from_run=...)"
        raise fail("not found" + (hint if producer_stage else "")) from None
    except OSError as e:
        raise fail(f"cannot be opened ({e.strerror or e})") from None
    with f:
        head = f.read(len(MCAP0_MAGIC))
        if head != MCAP0_MAGIC:
            raise fail("is truncated or corrupt (shorter than the MCAP magic)"
                       if MCAP0_MAGIC.startswith(head) else "is not an MCAP file")
        f.seek(0)
        try:
            records = read_records(f)
        except Exception as e:  # mcap raises many types here (struct.error, EndOfFile, CRC, zstd)
            raise _corrupt(path, e) from e
    schemas = {r.id: r for r in records if isinstance(r, Schema)}
    channels = {r.id: r for r in records if isinstance(r, Channel)}
    chunks: list[tuple[Chunk, set[int] | None]] = []
    for r in records:  # each chunk is followed by the message indexes of its channels
        if isinstance(r, Chunk):
            chunks.append((r, None))
        elif isinstance(r, MessageIndex) and chunks:
            chunks[-1] = (chunks[-1][0], (chunks[-1][1] or set()) | {r.channel_id})
    config = next((r.data for r in records
                   if isinstance(r, Attachment) and r.name == "config.yaml"), b"")
    meta = next((r.metadata for r in records
                 if isinstance(r, Metadata) and r.name == "run"), {})
    digest = next((r.metadata.get("sha256", "") for r in records
                   if isinstance(r, Metadata) and r.name == CONTENT_METADATA), "")
    messages = _Messages(path, channels, schemas, chunks,
                         [r for r in records if isinstance(r, Message)])
    if not lazy:
        messages.load_all()
    return Artefact(path, messages, config.decode("utf-8", errors="replace"), dict(meta),
                    digest).require(required_topics)
