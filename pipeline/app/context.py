"""What the stages share: the checked settings, the run dir, seeds, artefact I/O."""

from __future__ import annotations

import functools
import subprocess
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from functools import partial
from importlib import metadata as importlib_metadata
from pathlib import Path

import numpy as np

from pipeline.app.config import Config
from pipeline.app.provenance import check_config, check_inputs, provenance_metadata
from pipeline.artefacts.store import Artefact, ArtefactWriter, link_or_copy, read_artefact
from pipeline.artefacts.topics import ARTEFACT_FILE, STAGES
from pipeline.errors import PipelineError

PROJECT_ROOT = Path(__file__).resolve().parent.parent.parent
# conf/ and data/ of the package: links to the top-level dirs in the source tree, real
# copies in an installed wheel.
PACKAGE_ROOT = Path(__file__).resolve().parent.parent
_VERSIONED = ["numpy", "scipy", "scikit-learn", "mcap", "hydra-core", "pandas"]


def resolve_path(path: str) -> Path:
    """A user-given input path: as given (relative to the cwd), else relative to the package
    (so `data/scenes/metropolis.json` works from anywhere, also from an installed wheel)."""
    p = Path(path).expanduser()
    if input_path_exists(p, path) or p.is_absolute():
        return p
    return PACKAGE_ROOT / p if (PACKAGE_ROOT / p).exists() else p


def input_path_exists(p: Path, given: str) -> bool:
    """Does input path p exist? A path the system cannot look up at all (a name too long, a
    dir that may not be searched) is the user's input: one line naming it, not pathlib's
    OSError, which would read as a failure to write."""
    try:
        p.stat()
    except (FileNotFoundError, NotADirectoryError):
        return False
    except OSError as e:
        shown = given if len(given) <= 80 else f"{given[:60]}... ({len(given)} characters)"
        raise PipelineError(f"input path {shown} cannot be looked up: {e.strerror}") from None
    return True


def _git(*args: str) -> str | None:
    """A git command's output in the source tree; None where there is no git or no tree."""
    try:
        # --no-optional-locks: `git status` otherwise refreshes the index, writing
        # .git/index.lock in the source tree (outside the run dir) on every run, which can
        # collide with the user's own git commands
        out = subprocess.run(["git", "--no-optional-locks", *args], cwd=PROJECT_ROOT,
                             capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout if out.returncode == 0 else None


@functools.cache  # one process, one source tree: asked once, not per artefact
def git_revision() -> str:
    """HEAD of the source tree; "unknown" outside a git checkout."""
    return (_git("rev-parse", "HEAD") or "").strip() or "unknown"


@functools.cache
def git_tree_state() -> str:
    """"clean" when the tracked files are HEAD's, "modified" when not, else "unknown"."""
    if git_revision() == "unknown":
        return "unknown"
    status = _git("status", "--porcelain", "--untracked-files=no")
    return "unknown" if status is None else ("modified" if status.strip() else "clean")


def run_metadata(seed: int) -> dict[str, str]:
    return {"seed": str(seed), "git_revision": git_revision(), "git_tree": git_tree_state(),
            **_versions()}


@functools.cache  # read once per process (5 ms a run: a sweep's worker runs many)
def _versions() -> dict[str, str]:
    versions = {}
    for dist in ["birlg-pipeline"] + _VERSIONED:
        try:
            versions[f"version.{dist}"] = importlib_metadata.version(dist)
        except importlib_metadata.PackageNotFoundError:
            versions[f"version.{dist}"] = "not installed"
    return versions


def stage_rng(seed: int, stage: str, *stream: int) -> np.random.Generator:
    """The generator of `stage` (and optional sub-stream) for the run seed `seed`: each
    stage draws from its own, derived from the seed only (`api.learn` draws the same)."""
    return np.random.default_rng([int(seed), STAGES.index(stage), *stream])


@dataclass
class RunContext:
    cfg: Config  # the checked, typed settings
    run_dir: Path
    from_run: Path | None
    config: dict  # the resolved config as plain data (provenance digests)
    config_yaml: str  # the resolved config, attached to every artefact
    metadata: dict[str, str]
    # content digests of inputs that are no artefact of this run ("birl.from_run": the
    # birl.mcap birl=fixed takes its weights from), recorded in the provenance
    source_digests: dict[str, str] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)  # extra wall-clock measurements
    inputs: dict[str, Artefact] = field(default_factory=dict)  # read by the current stage
    # (stage, new content digest) -> None, run just before an artefact replaces the old one
    before_replace: Callable[[str, str], None] | None = None
    # Artefacts already read in this process, by path and file identity: later stages read
    # the same files again (graph.mcap by birl and evaluate). Files are replaced, never
    # modified, so a changed file has a new identity. Callers treat artefacts as read-only.
    _cache: dict[Path, tuple[tuple[int, int, int], Artefact]] = field(default_factory=dict)

    def rng(self, stage: str, seed: int | None = None, *stream: int) -> np.random.Generator:
        """An independent generator per stage (and optional sub-stream), derived from the run
        seed (or `seed`) only."""
        return stage_rng(self.cfg.seed if seed is None else seed, stage, *stream)

    def read(self, stage: str, required_topics: Iterable[str] = ()) -> Artefact:
        """The artefact of an earlier `stage`: made by this run, else from `from_run` (linked
        into this run dir, so the dir is complete), else already in this run dir. Refused
        when it was made with other config values or does not belong with the other inputs
        of the current stage."""
        path = self.run_dir / ARTEFACT_FILE[stage]
        # the run dir it is linked from (None: not linked)
        link_from = self.from_run if stage not in self.cfg.stages else None
        source = link_from / path.name if link_from is not None else path
        artefact = self._read_cached(source, required_topics, stage)
        check_config(stage, artefact, self.config, self.cfg)
        self.inputs[stage] = artefact
        check_inputs(self.inputs)
        if link_from is not None:  # checked first: a refused input never lands in this run dir
            if self.before_replace is not None:  # what was derived from the old one goes
                self.before_replace(stage, artefact.digest)
            link_or_copy(source, path)
            # Inputs of this stage linked before it (read out of pipeline order, e.g. the
            # graph before the scene) went with what was derived from the old one; they
            # belong with it (checked above): link them again, so the dir stays complete.
            for other in self.inputs:
                again = self.run_dir / ARTEFACT_FILE[other]
                if other not in self.cfg.stages and not again.exists():
                    link_or_copy(link_from / again.name, again)
        return artefact

    def _read_cached(self, path: Path, required_topics: Iterable[str], stage: str) -> Artefact:
        try:
            st = path.stat()
            identity = (st.st_ino, st.st_size, st.st_mtime_ns)
        except OSError:  # missing: read_artefact says so in one line
            return read_artefact(path, required_topics=required_topics, producer_stage=stage)
        cached = self._cache.get(path)
        if cached is None or cached[0] != identity:
            # lazy: a stage parses only the topics it reads (the whole file is checked now)
            cached = (identity, read_artefact(path, producer_stage=stage, lazy=True))
            self._cache[path] = cached
        return cached[1].require(required_topics)

    def writer(self, stage: str) -> ArtefactWriter:
        meta = {**self.metadata, **provenance_metadata(stage, self.config, self.inputs,
                                                       self.source_digests)}
        hook = self.before_replace
        return ArtefactWriter(self.run_dir / ARTEFACT_FILE[stage],
                              config_yaml=self.config_yaml, metadata=meta,
                              before_replace=None if hook is None else partial(hook, stage))
