"""A run dir that cannot be shared or left half-done without saying so.

- An exclusive lock (`fcntl.flock` on `<run dir>/.lock`, released by the kernel even on
  SIGKILL): a second run into a dir in use refuses with one line.
- `status.json`, written atomically: `running` while stages run (with the stage), then
  `complete`, `failed` (with the failing stage and the error) or `interrupted` (Ctrl-C or
  SIGTERM: the stage and the signal). A run killed with -9 leaves `running` behind; readers
  see that the lock is free and report it as `interrupted` too. When the disk is full and no
  new file can be made, the last status is overwritten in place (it fits in the space the file
  already holds), so a dir never says `running` after its run gave up.
- Stale `*.tmp` files of a dead writer are removed when the next run takes the lock.
- Just before a stage's artefact replaces a different one, the artefacts derived from the
  old one (later stages, `metrics.json`) are removed, so a dir never holds new inputs beside
  old outputs; a failed or killed stage leaves the earlier files untouched.
"""

from __future__ import annotations

import errno
import fcntl
import json
import logging
import os
import signal
import sys
import tempfile
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from types import TracebackType
from typing import Any, overload

from pipeline.artefacts.store import content_digest, write_json_atomic, write_text_atomic
from pipeline.artefacts.topics import ARTEFACT_FILE, STAGES
from pipeline.errors import Interrupted, PipelineError, not_ignored, os_error_reason

log = logging.getLogger("pipeline")

LOCK_FILE, STATUS_FILE, METRICS_FILE = ".lock", "status.json", "metrics.json"
TIMINGS_FILE = "timings.json"  # seconds per stage: side information, never in artefacts
# Hydra's record of a run's config (in its default hydra.output_subdir)
HYDRA_FILES = (".hydra/config.yaml", ".hydra/hydra.yaml", ".hydra/overrides.yaml")
SWEEP_FILE = "sweep.json"  # in a sweep dir: the number of the sweep that last ran into it
MULTIRUN_FILE = "multirun.yaml"  # Hydra's, at the top of a sweep dir
RUNNING, COMPLETE, FAILED, INTERRUPTED = "running", "complete", "failed", "interrupted"
UNKNOWN = "unknown"
KILLED = "the run was killed or crashed"  # a dir that says running, but nobody holds it
STATUS_ERROR_CHARS = 500  # status.json's error, cut: it must fit where the file already is


# The signals that stop a run or a sweep with a word (Interrupted): Ctrl-C, `kill`, and the
# terminal closing under it
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


def ignore_repeat(signum: int, frame: object) -> None:
    """The handler of a signal already acted on: nothing. (SIG_IGN would make Python raise
    "Signal N ignored due to race condition" for one that arrived meanwhile.)"""


@contextmanager
def signals_deferred() -> Iterator[None]:
    """STOP_SIGNALS that arrive in the block are acted on after it (the first of them, by
    the handlers from before the block): a message on a pipe goes out or comes in whole, a
    fork gives no half-made child. (Blocking the signals would not do: the kernel hands a
    process's signal to any thread that does not block it, e.g. one of numpy's, and Python
    runs the handler in the main thread all the same.) Elsewhere than in the main thread,
    where no handler runs, nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    arrived: list[int] = []
    previous = {sig: signal.getsignal(sig) for sig in not_ignored(STOP_SIGNALS)}
    for sig in previous:
        signal.signal(sig, lambda signum, frame: arrived.append(signum))
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if arrived:
            signal.raise_signal(arrived[0])


@contextmanager
def stopped_by_signals() -> Iterator[None]:
    """STOP_SIGNALS raise Interrupted for the block, so a run dir records the stage that was
    stopped and the CLI says so in one line; the previous handlers come back after. Python
    lets only the main thread handle signals: elsewhere nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    stops: list[int] = []

    def stop(signum: int, frame: object) -> None:
        # One signal stops the run; a second one (Ctrl-C reaches a sweep's workers both from
        # the terminal and from the sweep's process) must not cut short writing status.json.
        for sig in previous:
            signal.signal(sig, ignore_repeat)
        stops.append(signum)
        raise Interrupted(signum)

    # a signal the process ignores stays ignored (SIGHUP under nohup: it stopped the run)
    previous = {sig: signal.getsignal(sig) for sig in not_ignored(STOP_SIGNALS)}
    for sig in previous:
        signal.signal(sig, stop)
    unraisable_hook = sys.unraisablehook
    sys.unraisablehook = partial(_quiet_about_stops, unraisable_hook)
    _STOPS.append(stops)
    try:
        yield
        if stops:  # the Interrupted was raised where Python drops exceptions (a finaliser,
            raise Interrupted(stops[0])  # a weakref callback) and the block went on
    except Exception as e:
        # or where a library turned it into an error of its own (OmegaConf, interrupted
        # inside a node update, left it half-made: "AttributeError: 'NoneType' object has
        # no attribute '_invalidate_flags_cache'"): the signal is the news
        if stops and not isinstance(e, Interrupted):
            raise Interrupted(stops[0]) from e
        raise
    finally:
        # by identity: list.remove compares by value, and an inner block's [] equals this
        # one's, so it took the outer's list out and a later signal made the outer's
        # removal fail ("x not in list" from a sweep worker stopped by SIGTERM)
        del _STOPS[next(i for i, s in enumerate(_STOPS) if s is stops)]
        sys.unraisablehook = unraisable_hook
        for sig, handler in previous.items():
            signal.signal(sig, handler)


# the signals each open stopped_by_signals block has had (the innermost last)
_STOPS: list[list[int]] = []


def _quiet_about_stops(hook: Callable[[Any], None], unraisable: Any) -> None:
    """sys.unraisablehook while signals stop the run: an Interrupted that Python drops (it
    was raised inside a finaliser) says nothing; the block raises it again (`stopped_by_
    signals`, RunDir.start)."""
    if not isinstance(unraisable.exc_value, Interrupted):
        hook(unraisable)


def raise_if_stopped() -> None:
    """Raise the Interrupted of a signal whose exception Python dropped (see
    `stopped_by_signals`), where the run can stop cleanly: between its stages."""
    for stops in _STOPS:
        if stops:
            raise Interrupted(stops[0])


@dataclass(frozen=True)
class FailedJob:
    """What a sweep's failed job returns to Hydra's sweeper instead of a number: the other
    jobs go on (Hydra's basic sweeper re-raises a job's exception, which would stop the
    sweep), and a sweeper that optimises (Optuna) records a failed trial, as float() of it
    raises (NaN would not do: Optuna refuses it as a value)."""

    error: str

    def __float__(self) -> float:
        raise ValueError(str(self))

    def __str__(self) -> str:
        return f"the job failed: {self.error}"


# a stop's own exception is always one; any other, one while a stop is pending
@overload
def as_interrupted(exc: Interrupted | KeyboardInterrupt, stage: str | None) -> Interrupted: ...
@overload
def as_interrupted(exc: BaseException | None, stage: str | None) -> Interrupted | None: ...
def as_interrupted(exc: BaseException | None, stage: str | None) -> Interrupted | None:
    """`exc` as an Interrupted (a KeyboardInterrupt is SIGINT), with the stage it hit; None
    when it is no interruption. Any exception while a stop is pending is the stop: a library
    the signal's Interrupted hit can raise an error of its own in its place (as
    `stopped_by_signals` says)."""
    if isinstance(exc, Interrupted):
        if exc.stage is None:
            exc.stage = stage
        return exc
    if isinstance(exc, KeyboardInterrupt):
        return Interrupted(signal.SIGINT, stage)
    pending = next((stops[0] for stops in _STOPS if stops), None)
    if exc is not None and pending is not None:
        return Interrupted(pending, stage)
    return None


def is_locked(run_dir: Path) -> bool:
    """Whether a live process holds the run dir's lock (never blocks)."""
    try:
        fd = os.open(run_dir / LOCK_FILE, os.O_RDONLY)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
        return False
    except OSError:
        return True
    finally:
        os.close(fd)


@dataclass(frozen=True)
class RunStatus:
    state: str  # running | complete | failed | interrupted | UNKNOWN (no or no readable status)
    stage: str | None = None  # the running or failing stage
    error: str | None = None
    sweep: int | None = None  # the number of the sweep (SWEEP_FILE) whose job wrote it
    stages: tuple[str, ...] = ()  # the stages the run was to run, and those it completed
    done: tuple[str, ...] = ()

    @property
    def complete(self) -> bool:
        return self.state == COMPLETE

    def describe(self) -> str:
        at = f" at stage {self.stage}" if self.stage else ""
        return f"{self.state}{at}" + (f" ({self.error})" if self.error else "")


def read_status(run_dir: Path) -> RunStatus:
    """The truth about a run dir: `interrupted` when it says running but nobody holds it."""
    path = Path(run_dir) / STATUS_FILE
    try:
        present = path.exists()
    except OSError:  # e.g. a name too long to be a file's (a sweep's job that could not be)
        present = False
    if not present:
        return RunStatus(UNKNOWN)
    try:
        data = json.loads(path.read_text())
        state, stage, error = data["state"], data.get("stage"), data.get("error")
        sweep = data.get("sweep")
        stages, done = tuple(data.get("stages") or ()), tuple(data.get("done") or ())
        if state not in (RUNNING, COMPLETE, FAILED, INTERRUPTED):
            raise ValueError(state)
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return RunStatus(UNKNOWN, error=f"an unreadable {STATUS_FILE}")
    if state == RUNNING and not is_locked(Path(run_dir)):
        return RunStatus(INTERRUPTED, stage, KILLED, sweep, stages, done)
    return RunStatus(state, stage, error, sweep, stages, done)


def check_from_run(from_run: Path, given: str, key: str = "from_run",
                   needs: str | None = None) -> None:
    """A run dir whose artefacts this run reads (`key`=`given`) must be a dir whose run is
    over: not running now, not killed half-way; a failed one is used with a warning. When
    the run says which stages it completed, stage `needs` must be one of them (a failed
    re-run's dir may hold the artefact of an earlier run, made with another config)."""
    if not from_run.is_dir():
        what = "does not exist" if not from_run.exists() else "is not a directory"
        raise PipelineError(f"config error: {key}={given} {what}")
    status = read_status(from_run)
    if status.state in (RUNNING, INTERRUPTED):
        raise PipelineError(f"{key}={given} is {status.describe()}: its artefacts may be "
                            "half-made; let it finish, or re-run it (hydra.run.dir=...)")
    if needs is not None and status.stages and needs not in status.done:
        raise PipelineError(f"{key}={given} did not complete its {needs} stage (it is "
                            f"{status.describe()}; completed: {', '.join(status.done) or 'none'})"
                            f"; run that stage into it, or choose another run")
    if status.state == FAILED:
        log.warning("%s=%s %s; using the artefacts it completed", key, given,
                    status.describe())
    if status.state == UNKNOWN:  # copied artefacts, or a damaged dir: the reads still check
        why = status.error or f"no {STATUS_FILE}"
        log.warning("%s=%s has %s, so whether its run finished is not known; using its "
                    "artefacts as they are (each is checked as it is read)", key, given, why)


_HANDED_OVER: set[Path] = set()  # run dirs whose lock the CLI holds for this process's run
# The .hydra/ files of those dirs as they were before Hydra began the run (None: absent), so
# that a run its config refuses can put an earlier run's back (`_restore_hydra_files`).
_HYDRA_FILES_BEFORE: dict[Path, dict[str, str | None]] = {}


def acquire_lock(run_dir: Path, in_use: str | None = None, kind: str = "run dir") -> int:
    """Take the dir's exclusive lock (creating the dir) and return its fd, or refuse in one
    line when another process holds it (`in_use`: that line, and `kind`: the dir's name in
    the others, for a dir that is no run dir: a sweep's)."""
    try:
        Path(run_dir).mkdir(parents=True, exist_ok=True)
        fd = os.open(Path(run_dir) / LOCK_FILE, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as e:
        raise PipelineError(f"cannot use {kind} {run_dir}: {os_error_reason(e)}") from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        raise PipelineError(in_use or f"run dir {run_dir} is in use by another process (a "
                            "run or an export); wait for it to finish, or for a new run "
                            "choose another hydra.run.dir (pipeline.api: run_dir=)") from None
    return fd


@contextmanager
def locked(run_dir: Path) -> Iterator[None]:
    """Hold the run dir's lock for the block and hand it to the RunDir of the run inside
    (the CLI wraps Hydra in it, so a second run is refused before Hydra writes its files).
    A signal in the block marks the dir interrupted if Hydra had started the run in it
    (`mark_started_by_hydra`)."""
    fd = acquire_lock(run_dir)
    key = Path(run_dir).resolve()
    _HANDED_OVER.add(key)
    before = run_files_version(run_dir)
    try:
        check_writable(run_dir)
        with suppress(OSError, UnicodeDecodeError):  # unreadable: not put back, as before
            _HYDRA_FILES_BEFORE[key] = {name: _read_or_none(Path(run_dir) / name)
                                        for name in HYDRA_FILES}
        yield
    except (KeyboardInterrupt, Interrupted) as e:
        with suppress(OSError):
            mark_started_by_hydra(run_dir, before, as_interrupted(e, None).describe())
        raise
    finally:
        _HANDED_OVER.discard(key)
        _HYDRA_FILES_BEFORE.pop(key, None)
        os.close(fd)  # releases the lock


def _read_or_none(path: Path) -> str | None:
    try:
        return path.read_text()
    except FileNotFoundError:
        return None


def _restore_hydra_files(run_dir: Path) -> bool:
    """Put the .hydra/ files of the earlier run in `run_dir` back as `locked` found them,
    Hydra having replaced them with those of a run that its config then refused: the dir
    describes the earlier run again, whole (its status.json, artefacts and metrics were never
    touched). False where there was no earlier run, no files were taken, or writing fails."""
    before = _HYDRA_FILES_BEFORE.get(Path(run_dir).resolve())
    if before is None or read_status(run_dir).state == UNKNOWN:
        return False
    try:
        _put_back(Path(run_dir), before)
    except OSError:
        return False
    return True


def _put_back(run_dir: Path, files: dict[str, str | None]) -> None:
    """Files of `run_dir` (names relative to it) as they were: their text, or absent (None)."""
    for name, content in files.items():
        if content is None:
            (run_dir / name).unlink(missing_ok=True)
        else:
            write_text_atomic(run_dir / name, content)


def is_sweep_dir(path: Path) -> bool:
    """Whether a sweep ran into `path` (our record or Hydra's is at its top)."""
    return (Path(path) / SWEEP_FILE).exists() or (Path(path) / MULTIRUN_FILE).exists()


def check_not_a_sweep_dir(run_dir: Path) -> None:
    """Refuse a run into a sweep's dir: its .hydra/ and artefacts at the top would make the
    dir a run dir, whose sweep's jobs no table could list any more."""
    if is_sweep_dir(run_dir):
        raise PipelineError(f"{run_dir} is a sweep's dir (it has {SWEEP_FILE} or "
                            f"{MULTIRUN_FILE}): give the run a dir of its own")


def check_not_a_run_dir(sweep_dir: Path) -> None:
    """Refuse a sweep into a single run's dir (the reverse of check_not_a_sweep_dir)."""
    made = [name for name in (HYDRA_FILES[-1], STATUS_FILE) if (Path(sweep_dir) / name).exists()]
    if made:
        raise PipelineError(f"{sweep_dir} is a run dir (it has {made[0]}): give the sweep a "
                            "dir of its own")


def check_writable(run_dir: Path) -> None:
    """Refuse a run dir where no new file can be made (e.g. read-only) before Hydra
    rewrites its .hydra/ (a writable subdir): the dir would be left with this run's
    overrides beside the earlier run's status and metrics."""
    try:
        fd, probe = tempfile.mkstemp(dir=run_dir, suffix=".tmp")
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        raise PipelineError(f"cannot use run dir {run_dir}: {os_error_reason(e)}") from None


def run_files_version(run_dir: Path) -> tuple:
    """What tells the versions of Hydra's files and of status.json (last) in the dir apart."""
    return tuple(_file_version(Path(run_dir) / name) for name in (*HYDRA_FILES, STATUS_FILE))


def _file_version(path: Path) -> list[int] | None:
    """(inode, size, mtime) of a file, as a list (it is kept in sweep.json); None: none."""
    try:
        st = path.stat()
    except OSError:
        return None
    return [st.st_ino, st.st_size, st.st_mtime_ns]


def mark_started_by_hydra(run_dir: Path, before: tuple | None, error: str,
                          sweep: int | None = None) -> None:
    """A run stopped by a signal after Hydra rewrote its dir's .hydra/ but before the run
    wrote its status.json (Hydra's start of the job): the dir says interrupted with `error`,
    or an earlier run's `complete` there would pair its metrics with this run's overrides.
    `before`: the dir's run_files_version before Hydra began (None: there was no run in
    it); a dir Hydra had not written is left as the earlier run left it."""
    before = before or (None,) * (len(HYDRA_FILES) + 1)
    after = run_files_version(run_dir)
    if after[:-1] != before[:-1] and after[-1] == before[-1]:
        mark_ended_before_stages(run_dir, INTERRUPTED, error, sweep)


class RunDir:
    """`with RunDir(path, stages) as rd:` holds the lock; `rd.start(stage)` before each
    stage, `rd.done(stage)` after, `rd.before_replace` as the artefact writer's hook;
    leaving the block marks the dir complete or failed."""

    def __init__(self, path: Path, stages: list[str], sweep: int | None = None):
        self.path, self.stages, self.sweep = Path(path), list(stages), sweep
        self.done_stages: list[str] = []
        self.stage: str | None = None
        self._fd: int | None = None  # our own lock, unless the CLI handed its lock over
        # the earlier run's status.json and timings.json (None: absent), to put back
        self._side_files_before: dict[str, str | None] | None = None
        self._changed = False  # has an artefact of another content replaced one here?
        # links to the earlier artefacts that one of the same content replaced (its config
        # names this run's settings), and where each was: put back if this run fails
        self._kept: list[tuple[Path, Path]] = []

    def __enter__(self) -> RunDir:
        if Path(self.path).resolve() not in _HANDED_OVER:
            check_not_a_sweep_dir(self.path)
            self._fd = acquire_lock(self.path)
        self._remove_stale_temp_files()
        with suppress(OSError, UnicodeDecodeError):  # unreadable: not put back
            self._side_files_before = {name: _read_or_none(self.path / name)
                                       for name in (STATUS_FILE, TIMINGS_FILE)}
        self._write(RUNNING)
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        try:
            interrupted = as_interrupted(exc, self.stage)
            if exc_type is None:
                self._write(COMPLETE)
            elif interrupted is not None:
                if isinstance(exc, Interrupted):
                    exc.stage = interrupted.stage  # the CLI's one line names it
                self._write(INTERRUPTED, error=interrupted.describe())
                if not isinstance(exc, (Interrupted, KeyboardInterrupt)):
                    # a library's own error in the stop's place: the stop goes on, with its
                    # stage (stopped_by_signals' own would say "before the first stage")
                    raise interrupted from exc
            elif not self._restore_earlier_run():
                assert exc is not None  # exc_type is set: `with` passes its exception too
                self._write(FAILED, error=error_text(exc))
        except OSError as e:  # e.g. disk full: the stage's own error matters more
            log.error("cannot write %s: %s", self.path / STATUS_FILE, os_error_reason(e))
        finally:
            for kept, _ in self._kept:  # not put back: the run's own files stay
                with suppress(OSError):
                    kept.unlink(missing_ok=True)
            if self._fd is not None:
                os.close(self._fd)  # releases the lock
                self._fd = None

    def start(self, stage: str) -> None:
        raise_if_stopped()
        self.stage = stage
        self._write(RUNNING)

    def before_replace(self, stage: str, new_digest: str) -> None:
        """Called just before `stage`'s new artefact (content digest `new_digest`) replaces
        the old one. If the content changes, what was derived from the old one (later
        stages' artefacts, metrics.json) is removed first, so no moment leaves new inputs
        beside old outputs; a failed or killed stage leaves the earlier files untouched."""
        if content_digest(self.path / ARTEFACT_FILE[stage]) == new_digest:
            self._keep_earlier(self.path / ARTEFACT_FILE[stage])
            return
        self._changed = True
        # A later stage this run already made read the new inputs (an input linked out of
        # pipeline order, e.g. evaluate reading the scene after birl): its artefact stays.
        later = [self.path / ARTEFACT_FILE[s] for s in STAGES[STAGES.index(stage) + 1:]
                 if s not in self.done_stages]
        removed = [p for p in later + [self.path / METRICS_FILE] if p.exists()]
        for p in removed:
            try:
                p.unlink()
            except OSError as e:  # e.g. a directory of its name: that file is the culprit
                raise PipelineError(f"cannot remove {p} (derived from the {stage} artefact "
                                    f"this run replaces): {os_error_reason(e)}") from None
        if removed:
            log.info("removed %s: derived from the %s artefact this run replaces",
                     ", ".join(p.name for p in removed), stage)

    def _keep_earlier(self, path: Path) -> None:
        """A hard link to the artefact about to be replaced by one of the same content, so
        that a run that then fails with nothing changed leaves the dir as it was, byte for
        byte (the new file's config would name, say, the demonstration file it refused).
        The link's name ends in .tmp: a killed run's is removed by the next."""
        kept = path.with_name(path.name + ".earlier.tmp")
        try:
            kept.unlink(missing_ok=True)
            os.link(path, kept)
        except OSError:  # a file system without hard links: the new file stays
            return
        self._kept.append((kept, path))

    def done(self, stage: str) -> None:
        raise_if_stopped()  # (the stage's artefact stays: it is whole)
        self.done_stages.append(stage)

    def _remove_stale_temp_files(self) -> None:
        # We hold the lock, so no live writer owns a temp file in this dir.
        stale = sorted(self.path.glob("*.tmp"))
        for p in stale:
            p.unlink(missing_ok=True)
        if stale:
            log.info("removed %d stale temporary file(s) of an earlier run from %s", len(stale),
                     self.path)

    def _restore_earlier_run(self) -> bool:
        """A run that failed before any artefact here changed (a bad demonstration file, an
        artefact of `from_run` found corrupt or made with another config by the stage that
        reads it; stages before it may have re-made theirs, the same) leaves the earlier run
        in the dir as it was: its status.json and timings.json put back, and the .hydra/
        files of a command-line run, as for a run its config refuses (`mark_ended_before_
        stages`); a good run must not lose its export to a failed re-run. (An API run writes
        no .hydra/ files.) Not in a sweep, whose failed jobs must say so. False where nothing
        was put back."""
        before = self._side_files_before
        if self.sweep is not None or self._changed or before is None \
                or before[STATUS_FILE] is None:
            return False
        if Path(self.path).resolve() in _HANDED_OVER and not _restore_hydra_files(self.path):
            return False
        _put_back(self.path, before)
        for kept, path in self._kept:
            os.replace(kept, path)
        log.info("%s: nothing here was changed; the earlier run's status is kept", self.path)
        return True

    def _write(self, state: str, error: str | None = None) -> None:
        write_status(self.path, state, self.stage if state != COMPLETE else None, error,
                     self.stages, self.done_stages, self.sweep)


def error_text(e: BaseException) -> str:
    """A failed run's error as status.json and the sweep's log give it: ours as it is, any
    other with its type."""
    return str(e) if isinstance(e, PipelineError) else f"{type(e).__name__}: {e}"


def write_status(run_dir: Path, state: str, stage: str | None, error: str | None,
                 stages: list[str], done: list[str], sweep: int | None = None) -> None:
    """status.json (atomically); the error on one line, cut to STATUS_ERROR_CHARS. On a full
    disk, where no temp file can be made, the old status.json is overwritten in place."""
    if error is not None:
        error = " ".join(error.split())
        if len(error) > STATUS_ERROR_CHARS:
            error = error[:STATUS_ERROR_CHARS - 3] + "..."
    status: dict[str, object] = {"state": state, "stage": stage, "error": error,
                                 "stages": stages, "done": done}
    if sweep is not None:
        status["sweep"] = sweep
    path = Path(run_dir) / STATUS_FILE
    try:
        write_json_atomic(path, status)
    except OSError as e:
        if e.errno != errno.ENOSPC or not path.is_file():
            raise
        _overwrite_in_place(path, json.dumps(status, sort_keys=True).encode())


def _overwrite_in_place(path: Path, data: bytes) -> None:
    """Write `data` over the file's old content and cut it there: no new file, and on most
    file systems no new block for a file this small (status.json: < 1 KB in a 4 KB block).
    Not atomic; used only when the atomic write found the disk full."""
    fd = os.open(path, os.O_WRONLY)
    try:
        view = memoryview(data)
        while view:
            view = view[os.write(fd, view):]
        os.ftruncate(fd, len(data))
        os.fsync(fd)
    finally:
        os.close(fd)


def mark_ended_before_stages(run_dir: Path, state: str, error: str,
                             sweep: int | None = None) -> None:
    """A run that ended before its stages began (a config error: `failed`; a signal:
    `interrupted`): any status.json in its dir is an earlier run's, and Hydra has already
    replaced .hydra/config.yaml, so it says `state` with this run's error where it says
    anything else (`complete` would now be a lie, an old failure the wrong error); in a
    sweep (`sweep`, its number) also where there is none, so aggregation counts the job.
    A command-line run refused by its config puts the earlier run's .hydra/ files back
    instead (`_restore_hydra_files`), and the earlier run stays as it was: a typo in a
    re-run must not cost a good run its export. A dir another live process holds is left
    alone."""
    run_dir = Path(run_dir)
    if run_dir.resolve() not in _HANDED_OVER and is_locked(run_dir):
        return
    if state == FAILED and _restore_hydra_files(run_dir):
        return
    if read_status(run_dir).state != UNKNOWN or sweep is not None:
        run_dir.mkdir(parents=True, exist_ok=True)
        write_status(run_dir, state, None, error, [], [], sweep)


def mark_died(run_dir: Path, error: str, sweep: int | None = None) -> None:
    """A run whose process died without a word (killed with -9, out of memory, as a sweep's
    worker sees it): its status.json says failed with `error`, keeping the stage it was at
    and the stages it had done (and `sweep`, the number of the sweep whose job it is, where
    the run had recorded none). A status the run wrote at its end is left as it is."""
    status = read_status(run_dir)
    if status.state != UNKNOWN and status.error != KILLED:
        return
    Path(run_dir).mkdir(parents=True, exist_ok=True)
    write_status(run_dir, FAILED, status.stage, error, list(status.stages), list(status.done),
                 status.sweep if status.sweep is not None else sweep)


def job_dirs(sweep_dir: Path) -> list[Path]:
    """Every job of a Hydra sweep: the dirs holding Hydra's .hydra/overrides.yaml."""
    def natural(p: Path) -> tuple[int, list[tuple[int, int, str]]]:  # job 2 before job 10,
        # numbered jobs before others
        return len(p.parts), [(0, int(x), "") if x.isdigit() else (1, 0, x) for x in p.parts]

    return sorted((p.parent.parent for p in Path(sweep_dir).glob(f"**/{HYDRA_FILES[-1]}")),
                  key=natural)


def begin_sweep(sweep_dir: Path) -> tuple[int, dict]:
    """Number a new sweep into `sweep_dir` and return (its number, the record it replaced).
    Its jobs record the number in their status.json, so that job dirs an earlier sweep left
    in the dir (a re-run with fewer jobs) are told apart from this sweep's. The number is one
    more than the last sweep's that ran a job there (from 1; read from the jobs as well, so a
    damaged SWEEP_FILE does not restart it): a sweep that ran none is numbered again."""
    statuses = {j: read_status(j) for j in job_dirs(sweep_dir)}
    recorded = {status.sweep for status in statuses.values()}
    last = max([current_sweep(sweep_dir) or 0] + [n for n in recorded if isinstance(n, int)])
    number = last if last > 0 and last not in recorded else last + 1
    previous = _sweep_record(sweep_dir)
    record: dict = {"sweep": number, "finished": False}
    # job dirs whose status.json cannot be read are an earlier sweep's as long as this one
    # has not begun a job in them (Hydra rewrites their overrides)
    unreadable = {_relative(j, sweep_dir): _file_version(Path(j) / HYDRA_FILES[-1])
                  for j, status in statuses.items() if status.state == UNKNOWN}
    if unreadable:
        record["unreadable_before"] = unreadable
    Path(sweep_dir).mkdir(parents=True, exist_ok=True)
    write_json_atomic(Path(sweep_dir) / SWEEP_FILE, record)
    return number, previous


def abandon_sweep(sweep_dir: Path, previous: dict) -> None:
    """A sweep that stopped before any of its jobs began (a launcher's config error, Ctrl-C
    while composing) leaves the dir's record as it found it: the earlier sweep's jobs stay
    the ones a table shows."""
    number = current_sweep(sweep_dir)
    if number is None or any(read_status(j).sweep == number for j in job_dirs(sweep_dir)):
        return
    path = Path(sweep_dir) / SWEEP_FILE
    if previous:
        write_json_atomic(path, previous)
    else:
        path.unlink(missing_ok=True)


def end_sweep(sweep_dir: Path, unrecorded: dict[str, str] | None = None) -> None:
    """The sweep's launcher has returned every job (none may be left unstarted).
    `unrecorded`: job dir -> error of its jobs that failed where no status.json of this
    sweep says so (the dir could not be made, or holds an earlier sweep's job); the record
    keeps them, so a table lists them."""
    number = current_sweep(sweep_dir)
    if number is not None:
        # its jobs listed, so that a table can tell a job dir deleted since
        record = {**_sweep_record(sweep_dir), "finished": True,
                  "jobs": [_relative(j, sweep_dir) for j in sweep_jobs(sweep_dir)[0]]}
        if unrecorded:
            record["unrecorded"] = {_relative(Path(j), sweep_dir): e
                                    for j, e in unrecorded.items()}
        write_json_atomic(Path(sweep_dir) / SWEEP_FILE, record)


def stop_sweep(sweep_dir: Path, why: str | None) -> None:
    """The last sweep into `sweep_dir` stopped before its launcher returned every job: its
    record says `why` (the signal, the sweeper's error), which tables repeat."""
    record = _sweep_record(sweep_dir)
    if why and record.get("finished") is False:
        write_json_atomic(Path(sweep_dir) / SWEEP_FILE, {**record, "stopped": why})


def sweep_stopped_why(sweep_dir: Path) -> str | None:
    """Why the last sweep into `sweep_dir` stopped, as recorded (None: not recorded)."""
    why = _sweep_record(sweep_dir).get("stopped")
    return why if isinstance(why, str) else None


def unrecorded_jobs(sweep_dir: Path) -> dict[str, str]:
    """The failed jobs of the last sweep that end_sweep recorded beside their dirs (job,
    relative to the sweep dir -> error)."""
    jobs = _sweep_record(sweep_dir).get("unrecorded")
    if not isinstance(jobs, dict):
        return {}
    return {str(j): str(e) for j, e in jobs.items()}


def missing_jobs(sweep_dir: Path) -> dict[str, str]:
    """The jobs end_sweep recorded for the last sweep that are no longer found as jobs
    (relative to the sweep dir -> what is gone): deleted or moved after the sweep."""
    jobs = _sweep_record(sweep_dir).get("jobs")
    if not isinstance(jobs, list):
        return {}
    gone = {}
    for job in map(str, jobs):
        if not (Path(sweep_dir) / job).is_dir():
            gone[job] = "its job dir is gone (deleted or moved after the sweep)"
        elif not (Path(sweep_dir) / job / HYDRA_FILES[-1]).exists():
            gone[job] = f"its {HYDRA_FILES[-1]} is gone (deleted after the sweep)"
    return gone


def _relative(job_dir: Path, sweep_dir: Path) -> str:
    """job_dir relative to sweep_dir; either may be relative to the working dir (Hydra
    makes a job's dir absolute, a user's sweep dir often is not)."""
    try:
        return str(Path(os.path.abspath(job_dir)).relative_to(os.path.abspath(sweep_dir)))
    except ValueError:
        return str(job_dir)


def _sweep_record(sweep_dir: Path) -> dict:
    try:
        record = json.loads((Path(sweep_dir) / SWEEP_FILE).read_text())
    except (OSError, ValueError):
        return {}
    return record if isinstance(record, dict) else {}


def recorded_in_sweep(job_dir: Path, sweep: int | None) -> bool:
    """Whether the job dir's status.json says it is a job of sweep number `sweep`; a failed
    job whose dir does not (it could not be made, or holds an earlier sweep's status) is
    kept in the sweep's record instead (`end_sweep`'s `unrecorded`)."""
    status = read_status(job_dir)
    return status.state != UNKNOWN and status.sweep == sweep


def current_sweep(sweep_dir: Path) -> int | None:
    """The number of the last sweep into `sweep_dir`; None when none was numbered (or the
    file is damaged: then every job counts)."""
    number = _sweep_record(sweep_dir).get("sweep")
    return number if isinstance(number, int) and not isinstance(number, bool) else None


def sweep_finished(sweep_dir: Path) -> bool:
    """False when the last sweep into `sweep_dir` began but its launcher never returned (it
    was stopped, or runs still): jobs it had not started are in no table."""
    return _sweep_record(sweep_dir).get("finished") is not False


def sweep_jobs(sweep_dir: Path) -> tuple[list[Path], list[Path]]:
    """(the jobs of the last sweep into `sweep_dir`, job dirs earlier sweeps left there).
    A job with no readable status.json counts as the last sweep's (it may have been killed
    before writing one) unless it was so before the sweep began and the sweep has not
    begun a job in it."""
    jobs, number = job_dirs(sweep_dir), current_sweep(sweep_dir)
    if number is None:
        return jobs, []
    statuses = {j: read_status(j) for j in jobs}
    unreadable_before = _sweep_record(sweep_dir).get("unreadable_before")
    if not isinstance(unreadable_before, dict):
        unreadable_before = {}

    def left_before(j: Path) -> bool:
        if statuses[j].state != UNKNOWN:
            return statuses[j].sweep != number
        version = unreadable_before.get(_relative(j, sweep_dir))
        return version is not None and version == _file_version(Path(j) / HYDRA_FILES[-1])

    stale = [j for j in jobs if left_before(j)]
    return [j for j in jobs if j not in stale], stale
