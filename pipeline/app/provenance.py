"""Provenance: every artefact records digests of the config sections it was made from and
of the artefacts it read (their content digests, pipeline.artefacts.store.content_digest),
so a stage can refuse inputs that belong to another config or to another run (stored as
MCAP metadata `run`: `config_digest.<key>`, `input_digest.<stage>`). Inputs that are no
artefact of the run are recorded by what they hold too: `input_digest.birl.from_run`, the
content digest of the birl.mcap `birl=fixed birl.from_run=RUN` takes its weights from (a
config digest only covers the path), in the artefacts made with those weights.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Mapping
from pathlib import Path

import yaml

from pipeline.artefacts.store import Artefact
from pipeline.artefacts.topics import ARTEFACT_FILE
from pipeline.errors import PipelineError

# The config keys each stage's artefact depends on (besides its input artefacts); a dotted
# key is one entry of a section (the graph grows on the learner's features under the prior's
# mean, so it depends on those of birl's keys, not on how many iterations learn).
STAGE_CONFIG: dict[str, tuple[str, ...]] = {
    "scene": ("seed", "scene"),
    "demos": ("seed", "expert", "reward", "mdp", "roadmap", "evaluate.holdout"),
    "graph": ("seed", "graph", "reward", "mdp", "expert.kind", "birl.features", "birl.prior",
              "birl.lower", "birl.upper"),
    "birl": ("seed", "birl", "graph", "reward", "mdp"),
    "evaluate": ("evaluate", "reward", "mdp", "roadmap"),
}
CONFIG_KEY, INPUT_KEY = "config_digest.", "input_digest."
# Inputs from outside the run and the stages whose artefacts depend on them.
SOURCE_STAGES: dict[str, tuple[str, ...]] = {"birl.from_run": ("graph", "birl"),
                                             "expert.path": ("demos",),
                                             "scene.path": ("scene",), "scene.map": ("scene",)}


def file_digest(path: Path) -> str:
    """The content digest of a file, or of every file of a directory (a ROS 2 bag) by their
    relative paths: what `expert.path` held when the demonstrations were read from it."""
    h = hashlib.sha256()
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    for f in files:
        h.update(str(f.relative_to(path) if f != path else "").encode() + b"\0")
        with f.open("rb") as stream:
            for block in iter(lambda: stream.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()[:16]


def files_digest(paths: list[Path]) -> str:
    """The content digest of several files read together, in order (a scene file, its map's
    YAML and its image)."""
    return hashlib.sha256("".join(file_digest(p) for p in paths).encode()).hexdigest()[:16]


def check_source(artefact: Artefact, name: str, digest: str) -> None:
    """Refuse `artefact` when it was made from another version of the outside input `name`
    (e.g. demonstrations read from a file edited since). Artefacts without it pass."""
    recorded = artefact.metadata.get(INPUT_KEY + name)
    if recorded is not None and recorded != digest:
        stage = next(s for s, f in ARTEFACT_FILE.items() if f == artefact.path.name)
        raise PipelineError(f"{artefact.path} was made from other contents of {name} than "
                            "it names now (another file, or the file changed since): add "
                            f"'{stage}' to stages to read it again")


def _lookup(config: Mapping, key: str) -> object:
    """config[key] for a section name, config[a][b] for a dotted key (None if absent)."""
    value: object = config
    for part in key.split("."):
        value = value.get(part) if isinstance(value, Mapping) else None
    return value


def _lookup_typed(settings: object, key: str) -> object:
    """settings.<key> for a dotted key (None if absent or without `settings`)."""
    for part in key.split("."):
        settings = getattr(settings, part, None)
    return settings


def _digest(value: object) -> str:
    return hashlib.sha256(json.dumps(value, sort_keys=True, separators=(",", ":"))
                          .encode()).hexdigest()[:16]


def provenance_metadata(stage: str, config: Mapping, inputs: Mapping[str, Artefact],
                        sources: Mapping[str, str] | None = None) -> dict[str, str]:
    """The metadata entries of `stage`'s artefact: its config digests and input digests (of
    the artefacts it read, and of the outside `sources` it depends on, SOURCE_STAGES)."""
    meta = {CONFIG_KEY + key: _digest(_lookup(config, key)) for key in STAGE_CONFIG[stage]}
    meta.update({INPUT_KEY + s: a.digest for s, a in inputs.items()})
    meta.update({INPUT_KEY + name: digest for name, digest in (sources or {}).items()
                 if stage in SOURCE_STAGES.get(name, ())})
    return meta


def _flatten(value: object, prefix: str) -> dict[str, object]:
    if isinstance(value, Mapping):
        out: dict[str, object] = {}
        for k, v in value.items():
            out.update(_flatten(v, f"{prefix}.{k}"))
        return out or {prefix: {}}
    return {prefix: value}


def _first_difference(key: str, made_with: object, now: object) -> tuple[str, object, object]:
    """The first key (dotted) whose value differs, and its two values (UNSET where a side
    has no such key); for a config group whose `kind` differs (another method or expert
    kind, whose other keys differ as a consequence), the group itself and the two kinds."""
    old, new = _flatten(made_with, key), _flatten(now, key)
    kind = f"{key}.kind"
    if kind in old and kind in new and old[kind] != new[kind]:
        return key, old[kind], new[kind]  # e.g. birl=policywalk, set as the group's option
    for k in sorted(set(old) | set(new)):
        if old.get(k, UNSET) != new.get(k, UNSET):
            return k, old.get(k, UNSET), new.get(k, UNSET)
    return key, made_with, now  # same values, different digest: say so plainly


UNSET = "<unset>"  # _first_difference: a key one of the two configs does not have


def without_added_defaults(now: object, made_with: object, settings: object) -> object:
    """`now` (a config section as plain data) without the keys that `made_with` (the same
    section of an older artefact's config) lacks and that hold their field's default in
    `settings` (the typed section): a key added to the pipeline since, at the value that
    keeps the old behaviour, is no difference (a run re-using demonstrations read before
    expert.select_walks existed was refused for "expert.select_walks=<unset>")."""
    if not isinstance(now, Mapping) or not isinstance(made_with, Mapping):
        return now
    defaults = {f.name: f.default for f in dataclasses.fields(settings)} \
        if dataclasses.is_dataclass(settings) else {}
    return {k: without_added_defaults(v, made_with.get(k), getattr(settings, k, None))
            for k, v in now.items()
            if k in made_with or k not in defaults or defaults[k] != v}


def check_config(stage: str, artefact: Artefact, config: Mapping,
                 settings: object = None) -> None:
    """Refuse `artefact` (of `stage`) when it was made with other config values than this
    run has for the keys it depends on (`config`, plain data; `settings`, the same typed,
    knows which keys were added since at their default: `without_added_defaults`).
    Artefacts without digests (older versions) pass."""
    recorded = artefact.metadata
    if not any(k.startswith(CONFIG_KEY) for k in recorded):
        return
    for key in STAGE_CONFIG[stage]:
        if recorded.get(CONFIG_KEY + key) == _digest(_lookup(config, key)):
            continue
        try:
            made_with = _lookup(yaml.safe_load(artefact.config_yaml) or {}, key)
        except yaml.YAMLError:
            made_with = "<unreadable>"
        now = without_added_defaults(_lookup(config, key), made_with,
                                     _lookup_typed(settings, key))
        if recorded.get(CONFIG_KEY + key) == _digest(now):
            continue
        path, old, new = _first_difference(key, made_with, now)
        # a key the run's settings do not have cannot be set to match: re-making is the way
        settable = old != UNSET and new != UNSET and not isinstance(old, Mapping)
        raise PipelineError(
            f"{artefact.path} was made with {path}={_show(old)} but this run has "
            f"{path}={_show(new)}: add '{stage}' to stages to re-make it"
            + (f", or run with {path}={_show(old)}" if settable else ""))


def check_inputs(read: Mapping[str, Artefact]) -> None:
    """Refuse artefacts that do not belong together: one was made from a different version
    of another (e.g. a graph grown from other demonstrations than the ones beside it)."""
    for stage, art in read.items():
        for other, other_art in read.items():
            recorded = art.metadata.get(INPUT_KEY + other)
            if recorded is not None and other_art.digest and recorded != other_art.digest:
                raise PipelineError(
                    f"{art.path} was made from another {ARTEFACT_FILE[other]} than "
                    f"{other_art.path}: they come from different runs; re-run stage "
                    f"'{stage}' (add it to stages) so they belong together")


def _show(value: object) -> str:
    return json.dumps(value) if not isinstance(value, str) else value
