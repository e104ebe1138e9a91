"""JSON Schema checks of scene and demonstration files (DESIGN §3).

The published schemas are `pipeline/schemas/scene.schema.json` and `demos.schema.json`
(draft 2020-12, shipped as package data). A wrong type, shape or key is refused with one line:
the file, the JSON path of the culprit (`persons[2].x`) and what was expected. Non-finite
numbers are refused too: JSON has none, but Python's json module would read `NaN` and
`Infinity` literals; so are integers too large for a float and a key given twice in one object
(the json module would keep the last silently). What a schema cannot say (persons inside
the room, relation ids that exist, ...) is checked by the readers after this.
"""

from __future__ import annotations

import functools
import json
import math
import re
import sys
from importlib import resources
from pathlib import Path
from typing import Any

from jsonschema import Draft202012Validator
from jsonschema.exceptions import ValidationError, best_match

from pipeline.core.world import SceneError
from pipeline.errors import PipelineError

# Schema name -> the error type its file's reader raises.
ERRORS: dict[str, type[PipelineError]] = {"scene": SceneError, "demos": PipelineError}
JSON_TYPES = {"number": "a number", "integer": "an integer", "string": "a string",
              "array": "an array", "object": "an object", "boolean": "true or false",
              "null": "null"}


class NonFinite:
    """What a `NaN`, `Infinity` or `-Infinity` literal parses to: a marker, not a float, so
    `validate` can name the field that holds it."""

    def __init__(self, literal: str) -> None:
        self.literal = literal


class TooLarge:
    """What an integer literal of more digits than any float holds parses to (`_parse_int`):
    a marker, so `validate` can name the field (Python would make it an int no float holds,
    or refuse it beyond 4300 digits with a ValueError)."""

    def __init__(self, digits: int) -> None:
        self.digits = digits


def _parse_int(literal: str) -> int | TooLarge:
    digits = len(literal.lstrip("-"))
    return TooLarge(digits) if digits > sys.float_info.max_10_exp else int(literal)


class RepeatedKey(Exception):
    """A JSON object names a key twice (Python's json module would keep the last silently)."""

    def __init__(self, key: str) -> None:
        self.key = key


def _object_without_repeats(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out = dict(pairs)
    if len(out) < len(pairs):
        seen: set[str] = set()
        for k, _ in pairs:  # the first key named a second time
            if k in seen:
                raise RepeatedKey(k)
            seen.add(k)
    return out


@functools.cache
def load_schema(name: str) -> dict[str, Any]:
    """The published schema `name` ("scene" or "demos"), read from the package."""
    text = (resources.files("pipeline") / "schemas" / f"{name}.schema.json").read_text()
    return json.loads(text)


@functools.cache
def _validator(name: str) -> Draft202012Validator:
    return Draft202012Validator(load_schema(name))


def _map_yaml_hint(path: Path) -> str:
    """What to do with a map_server map's YAML given where a JSON file belongs."""
    try:
        text = path.read_text(errors="replace")[:10_000]
    except OSError:
        return ""
    if re.search(r"^\s*image\s*:", text, re.M) and re.search(r"^\s*resolution\s*:", text, re.M):
        return ("; it is a map_server map's YAML: name it in a scene file's \"map\" key, or "
                "place random people on it with scene=random scene.map=PATH")
    return ""


def read_json(path: Path, schema_name: str, source: str) -> Any:
    """Parse the JSON file `path` and `validate` it; errors name `source`."""
    error = ERRORS[schema_name]
    try:
        # utf-8-sig: editors on Windows save JSON with a byte-order mark, which is no JSON
        data = json.loads(path.read_text(encoding="utf-8-sig"), parse_constant=NonFinite,
                          parse_int=_parse_int, object_pairs_hook=_object_without_repeats)
        validate(data, schema_name, source)
    except RepeatedKey as e:
        raise error(f"{source}: key {e.key!r} appears twice in one object; which one is "
                    f"meant?") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise error(f"{source} is not valid JSON ({e}){_map_yaml_hint(path)}") from None
    except OSError as e:
        raise error(f"{source} cannot be read ({e.strerror or e})") from None
    except RecursionError:  # parsing and checking recurse; no valid file is this deep
        raise error(f"{source}: JSON nested too deeply") from None
    return data


def validate(data: Any, schema_name: str, source: str) -> None:
    """Check parsed JSON `data` against the schema `schema_name`.

    Raises the reader's error type (`ERRORS`) with one line: `source`, the JSON path of the
    culprit and what was expected.
    """
    error = ERRORS[schema_name]

    def fail(path: str, message: str) -> PipelineError:
        return error(f"{source}: {path}: {message}" if path else f"{source}: {message}")

    bad = _first_non_finite(data, "")
    if bad is not None:
        raise fail(*bad)
    # The shallowest error, and of equals the first found: jsonschema's default key would
    # report the last of several bad siblings (starts[6] before starts[0]).
    found = best_match(_validator(schema_name).iter_errors(_compacted(data, schema_name)),
                       key=_depth)
    if found is not None:
        raise fail(_json_path(found), _expected(found, load_schema(schema_name)))


# Where each schema has lists of points ([x, y]) that recordings make long: keys of the top
# level whose value is a list of such lists. jsonschema checks a point in about 30 µs, so a
# recording of 200 000 points took 11 s to check; `_compacted` checks them in bulk instead.
POINT_LISTS = {"demos": ("trajectories",), "scene": ("obstacles",)}
COMPACT_FROM = 64  # points: shorter lists are left to jsonschema


def _compacted(data: Any, schema_name: str) -> Any:
    """`data` with every long list of points at POINT_LISTS that holds nothing but valid
    points (two numbers within the schema's coordinate range) cut to its first COMPACT_FROM:
    what jsonschema then finds is what it would find in the whole (a list with a bad point
    is left whole, so the error names that point)."""
    if not isinstance(data, dict):
        return data
    coordinate = load_schema(schema_name)["$defs"]["coordinate"]
    low, high = coordinate["minimum"], coordinate["maximum"]

    def valid_point(q: Any) -> bool:
        return type(q) is list and len(q) == 2 and all(
            type(v) in (int, float) and low <= v <= high for v in q)

    def compact(points: Any) -> Any:
        if type(points) is list and len(points) > COMPACT_FROM and all(map(valid_point, points)):
            return points[:COMPACT_FROM]
        return points

    out = dict(data)
    for key in POINT_LISTS[schema_name]:
        if type(out.get(key)) is list:
            out[key] = [compact(points) for points in out[key]]
    return out


def _depth(error: ValidationError) -> int:
    return -len(error.path)


def _plain_number(v: Any) -> bool:
    return type(v) is int or (type(v) is float and math.isfinite(v))


def _first_non_finite(value: Any, path: str) -> tuple[str, str] | None:
    """(JSON path, what is wrong) of the first NaN, Infinity or integer too large for a float
    in `value`, or None."""
    no_nan = "is not a finite number (JSON has no NaN or Infinity)"
    if isinstance(value, NonFinite):
        return path, f"{value.literal} {no_nan}"
    if isinstance(value, float) and not math.isfinite(value):  # data not read by read_json
        return path, f"{value!r} {no_nan}"
    if isinstance(value, TooLarge):
        return path, f"an integer of {value.digits} digits is too large for a number"
    # fast paths: a list of plain finite numbers, or of such lists (points), holds nothing
    # to name; a recording's million points would otherwise each be visited with its path
    if isinstance(value, list) and (all(map(_plain_number, value)) or all(
            type(q) is list and all(map(_plain_number, q)) for q in value)):
        return None
    items = value.items() if isinstance(value, dict) else \
        enumerate(value) if isinstance(value, list) else ()
    for key, item in items:
        sub = f"{path}[{key}]" if isinstance(key, int) else f"{path}.{key}" if path else key
        found = _first_non_finite(item, sub)
        if found is not None:
            return found
    return None


def _json_path(error: ValidationError) -> str:
    """`persons[2].x` for the deque ['persons', 2, 'x']; '' for the top level."""
    path = ""
    for part in error.absolute_path:
        path += f"[{part}]" if isinstance(part, int) else f".{part}" if path else str(part)
    return path


def _short(value: Any) -> str:
    """The value as JSON, cut to 40 characters: a wrong value can be a whole list."""
    text = json.dumps(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _title(schema: dict[str, Any], root: dict[str, Any]) -> str | None:
    """The title of `schema`, following a local `$ref` into the root's `$defs`."""
    ref = schema.get("$ref", "")
    if ref.startswith("#/$defs/"):
        schema = root["$defs"][ref.removeprefix("#/$defs/")]
    return schema.get("title")


def _plural(noun: str, n: int) -> str:
    return noun if n == 1 else f"{noun}s"


def _expected(error: ValidationError, root: dict[str, Any]) -> str:
    """What was expected and what was found, in a few words (jsonschema's own message for
    keywords the published schemas do not use)."""
    kind, want, got = error.validator, error.validator_value, error.instance
    if kind == "type":
        names = [want] if isinstance(want, str) else want
        title = _title(error.schema, root)
        what = " or ".join(JSON_TYPES.get(n, n) for n in names)
        return f"expected {what}{f' ({title})' if title else ''}, got {_short(got)}"
    if kind in ("minItems", "maxItems"):
        lo, hi = error.schema.get("minItems"), error.schema.get("maxItems")
        if lo == hi:
            count = f"{lo}"
        elif hi is None or lo is None:
            count = f"at least {lo}" if hi is None else f"at most {hi}"
        else:
            count = f"{lo} to {hi}"
        noun = _title(error.schema.get("items", {}), root) or "item"
        bound = hi if lo is None else lo
        return f"expected {count} {_plural(noun, bound)}, got {len(got)} " \
               f"{_plural('item', len(got))}"
    if kind == "required":
        key = next(k for k in want if k not in got)
        # a requirement under a condition (room without a map) says why in its description
        why = f" ({error.schema['description']})" if "then" in error.relative_schema_path \
            and "description" in error.schema else ""
        return f"missing key {key!r}{why}"
    if kind == "additionalProperties":
        known = list(error.schema.get("properties", {}))
        unknown = [k for k in got if k not in known]
        return f"unknown key{'s' if len(unknown) > 1 else ''} " \
               f"{', '.join(repr(k) for k in unknown)}; expected one of {', '.join(known)}"
    if kind == "exclusiveMinimum":
        return f"expected a number > {want}, got {_short(got)}"
    if kind == "minimum":
        return f"expected a number >= {want:g}, got {_short(got)}"
    if kind == "maximum":
        return f"expected a number <= {want:g}, got {_short(got)}"
    if kind == "minLength":
        return f"expected a string of at least {want} character(s), got {_short(got)}"
    return error.message.splitlines()[0][:200]
