"""`python -m pipeline [overrides]`: the Hydra app that runs the BIRL-G pipeline stages.

Errors are one line and exit status 2: our own (PipelineError), Hydra's (a typo, a wrong
type, a bad override: Hydra's wording, first line only) and anything unexpected.
`HYDRA_FULL_ERROR=1` shows the full traceback instead. Ctrl-C is one line too
(`interrupted by the user at stage X`) and exit status 130 (SIGTERM: 143, SIGHUP: 129),
whenever it comes.

The command line is read before anything is created: flags after overrides (`seed=1 -m`)
are put first, every override is parsed with Hydra's own grammar (a value that needs quoting
says how), and an explicit run dir is locked under the name Hydra will use.
"""

from __future__ import annotations

import os
import signal
import sys
import threading

from pipeline.errors import (
    restore_handlers,
    stop_quietly_while_starting,
    survive_closed_stdout,
)

# The handlers Python had come back once the imports below are done (cli() then installs
# its own).
_HANDLERS_BEFORE_IMPORTS = stop_quietly_while_starting()

from pipeline.app.scipy_docs import keep_scipy_docstrings

keep_scipy_docstrings()  # before the imports below import scipy: a sixth of their time

import json
import logging
import re
from collections.abc import Iterator
from contextlib import contextmanager, nullcontext, suppress
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.errors import OverrideParseException
from hydra.types import RunMode
from omegaconf import DictConfig

from pipeline.app.config import check_boolean_overrides, one_job_of_a_sweep, register_configs
from pipeline.app.outcome import SweepOutcome, SweepRefused, failed_jobs
from pipeline.app.rundir import (
    METRICS_FILE,
    STOP_SIGNALS,
    FailedJob,
    Interrupted,
    as_interrupted,
    check_not_a_sweep_dir,
    current_sweep,
    error_text,
    ignore_repeat,
    locked,
    read_status,
    recorded_in_sweep,
    stopped_by_signals,
)
from pipeline.errors import PipelineError, not_ignored, one_line, os_error_reason
from pipeline.stages import run_pipeline

register_configs()
if __name__ != "__main__" and Path(sys.argv[0]).name != "birlg":  # imported, not the command:
    restore_handlers(_HANDLERS_BEFORE_IMPORTS)  # (the command keeps them until cli() sets its own)


CONF_DIR = str(Path(__file__).resolve().parent / "conf")  # the package's conf/ (see context)


@hydra.main(version_base="1.3", config_path=CONF_DIR, config_name="config")
def main(cfg: DictConfig) -> float | FailedJob | None:
    guard_log_files()
    hydra_cfg = HydraConfig.get()
    run_dir = Path(hydra_cfg.runtime.output_dir)
    if hydra_cfg.job.chdir:  # input paths are relative to where the run was launched, as
        os.chdir(hydra_cfg.runtime.cwd)  # without it (Hydra restores its cwd after the job)
    if hydra_cfg.mode != RunMode.MULTIRUN:
        if warning := one_job_of_a_sweep(hydra_cfg.sweeper.get("params"),
                                         "add -m to run the sweep"):
            logging.getLogger("pipeline").warning(warning)
        try:
            check_boolean_overrides(cfg, hydra_cfg.overrides.task)
            run_pipeline(cfg, run_dir, group_choices=hydra_cfg.runtime.choices)
        except Exception as e:  # noqa: BLE001 - SystemExit passes through Hydra untouched
            exit_with_one_line(e)
        _Progress.run_ended = True
        return None
    # In a sweep a failing job must not stop the others: its status.json says failed (with
    # the sweep's number, as every job's does), and `make aggregate` reports it in its table
    # and exit status.
    number = current_sweep(Path(hydra_cfg.sweep.dir))
    try:
        check_boolean_overrides(cfg, hydra_cfg.overrides.task)
        run_pipeline(cfg, run_dir, sweep=number, group_choices=hydra_cfg.runtime.choices)
    except Exception as e:  # noqa: BLE001 - any failure of one job, reported per job
        error = error_text(e)
        logging.getLogger("pipeline").error("job failed: %s", error,
                                            exc_info=not isinstance(e, PipelineError))
        if not recorded_in_sweep(run_dir, number):  # (e.g. a read-only job dir)
            SweepOutcome.unrecorded[str(run_dir)] = error
            SweepOutcome.restore_hydra_files(run_dir)
        return FailedJob(error)
    if "evaluate" not in cfg.stages:  # no metrics: nothing to optimise, nor to warn of
        return FailedJob(f"objective {cfg.objective}: the job ran no evaluate stage")
    return objective_value(run_dir, cfg.objective)


def objective_value(run_dir: Path, key: str) -> float | FailedJob:
    """The job's metric for a sweeper that optimises (Optuna); a FailedJob when there is
    none, which such a sweeper records as a failed trial."""
    metrics_path = run_dir / METRICS_FILE
    metrics = json.loads(metrics_path.read_text()) if metrics_path.exists() else {}
    if key not in metrics:
        # e.g. a held-out fraction that held nothing out (one demonstration per start)
        logging.getLogger("pipeline").warning(
            "objective %s: the run wrote no such metric (%s); for the sweeper a failed trial",
            key, metrics_path)
        return FailedJob(f"objective {key}: the run wrote no such metric")
    return float(metrics[key])


MAX_OVERRIDE_CHARS = 5000  # Hydra's parser needs ~4 s for 20,000 characters (a long list)
# What Hydra's grammar takes in a value without quotes (besides letters, digits and spaces)
_PLAIN_VALUE = re.compile(r"[A-Za-z0-9_\-+./:\\*%@$ ]*")


def shorten(text: str, limit: int = 120) -> str:
    """`text` cut to about `limit` characters, saying how long it was: a value can be 20,000
    numbers long, an error line must stay readable."""
    return text if len(text) <= limit else f"{text[:limit - 20]}... ({len(text):,} characters)"


def quoting_hint(override: str) -> str:
    """How to pass a value Hydra's grammar does not take unquoted (non-ASCII letters, `=`,
    `~`, `#`, ...): quoted for Hydra, and the quotes kept from the shell."""
    key, _, value = override.partition("=")
    if not value or value[:1] in "'\"" or _PLAIN_VALUE.fullmatch(value) \
            or any(c in value for c in "[]{}(),"):  # a list or a sweep: a syntax error
        return ""
    return (f"; quote such a value for Hydra and keep the quotes from the shell: "
            f"'{key}=\"{shorten(value, 60)}\"'")


def parse_command_line(argv: list[str]) -> tuple[list[str], list, bool]:
    """(argv with Hydra's flags before the overrides, the parsed overrides, multirun?).

    Hydra's argument parser takes flags only before the overrides (`seed=1 -m` was an 8-line
    usage message); its override grammar would reject a bad override only after the run dir
    exists. Both are applied here first, so a bad command line is one line and creates
    nothing.
    """
    from hydra._internal.utils import get_args_parser  # the parser hydra.main itself uses

    parser = get_args_parser()

    def refuse(message: str) -> None:
        raise PipelineError(f"{message} (see birlg --help)")

    parser.error = refuse  # type: ignore[method-assign]
    args = parser.parse_intermixed_args(argv)
    overrides = list(args.overrides)
    for text in overrides:
        if len(text) > MAX_OVERRIDE_CHARS:
            raise PipelineError(f"override {shorten(text, 60)!r} is {len(text):,} characters "
                                f"long, more than {MAX_OVERRIDE_CHARS:,}: no setting needs "
                                "that many; put long lists in a config file (conf/)")
    flags = [a for a in argv if a not in overrides]
    try:
        parsed = OverridesParser.create().parse_overrides(overrides)
    except OverrideParseException as e:
        detail = (str(e).splitlines() or ["syntax error"])[0]
        text = e.override or ""
        if "=" not in text and not text.startswith("~"):
            detail = f"an override is key=value (e.g. {shorten(text, 40)}=VALUE)"
        elif text.count('"') % 2 or text.count("'") % 2:
            detail = "a quote is not closed"
        elif detail.startswith("LexerNoViableAltException"):  # ANTLR's name for it
            detail = "it holds a character Hydra's grammar does not take unquoted"
        raise PipelineError(f"cannot parse override {shorten(e.override, 80)!r}: "
                            f"{shorten(detail, 160)}{quoting_hint(e.override)}") from None
    for text, override in zip(overrides, parsed, strict=True):
        if not override.key_or_group:
            raise PipelineError(f"override {shorten(text, 80)!r} has no key: write key=value "
                                "(see birlg --help)")
        check_range_sweep(text, override)
    return flags + overrides, parsed, bool(args.multirun)


def check_range_sweep(text: str, override) -> None:
    """A `range(start, stop, step)` sweep with step 0 (Python's range error, as a bug line,
    after the sweep had begun) or over no value (a sweep of no job, exit 0) is refused."""
    from hydra.core.override_parser.types import RangeSweep

    sweep = override.value() if override.is_sweep_override() else None
    if not isinstance(sweep, RangeSweep):
        return
    if sweep.step == 0:
        raise PipelineError(f"override {shorten(text, 80)!r}: a range's step must not be 0")
    if (sweep.stop - sweep.start) / sweep.step <= 0:
        raise PipelineError(f"override {shorten(text, 80)!r} sweeps over no value (range("
                            "start, stop) runs from start up to, not including, stop)")


def explicit_run_dir(parsed: list, multirun: bool) -> Path | None:
    """The run dir given on the command line (hydra.run.dir=, also with + or ++), as Hydra
    reads it (quotes and escapes resolved), for a single run; None for sweeps, default dirs
    (those carry microseconds) and dirs made of interpolations (`${now:...}`)."""
    for override in parsed:  # an empty dir is the working directory: the repo's own root
        if override.key_or_group in ("hydra.run.dir", "hydra.sweep.dir") \
                and not override.is_sweep_override() and override.value() in ("", None):
            raise PipelineError(f"config error: {override.key_or_group} is empty; give a "
                                "directory for the artefacts, or leave it out for a new one")
    if multirun:
        return None
    for override in parsed:
        if override.key_or_group == "hydra.run.dir" and not override.is_sweep_override():
            value = override.value()
            if isinstance(value, str) and value and "${" not in value:
                return Path(value)
    return None


@contextmanager
def mode_from_the_command_line(parsed: list, flags: list[str]) -> Iterator[None]:
    """Hydra composes the whole config once only to read `hydra.mode`, then again to run
    (0.2-0.3 s each). No config of this package sets hydra.mode (tests/cli/test_cli.py
    checks), so unless the command line can (a hydra.mode override, an experiment preset
    that is not one of the package's, another config dir, path, search path or name)
    Hydra's answer is known: None, `-m` decides."""
    def may_set_mode(o) -> bool:
        key = o.key_or_group
        return key.startswith(("hydra.mode", "hydra.searchpath")) or \
            (key == "experiment" and not _preset_without_mode(o))

    if any(may_set_mode(o) for o in parsed) \
            or any(f.startswith(("--config", "-c")) for f in flags):
        yield
        return
    from hydra._internal.hydra import Hydra  # the method hydra.main calls

    real = Hydra.get_mode
    Hydra.get_mode = lambda self, config_name, overrides: None  # type: ignore[method-assign]
    try:
        yield
    finally:
        Hydra.get_mode = real  # type: ignore[method-assign]


def _preset_without_mode(override) -> bool:
    """`experiment=NAME` names a preset of the package's conf/experiment/ whose text sets no
    `mode` (tests/cli/test_cli.py checks that none sets hydra.mode): a sweep of a preset
    (`make sweep`) needs no extra composition either."""
    if override.is_sweep_override() or override.is_delete():
        return False
    name = override.value()
    path = Path(CONF_DIR) / "experiment" / f"{name}.yaml"
    if not isinstance(name, str) or "/" in name or not path.is_file():
        return False
    return re.search(r"^\s*mode\s*:", path.read_text(), re.MULTILINE) is None


class LogFiles:
    """Log files that could not be written (e.g. the disk is full), for the run's last line."""

    failed: list[str] = []


def guard_log_files(root: logging.Logger | None = None) -> None:
    """A log file (of the root logger, where Hydra puts birlg.log) that cannot be written is
    dropped with a note instead of printing Python's `--- Logging error ---` traceback for
    every record (68 lines on a full disk)."""
    root = root or logging.getLogger()
    for handler in list(root.handlers):
        if not isinstance(handler, logging.FileHandler):
            continue

        def handle_error(record: logging.LogRecord, h: logging.FileHandler = handler) -> None:
            error = sys.exc_info()[1]
            reason = os_error_reason(error) if isinstance(error, OSError) else repr(error)
            LogFiles.failed.append(f"{h.baseFilename}: {reason}")
            root.removeHandler(h)
            try:
                h.close()
            except OSError:
                pass

        handler.handleError = handle_error  # type: ignore[method-assign]


def preset_key_error(text: str) -> str | None:
    """A preset (`experiment=quick`) setting a key the chosen option has not (quick's
    birl.alternatives with birl=fixed): Hydra names the file and the key on separate lines."""
    found = re.match(r"In '(\w+)/([\w.-]+)': ConfigKeyError.*?full_key: ([\w.]+).*?"
                     r"object_type=(\w+)", text, re.S)
    if found is None:
        return None
    group, option, key, schema = found.groups()
    section = key.split(".")[0]
    return (f"config error: {group}={option} sets {key}, which the chosen {section} option "
            f"({schema}) does not have; leave out {group}={option} or choose another {section}")


def exit_with_one_line(e: Exception) -> None:
    if _show_tracebacks[0]:
        raise e
    if isinstance(e, PipelineError):
        message = str(e)
    elif type(e).__module__.startswith(("hydra", "omegaconf")):
        message = preset_key_error(str(e)) or one_line(e)
    elif isinstance(e, ValueError) and raised_in(e).startswith("hydra."):
        # Hydra's own check of its flags (--cfg with -m, --shell-completion without a verb)
        message = f"command line: {one_line(e)} (birlg --help)"
    elif isinstance(e, OSError):  # e.g. Hydra creating a run dir where a file is
        message = f"cannot create or write files: {os_error_reason(e)}"
    elif (plugin := raised_by_a_plugin(e)) is not None:  # a launcher's or sweeper's own check
        if plugin == "optuna" and "No trials are completed" in str(e):
            message = (f"{one_line(e)} (said by optuna: every trial failed or wrote no "
                       "`objective` metric, the log names which; there is no policy loss "
                       "without true weights (expert=file, planner or none): e.g. "
                       "objective=heldout_log_likelihood with evaluate.holdout=0.3)")
        else:
            message = (f"{one_line(e)} (said by {plugin} while sweeping: check the "
                       "hydra.launcher and hydra.sweeper settings)")
    else:  # a bug, not bad input: still one line, with the way to the traceback
        message = f"{type(e).__name__}: {one_line(e)} (HYDRA_FULL_ERROR=1 shows the traceback)"
    print(f"error: {shorten_values(message)}", file=sys.stderr)
    also_in_log_file(f"error: {shorten_values(message)}")
    sys.exit(2)


def also_in_log_file(line: str) -> None:
    """The command's last line, said on stderr, also at the end of the run's log file
    (birlg.log), which otherwise stopped at the last progress line of a run that failed or
    was stopped. Not through the logger: its console handler would say it twice. Not for a
    sweep: its handlers may still hold a finished job's log, and each job's status.json
    says how it ended."""
    if SweepOutcome.sweep_dir is not None or _Progress.multirun:
        return
    record = logging.LogRecord("pipeline", logging.ERROR, __file__, 0, line, None, None)
    # a log that cannot be written (the disk is full): stderr has said it. A handler does not
    # raise but prints "--- Logging error ---" and a traceback, unless told not to
    raising, logging.raiseExceptions = logging.raiseExceptions, False
    try:
        for handler in logging.getLogger().handlers:
            if isinstance(handler, logging.FileHandler):
                with suppress(Exception):
                    handler.handle(record)
                    handler.flush()
    finally:
        logging.raiseExceptions = raising


# Packages a sweep hands its settings to (Hydra's launcher and sweeper plugins, what they
# drive): what they raise is their check of those settings (joblib's n_jobs=0, submitit's
# Slurm launcher where there is no srun), not a bug of this package.
SWEEP_PLUGINS = ("hydra_plugins", "joblib", "submitit", "optuna")


def raised_in(e: BaseException) -> str:
    """The module where `e` was raised (its innermost frame's), or ''."""
    tb = e.__traceback__
    while tb is not None and tb.tb_next is not None:
        tb = tb.tb_next
    return tb.tb_frame.f_globals.get("__name__", "") if tb is not None else ""


def raised_by_a_plugin(e: BaseException) -> str | None:
    """The top-level package of the sweep plugin where `e` was raised, or None."""
    module = raised_in(e)
    package = module.split(".")[0]
    if package in SWEEP_PLUGINS and not module.startswith("hydra_plugins.birlg_"):
        return module.split(".")[1] if package == "hydra_plugins" else package
    return None


def shorten_values(message: str) -> str:
    """The message with every very long word or list of many items (a value echoed whole:
    thousands of start indices) cut (`shorten`)."""
    if len(message) <= 400:
        return message
    message = re.sub(r"\S{200,}", lambda m: shorten(m.group(0), 120), message)
    return re.sub(r"(?:[^\s,\[\]]+, ){30,}[^\s,\[\]]+", lambda m: shorten(m.group(0), 120),
                  message)


_show_tracebacks = [False]  # HYDRA_FULL_ERROR=1 as the user set it


def cli() -> None:
    user_setting = os.environ.get("HYDRA_FULL_ERROR")
    _show_tracebacks[0] = user_setting == "1"
    os.environ["HYDRA_FULL_ERROR"] = "1"  # Hydra raises instead of printing; we print one line
    SweepOutcome.failed.clear()
    SweepOutcome.sweep_dir, SweepOutcome.ended, _Progress.run_ended = None, False, False
    multirun = _Progress.multirun = "-m" in sys.argv[1:] or "--multirun" in sys.argv[1:]
    if is_the_command():  # what a signal does once the work is over (and until it begins)
        for signum in not_ignored(STOP_SIGNALS):  # SIGHUP under nohup stays ignored
            signal.signal(signum, _exit_stopped)
        survive_closed_stdout()  # before Hydra's log handlers take sys.stdout
    LogFiles.failed.clear()
    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    try:
        argv, parsed, multirun = parse_command_line(sys.argv[1:])
        _Progress.multirun = multirun
        sys.argv[1:] = argv  # flags first: the order Hydra's parser takes
        run_dir = explicit_run_dir(parsed, multirun)
        if run_dir is not None:  # before Hydra writes its .hydra/ there
            check_not_a_sweep_dir(run_dir)
        # Held from before Hydra writes its .hydra/ files until the run ends: a second run
        # into the dir is refused before it touches anything.
        with stopped_by_signals(), \
                locked(run_dir) if run_dir is not None else nullcontext(), \
                mode_from_the_command_line(parsed, argv[:len(argv) - len(parsed)]):
            main()
    except SweepRefused as e:
        exit_with_one_line(e.error)
    except (KeyboardInterrupt, Interrupted, Exception) as e:  # noqa: BLE001 - all but exit
        interrupted = as_interrupted(e, None)
        if interrupted is not None and is_the_command():
            for signum in STOP_SIGNALS:  # the first one counts: a repeat (Ctrl-C pressed
                signal.signal(signum, ignore_repeat)  # again, a second kill) is ignored
        if interrupted is not None and interrupted.stage is None and interrupted.during is None:
            interrupted.during = phase()
        SweepOutcome.stopped(interrupted, why=None if interrupted is not None else one_line(e))
        if interrupted is not None:
            if _show_tracebacks[0]:
                raise
            print(interrupted.describe(), file=sys.stderr)
            also_in_log_file(interrupted.describe())
            if is_the_command():  # the run dirs say interrupted, the lock is the kernel's
                exit_now(interrupted.exit_code, wait_for_threads=False)
            sys.exit(interrupted.exit_code)
        if SweepOutcome.sweep_dir is not None and not _show_tracebacks[0]:
            # e.g. Optuna's "No trials are completed yet" when every trial failed: the
            # failed jobs are the news, the sweeper's complaint about them is the aftermath
            try:
                SweepOutcome.failed[:] = failed_jobs(SweepOutcome.sweep_dir)
            except OSError:  # e.g. a sweep dir whose name is too long: the error says it
                pass
            if SweepOutcome.failed:
                exit_with_failed_jobs(f" (the sweep then stopped: {one_line(e)})")
        exit_with_one_line(e)  # type: ignore[arg-type]
    finally:
        SweepOutcome.release()
        if user_setting is None:
            os.environ.pop("HYDRA_FULL_ERROR", None)
        else:
            os.environ["HYDRA_FULL_ERROR"] = user_setting
        # Hydra's log handlers (console, birlg.log) go with the run: called in a process that
        # goes on (tests, notebooks), later records must not reach a closed stream or file
        for handler in [h for h in root.handlers if h not in handlers]:
            root.removeHandler(handler)
            try:
                handler.close()
            except OSError:
                pass
        for handler in handlers:
            if handler not in root.handlers:
                root.addHandler(handler)
        root.setLevel(level)
    if SweepOutcome.failed:
        exit_with_failed_jobs()
    if LogFiles.failed:
        print(f"warning: the log could not be written ({shorten(LogFiles.failed[0], 200)}); "
              "the run itself completed", file=sys.stderr)
    if is_the_command():
        exit_now()


class _Progress:
    """How far the command got (cli() resets it), for a signal that hits no stage or job."""

    multirun = False  # -m: a sweep
    run_ended = False  # the single run's stages are over


def phase() -> str | None:
    """Where a signal that hit no stage and no sweep job stopped the command, as
    Interrupted.describe says it (None: before the first stage)."""
    if SweepOutcome.ended:
        return "after the sweep's jobs had all ended"
    if SweepOutcome.sweep_dir is not None:
        return "during the sweep"
    if _Progress.multirun:
        return "while starting the sweep (no job had begun)"
    return "after the run had completed" if _Progress.run_ended else None


def _exit_stopped(signum: int, frame: object) -> None:
    """A signal while the command finishes (its runs' files all written: Python's teardown
    is all that is left, a fraction of a second) or before it began: one line, exit
    128 + the signal, without the teardown a second signal could cut into a traceback."""
    print(Interrupted(signum, during=phase()).describe(), file=sys.stderr, flush=True)
    os._exit(128 + signum)


def exit_with_failed_jobs(then: str = "") -> None:
    first = SweepOutcome.failed[0]
    why = SweepOutcome.unrecorded.get(first) or read_status(Path(first)).error
    print(f"error: {len(SweepOutcome.failed)} sweep job(s) failed, first {first}"
          f"{f': {shorten(why, 200)}' if why else ''} (make aggregate lists all){then}",
          file=sys.stderr)
    sys.exit(1)


def is_the_command() -> bool:
    """Whether cli() runs as the process's command (`python -m pipeline`, the `birlg`
    script), not called from a process that goes on (tests, notebooks)."""
    main_module = sys.modules.get("__main__")
    spec = getattr(main_module, "__spec__", None)
    if spec is not None and spec.name == "pipeline.__main__":
        return True
    return Path(sys.argv[0]).name == "birlg"


def exit_now(status: int = 0, wait_for_threads: bool = True) -> None:
    """Exit without Python's teardown (freeing every module and object, ~0.15 s of the
    default run's 2.6 s, during which a signal would end the process without a word): the
    run is over, each artefact closed and renamed and status.json written (RunDir); what
    remains is memory the OS frees and the run dir's lock, which the kernel releases. On
    success only with no other thread alive (one whose work a normal exit would wait for);
    after a stop (`wait_for_threads=False`) no thread is waited for. The standard streams
    and the logging handlers are flushed first."""
    if wait_for_threads and threading.active_count() > 1:
        return
    logging.shutdown()  # flushes and closes the handlers still registered
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed or broken pipe: the normal exit decides
            return
    os._exit(status)


if __name__ == "__main__":
    cli()
