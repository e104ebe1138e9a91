"""A Hydra launcher for many short jobs: a pool of long-lived worker processes, forked from
the sweep's process once it has imported everything a job needs (`hydra/launcher=pool`,
the presets' default; `hydra/launcher=joblib` is Hydra's joblib launcher as before).

Each job gets the run dir Hydra's launchers give it (SWEEP_DIR/<job number>/, with .hydra/,
its log, status.json, artefacts and metrics.json) and runs through Hydra's own `run_job`;
what it saves is the start-up of each worker (a fresh interpreter importing Hydra, numpy,
scipy and the stages: ~1 s per worker) and time composing configs: Hydra's sweeper
composes every job's config to check the batch before launching it (0.1-0.2 s per job, one
after another), and a launcher composes each again to run it. Here the workers compose each
job's config once, in parallel, all before any job runs (so a batch that does not compose
still fails before anything runs, as with Hydra's check), and the job runs on that config.
Measured on `make sweep EXP=quick` (pipeline/tools/bench.py startup).

The worker processes are forked (POSIX), each serving one job at a time over a pipe: a job's
number goes out, its composed config comes back and goes out again pickled, and so does its
result (Hydra's JobReturn). A job goes to a worker only when that worker is free, so no job
waits in a queue where a stop could not reach it. The sweep's process has one thread when it
forks: a thread there could hold a lock that a worker would then wait on for ever (Python
3.12+ warns of any). numpy's and scipy's OpenBLAS start idle thread pools on import and stop
them in their own fork handlers; start no thread here (test_sweeps counts them at the forks).
A forkserver would not depend on it, but added ~2 s to each sweep.
- A failing job fails alone (pipeline.__main__ writes its status.json and returns a
  FailedJob); so does one whose run dir Hydra cannot make (noted for the sweep's outcome,
  as no status.json can say it). A worker that dies (killed, out of memory) fails its job
  alone too: its status.json says so, a new worker takes its place and the sweep goes on.
- Ctrl-C, SIGTERM or SIGHUP to the sweep's process (pipeline.__main__ turns each into
  Interrupted) stops the sweep: no new job starts, the running ones get the signal, record
  `interrupted` and finish writing, and the command says so in one line. Workers ignore
  Ctrl-C between jobs (other signals end an idle worker), and a worker whose sweep process
  died (killed with -9) stops by itself within a second.
"""

from __future__ import annotations

import importlib
import logging
import multiprocessing
import os
import signal
import threading
import time
from collections.abc import Callable, Sequence
from contextlib import suppress
from multiprocessing.connection import Connection, wait
from pathlib import Path
from typing import Any

from hydra.core.hydra_config import HydraConfig
from hydra.core.utils import (
    JobReturn,
    JobStatus,
    configure_log,
    filter_overrides,
    run_job,
    setup_globals,
)
from hydra.plugins.launcher import Launcher
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig, OmegaConf, open_dict, read_write

from pipeline.app.outcome import SweepOutcome
from pipeline.app.rundir import (
    HYDRA_FILES,
    INTERRUPTED,
    STOP_SIGNALS,
    UNKNOWN,
    FailedJob,
    Interrupted,
    as_interrupted,
    check_writable,
    current_sweep,
    error_text,
    ignore_repeat,
    mark_died,
    mark_ended_before_stages,
    mark_started_by_hydra,
    read_status,
    recorded_in_sweep,
    run_files_version,
    signals_deferred,
    stopped_by_signals,
)
from pipeline.artefacts.topics import STAGES
from pipeline.errors import PipelineError, not_ignored, os_error_reason

log = logging.getLogger(__name__)


class PoolLauncher(Launcher):
    """`n_jobs` forked workers (-1 or 0: one per CPU), each taking the next job when done."""

    def __init__(self, n_jobs: int = 2, **_: Any) -> None:
        if isinstance(n_jobs, bool) or not isinstance(n_jobs, int) or n_jobs < -1:
            raise PipelineError(f"config error: hydra.launcher.n_jobs={n_jobs!r} is not allowed "
                                "(allowed: an integer >= 1, or -1 or 0 for one per CPU)")
        self.n_jobs = n_jobs
        self.config: DictConfig | None = None
        self.task_function: TaskFunction | None = None
        self.hydra_context: HydraContext | None = None

    def setup(self, *, hydra_context: HydraContext, task_function: TaskFunction,
              config: DictConfig) -> None:
        self.config, self.task_function, self.hydra_context = config, task_function, hydra_context
        defer_batch_check(hydra_context)

    def launch(self, job_overrides: Sequence[Sequence[str]],
               initial_job_idx: int) -> Sequence[JobReturn]:
        assert self.config is not None and self.hydra_context is not None
        setup_globals()
        configure_log(self.config.hydra.hydra_logging, self.config.hydra.verbose)
        sweep_dir = Path(str(self.config.hydra.sweep.dir))
        sweep_dir.mkdir(parents=True, exist_ok=True)
        n_workers = max(1, min(self.n_jobs if self.n_jobs > 0 else os.cpu_count() or 1,
                               len(job_overrides)))
        log.info("Pool of %d worker(s) is launching %d jobs", n_workers, len(job_overrides))
        log.info("Launching jobs, sweep output dir : %s", sweep_dir)
        jobs = [(initial_job_idx + k, list(o)) for k, o in enumerate(job_overrides)]
        for idx, overrides in jobs:
            log.info("\t#%d : %s", idx, " ".join(filter_overrides(overrides)))
        _Current.launcher, _Current.jobs = self, dict(jobs)
        if n_workers == 1:  # no fork: one job after another in this process
            return self._one_by_one(jobs, sweep_dir)
        pool: _Pool | None = None
        try:
            for stage in STAGES:  # imported once here, shared by every forked worker
                importlib.import_module(f"pipeline.stages.{stage}")
            with signals_deferred():  # a signal now comes after the forks, not inside one
                pool = _Pool(n_workers)
            composed = pool.run("compose", [(idx, None) for idx, _ in jobs],
                                on_death=lambda idx, payload, exit_code: None)
            for (idx, overrides) in jobs:
                if composed[idx] is None:  # compose it here: its error, as Hydra's raises it
                    composed[idx] = self.compose(overrides)
            runs = [(idx, composed[idx]) for idx, _ in jobs]
            refuse_misplaced_job_dirs(runs, sweep_dir)
            returns = pool.run("execute", runs, on_death=self._died)
            return [_noted(returns[idx], idx, cfg) for idx, cfg in runs]
        except (KeyboardInterrupt, Interrupted) as e:
            raise _sweep_stopped(e, pool.executed if pool else 0, len(jobs)) from None
        finally:
            if pool is not None:
                pool.close()

    def _one_by_one(self, jobs: list[tuple[int, list[str]]],
                    sweep_dir: Path) -> list[JobReturn]:
        returns: list[JobReturn] = []
        try:
            runs = [(idx, self.compose(overrides)) for idx, overrides in jobs]
            refuse_misplaced_job_dirs(runs, sweep_dir)
            for idx, cfg in runs:
                returns.append(_noted(_execute_or_fail(self, idx, cfg), idx, cfg))
        except (KeyboardInterrupt, Interrupted) as e:
            raise _sweep_stopped(e, len(returns), len(jobs)) from None
        return returns

    def _died(self, idx: int, sweep_config: DictConfig, exit_code: int | None) -> JobReturn:
        """The return of job idx whose worker died: its status.json says so (unless the job
        had recorded its own end), and the sweep's outcome counts it as failed."""
        how = f"killed by {signal.Signals(-exit_code).name}" \
            if exit_code is not None and exit_code < 0 else f"exit status {exit_code}"
        error = f"the worker process running this job died ({how})"
        job_dir = numbered_job_dir(idx, sweep_config)
        try:
            mark_died(job_dir, error, current_sweep(Path(str(sweep_config.hydra.sweep.dir))))
            save_overrides(job_dir, sweep_config)
        except OSError:  # no dir to say it in: the sweep's outcome notes it (_noted)
            pass
        log.error("job #%d failed: %s", idx, error)
        return _failed_return(idx, error)

    def compose(self, overrides: list[str]) -> DictConfig:
        """A job's config, as Hydra's launchers compose it."""
        assert self.config is not None and self.hydra_context is not None
        loader = self.hydra_context.config_loader
        return type(loader).load_sweep_config(loader, self.config, overrides)

    def execute(self, idx: int, sweep_config: DictConfig) -> JobReturn:
        """One job, as Hydra's launchers run it: hydra.job.id/num of its composed config,
        then `run_job` in its run dir."""
        assert self.config is not None and self.hydra_context is not None
        setup_globals()
        job_dir = numbered_job_dir(idx, sweep_config)
        HydraConfig.instance().set_config(sweep_config)
        assert self.task_function is not None
        if job_dir.is_dir():  # e.g. read-only: refused before Hydra rewrites its .hydra/
            check_writable(job_dir)
        return run_job(hydra_context=self.hydra_context, config=sweep_config,
                       task_function=self.task_function, job_dir_key="hydra.sweep.dir",
                       job_subdir_key="hydra.sweep.subdir")


def numbered_job_dir(idx: int, sweep_config: DictConfig) -> Path:
    """Job idx's run dir, as Hydra's run_job makes it (hydra.sweep.dir/subdir, where the
    subdir may name the job's number). The number goes on the job's config, where Hydra's
    launchers put it before run_job (hydra.job.id/num, the same values every time)."""
    # in place: a copy of the config took 9 ms; run_job leaves the config read-only
    with read_write(sweep_config.hydra), open_dict(sweep_config):
        sweep_config.hydra.job.id = f"{sweep_config.hydra.job.name}_{idx}"
        sweep_config.hydra.job.num = idx
    return Path(str(sweep_config.hydra.sweep.dir)) / str(sweep_config.hydra.sweep.subdir)


def save_overrides(job_dir: Path, sweep_config: DictConfig) -> None:
    """The job's overrides where Hydra writes them, if Hydra had not begun the job: its
    failed status then makes a row of the sweep's table with the settings it was for."""
    overrides = job_dir / HYDRA_FILES[-1]
    if not overrides.exists():
        overrides.parent.mkdir(parents=True, exist_ok=True)
        OmegaConf.save(sweep_config.hydra.overrides.task, overrides)


def refuse_misplaced_job_dirs(runs: list[tuple[int, DictConfig]], sweep_dir: Path) -> None:
    """Every job's run dir must lie inside the sweep dir (a hydra.sweep.subdir of `..` or an
    absolute path would scatter the sweep where no table finds it), and two jobs must not
    share one (a subdir without the job's number: they would overwrite each other's .hydra/
    config before either could lock the dir). Refused before any job runs."""
    seen: dict[Path, int] = {}
    inside = sweep_dir.resolve()
    for idx, cfg in runs:
        job_dir = numbered_job_dir(idx, cfg)
        if inside not in job_dir.resolve().parents:
            raise PipelineError(f"config error: job #{idx}'s run dir {job_dir} is not inside "
                                f"the sweep dir {sweep_dir}; give hydra.sweep.subdir a "
                                "relative path below it (the default: ${hydra.job.num})")
        if job_dir in seen:
            raise PipelineError(f"config error: jobs #{seen[job_dir]} and #{idx} of the sweep "
                                f"would share the run dir {job_dir}; give hydra.sweep.subdir "
                                "a value that differs per job (the default: ${hydra.job.num})")
        seen[job_dir] = idx


def _execute_or_fail(launcher: PoolLauncher, idx: int, cfg: DictConfig) -> JobReturn:
    """Job idx run by `launcher`; a failure outside the job's own run (Hydra's run_job making
    its run dir, its log or .hydra/ files: a file where the dir should be, a name too long)
    fails that job alone."""
    try:
        return launcher.execute(idx, cfg)
    except Exception as e:  # noqa: BLE001 - the job's own errors are returned, not raised
        error = (f"cannot set up the job's run dir: {os_error_reason(e)}"
                 if isinstance(e, OSError) else error_text(e))
        log.error("job #%d failed: %s", idx, error)
        return _failed_return(idx, error)


def _noted(job_return: JobReturn, idx: int, cfg: DictConfig) -> JobReturn:
    """The job's return; a failed job whose run dir has no status.json of this sweep to say
    so (the dir could not be made; a job that failed while Hydra started it, beside an
    earlier sweep's status.json) is noted for the sweep's outcome."""
    value = job_return._return_value
    if isinstance(value, FailedJob):
        job_dir = numbered_job_dir(idx, cfg)
        if not recorded_in_sweep(job_dir, current_sweep(Path(str(cfg.hydra.sweep.dir)))):
            SweepOutcome.unrecorded[str(job_dir)] = value.error
    return job_return


def _failed_return(idx: int, error: str) -> JobReturn:
    """A job's return when its worker could not give one: a failed job, as the sweeper and
    pipeline.__main__'s own failed jobs give it (COMPLETED, so the sweep goes on)."""
    return JobReturn(overrides=_Current.jobs[idx], status=JobStatus.COMPLETED,
                     _return_value=FailedJob(error))


def _sweep_stopped(e: BaseException, completed: int, total: int) -> Interrupted:
    stopped = as_interrupted(e, None)
    assert stopped is not None
    return Interrupted(stopped.signum, during=f"during the sweep ({completed} of {total} "
                       "jobs completed; make aggregate lists them)")


class _Current:
    """The launching launcher and its jobs, for the forked workers (nothing is pickled)."""

    launcher: PoolLauncher | None = None
    jobs: dict[int, list[str]] = {}


class _Worker:
    """A forked worker process and the sweep's end of its pipe; `job` is what it runs."""

    def __init__(self) -> None:
        context = multiprocessing.get_context("fork")
        self.conn, child_end = context.Pipe()
        self.process = context.Process(target=_serve, args=(child_end, os.getpid()),
                                       daemon=True)
        self.process.start()
        child_end.close()
        self.job: tuple[int, Any] | None = None

    def send(self, kind: str, idx: int, payload: Any) -> None:
        self.job = (idx, payload)
        self.conn.send((kind, idx, payload))


class _Pool:
    """`n` workers; `run` hands each the next request when it is free and returns the
    replies by job number."""

    STOP_WAIT_S = 60  # after a stop, how long running jobs get to record it

    def __init__(self, n: int) -> None:
        self.workers = [_Worker() for _ in range(n)]
        self.executed = 0  # jobs run to their end (or their worker's)

    def run(self, kind: str, requests: list[tuple[int, Any]],
            on_death: Callable[[int, Any, int | None], Any]) -> dict[int, Any]:
        todo = list(requests)
        replies: dict[int, Any] = {}
        try:
            while todo or any(w.job for w in self.workers):
                # A signal waits while messages go out or come in: one cut short would leave
                # the rest of it in the pipe, read later as the start of the next (the sweep
                # waited for ever on a length read from the middle of a config)
                with signals_deferred():
                    self._hand_out(kind, todo)
                busy = [w for w in self.workers if w.job]
                wait([w.conn for w in busy] + [w.process.sentinel for w in busy])
                with signals_deferred():
                    self._take_replies(kind, busy, replies, on_death)
        except (KeyboardInterrupt, Interrupted) as e:
            stopped = as_interrupted(e, None)
            self._stop(stopped.signum if stopped else signal.SIGINT, kind)
            raise
        return replies

    def _hand_out(self, kind: str, todo: list[tuple[int, Any]]) -> None:
        """The next requests to the free workers."""
        for k in range(len(self.workers)):
            while self.workers[k].job is None and todo:
                request = todo.pop(0)
                try:
                    self.workers[k].send(kind, *request)
                except OSError:  # the worker died since its last reply (a signal of its
                    self.workers[k].job = None  # own): the job never reached it; a new
                    todo.insert(0, request)  # worker takes it
                    self._replace(self.workers[k])

    def _take_replies(self, kind: str, busy: list[_Worker], replies: dict[int, Any],
                      on_death: Callable[[int, Any, int | None], Any]) -> None:
        """The replies that came in, and the jobs of the workers that died."""
        for w in busy:
            assert w.job is not None  # busy: the workers with a job
            reply = _receive(w.conn)
            if reply is not _NOTHING:
                idx = w.job[0]
                w.job = None
                if isinstance(reply, Interrupted):  # a signal to this worker alone
                    reply = _failed_return(idx, reply.describe())
                replies[idx] = reply
                self.executed += kind == "execute"
            elif not w.process.is_alive():
                idx, payload = w.job
                w.job = None
                w.process.join()
                replies[idx] = on_death(idx, payload, w.process.exitcode)
                self.executed += kind == "execute"
                self._replace(w)

    def _replace(self, worker: _Worker) -> None:
        """A new worker in the place of one that died."""
        worker.process.join()
        worker.conn.close()
        with signals_deferred():
            self.workers[self.workers.index(worker)] = _Worker()

    def _stop(self, signum: int, kind: str) -> None:
        """The running jobs get the signal (from the terminal they may have had it already:
        they take the first) and record it; a second Ctrl-C here kills them. A job that
        ended before the signal reached it counts as executed: its reply, not Interrupted,
        comes in now (the sweep's last line said 0 of 6 jobs completed with job 0
        complete)."""
        busy = [w for w in self.workers if w.job and w.process.is_alive()]
        for w in busy:
            assert w.process.pid is not None  # started by _Worker()
            os.kill(w.process.pid, signum)
        deadline = time.monotonic() + self.STOP_WAIT_S
        # The first stop set every stop signal to be ignored (a worker's status must not be
        # cut short); here a second Ctrl-C must not: it is the user giving up on a job that
        # does not answer (stuck in a long C call) before STOP_WAIT_S is out.
        in_main = threading.current_thread() is threading.main_thread()
        before = signal.signal(signal.SIGINT, signal.default_int_handler) if in_main else None
        try:
            while busy and time.monotonic() < deadline:
                wait([w.conn for w in busy] + [w.process.sentinel for w in busy],
                     timeout=max(0.0, deadline - time.monotonic()))
                for w in list(busy):
                    reply = _receive(w.conn)
                    if reply is not _NOTHING or not w.process.is_alive():
                        self.executed += kind == "execute" and reply is not _NOTHING \
                            and not isinstance(reply, Interrupted)
                        w.job = None
                        busy.remove(w)
        except KeyboardInterrupt:
            pass
        finally:
            if before is not None:
                signal.signal(signal.SIGINT, before)
        for w in busy:
            w.process.kill()

    def close(self) -> None:
        for w in self.workers:
            if w.process.is_alive() and w.job is None:
                try:
                    w.conn.send(None)
                except OSError:
                    pass
        for w in self.workers:
            w.process.join(5)
            if w.process.is_alive():
                w.process.kill()
                w.process.join()
            w.conn.close()


_NOTHING = object()


def _receive(conn: Connection) -> Any:
    """The worker's reply, or _NOTHING when it has none (yet, or ever: it died)."""
    try:
        return conn.recv() if conn.poll() else _NOTHING
    except (EOFError, OSError):
        return _NOTHING


def _serve(conn: Connection, parent_pid: int) -> None:
    """A worker's life: requests from the pipe until told to stop, or until the sweep's
    process is gone. Ctrl-C is ignored between jobs (the sweep's process decides and
    forwards it); during a job it and SIGTERM stop the job, which records it."""
    # (the fork copied the sweep's process: Hydra's singletons, and its signal handlers)
    signal.signal(signal.SIGINT, ignore_repeat)
    for signum in not_ignored(STOP_SIGNALS[1:]):  # between jobs a worker just ends
        signal.signal(signum, signal.SIG_DFL)  # (under nohup SIGHUP stays ignored)
    threading.Thread(target=_stop_when_orphaned, args=(parent_pid,), daemon=True).start()
    launcher = _Current.launcher
    assert launcher is not None
    while True:
        try:  # other workers hold copies of the sweep's end: its death shows as a new parent
            while not conn.poll(1.0):
                if os.getppid() != parent_pid:
                    return
            request = conn.recv()
        except (EOFError, OSError):
            return
        if request is None:
            return
        kind, idx, payload = request
        if kind == "compose":
            try:
                reply: Any = launcher.compose(_Current.jobs[idx])
            except Exception:  # the parent composes it again to raise the error: some of
                reply = None  # Hydra's exceptions do not survive pickling
            conn.send(reply)
            continue
        job_dir = numbered_job_dir(idx, payload)
        before = run_files_version(job_dir)
        try:
            with stopped_by_signals():
                reply = _execute_or_fail(launcher, idx, payload)
        except (KeyboardInterrupt, Interrupted) as e:
            reply = as_interrupted(e, None)
            with suppress(OSError):  # stopped while Hydra started it: the dir says so
                number = current_sweep(Path(str(payload.hydra.sweep.dir)))
                mark_started_by_hydra(job_dir, before, reply.describe(), number)
                if read_status(job_dir).state == UNKNOWN:  # before Hydra began it
                    mark_ended_before_stages(job_dir, INTERRUPTED, reply.describe(), number)
                    save_overrides(job_dir, payload)
        try:
            conn.send(reply)
        except OSError:  # the sweep's process is gone
            return


def _stop_when_orphaned(parent_pid: int) -> None:
    """SIGTERM to this worker once the sweep's process is gone (killed with -9): a running
    job records `interrupted`, an idle worker ends."""
    while os.getppid() == parent_pid:
        time.sleep(1.0)
    os.kill(os.getpid(), signal.SIGTERM)


def defer_batch_check(hydra_context: HydraContext) -> None:
    """Hydra's sweeper composes every job's config one after another to check a batch
    (`validate_batch_is_legal`, which uses nothing but the errors). The pool launcher
    composes them in its workers, in parallel, before any job runs: so the sweeper's
    composing is turned into a no-op on this loader (launchers compose through the
    class's method)."""
    loader = hydra_context.config_loader

    def checked_by_the_launcher(master_config: DictConfig,
                                sweep_overrides: list[str]) -> None:
        return None

    # a method replaced on the instance, by one that returns nothing: the sweeper's check
    # ignores the composed config (its errors were all it wanted)
    loader.load_sweep_config = checked_by_the_launcher  # type: ignore[method-assign,assignment]
