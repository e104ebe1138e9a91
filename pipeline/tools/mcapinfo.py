"""What an MCAP file holds: topics, schemas, message counts, attachments and metadata.

    python -m pipeline.tools.mcapinfo RUN_DIR/graph.mcap [more files ...]
    python -m pipeline.tools.mcapinfo --check RUN_DIR/*.mcap   # also validate every message

A stand-in for the Go `mcap info` CLI (not installable with pip), built on the `mcap` Python
library only, so it reads any MCAP file, not only this pipeline's. With --check, every JSON
message is validated against the JSON Schema stored in the file (jsonschema); the exit
status is 1 when a message does not match, 2 when a file cannot be read.
"""

from __future__ import annotations

import argparse
import io
import json
import sys
from collections import Counter
from pathlib import Path

from jsonschema import Draft202012Validator
from jsonschema.exceptions import SchemaError, UnknownType
from mcap.reader import make_reader
from mcap.well_known import MessageEncoding, SchemaEncoding
from mcap.writer import MCAP0_MAGIC as MCAP_MAGIC

from pipeline.artefacts.store import read_records
from pipeline.errors import file_kind
from pipeline.tools import run_tool


def describe(path: Path, check: bool = False) -> tuple[list[str], int]:
    """The report lines for one file and the number of invalid messages (with check)."""
    with open(path, "rb") as raw:
        # a pipe (`<(...)`, /dev/stdin) cannot seek, and the reader reads the summary first
        f = raw if raw.seekable() else io.BytesIO(raw.read())
        reader = make_reader(f, validate_crcs=True)
        header, summary = reader.get_header(), reader.get_summary()
        counts: Counter[int] = Counter()
        times: list[int] = []
        validators: dict[int, Draft202012Validator] = {}
        bad: list[str] = []
        checked = 0  # messages with a JSON schema and JSON encoding: the others cannot be
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            counts[channel.id] += 1
            times.append(message.log_time)
            if not (check and schema is not None and schema.encoding == SchemaEncoding.JSONSchema
                    and channel.message_encoding == MessageEncoding.JSON):
                continue
            checked += 1
            at = f"  INVALID {channel.topic} at log_time {message.log_time}: "
            try:  # a schema or message that is no JSON, or a schema that loops, is invalid
                if schema.id not in validators:
                    validators[schema.id] = Draft202012Validator(json.loads(schema.data))
                errors = list(validators[schema.id].iter_errors(json.loads(message.data)))
            except (ValueError, RecursionError, LookupError, SchemaError, UnknownType) as e:
                bad.append(f"{at}(message): not checkable against schema {schema.name!r} "
                           f"({' '.join(str(e).split())[:160] or type(e).__name__})")
                continue
            for err in errors:
                where = "".join(f"[{p}]" if isinstance(p, int) else f".{p}"
                                for p in err.absolute_path)
                bad.append(f"{at}{where or '(message)'}: {err.message[:200]}")
        attachments = list(reader.iter_attachments())
        metadata = list(reader.iter_metadata())
        if check:  # every byte, as the pipeline reads it: the data-section and summary CRCs
            f.seek(0)
            try:
                read_records(f)
            except Exception as e:  # noqa: BLE001 - mcap raises many types (struct, CRC, EOF)
                why = " ".join(str(e).split())[:200] or type(e).__name__
                bad.insert(0, f"  INVALID file: {why}")
    schemas = summary.schemas if summary else {}
    span = f", log_time {min(times) / 1e9:g} .. {max(times) / 1e9:g} s" \
        if times else ""
    rows = [("topic", "schema", "encoding", "messages")]
    for channel in sorted(summary.channels.values() if summary else [], key=lambda c: c.topic):
        schema = schemas.get(channel.schema_id)
        rows.append((channel.topic, schema.name if schema else "(none)",
                     f"{schema.encoding if schema else '-'}/{channel.message_encoding}",
                     str(counts[channel.id])))
    widths = [max(len(r[i]) for r in rows) for i in range(3)]
    lines = [f"{path}  (profile '{header.profile}', library '{header.library}')",
             f"  messages  {sum(counts.values())}{span}"]
    lines += ["  " + "  ".join(c.ljust(w) for c, w in zip(r, widths + [0], strict=True)).rstrip()
              for r in rows]
    lines += [f"  attachment {a.name}  {a.media_type}  {len(a.data)} bytes" for a in attachments]
    for m in metadata:
        lines.append(f"  metadata '{m.name}'")
        lines += [f"    {k} = {v}" for k, v in sorted(m.metadata.items())]
    if check:
        unchecked = sum(counts.values()) - checked
        if bad or checked or not unchecked:
            lines += bad or [f"  check: all {checked} messages match their schemas"]
        if unchecked:  # it said "all N match" of messages it never checked
            lines.append(f"  check: {unchecked} messages have no JSON schema or are not JSON "
                         "encoded: not checked")
    return lines, len(bad)


def cut_short(path: Path) -> bool:
    """Does the file begin with the MCAP magic and not end with it (a copy or a write that
    stopped)? False for what cannot be read or sought (a pipe)."""
    try:
        if file_kind(path) is not None:  # opening a named pipe again would wait for a writer
            return False
        with open(path, "rb") as f:
            head = f.read(len(MCAP_MAGIC))
            f.seek(-len(MCAP_MAGIC), io.SEEK_END)
            return head == MCAP_MAGIC and f.read() != MCAP_MAGIC
    except OSError:
        return False


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m pipeline.tools.mcapinfo", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("files", type=Path, nargs="+", metavar="FILE")
    parser.add_argument("--check", action="store_true",
                        help="validate every JSON message against its stored JSON Schema")
    args = parser.parse_args(argv)
    status = 0
    for path in args.files:
        try:
            lines, invalid = describe(path, args.check)
        except Exception as e:  # noqa: BLE001 - missing, truncated, foreign: one line each
            detail = " ".join((str(e) or type(e).__name__).split())
            if cut_short(path):  # the reader's own words for it are a misread record
                detail = f"truncated: it begins as MCAP but does not end with its magic; {detail}"
            print(f"error: {path} cannot be read as MCAP ({detail})", file=sys.stderr)
            status = 2
            continue
        print("\n".join(lines))
        status = max(status, 1 if invalid else 0)
    return status


if __name__ == "__main__":
    run_tool(main)
