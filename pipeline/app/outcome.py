"""The Hydra callback that tells the command whether a sweep's jobs all completed (apart from
pipeline.app.rundir, which the sweep's table reads without importing Hydra)."""

from __future__ import annotations

import os
import signal
from contextlib import suppress
from pathlib import Path
from typing import Any

from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from pipeline.app.config import check_objective_is_written, check_objective_name
from pipeline.app.rundir import (
    HYDRA_FILES,
    Interrupted,
    abandon_sweep,
    acquire_lock,
    begin_sweep,
    check_not_a_run_dir,
    end_sweep,
    job_dirs,
    mark_started_by_hydra,
    read_status,
    run_files_version,
    stop_sweep,
    sweep_jobs,
)
from pipeline.errors import PipelineError, os_error_reason


class SweepRefused(BaseException):
    """A sweep refused by the callback: Hydra turns a callback's Exception into a warning and
    goes on, so the refusal travels as a BaseException; the command says `error` in one line."""

    def __init__(self, error: PipelineError):
        super().__init__(error)
        self.error = error


def _sweeps(config: DictConfig, key: str) -> bool:
    """Does the sweep set `key` per job (a swept override, or an Optuna search parameter)?
    A plain override is in the config already."""
    task = [str(o) for o in OmegaConf.select(config, "hydra.overrides.task") or []]
    params = OmegaConf.select(config, "hydra.sweeper.params") or {}
    try:
        swept = [o.key_or_group for o in OverridesParser.create().parse_overrides(task)
                 if o.is_sweep_override()]
    except Exception:  # noqa: BLE001 - Hydra reports a malformed override itself
        return True
    return key in swept or key in params


class SweepOutcome(Callback):
    """Hydra callback (conf/config.yaml, hydra.callbacks): locks the sweep dir for the sweep
    (a second sweep into it is refused) and numbers the sweep there before any job runs (so
    its jobs are told apart from an earlier sweep's); after it, lists this sweep's jobs
    whose run dir is not complete, so the command exits non-zero when any job failed."""

    sweep_dir: Path | None = None  # of the last sweep begun in this process
    failed: list[str] = []  # job dirs of the last sweep in this process, read by cli()
    # job dir -> error of jobs that failed where no status.json could say so (their dir could
    # not be made), as the launcher saw them
    unrecorded: dict[str, str] = {}
    ended = False  # on_multirun_end ran: the launcher returned every job
    _lock_fd: int | None = None
    _previous: dict = {}  # the sweep dir's record before this sweep
    _number: int | None = None  # this sweep's
    _versions: dict[Path, tuple] = {}  # job dir -> its run files' version before the sweep
    # job dir this process cannot write in -> its .hydra/ files' bytes before the sweep
    # (Hydra's basic launcher only: `restore_hydra_files`)
    _read_only: dict[Path, dict[str, bytes]] = {}

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        try:  # before any job: a misspelt objective would fail every one of them
            check_objective_name(str(config.objective))
            if not _sweeps(config, "evaluate.holdout"):  # nor one no job writes
                check_objective_is_written(str(config.objective),
                                           OmegaConf.select(config, "evaluate.holdout"))
        except PipelineError as e:
            raise SweepRefused(e) from None
        sweep_dir = Path(config.hydra.sweep.dir)
        launcher = str(config.hydra.launcher.get("_target_", ""))
        try:
            check_not_a_run_dir(sweep_dir)
            if "PoolLauncher" not in launcher:  # it checks every job's resolved run dir
                sweep = OmegaConf.to_container(config.hydra.sweep, resolve=False)
                assert isinstance(sweep, dict)  # hydra.sweep is a section: a mapping
                check_subdir_template(str(sweep["subdir"]))
        except PipelineError as e:
            raise SweepRefused(e) from None
        SweepOutcome.sweep_dir, SweepOutcome.unrecorded = sweep_dir, {}
        try:
            sweep_dir.mkdir(parents=True, exist_ok=True)
        except OSError:  # a sweep dir that cannot be made: the launcher says so in one line
            return
        try:
            SweepOutcome._lock_fd = acquire_lock(sweep_dir, kind="sweep dir", in_use=(
                f"sweep dir {sweep_dir} is in use by another sweep; wait for it to finish, "
                "or choose another hydra.sweep.dir"))
        except PipelineError as e:
            raise SweepRefused(e) from None
        try:
            SweepOutcome._number, SweepOutcome._previous = begin_sweep(sweep_dir)
        except OSError as e:  # e.g. a read-only sweep dir: its jobs could not be told apart
            SweepOutcome.release()
            raise SweepRefused(PipelineError(
                f"cannot use sweep dir {sweep_dir}: {os_error_reason(e)}")) from None
        jobs = job_dirs(sweep_dir)
        SweepOutcome._versions = {j: run_files_version(j) for j in jobs}
        SweepOutcome._read_only = \
            hydra_files_of_read_only_dirs(jobs) if "BasicLauncher" in launcher else {}
        if "joblib" in launcher:
            start_resource_tracker_deaf_to_hangups()
        if "optuna" in str(config.hydra.sweeper.get("_target_", "")):
            log_optuna_like_hydra()

    @classmethod
    def restore_hydra_files(cls, job_dir: Path) -> None:
        """Put back the .hydra/ files of a job dir this process could not write in as they
        were before the sweep. Hydra's basic launcher rewrites them before the job starts
        (a read-only dir may hold a writable .hydra/), and the job then fails on its dir:
        without this the dir would pair this sweep's overrides with an earlier run's
        metrics. (The pool launcher refuses such a dir before Hydra writes anything.)"""
        for name, content in cls._read_only.get(Path(os.path.abspath(job_dir)), {}).items():
            with suppress(OSError):
                (job_dir / name).write_bytes(content)

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        SweepOutcome.failed[:] = failed_jobs(Path(config.hydra.sweep.dir))
        SweepOutcome.ended = True
        SweepOutcome.release()
        try:
            end_sweep(Path(config.hydra.sweep.dir), SweepOutcome.unrecorded)
        except OSError:  # a full disk: the record stays unfinished, the failed jobs say why
            pass

    @staticmethod
    def stopped(interrupted: Interrupted | None = None, why: str | None = None) -> None:
        """The sweep stopped (a signal: `interrupted`; an error, e.g. the sweeper's: `why`):
        a job Hydra had begun (its .hydra/ written) but the signal stopped before it wrote
        its status says interrupted; the dir's record says why it stopped, and one that
        ran no job leaves it as it was; the dir is unlocked."""
        sweep_dir = SweepOutcome.sweep_dir
        if sweep_dir is not None and SweepOutcome._lock_fd is not None:
            if interrupted is not None:
                for job in job_dirs(sweep_dir):
                    with suppress(OSError):
                        mark_started_by_hydra(job, SweepOutcome._versions.get(job),
                                              interrupted.describe(), SweepOutcome._number)
            with suppress(OSError):
                stop_sweep(sweep_dir, interrupted.describe() if interrupted else why)
            abandon_sweep(sweep_dir, SweepOutcome._previous)
        SweepOutcome.release()

    @staticmethod
    def release() -> None:
        if SweepOutcome._lock_fd is not None:
            os.close(SweepOutcome._lock_fd)
            SweepOutcome._lock_fd = None


def failed_jobs(sweep_dir: Path) -> list[str]:
    """The dirs of the last sweep's jobs in `sweep_dir` that did not complete, then those of
    its jobs that failed where no status.json could say so."""
    failed = [str(j) for j in sweep_jobs(sweep_dir)[0] if not read_status(j).complete]
    return failed + [d for d in SweepOutcome.unrecorded if d not in failed]


def start_resource_tracker_deaf_to_hangups() -> None:
    """Start the joblib launcher's resource tracker (loky's) ignoring SIGHUP, as it ignores
    SIGINT and SIGTERM: the terminal closing would end it mid-sweep (the signal goes to the
    whole process group), and its relaunched successor prints tracebacks about resources
    it never knew. An ignored signal stays ignored across the tracker's exec. Its warning
    about the semaphores of workers a signal ended, which it then removes, is silenced
    (after Ctrl-C it came below the command's one line)."""
    from joblib.externals.loky.backend import resource_tracker

    hangup = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    warnings = os.environ.get("PYTHONWARNINGS")
    os.environ["PYTHONWARNINGS"] = f"ignore::UserWarning:{resource_tracker.__name__}"
    try:
        resource_tracker.ensure_running()
    finally:
        signal.signal(signal.SIGHUP, hangup)
        if warnings is None:
            del os.environ["PYTHONWARNINGS"]
        else:
            os.environ["PYTHONWARNINGS"] = warnings


def check_subdir_template(subdir: str) -> None:
    """hydra.sweep.subdir as written, for the launchers that make each job's run dir only
    as the job begins (Hydra's basic launcher of `birlg -m`, joblib, Slurm): a subdir without
    an interpolation is one dir that every job would share, overwriting the one before; an
    absolute one, one with `..` or `.` puts the jobs outside the sweep dir, where no table
    finds them. (Interpolations that happen to agree between jobs are caught only by the
    pool launcher, which resolves them all first.)"""
    parts = Path(subdir).parts
    if Path(subdir).is_absolute() or ".." in parts or not parts:
        raise PipelineError(f"config error: hydra.sweep.subdir={subdir} puts the jobs' run "
                            "dirs outside the sweep dir, or in it; give a relative path below "
                            "it (the default: ${hydra.job.num})")
    if "${" not in subdir:
        raise PipelineError(f"config error: hydra.sweep.subdir={subdir} is one run dir that "
                            "every job of the sweep would share; give a value that differs "
                            "per job (the default: ${hydra.job.num})")


def hydra_files_of_read_only_dirs(dirs: list[Path]) -> dict[Path, dict[str, bytes]]:
    """The .hydra/ files (HYDRA_FILES) of each of `dirs` this process cannot write in, by
    the dir's absolute path (as Hydra names a job's output dir)."""
    saved: dict[Path, dict[str, bytes]] = {}
    effective = os.access in os.supports_effective_ids
    for job_dir in dirs:
        if os.access(job_dir, os.W_OK, effective_ids=effective):
            continue
        files = saved.setdefault(Path(os.path.abspath(job_dir)), {})
        for name in HYDRA_FILES:
            with suppress(OSError):
                files[name] = (job_dir / name).read_bytes()
    return saved


def log_optuna_like_hydra() -> None:
    """Optuna (the tune preset's sweeper) prints its messages on stderr in a format of its
    own; they go through Python's logging instead, formatted and filed like every other line
    of the sweep (stdout and the sweep's log)."""
    try:
        import optuna
    except ImportError:  # the sweeper says so itself, in a moment
        return
    optuna.logging.disable_default_handler()
    optuna.logging.enable_propagation()
