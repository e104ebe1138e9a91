"""The one exception type that the app turns into a single clear line and a non-zero exit."""

import errno
import os
import signal
import stat
import sys
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TextIO


class PipelineError(Exception):
    """A user-facing error: bad config value, malformed input file, missing artefact."""


def file_kind(path: Path) -> str | None:
    """What an existing path is when it is not a regular file ('a directory', 'a named
    pipe', ...), else None: checked before a reader opens a path a user gave, as `/dev/zero`
    is read for ever and opening a named pipe waits for a writer."""
    mode = path.stat().st_mode
    for test, name in ((stat.S_ISREG, None), (stat.S_ISDIR, "a directory"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISFIFO, "a named pipe"), (stat.S_ISSOCK, "a socket")):
        if test(mode):
            return name
    return "not a regular file"


def existing_dir(path: Path, kind: str) -> Path:
    """`path`, or one line saying that the `kind` of dir ("run dir", "sweep dir") a user
    named is not there."""
    if not path.is_dir():
        raise PipelineError(f"{kind} {path} " + ("is not a directory" if path.exists() else
                                                 "not found"))
    return path


def first_line(e: BaseException, limit: int = 200) -> str:
    """The first line of an error's message (its type's name when it has none), cut to
    `limit` characters: a parser's or a library's message can run over many lines."""
    return (str(e).splitlines() or [type(e).__name__])[0][:limit]


def listed(items: Sequence[object], most: int, sep: str = ", ") -> str:
    """The first `most` items joined by `sep`, then "..." when there are more: a message
    names a few culprits on one line, not every one of thousands."""
    return sep.join(map(str, items[:most])) + (f"{sep}..." if len(items) > most else "")


def one_line(e: BaseException) -> str:
    """Hydra's and OmegaConf's messages run over several lines (the key, the object type,
    a hint); the first line of the error and of its cause say what went wrong."""
    def first(x: BaseException) -> str:
        lines = [ln.strip() for ln in str(x).splitlines() if ln.strip()]
        if not lines:
            return type(x).__name__
        # "... raised while composing config:" says what follows on the next line
        return f"{lines[0]} {lines[1]}" if lines[0].endswith(":") and len(lines) > 1 \
            else lines[0]

    line = first(e)
    options = group_options(str(e))
    if options:  # Hydra lists a config group's options on the lines that one_line drops
        line += f" (options: {', '.join(options)})"
    if isinstance(getattr(e, "override", None), str):  # Hydra's override parse errors
        line = f"cannot parse override '{e.override}': {line}"  # type: ignore[attr-defined]
    if e.__cause__ is not None and first(e.__cause__) not in line:
        line += f" ({first(e.__cause__)})"
    return line


def group_options(text: str) -> list[str]:
    """The options Hydra lists under "Available options in 'GROUP':" in an error's text (a
    tab before each), without the base_* configs the options extend (not choices)."""
    lines = text.splitlines()
    start = next((i for i, ln in enumerate(lines) if ln.startswith("Available options in")),
                 None)
    if start is None:
        return []
    options = []
    for ln in lines[start + 1:]:
        if not ln.startswith("\t"):
            break
        options.append(ln.strip())
    return [o for o in options if not o.startswith("base_")]


def os_error_reason(e: OSError) -> str:
    """Why an OSError happened, in words (disk full said plainly), with the file if known."""
    reason = "the disk is full" if e.errno == errno.ENOSPC else (e.strerror or str(e))
    return reason + (f" ({e.filename})" if e.filename else "")


def report(e: PipelineError | OSError, writing: str) -> int:
    """A command-line tool's error as one line on stderr; returns the exit status, 2. An
    OSError (a read-only dir, a full disk) is said as "cannot write `writing`"."""
    if isinstance(e, OSError):
        print(f"error: cannot write {writing}: {os_error_reason(e)}", file=sys.stderr)
    else:
        print(f"error: {e}", file=sys.stderr)
    return 2


class Interrupted(BaseException):
    """The run was stopped by a signal (Ctrl-C is SIGINT): not an error of the run, so a
    BaseException like KeyboardInterrupt, which no `except Exception` swallows."""

    def __init__(self, signum: int, stage: str | None = None, during: str | None = None):
        super().__init__(signum, stage, during)
        self.signum, self.stage, self.during = signum, stage, during

    @property
    def exit_code(self) -> int:
        return 128 + self.signum  # the shell's convention: 130 for SIGINT

    def describe(self) -> str:
        at = f" at stage {self.stage}" if self.stage else \
            f" {self.during}" if self.during else " before the first stage"
        if self.signum == signal.SIGINT:
            return f"interrupted by the user{at}"
        return f"stopped by {signal.Signals(self.signum).name}{at}"

    def __str__(self) -> str:
        return self.describe()


_START_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


def _stopped_while_starting(signum: int, frame: object) -> None:
    for repeat in _START_SIGNALS:  # the first one counts
        signal.signal(repeat, lambda signum, frame: None)
    who = "interrupted by the user" if signum == signal.SIGINT \
        else f"stopped by {signal.Signals(signum).name}"
    print(f"{who} while starting", file=sys.stderr, flush=True)
    os._exit(128 + signum)  # nothing made yet; Python's teardown would let a repeat kill it


def not_ignored(signals: Sequence[int]) -> tuple[int, ...]:
    """Of `signals`, those this process does not ignore: the ones the pipeline may take over.
    One the process was started ignoring stays ignored (`nohup` ignores SIGHUP, so that
    closing the terminal does not stop the work; a shell's background job ignores SIGINT)."""
    return tuple(s for s in signals if signal.getsignal(s) is not signal.SIG_IGN)


def stop_quietly_while_starting() -> dict:
    """A command's Ctrl-C, SIGTERM or SIGHUP during its imports (most of a second) is one
    line and exit status 128 + signal, not a traceback from inside numpy or a silent end.
    Returns the handlers it replaced, for `restore_handlers` once the imports are done."""
    if threading.current_thread() is not threading.main_thread():
        return {}
    return {signum: signal.signal(signum, _stopped_while_starting)
            for signum in not_ignored(_START_SIGNALS)}


def restore_handlers(handlers: dict) -> None:
    for signum, handler in handlers.items():
        signal.signal(signum, handler)


class _ClosedPipeSafe:
    """A command's stdout that outlives its reader: once a pipe's reader has gone
    (`birlg | head -1`, a pager closed), what is written goes to /dev/null instead of raising
    BrokenPipeError inside a stage or a logging handler, which failed the run."""

    def __init__(self, stream: TextIO) -> None:
        self._stream = stream

    def write(self, text: str) -> int:
        try:
            return self._stream.write(text)
        except BrokenPipeError:
            self._to_devnull()
            return len(text)

    def flush(self) -> None:
        try:
            self._stream.flush()
        except BrokenPipeError:
            self._to_devnull()

    def _to_devnull(self) -> None:
        devnull = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(devnull, self._stream.fileno())
        finally:
            os.close(devnull)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


def survive_closed_stdout() -> None:
    """Make the command's sys.stdout a _ClosedPipeSafe (once; commands only: tests and
    notebooks keep theirs)."""
    if sys.stdout is not None and not isinstance(sys.stdout, _ClosedPipeSafe):
        sys.stdout = _ClosedPipeSafe(sys.stdout)
